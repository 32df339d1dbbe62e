"""`pmctl` command line. Each subcommand lives in pmctl.interfaces.commands.<name> with
``add_parser(subparsers)`` registering it and setting ``func``; errors become one line on stderr.

Registering must stay light: no module imported while building the parser may import numpy,
scipy or matplotlib at module level (``tests/interfaces/test_cli_help.py`` checks it); heavy work is imported
inside ``func`` or through :func:`lazy`.

Exit status (``main``): 0 done; 1 an error pmctl reports (bad input, config...); 2 usage; a
command's own documented codes (``pmctl run``: 3 controlled stop, 4 fault); 70 internal error
(one line, the traceback only with PMCTL_DEBUG=1); 130 interrupted."""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys
import traceback
import warnings

from pmctl import __version__
from pmctl.core.errors import PmctlError

# Subcommand modules, in the order --help lists them.
COMMANDS = ["run", "check", "post", "serve", "ctl", "init_config", "kin", "analyze", "twin", "calibrate"]


def add_module_parsers(subparsers, modules, hook="add_parser"):
    """Let each module register its own subcommand(s) by calling ``module.<hook>(subparsers)``.
    A module that does not exist yet is skipped; an import error inside one is not hidden."""
    for name in modules:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as e:
            if e.name == name:
                continue
            raise
        getattr(mod, hook)(subparsers)


def lazy(target: str):
    """A subcommand ``func`` that imports ``"package.module:function"`` only when it runs, so
    registering a parser never loads numpy, scipy or matplotlib (``pmctl --help`` stays fast)."""
    mod_name, _, fn_name = target.partition(":")

    def call(args):
        return getattr(importlib.import_module(mod_name), fn_name)(args)
    call.target = target
    return call


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="pmctl",
        description="Controller and digital twin for the 3-RPS + XY-table hybrid milling machine.",
        epilog="Each command has --help. Documentation: README.md and docs/ in the repository "
               "(docs/README.md is the index). Exit status: 0 done, 1 an error pmctl reports (bad input, "
               "config, a refused request), 2 usage (the command's own usage is printed), 70 internal "
               "error, 130 interrupted; pmctl run also 3 (controlled stop) and 4 (fault).")
    p.add_argument("--version", action="version", version=f"pmctl {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    add_module_parsers(sub, [f"pmctl.interfaces.commands.{name}" for name in COMMANDS])
    return p


def _subparser(parser, name):
    """The parser of subcommand ``name`` (None when there is none)."""
    for act in parser._actions:
        if isinstance(act, argparse._SubParsersAction):
            return act.choices.get(name)
    return None


# A value such as "-5,0,173" looks like an option to argparse; glue it to its option.
_NEGATIVE_LIST = re.compile(r"^-\.?\d[\d.eE+-]*(,.*)?$")


def _glue_negative_values(argv):
    out = []
    for tok in argv:
        if out and out[-1].startswith("--") and "=" not in out[-1] and _NEGATIVE_LIST.match(tok):
            out[-1] = f"{out[-1]}={tok}"
        else:
            out.append(tok)
    return out


EXIT_ERROR = 1          # an error pmctl reports: bad input, config, unreachable pose, ...
EXIT_USAGE = 2          # command-line usage (argparse)
EXIT_INTERNAL = 70      # an internal error (a bug): one line; the traceback with PMCTL_DEBUG=1 (EX_SOFTWARE)
EXIT_INTERRUPTED = 130  # Ctrl-C


def _one_line(text: str, limit: int = 2000) -> str:
    text = "; ".join(part.strip() for part in str(text).splitlines() if part.strip())
    return text if len(text) <= limit else text[:limit - 3] + "..."


def main(argv=None) -> int:
    """Run one pmctl command; every outcome ends in at most one line on stderr and an exit status:
    0 done; 1 an error pmctl reports (``PmctlError``: bad input, config, unreachable pose...; a command
    may document its own codes, e.g. ``pmctl run``: 3 controlled stop, 4 fault); 2 usage (argparse);
    70 internal error (any other exception: ``pmctl: internal error: ...``, the traceback only with
    ``PMCTL_DEBUG=1``); 130 interrupted."""
    with warnings.catch_warnings():
        if os.environ.get("PMCTL_DEBUG") != "1":
            # numeric warnings (overflow in a norm of an absurd input...) are not for the operator: the
            # command still ends in its one line; PMCTL_DEBUG=1 shows them
            warnings.simplefilter("ignore", RuntimeWarning)
        return _main(argv)


def _main(argv) -> int:
    try:
        parser = build_parser()
        argv = _glue_negative_values(sys.argv[1:] if argv is None else list(argv))
        args, extra = parser.parse_known_args(argv)
        if extra:                 # an unknown option of a subcommand: that subcommand's usage, not pmctl's
            sub = _subparser(parser, getattr(args, "command", None))
            (sub or parser).error(f"unrecognized arguments: {' '.join(extra)}")
        if not getattr(args, "func", None):
            parser.print_help()
            return EXIT_USAGE
        return int(args.func(args) or 0)
    except PmctlError as e:
        print(f"pmctl: error: {_one_line(e)}", file=sys.stderr)
        return int(getattr(e, "exit_code", EXIT_ERROR))
    except KeyboardInterrupt:
        print("pmctl: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except BrokenPipeError:
        # stdout went away (e.g. piped into `head`): nothing left to say; keep Python from
        # complaining again when it flushes stdout at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return EXIT_ERROR
    except Exception as e:       # noqa: BLE001 -- the last line of defence: never a bare traceback
        if os.environ.get("PMCTL_DEBUG") == "1":
            traceback.print_exc()
        what = "out of memory" if isinstance(e, MemoryError) else f"{type(e).__name__}: {e}"
        print(f"pmctl: internal error: {_one_line(what, 500)}"
              + ("" if os.environ.get("PMCTL_DEBUG") == "1" else " (PMCTL_DEBUG=1 shows the traceback)"),
              file=sys.stderr)
        return EXIT_INTERNAL


if __name__ == "__main__":
    sys.exit(main())
