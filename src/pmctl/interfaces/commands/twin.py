"""`pmctl twin ...`: digital-twin tools. Modules under pmctl.tools.twin register their own subcommands
with ``add_parser(subparsers)``: diagnose (the report), synth (concealed-effect recordings)."""

from __future__ import annotations

from pmctl.interfaces.cli import add_module_parsers

TOOLS = ["pmctl.tools.twin.diagnose", "pmctl.tools.twin.synth"]


def add_parser(sub):
    p = sub.add_parser("twin", help="digital twin: diagnose recordings, synthesise test recordings",
                       description="Where and why does the machine differ from the nominal twin?")
    add_module_parsers(p.add_subparsers(dest="twin_command", metavar="TOOL", required=True), TOOLS)
