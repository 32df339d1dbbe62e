"""`pmctl twin ...`: digital-twin tools. Modules under pmctl.twin register their own subcommands
with ``add_parser(subparsers)``: synth (concealed-effect recordings), diagnose (the report)."""

from __future__ import annotations

import importlib

TOOLS = ["pmctl.twin.diagnose", "pmctl.twin.synth"]


def add_parser(sub):
    p = sub.add_parser("twin", help="digital twin: diagnose recordings, synthesise test recordings",
                       description="Where and why does the machine differ from the nominal twin?")
    tsub = p.add_subparsers(dest="twin_command", metavar="TOOL", required=True)
    for name in TOOLS:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as e:
            if e.name == name:
                continue
            raise
        mod.add_parser(tsub)
