"""One line of RS-274/NGC text -> a :class:`Line`: its words, parameter assignments, comments and
O-word command, as LinuxCNC reads them.

Outside comments, case and white space do not matter (LinuxCNC removes the blanks and folds the
case before it reads a line, so ``G01 X1 0.5`` is ``g1x10.5``). Comments are ``( ... )`` (no
nesting) and ``;`` to the end of the line; a ``/`` first on the line marks it for block delete; a
line that is only ``%`` frames the program. A word is a letter and a *real value*: a number (no
exponent), an expression ``[...]``, a parameter (``#5``, ``#<name>``, ``##1``, ``#[1+2]``), a unary
function (``sin[30]``, ``atan[1]/[2]``, ``exists[#<x>]``) or a real value with a sign in front
(``-#1``). ``#n = value`` and ``#<name> = value`` set parameters (after the whole line is read, so
the words of the line see the old values). A line may instead carry an O-word command
(``o100 sub``, ``o<name> call [1] [2]``, ``o101 while [#1 lt 3]``, ...) and nothing else but a
line number and comments; a bare ``O1003`` is a Fanuc program number.

Values are kept as floats where they are constant (the fast path of plain CAM lines) and as
expression trees (pmctl.task.rs274.expressions) where they depend on parameters; they are
evaluated when the line is executed. Columns are 1-based in the original text. A malformed line
raises :class:`LexError` with its column.
"""

from __future__ import annotations

import re

from pmctl.task.rs274 import expressions as E

_NUMBER_RE = r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)"
_FAST = re.compile(r"[ \t]*(?:[A-Za-z][ \t]*" + _NUMBER_RE + r"[ \t]*)+")
_FAST_WORD = re.compile(r"([ \t]*)([A-Za-z])([ \t]*)(" + _NUMBER_RE + ")")

O_KEYWORDS = ("sub", "endsub", "call", "return", "if", "elseif", "else", "endif", "while", "endwhile",
              "do", "break", "continue", "repeat", "endrepeat")


class LexError(Exception):
    """A malformed line: ``column`` (1-based, in the original text) and the reason."""

    def __init__(self, message, column=None):
        super().__init__(message)
        self.message, self.column = message, column


class OWord:
    """An O-word command: ``label`` (``"100"`` or ``"<name>"`` lower case), ``keyword``, its
    expression or call arguments (expression trees), and the column of the ``o``."""

    __slots__ = ("label", "keyword", "expr", "args", "column", "number")

    def __init__(self, label, keyword, expr=None, args=(), column=1, number=None):
        self.label, self.keyword, self.expr, self.args, self.column = label, keyword, expr, args, column
        self.number = number          # the label's number for numeric labels (Fanuc O-numbers), else None


class Line:
    """A lexed line. ``words``: (letter, value, column) in order (value: float or expression tree);
    ``assigns``: (target, value, column) with target an int (numbered) or a str (named, lower
    case); ``comments``: (text, column) with the text as written; ``oword``: an :class:`OWord` or
    None; ``delete``: a ``/`` line; ``percent``: a ``%`` line; ``blank``: nothing to execute."""

    __slots__ = ("words", "assigns", "comments", "oword", "delete", "percent", "blank", "grbl")

    def __init__(self):
        self.words = []
        self.assigns = ()                 # a list once there is one (most lines have none)
        self.comments = ()
        self.oword = None
        self.delete = False
        self.percent = False
        self.blank = True
        self.grbl = None                  # a grbl system command ($..., ?): its text


class _Text:
    """The comment-free, blank-free, lower-case text of a line with the original column of each
    character (built only when a line needs more than the fast path)."""

    __slots__ = ("s", "cols", "n")

    def __init__(self, s, cols):
        self.s, self.cols, self.n = s, cols, len(s)

    def col(self, i):
        if i < self.n:
            return self.cols[i]
        return (self.cols[-1] + 1) if self.cols else 1


def lex_line(raw: str) -> Line:
    """Lex one line (no line end). Raises LexError."""
    out = Line()
    # comments first: they may hold anything, and ';' or '(' in them ends nothing
    if "(" in raw or ";" in raw or ")" in raw:
        parts = []                       # the code with every comment blanked out (columns kept)
        i, n = 0, len(raw)
        while True:
            js = [j for j in (raw.find("(", i), raw.find(";", i), raw.find(")", i)) if j >= 0]
            if not js:
                parts.append(raw[i:])
                break
            j = min(js)
            parts.append(raw[i:j])
            ch = raw[j]
            if ch == ";":
                out.comments = list(out.comments) + [(raw[j + 1:], j + 1)]
                break
            if ch == ")":
                raise LexError("')' without '(' before it", j + 1)
            e = raw.find(")", j + 1)
            if e < 0:
                raise LexError("comment '(' is never closed: close it with ')'", j + 1)
            k = raw.find("(", j + 1, e)
            if k >= 0:
                raise LexError("nested '(' inside a comment (comments do not nest)", k + 1)
            out.comments = list(out.comments) + [(raw[j + 1:e], j + 1)]
            parts.append(" " * (e + 1 - j))
            i = e + 1
        code = "".join(parts)
    else:
        code = raw
    body = code.strip()
    if not body:
        return out
    if body[0] == "/":
        out.delete = True
        k = code.index("/")
        code = code[:k] + " " + code[k + 1:]
        body = body[1:].strip()
        if not body:
            return out
    if body == "%":
        out.percent = True
        return out
    if body[0] in "$?":
        out.grbl = body
        return out
    out.blank = False
    if "o" not in code and "O" not in code and _FAST.fullmatch(code):
        # plain words, blanks only between them (the lines CAM writes): columns straight from the text
        words = out.words
        pos = 0
        for lead, letter, gap, num in _FAST_WORD.findall(code):
            pos += len(lead)
            v = float(num)
            if v - v != 0.0:
                raise LexError(_too_big(letter, num), pos + 1)
            words.append((letter.lower(), v, pos + 1))
            pos += 1 + len(gap) + len(num)
        return out
    _Reader(_text(code), out).read()
    return out


def _text(code):
    s, cols = [], []
    for i, ch in enumerate(code):
        if ch in " \t\r\f\v":
            continue
        s.append(ch.lower() if ch.isascii() else ch)
        cols.append(i + 1)
    return _Text("".join(s), cols)


class _Reader:
    """Recursive-descent reader of a line's items (words, assignments, O-word) and expressions."""

    def __init__(self, t: _Text, out: Line):
        self.t, self.s, self.i, self.out = t, t.s, 0, out

    def err(self, msg, i=None):
        return LexError(msg, self.t.col(self.i if i is None else i))

    def read(self):
        s, out = self.s, self.out
        n = len(s)
        # a line number may come before an O-word
        if s.startswith("n"):
            j = 1
            m = re.match(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)", s[1:])
            if m and s[1 + m.end():2 + m.end()] == "o":
                out.words.append(("n", float(m.group(0)), self.t.col(0)))
                self.i = j + m.end()
        if self.i < n and s[self.i] == "o":
            self.oword()
            return
        while self.i < n:
            ch = s[self.i]
            if ch == "#":
                self.assignment()
            elif "a" <= ch <= "z":
                start = self.i
                self.i += 1
                if self.i >= n:
                    raise self.err(f"missing value after '{ch.upper()}'", start)
                if ch == "o":
                    raise self.err("an O-word must be the first word of its line (after an optional N word)",
                                   start)
                v = self.real_value(ch, start)
                out.words.append((ch, v, self.t.col(start)))
            elif ch in "@^":                           # polar coordinates: radius, angle
                start = self.i
                self.i += 1
                if self.i >= n:
                    raise self.err(f"missing value after '{ch}'", start)
                v = self.real_value(ch, start)
                out.words.append((ch, v, self.t.col(start)))
            else:
                raise self.err(f"expected a word letter, got {ch!r}")

    # ---- O-words
    def oword(self):
        s, n = self.s, len(self.s)
        start = self.i
        self.i += 1
        number = None
        if self.i < n and s[self.i] == "<":
            j = s.find(">", self.i)
            if j < 0:
                raise self.err("O-word name '<' is never closed with '>'", self.i)
            label = s[self.i:j + 1]
            if label == "<>":
                raise self.err("empty O-word name", self.i)
            self.i = j + 1
        else:
            m = re.match(r"[0-9]+", s[self.i:])
            if not m:
                raise self.err("an O-word needs a number or a <name> after 'O'", start)
            number = int(m.group(0))
            label = str(number)
            self.i += m.end()
        rest = s[self.i:]
        if not rest:                               # a bare O-number: a Fanuc program number
            self.out.oword = OWord(label, "", column=self.t.col(start), number=number)
            return
        kw = None
        for k in sorted(O_KEYWORDS, key=len, reverse=True):
            if rest.startswith(k):
                kw = k
                break
        if kw is None:
            raise self.err(f"unknown O-word command {rest[:12]!r}: use sub, endsub, call, return, if, elseif, "
                           "else, endif, while, endwhile, do, break, continue, repeat or endrepeat", self.i)
        self.i += len(kw)
        ow = OWord(label, kw, column=self.t.col(start), number=number)
        if kw in ("if", "elseif", "while", "repeat"):
            if self.i >= n or s[self.i] != "[":
                raise self.err(f"O-word {kw} needs an expression [...]")
            ow.expr = self.expression()
        elif kw in ("call",):
            args = []
            while self.i < n:
                if s[self.i] != "[":
                    raise self.err("O-word call arguments are expressions [...]")
                args.append(self.expression())
            ow.args = tuple(args)
        elif kw in ("return", "endsub"):
            if self.i < n:
                if s[self.i] != "[":
                    raise self.err(f"O-word {kw} takes at most one expression [...]")
                ow.expr = self.expression()
        if self.i < n:
            raise self.err(f"nothing but a comment may follow O-word {kw}")
        self.out.oword = ow

    # ---- parameters
    def assignment(self):
        start = self.i
        target = self.param_ref()
        if self.i >= len(self.s) or self.s[self.i] != "=":
            raise self.err("a parameter at the start of an item must be set: #n = value "
                           "(to use its value, put it after a word letter)", start)
        self.i += 1
        v = self.real_value("=")
        self.out.assigns = list(self.out.assigns) + [(target, v, self.t.col(start))]

    def param_ref(self):
        """After '#': an int (numbered, constant), a str (named), or ('#', tree) (computed number)."""
        s = self.s
        self.i += 1                                   # '#'
        if self.i < len(s) and s[self.i] == "<":
            j = s.find(">", self.i)
            if j < 0:
                raise self.err("named parameter '<' is never closed with '>'", self.i)
            name = s[self.i + 1:j]
            if not name:
                raise self.err("empty parameter name #<>", self.i)
            self.i = j + 1
            return name
        if self.i >= len(s):
            raise self.err("missing parameter number after '#'")
        v = self.real_value("#")
        if isinstance(v, float):
            return _param_number(v, self)
        return ("#", v)

    # ---- real values and expressions
    def real_value(self, letter, at=None):  # noqa: C901
        s, n = self.s, len(self.s)
        if self.i >= n:
            raise self.err(f"missing value after '{letter.upper()}'", at)
        ch = s[self.i]
        if ch == "[":
            return self.expression()
        if ch == "#":
            ref = self.param_ref()
            return E.Param(ref)
        if ch in "+-" and self.i + 1 < n and not (s[self.i + 1].isdigit() or s[self.i + 1] == "."):
            self.i += 1
            v = self.real_value(letter)
            if ch == "-":
                return -v if isinstance(v, float) else E.Neg(v)
            return v
        if "a" <= ch <= "z":
            return self.function()
        m = _NUM.match(s, self.i)
        if not m:
            if letter in "=#":
                raise self.err("missing value")
            raise self.err(f"missing value after '{letter.upper()}'", at)
        v = float(m.group(0))
        if v - v != 0.0:
            raise self.err(_too_big(letter if letter.isalpha() else "", m.group(0)), at)
        self.i = m.end()
        return v

    def function(self):
        s = self.s
        start = self.i
        for name in E.FUNCTION_NAMES:
            if s.startswith(name, self.i):
                break
        else:
            m = re.match(r"[a-z]+", s[self.i:])
            raise self.err(f"unknown function or operation {m.group(0)!r}" if m else "bad value", start)
        self.i += len(name)
        if self.i >= len(s) or s[self.i] != "[":
            raise self.err(f"function {name.upper()} needs its argument in [...]")
        if name == "exists":
            self.i += 1
            if not s.startswith("#<", self.i):
                raise self.err("EXISTS takes a named parameter: EXISTS[#<name>]")
            j = s.find(">", self.i)
            if j < 0 or s[j + 1:j + 2] != "]":
                raise self.err("EXISTS takes a named parameter: EXISTS[#<name>]")
            pname = s[self.i + 2:j]
            self.i = j + 2
            return E.Exists(pname)
        arg = self.expression()
        if name == "atan":
            if s[self.i:self.i + 2] != "/[":
                raise self.err("ATAN takes two arguments: ATAN[y]/[x]")
            self.i += 1
            arg2 = self.expression()
            return E.Func("atan", (arg, arg2), self.t.col(start))
        return E.Func(name, (arg,), self.t.col(start))

    def expression(self):
        """'[' value (op value)* ']' with LinuxCNC's precedence (left associative at each level)."""
        s = self.s
        start = self.i
        self.i += 1                                   # '['
        values = [self.real_value("[")]
        ops = []
        while True:
            if self.i >= len(s):
                raise self.err("expression '[' is never closed with ']'", start)
            if s[self.i] == "]":
                self.i += 1
                break
            op = None
            for name in E.OPERATORS:
                if s.startswith(name, self.i):
                    op = name
                    break
            if op is None:
                raise self.err(f"expected an operation or ']' in the expression, got {s[self.i]!r}")
            self.i += len(op)
            ops.append((op, self.t.col(self.i - len(op))))
            values.append(self.real_value(op))
        return E.build(values, ops)


_NUM = re.compile(r"[-+]?(?:[0-9]+\.?[0-9]*|\.[0-9]+)")


def _too_big(letter, text):
    show = text if len(text) <= 24 else text[:20] + "..."
    return f"{letter.upper()}{show} is out of range (not a finite number)"


def _param_number(v, reader):
    k = round(v)
    if abs(v - k) > 1e-4:
        raise reader.err(f"parameter number {v:g} is not an integer")
    if not 1 <= k <= E.MAX_PARAMETER:
        raise reader.err(f"parameter number #{k} is out of range (1 .. {E.MAX_PARAMETER})")
    return int(k)
