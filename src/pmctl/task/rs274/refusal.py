"""A block's refusal (:class:`Refusal`: syntax / unsupported / machine, with its column) and how the
messages quote G-codes and numbers; shared by the executor, the canned cycles and cutter compensation."""

from __future__ import annotations

import math


class Refusal(Exception):
    """A problem with a block: ``kind`` (syntax / unsupported / machine), message, column."""

    def __init__(self, kind, message, column=None):
        super().__init__(message)
        self.kind, self.message, self.column = kind, message, column


def gname(code: int) -> str:
    """G-code text of a code x 10: 382 -> 'G38.2'."""
    return f"G{code // 10}" + (f".{code % 10}" if code % 10 else "")


def fmt(v: float) -> str:
    return f"{v:.6f}".rstrip("0").rstrip(".") if math.isfinite(v) else str(v)


def whole(value, word, column, what):
    """A word that must be a non-negative integer (a tool number, a line number): its int, or a Refusal
    saying what the word is."""
    if value != int(value) or value < 0:
        raise Refusal("syntax", f"{word}{fmt(value)}: {what} (a non-negative integer)", column)
    return int(value)
