"""The tool table: LinuxCNC's ``.tbl`` format (config/tools.tbl).

One tool a line: ``T<number> P<pocket> Z<length offset> D<diameter> ;comment``, words in any
order, blank lines and ``;`` comments allowed. Units are the machine's: mm. On this machine:

- ``Z`` is the tool's **length offset**: how much longer the tool is than the machine config's
  reference tool (``geometry.tool_length_mm``), along the tool axis; ``G43 H<n>`` applies it
  (pmctl.task.job: ``Move.tool_offset``). A tool with ``Z0`` is as long as the reference tool.
- ``D`` is the diameter; cutter radius compensation (``G41``/``G42`` with ``D<n>``) uses half of it.
- ``P`` (pocket) is kept for LinuxCNC compatibility; the tool changer is the operator.
- ``X Y A B C U V W`` offsets and the lathe words ``I J Q`` have no meaning on a mill whose tool
  length lies along its tilting axis; they must be 0 or absent.

A malformed table is a ConfigError naming the file, the line and the word.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

from pmctl.core.errors import ConfigError

MAX_TOOL = 99_999
_WORD = re.compile(r"([A-Za-z])\s*([-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+))")


@dataclass(frozen=True)
class Tool:
    number: int
    pocket: int = 0
    length: float = 0.0          # mm longer than the reference tool (the table's Z)
    diameter: float = 0.0        # mm
    comment: str = ""


class ToolTable:
    """Tools by number. ``source``: where it was read from (named in messages)."""

    def __init__(self, tools=(), source="<none>"):
        self.tools = {t.number: t for t in tools}
        self.source = str(source)

    def get(self, number):
        return self.tools.get(int(number))

    def __contains__(self, number):
        return int(number) in self.tools

    def with_tool(self, tool: Tool) -> "ToolTable":
        """A copy with ``tool`` added or replaced (G10 L1/L10/L11 within a program)."""
        t = ToolTable((), self.source)
        t.tools = dict(self.tools)
        t.tools[tool.number] = tool
        return t

    def __len__(self):
        return len(self.tools)


def parse_tool_table(text: str, source="<string>") -> ToolTable:
    tools = []
    for lineno, raw in enumerate(text.splitlines(), 1):
        body, _, comment = raw.partition(";")
        if not body.strip():
            continue
        words = {}
        pos = 0
        s = body.strip()
        for m in _WORD.finditer(s):
            if s[pos:m.start()].strip():
                raise ConfigError(source, f"line {lineno}", f"cannot read {s[pos:m.start()].strip()!r}: "
                                  "a tool line is words such as T1 P1 Z0 D6")
            k = m.group(1).upper()
            if k in words:
                raise ConfigError(source, f"line {lineno}", f"word {k} appears twice")
            v = float(m.group(2))
            if not math.isfinite(v):
                raise ConfigError(source, f"line {lineno}", f"{k} is not a finite number")
            words[k] = v
            pos = m.end()
        if s[pos:].strip():
            raise ConfigError(source, f"line {lineno}", f"cannot read {s[pos:].strip()!r}: "
                              "a tool line is words such as T1 P1 Z0 D6")
        if "T" not in words:
            raise ConfigError(source, f"line {lineno}", "a tool line needs its number T")
        t = words.pop("T")
        if t != int(t) or not 0 <= t <= MAX_TOOL:
            raise ConfigError(source, f"line {lineno}", f"tool number T{t:g} must be an integer 0 .. {MAX_TOOL}")
        p = words.pop("P", 0.0)
        if p != int(p) or p < 0:
            raise ConfigError(source, f"line {lineno}", f"pocket P{p:g} must be an integer >= 0")
        z = words.pop("Z", 0.0)
        if abs(z) > 1000.0:
            raise ConfigError(source, f"line {lineno}", f"length offset Z{z:g} mm is beyond +-1000 mm")
        d = words.pop("D", 0.0)
        if not 0.0 <= d <= 1000.0:
            raise ConfigError(source, f"line {lineno}", f"diameter D{d:g} mm must be within 0 .. 1000")
        for k, v in words.items():
            if k in "XYABCUVWIJQ":
                if v != 0.0:
                    raise ConfigError(source, f"line {lineno}", f"{k}{v:g}: this machine's tool table holds a length "
                                      "offset (Z) and a diameter (D); offsets in X Y A B C U V W and lathe "
                                      "words I J Q have no meaning here (set them to 0 or leave them out)")
            else:
                raise ConfigError(source, f"line {lineno}", f"unknown word {k} (a tool line has T P Z D and "
                                  "LinuxCNC's X Y A B C U V W I J Q)")
        if int(t) in [x.number for x in tools]:
            raise ConfigError(source, f"line {lineno}", f"tool {int(t)} is listed twice")
        tools.append(Tool(int(t), int(p), float(z), float(d), comment.strip()))
    return ToolTable(tools, source)


def load_tool_table(path) -> ToolTable:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(p, None, "tool table not found (interpreter.tool_table in the service config)") from None
    except (OSError, UnicodeDecodeError) as e:
        raise ConfigError(p, None, f"cannot read the tool table: {e}") from None
    return parse_tool_table(text, p)
