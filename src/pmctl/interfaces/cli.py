"""`pmctl` command line. Each subcommand lives in pmctl.interfaces.commands.<name> with
``add_parser(subparsers)`` registering it and setting ``func``; errors become one line on stderr."""

from __future__ import annotations

import argparse
import importlib
import os
import re
import sys

from pmctl import __version__
from pmctl.core.errors import PmctlError

# Subcommand modules, in the order --help lists them.
COMMANDS = ["run", "serve", "ctl", "kin", "analyze", "twin"]


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


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="pmctl",
        description="Controller and digital twin for the 3-RPS + XY-table hybrid milling machine.")
    p.add_argument("--version", action="version", version=f"pmctl {__version__}")
    sub = p.add_subparsers(dest="command", metavar="COMMAND")
    add_module_parsers(sub, [f"pmctl.interfaces.commands.{name}" for name in COMMANDS])
    return p


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


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(_glue_negative_values(sys.argv[1:] if argv is None else list(argv)))
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except PmctlError as e:
        print(f"pmctl: error: {e}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("pmctl: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # stdout went away (e.g. piped into `head`): nothing left to say; keep Python from
        # complaining again when it flushes stdout at exit
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


if __name__ == "__main__":
    sys.exit(main())
