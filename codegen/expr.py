"""The expression language of scene files: parse, check, evaluate.

Scene files carry formulas as strings (`"A*sin(2*pi*t/T)"`). They are parsed here
with Python's own :mod:`ast` into a small, closed grammar (numbers, names, the
four operations, powers and a fixed list of functions), so that a bad formula is
refused with a precise message before anything runs, without importing sympy.
The compiler (:mod:`codegen.model`) turns the same checked tree into sympy; the
runtime checks a scene's formulas with it and only ever evaluates them
numerically, for start-state checks.
"""

from __future__ import annotations

import ast
import math
from dataclasses import dataclass

#: Functions a formula may call, with their numeric meaning.
FUNCTIONS = {
    "sin": math.sin,
    "cos": math.cos,
    "tan": math.tan,
    "asin": math.asin,
    "acos": math.acos,
    "atan": math.atan,
    "atan2": math.atan2,
    "sinh": math.sinh,
    "cosh": math.cosh,
    "tanh": math.tanh,
    "exp": math.exp,
    "log": math.log,
    "sqrt": math.sqrt,
    "abs": abs,
}
ARITY = {"atan2": 2}
CONSTANTS = {"pi": math.pi}

_BINOPS = {ast.Add: "+", ast.Sub: "-", ast.Mult: "*", ast.Div: "/", ast.Pow: "**"}
_UNARY = {ast.UAdd: "+", ast.USub: "-"}


class ExprError(ValueError):
    """A formula that does not parse or uses something it may not."""


@dataclass(frozen=True)
class Expr:
    """A checked formula: its text, its syntax tree and the names it uses."""

    text: str
    tree: ast.expr
    names: frozenset[str]

    def evaluate(self, values: dict[str, float]) -> float:
        """Numeric value with `values` for the free names (plus `pi`).

        Raises :class:`ExprError` when the value is undefined (``1/0``, ``log(0)``,
        an overflow) or not finite.
        """
        try:
            value = float(_eval(self.tree, {**CONSTANTS, **values}))
        except OverflowError:
            raise ExprError(f"cannot be evaluated: {self.text!r} (a number too large for a float)") from None
        except (ArithmeticError, ValueError) as exc:
            raise ExprError(f"cannot be evaluated: {self.text!r} ({exc})") from None
        if not math.isfinite(value):
            raise ExprError(f"is not finite: {self.text!r} = {value}")
        return value


def parse(text: object, allowed: set[str] | frozenset[str]) -> Expr:
    """Parse `text` and check that it only names `allowed` symbols.

    Numbers (TOML ints and floats) are accepted too and become constant formulas.
    Raises :class:`ExprError` with a one-line reason.
    """
    if isinstance(text, bool) or not isinstance(text, (str, int, float)):
        raise ExprError(f"expected a formula string or a number, got {type(text).__name__}")
    source = repr(float(text)) if not isinstance(text, str) else text.strip()
    if not source:
        raise ExprError("empty formula")
    try:
        tree = ast.parse(source, mode="eval").body
    except SyntaxError as exc:
        raise ExprError(f"does not parse: {source!r} ({exc.msg})") from None
    names: set[str] = set()
    _check(tree, source, names)
    unknown = sorted(names - set(allowed) - set(CONSTANTS))
    if unknown:
        raise ExprError(
            f"unknown symbol{'s' if len(unknown) > 1 else ''} {', '.join(map(repr, unknown))} in {source!r}"
        )
    return Expr(source, tree, frozenset(names - set(CONSTANTS)))


def _check(node: ast.AST, source: str, names: set[str]) -> None:
    if isinstance(node, ast.Constant):
        if isinstance(node.value, bool) or not isinstance(node.value, (int, float)):
            raise ExprError(f"only numbers are allowed as constants in {source!r}")
    elif isinstance(node, ast.Name):
        if node.id in FUNCTIONS:
            raise ExprError(f"function {node.id!r} used without arguments in {source!r}")
        names.add(node.id)
    elif isinstance(node, ast.BinOp) and type(node.op) in _BINOPS:
        _check(node.left, source, names)
        _check(node.right, source, names)
    elif isinstance(node, ast.UnaryOp) and type(node.op) in _UNARY:
        _check(node.operand, source, names)
    elif isinstance(node, ast.Call):
        func = node.func.id if isinstance(node.func, ast.Name) else None
        if func not in FUNCTIONS:
            raise ExprError(
                f"unknown function {ast.unparse(node.func)!r} in {source!r} "
                f"(known: {', '.join(sorted(FUNCTIONS))})"
            )
        if node.keywords or len(node.args) != ARITY.get(func, 1):
            raise ExprError(f"{func} takes {ARITY.get(func, 1)} argument(s) in {source!r}")
        for arg in node.args:
            _check(arg, source, names)
    else:
        what = type(node).__name__
        if isinstance(node, ast.BinOp):
            what = f"operator {type(node.op).__name__}"
        raise ExprError(f"{what} is not allowed in a formula: {source!r} (use + - * / ** and functions)")


def _eval(node: ast.expr, env: dict[str, float]) -> float:
    if isinstance(node, ast.Constant):
        # as a float: Python's whole numbers are exact and unbounded, so 9**9**9**9 would be computed
        # digit by digit (hundreds of millions of them) where a float overflows at once
        return float(node.value)
    if isinstance(node, ast.Name):
        return env[node.id]
    if isinstance(node, ast.UnaryOp):
        value = _eval(node.operand, env)
        return -value if isinstance(node.op, ast.USub) else value
    if isinstance(node, ast.BinOp):
        left, right = _eval(node.left, env), _eval(node.right, env)
        op = _BINOPS[type(node.op)]
        if op == "+":
            return left + right
        if op == "-":
            return left - right
        if op == "*":
            return left * right
        if op == "/":
            return left / right
        return left**right
    assert isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
    return FUNCTIONS[node.func.id](*(_eval(arg, env) for arg in node.args))
