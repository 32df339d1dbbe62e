"""O-word flow of control: subroutines (in the file and in external files on a search path), Fanuc
subprograms (``O<n>`` ... ``M99``, called by ``M98 P<n> L<k>``), if/elseif/else/endif,
while/endwhile, do/while, repeat/endrepeat, break, continue, return.

A program file is scanned once for its O-words (:class:`Source`): each structure is matched by its
label (``o100 while`` ... ``o100 endwhile``); a structure that does not close, or a keyword outside
its structure, is a syntax problem found before anything runs. Subroutines are known to the whole
file wherever they are defined (a definition met in the flow is skipped to its ``endsub``); a call to
``o<name>`` not defined in the file looks for ``name.ngc`` on the subroutine search path (LinuxCNC's
SUBROUTINE_PATH; the file holds ``o<name> sub`` ... ``o<name> endsub``).

Numbered Fanuc-style program numbers: a bare ``O1003`` line is a program number (ignored) unless an
``M99`` follows it before the next bare O-number, which makes it a subprogram that the main flow
skips and ``M98 P1003`` calls.
"""

from __future__ import annotations

import re
from pathlib import Path

from pmctl.task.rs274.words import LexError, lex_line

_MAYBE_O = re.compile(r"^\s*(?:/\s*)?(?:[nN]\s*[-+]?[0-9.]+\s*)?[oO]")
_M99 = re.compile(r"[mM]\s*0*99(?![0-9.])")
_COMMENTS = re.compile(r"\([^)]*\)|;.*")


class FlowError(Exception):
    def __init__(self, message, line=None, column=None):
        super().__init__(message)
        self.message, self.line, self.column = message, line, column


class Source:
    """A program file: its lines, lexed on demand, and its O-word structures (0-based indices)."""

    def __init__(self, text: str, path: str, label: str = ""):
        self.path = str(path)
        self.label = label                       # Move.file for its moves ("" for the job itself)
        self.lines = text.split("\n")
        if self.lines and self.lines[-1] == "":
            self.lines.pop()
        self.lexed: dict = {}
        self.problems: list = []                 # FlowError found by the scan
        self.subs: dict = {}                     # label -> (sub index, endsub index)
        self.fanuc: dict = {}                    # number -> (O index, last M99 index)
        self.jump: dict = {}                     # index -> data for the flow (see _scan)
        self.loops: list = []                    # (first, last) index of each sub/loop body: lines run again
        self.scope: dict = {}                    # O-word line index -> the label of the subroutine it is in
        self._scan()
        self.cached = bytearray(len(self.lines))
        for a, b in self.loops:
            self.cached[a:b + 1] = b"\x01" * (b + 1 - a)

    def lex(self, i):
        """Line ``i`` lexed (LexError if malformed). Lines that can run more than once (in a subroutine
        or a loop) are kept lexed; the others are lexed when they run."""
        ln = self.lexed.get(i)
        if ln is None:
            raw = self.lines[i]
            if raw.endswith("\r"):
                raw = raw[:-1]
            ln = lex_line(raw)            # may raise LexError (not cached)
            if self.cached is None or self.cached[i]:
                self.lexed[i] = ln
        return ln

    cached = None                         # during the scan: keep every O-word line

    def _err(self, msg, i, col=None):
        self.problems.append(FlowError(msg, i + 1, col))

    def _scan(self):
        stack = []                               # (keyword, label, index, data)
        bare = []                                # indices of bare O-numbers
        for i, raw in enumerate(self.lines):
            if not _MAYBE_O.match(raw):
                continue
            try:
                ln = self.lex(i)
            except LexError as e:
                self._err(e.message, i, e.column)
                continue
            ow = ln.oword
            if ow is None:
                continue
            kw, label, col = ow.keyword, ow.label, ow.column
            if kw == "":
                bare.append((i, ow.number))
                continue
            # the subroutine a line is in (its labels are its own, as LinuxCNC names them within it)
            self.scope[i] = next((x[1] for x in stack if x[0] == "sub"), None) if kw != "sub" else None
            if kw == "sub":
                if any(s[0] == "sub" for s in stack):
                    self._err(f"o{label} sub inside another subroutine: subroutines do not nest", i, col)
                stack.append(("sub", label, i, None))
            elif kw == "endsub":
                top = self._pop(stack, "sub", label, i, col, "endsub")
                if top is not None:
                    if label in self.subs:
                        self._err(f"subroutine o{label} is defined twice (first at line {self.subs[label][0] + 1})",
                                  top[2], col)
                    else:
                        self.subs[label] = (top[2], i)
                    self.jump[top[2]] = i
                    self.loops.append((top[2], i))
            elif kw == "if":
                stack.append(("if", label, i, [i]))
            elif kw in ("elseif", "else"):
                top = stack[-1] if stack else None
                if top is None or top[0] != "if" or top[1] != label:
                    self._err(f"o{label} {kw} without a matching o{label} if", i, col)
                    continue
                if any(self.lines_kw(j) == "else" for j in top[3]):
                    self._err(f"o{label} {kw} after o{label} else", i, col)
                top[3].append(i)
            elif kw == "endif":
                top = self._pop(stack, "if", label, i, col, "endif")
                if top is not None:
                    chain = top[3] + [i]
                    for j in chain:
                        self.jump[j] = (chain, i)
            elif kw == "while":
                top = stack[-1] if stack else None
                if top is not None and top[0] == "do" and top[1] == label:
                    stack.pop()
                    self._close_loop(top, i, top[2], ("dowhile", top[2]))   # do -> its closing while
                else:
                    stack.append(("while", label, i, []))
            elif kw == "endwhile":
                top = self._pop(stack, "while", label, i, col, "endwhile")
                if top is not None:
                    self._close_loop(top, i, ("while", i), ("endwhile", top[2]))
            elif kw == "do":
                stack.append(("do", label, i, []))
            elif kw == "repeat":
                stack.append(("repeat", label, i, []))
            elif kw == "endrepeat":
                top = self._pop(stack, "repeat", label, i, col, "endrepeat")
                if top is not None:
                    self._close_loop(top, i, ("repeat", i), ("endrepeat", top[2]))
            elif kw in ("break", "continue"):
                loop = next((s for s in reversed(stack) if s[0] in ("while", "do", "repeat") and s[1] == label), None)
                if loop is None:
                    self._err(f"o{label} {kw} outside an o{label} loop (while, do or repeat)", i, col)
                else:
                    loop[3].append(i)
            elif kw == "return":                  # LinuxCNC: returns from the subroutine it is in, whatever its label
                if not any(s[0] == "sub" for s in stack):
                    self._err(f"o{label} return outside a subroutine", i, col)
            # call: nothing to match
        for s in stack:
            closer = {"sub": "endsub", "if": "endif", "while": "endwhile", "do": "while", "repeat": "endrepeat"}[s[0]]
            self._err(f"o{s[1]} {s[0]} is never closed (o{s[1]} {closer} is missing)", s[2])
        # Fanuc subprograms: a bare O-number followed by M99 before the next bare O-number
        for k, (i, number) in enumerate(bare):
            end = bare[k + 1][0] if k + 1 < len(bare) else len(self.lines)
            last = None
            for j in range(i + 1, end):
                if _M99.search(_COMMENTS.sub("", self.lines[j])):
                    last = j
            if last is not None:
                self.fanuc[number] = (i, last)
                self.jump[i] = ("fanuc", last)
                self.loops.append((i, last))

    def lines_kw(self, j):
        ln = self.lexed.get(j)
        return ln.oword.keyword if ln is not None and ln.oword is not None else None

    def _pop(self, stack, want, label, i, col, kw):
        if not stack or stack[-1][0] != want or stack[-1][1] != label:
            opened = next((s for s in reversed(stack) if s[0] == want and s[1] == label), None)
            if opened is None:
                self._err(f"o{label} {kw} without a matching o{label} {want}", i, col)
                return None
            while stack and stack[-1] is not opened:
                s = stack.pop()
                self._err(f"o{s[1]} {s[0]} is not closed before o{label} {kw}", s[2])
        return stack.pop()

    def _close_loop(self, top, end, at_start, at_end):
        """A loop from ``top`` (its opening line) to ``end``: the jumps of both ends, and of its break
        and continue lines."""
        self.jump[top[2]] = at_start
        self.jump[end] = at_end
        self.loops.append((top[2], end))
        for j in top[3]:
            self.jump[j] = (top[0], top[2], end)


class SubroutineFiles:
    """External subroutine files found on the search path, loaded once."""

    def __init__(self, search_path=()):
        self.path = [Path(p) for p in search_path]
        self.cache: dict = {}

    def find(self, name: str):
        """The Source of ``<name>``'s file, or None. ``name`` is the label without <>."""
        if name in self.cache:
            return self.cache[name]
        src = None
        for d in self.path:
            f = d / f"{name}.ngc"
            if f.is_file():
                from pmctl.task.job import read_job_text
                src = Source(read_job_text(f), f, label=str(f))
                break
        self.cache[name] = src
        return src
