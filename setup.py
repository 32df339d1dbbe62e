"""Build of the compiled NC core (the C extension pmctl.motion.ncore._ncore), the sim plant's tick and
the loop's compiled path follower (pmctl.motion._follow); everything else is
in pyproject.toml. ``pip install .`` and ``pip install -e .`` both compile it with the machine's C
compiler; without one the install stops and says which compiler it looked for."""

import os
import shlex
import shutil
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

NCORE = "src/pmctl/motion/ncore"


class BuildExt(build_ext):
    """build_ext that names the missing C compiler instead of failing with a bare exec error."""

    def build_extensions(self):
        cc = getattr(self.compiler, "compiler_so", None) or getattr(self.compiler, "compiler", None)
        exe = cc[0] if isinstance(cc, list) and cc else None
        if exe is not None and shutil.which(exe) is None:
            sys.exit(f"error: pmctl needs a C99 compiler to build its compiled NC core ({NCORE}/ncore.c); "
                     f"the C compiler {exe!r} (from CC or Python's build configuration: "
                     f"{shlex.join(cc)}) was not found. Install one (Debian/Ubuntu: apt-get install gcc) "
                     f"or set CC to a C compiler, then install again.")
        try:
            super().build_extensions()
        except Exception as e:     # CompileError, DistutilsExecError, ...
            sys.exit(f"error: building pmctl's compiled NC core ({NCORE}/ncore.c) with {exe!r} failed: {e}")


ext = Extension(
    "pmctl.motion.ncore._ncore",
    sources=[f"{NCORE}/ncore.c", f"{NCORE}/_ncoremodule.c"],
    depends=[f"{NCORE}/ncore.h", f"{NCORE}/pymodule.h"],
    include_dirs=[NCORE],
    extra_compile_args=["-std=c99", "-O2", "-fno-fast-math", "-ffp-contract=off"] if os.name == "posix" else [],
    libraries=["m"] if os.name == "posix" else [],
)

plant = Extension(          # the loopback sim plant's tick (pmctl.hal.sim), with the core's FK
    "pmctl.hal._simplant",
    sources=["src/pmctl/hal/simplant.c", f"{NCORE}/ncore.c"],
    depends=[f"{NCORE}/ncore.h", f"{NCORE}/pymodule.h"],
    include_dirs=[NCORE],
    extra_compile_args=ext.extra_compile_args,
    libraries=ext.libraries,
)

FOLLOW = "src/pmctl/motion/follow"
follow = Extension(         # the loop's path follower (pmctl.motion.timescale.CompiledFollower)
    "pmctl.motion._follow",
    sources=[f"{FOLLOW}/follow.c", f"{FOLLOW}/_followmodule.c"],
    depends=[f"{FOLLOW}/follow.h", f"{NCORE}/pymodule.h"],
    include_dirs=[FOLLOW, NCORE],
    extra_compile_args=ext.extra_compile_args,
    libraries=ext.libraries,
)

setup(ext_modules=[ext, plant, follow], cmdclass={"build_ext": BuildExt})
