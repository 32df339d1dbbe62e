"""Expressions and functions of RS-274/NGC, with LinuxCNC's meaning.

Binary operations, by precedence (high to low; left to right within a level, ``2**3**2`` = 64):
``**``; ``*`` ``/`` ``MOD``; ``+`` ``-``; ``EQ NE GT GE LT LE`` (1.0 or 0.0); ``AND OR XOR``
(non-zero is true). ``MOD`` is the floating remainder made non-negative for a positive divisor
(``-7 MOD 3`` = 2, ``7 MOD -3`` = 1, as LinuxCNC). Functions take degrees and give degrees:
``SIN COS TAN ASIN ACOS ATAN[y]/[x] ABS EXP LN SQRT ROUND`` (half away from zero) ``FIX`` (floor)
``FUP`` (ceiling) ``EXISTS[#<name>]``. A division by zero, a root of a negative number, the
logarithm of a number <= 0, an arc sine or cosine out of [-1, 1] and a value that is not finite are
errors (:class:`EvalError`), never a silent NaN.

A tree node evaluates with ``node.ev(ctx)``; ``ctx.param(ref)`` reads a parameter (``ref``: an int,
a lower-case name, or ``("#", node)`` for ``#[...]``) and ``ctx.exists(name)`` answers EXISTS.
Constant sub-trees are folded to floats when the line is read.
"""

from __future__ import annotations

import math

MAX_PARAMETER = 5602                # LinuxCNC's RS274NGC_MAX_PARAMETERS: #1 .. #5602

# longest first where one is a prefix of another ("**" before "*")
OPERATORS = ("**", "*", "/", "mod", "+", "-", "eq", "ne", "gt", "ge", "lt", "le", "and", "or", "xor")
PRECEDENCE = {"**": 6, "*": 5, "/": 5, "mod": 5, "+": 4, "-": 4, "eq": 3, "ne": 3, "gt": 3, "ge": 3,
              "lt": 3, "le": 3, "and": 2, "or": 2, "xor": 2}
FUNCTION_NAMES = ("abs", "acos", "asin", "atan", "cos", "exists", "exp", "fix", "fup", "ln", "round", "sin",
                  "sqrt", "tan")


class EvalError(Exception):
    def __init__(self, message, column=None):
        super().__init__(message)
        self.message, self.column = message, column


def _finite(v, what, column):
    if not math.isfinite(v):
        raise EvalError(f"{what} is not a finite number", column)
    return v


def binary(op, a, b, column=None):
    if op == "+":
        v = a + b
    elif op == "-":
        v = a - b
    elif op == "*":
        v = a * b
    elif op == "/":
        if b == 0.0:
            raise EvalError("division by zero in an expression", column)
        v = a / b
    elif op == "mod":
        if b == 0.0:
            raise EvalError("MOD by zero in an expression", column)
        v = math.fmod(a, b)
        if v < 0.0:
            v += abs(b)
    elif op == "**":
        if a < 0.0 and b != math.floor(b):
            raise EvalError(f"{a:g} ** {b:g}: a negative number to a non-integer power", column)
        if a == 0.0 and b < 0.0:
            raise EvalError("0 ** a negative power (division by zero)", column)
        try:
            v = a ** b
        except OverflowError:
            raise EvalError(f"{a:g} ** {b:g} overflows", column) from None
    elif op == "eq":
        v = 1.0 if a == b else 0.0
    elif op == "ne":
        v = 1.0 if a != b else 0.0
    elif op == "gt":
        v = 1.0 if a > b else 0.0
    elif op == "ge":
        v = 1.0 if a >= b else 0.0
    elif op == "lt":
        v = 1.0 if a < b else 0.0
    elif op == "le":
        v = 1.0 if a <= b else 0.0
    elif op == "and":
        v = 1.0 if (a != 0.0 and b != 0.0) else 0.0
    elif op == "or":
        v = 1.0 if (a != 0.0 or b != 0.0) else 0.0
    elif op == "xor":
        v = 1.0 if ((a != 0.0) != (b != 0.0)) else 0.0
    else:                                   # pragma: no cover - the reader only makes the above
        raise EvalError(f"unknown operation {op}", column)
    return _finite(v, f"the result of {op.upper()}", column)


def function(name, args, column=None):
    a = args[0]
    if name == "abs":
        v = abs(a)
    elif name == "acos":
        if not -1.0 <= a <= 1.0:
            raise EvalError(f"ACOS[{a:g}]: the argument must be within -1 .. 1", column)
        v = math.degrees(math.acos(a))
    elif name == "asin":
        if not -1.0 <= a <= 1.0:
            raise EvalError(f"ASIN[{a:g}]: the argument must be within -1 .. 1", column)
        v = math.degrees(math.asin(a))
    elif name == "atan":
        v = math.degrees(math.atan2(a, args[1]))
    elif name == "cos":
        v = math.cos(math.radians(a))
    elif name == "sin":
        v = math.sin(math.radians(a))
    elif name == "tan":
        v = math.tan(math.radians(a))
    elif name == "exp":
        try:
            v = math.exp(a)
        except OverflowError:
            raise EvalError(f"EXP[{a:g}] overflows", column) from None
    elif name == "ln":
        if a <= 0.0:
            raise EvalError(f"LN[{a:g}]: the argument must be > 0", column)
        v = math.log(a)
    elif name == "sqrt":
        if a < 0.0:
            raise EvalError(f"SQRT[{a:g}]: the argument must be >= 0", column)
        v = math.sqrt(a)
    elif name == "round":
        v = float(math.floor(a + 0.5)) if a >= 0 else -float(math.floor(-a + 0.5))
    elif name == "fix":
        v = float(math.floor(a))
    elif name == "fup":
        v = float(math.ceil(a))
    else:                                   # pragma: no cover
        raise EvalError(f"unknown function {name}", column)
    return _finite(v, f"{name.upper()}[...]", column)


class Node:
    __slots__ = ()

    def ev(self, ctx):                      # pragma: no cover - abstract
        raise NotImplementedError

    def __neg__(self):
        return Neg(self)


class Param(Node):
    __slots__ = ("ref",)

    def __init__(self, ref):
        self.ref = ref

    def ev(self, ctx):
        return ctx.param(self.ref)


class Exists(Node):
    __slots__ = ("name",)

    def __init__(self, name):
        self.name = name

    def ev(self, ctx):
        return 1.0 if ctx.exists(self.name) else 0.0


class Neg(Node):
    __slots__ = ("a",)

    def __init__(self, a):
        self.a = a

    def ev(self, ctx):
        return -value(self.a, ctx)


class Func(Node):
    __slots__ = ("name", "args", "column")

    def __new__(cls, name, args, column=None):
        if all(isinstance(a, float) for a in args):
            return function(name, args, column)          # constant: folded now (errors at read time)
        return super().__new__(cls)

    def __init__(self, name, args, column=None):
        self.name, self.args, self.column = name, args, column

    def ev(self, ctx):
        return function(self.name, [value(a, ctx) for a in self.args], self.column)


class Bin(Node):
    __slots__ = ("op", "a", "b", "column")

    def __init__(self, op, a, b, column):
        self.op, self.a, self.b, self.column = op, a, b, column

    def ev(self, ctx):
        return binary(self.op, value(self.a, ctx), value(self.b, ctx), self.column)


def value(v, ctx):
    """A word's value: a float as is, a tree evaluated."""
    return v if v.__class__ is float else v.ev(ctx)


def build(values, ops):
    """The tree of ``values[0] ops[0] values[1] ...`` by precedence, left associative; constant
    parts folded (raising EvalError at read time for a constant division by zero and the like)."""
    def make(op, a, b, col):
        if a.__class__ is float and b.__class__ is float:
            return binary(op, a, b, col)
        return Bin(op, a, b, col)

    out = [values[0]]
    stack = []                                  # (op, col)
    for (op, col), v in zip(ops, values[1:]):
        while stack and PRECEDENCE[stack[-1][0]] >= PRECEDENCE[op]:
            o, c = stack.pop()
            b = out.pop()
            a = out.pop()
            out.append(make(o, a, b, c))
        stack.append((op, col))
        out.append(v)
    while stack:
        o, c = stack.pop()
        b = out.pop()
        a = out.pop()
        out.append(make(o, a, b, c))
    return out[0]
