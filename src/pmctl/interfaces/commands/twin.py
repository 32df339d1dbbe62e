"""`pmctl twin ...`: digital-twin tools: diagnose (the report), synth (concealed-effect recordings),
import (bench logs as recordings of independent axes).
Registered by :mod:`pmctl.tools.twin.cli`, which imports no numpy (the tools load when they run)."""

from __future__ import annotations

from pmctl.interfaces.cli import add_module_parsers

TOOLS = ["pmctl.tools.twin.cli"]


def add_parser(sub):
    p = sub.add_parser("twin", help="digital twin: diagnose recordings, synthesise test recordings, import bench logs",
                       description="Where and why does the machine differ from the nominal twin?")
    add_module_parsers(p.add_subparsers(dest="twin_command", metavar="TOOL", required=True), TOOLS)
