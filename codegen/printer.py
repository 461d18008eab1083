"""Stage 3a: print one sympy expression as Python text for Numba.

:class:`KernelPrinter` is sympy's Python code printer (``math.sin``, ``math.pi``)
with three changes: symbols print as the local names the emitter assigned
(``_print_Symbol``, never string replacement, and an unknown symbol is an
error), floats print with ``repr`` so they round-trip exactly, and small
integer powers print as products, which Numba compiles to multiplications.
"""

from __future__ import annotations

import sympy as sp
from sympy.printing.pycode import PythonCodePrinter


class UnknownSymbolError(KeyError):
    """An expression names a symbol that is not a declared input or local."""


class KernelPrinter(PythonCodePrinter):
    """Python printer mapping every symbol through ``names`` (symbol -> local name)."""

    def __init__(self, names: dict[sp.Symbol, str]):
        super().__init__({"fully_qualified_modules": True, "standard": "python3"})
        self.names = names

    def _print_Symbol(self, expr: sp.Symbol) -> str:
        try:
            return self.names[expr]
        except KeyError:
            raise UnknownSymbolError(f"symbol {expr} is not a declared input") from None

    _print_Dummy = _print_Symbol

    def _print_Float(self, expr: sp.Float) -> str:
        return repr(float(expr))

    def _print_Pow(self, expr: sp.Pow, rational: bool = False) -> str:
        base, exp = expr.as_base_exp()
        if exp.is_Integer and 2 <= int(exp) <= 4 and (base.is_Symbol or base.is_Number):
            return "*".join([self._print(base)] * int(exp))
        if exp.is_Integer and -4 <= int(exp) <= -1 and (base.is_Symbol or base.is_Number):
            return "1.0/(" + "*".join([self._print(base)] * -int(exp)) + ")"
        return super()._print_Pow(expr, rational=rational)
