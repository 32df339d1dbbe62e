"""`pmctl analyze ...`: the analyses under pmctl.tools.analysis, registered by
:mod:`pmctl.tools.analysis.cli` (no numpy at import: each analysis loads when it runs)."""

from __future__ import annotations

from pmctl.interfaces.cli import add_module_parsers

ANALYSES = ["pmctl.tools.analysis.cli"]


def add_parser(sub):
    p = sub.add_parser("analyze", help="mechanism and controller analyses (PNG maps + figures)",
                       description="Analyses reproducing the figures of the source reports (Tachiya et al. "
                                   "2006; Kamiya et al. 2005; see docs/README.md). PNGs go to --out.")
    add_module_parsers(p.add_subparsers(dest="analysis", metavar="ANALYSIS", required=True),
                       ANALYSES, hook="add_parsers")
