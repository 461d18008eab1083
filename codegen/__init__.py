"""The jackbox compiler: model spec -> symbolic model -> cse -> plain-Python source.

Stages, one module each (the pipeline is the layout):

* :mod:`codegen.spec`    what the compiler is given: the model vocabulary
  (coordinates, walls, parameter slots) and :class:`ModelSpec`, one model's
  structure as plain data; :mod:`codegen.expr` is the formula language its
  formulas are written in;
* :mod:`codegen.model`   derives the equations of motion and the contact gaps
  of a spec with sympy (SE(2) transforms, Lagrangian, Euler-Lagrange);
* :mod:`codegen.printer` turns one sympy expression into Python text, mapping
  symbols to local names;
* :mod:`codegen.emitter` runs one ``sympy.cse`` over every output of a model and
  lays out the functions and the file (header, constants, bodies);
* :mod:`codegen.driver`  runs the stages: :func:`generate` turns a spec into the
  module's text (it writes nothing).

The compiler knows nothing of its users. This package's top level is its whole
interface (``__all__``): the runtime imports from ``codegen`` only, never from
a stage. Importing it does not import sympy: :func:`generate` imports the stages
when it runs, and ``derive`` and ``Model`` (the symbolic model, for the slow
reference twin) are imported on first use.
"""

from .driver import generate
from .expr import FUNCTIONS as FORMULA_FUNCTIONS
from .expr import Expr, ExprError
from .expr import parse as parse_formula
from .spec import (BASE_PARAMS, BASE_SYMBOLS, BOX_COORDS, COORDS, CORNER_SIGNS, JACK_COORDS, JACK_SHAPES, RATES,
                   WALL_NORMALS, WALLS, ModelSpec, constraint_names)
from .version import GENERATOR, SEAL, is_sealed, model_hash, seal

__all__ = [
    # the spec and its vocabulary
    "ModelSpec", "COORDS", "RATES", "BOX_COORDS", "JACK_COORDS", "WALLS", "WALL_NORMALS", "CORNER_SIGNS",
    "JACK_SHAPES", "BASE_SYMBOLS", "BASE_PARAMS", "constraint_names",
    # the formula language
    "Expr", "ExprError", "parse_formula", "FORMULA_FUNCTIONS",
    # compiling, and telling a generated module's model and integrity
    "generate", "GENERATOR", "model_hash", "SEAL", "seal", "is_sealed",
    # the symbolic model (imports sympy on first use)
    "derive", "Model",
]

#: names whose modules import sympy: imported on first use (PEP 562)
_LAZY = {"derive": "model", "Model": "model"}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'codegen' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
