"""`pmctl analyze ...`: each analysis module under pmctl.tools.analysis registers its own subcommands
with ``add_parsers(subparsers)``."""

from __future__ import annotations

from pmctl.interfaces.cli import add_module_parsers

ANALYSES = ["pmctl.tools.analysis.mechanism", "pmctl.tools.analysis.vibration", "pmctl.tools.analysis.resonance"]


def add_parser(sub):
    p = sub.add_parser("analyze", help="mechanism and controller analyses (PNG maps + figures)",
                       description="Analyses reproducing the seed documents' figures.")
    add_module_parsers(p.add_subparsers(dest="analysis", metavar="ANALYSIS", required=True),
                       ANALYSES, hook="add_parsers")
