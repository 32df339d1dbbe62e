"""`pmctl analyze ...`: each analysis module under pmctl.analysis registers its own subcommands
with ``add_parsers(subparsers)``."""

from __future__ import annotations

import importlib

ANALYSES = ["pmctl.analysis.mechanism", "pmctl.analysis.vibration"]


def add_parser(sub):
    p = sub.add_parser("analyze", help="mechanism and controller analyses (PNG maps + figures)",
                       description="Analyses reproducing the seed documents' figures.")
    asub = p.add_subparsers(dest="analysis", metavar="ANALYSIS", required=True)
    for name in ANALYSES:
        try:
            mod = importlib.import_module(name)
        except ModuleNotFoundError as e:
            if e.name == name:
                continue
            raise
        mod.add_parsers(asub)
