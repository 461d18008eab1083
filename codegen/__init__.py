"""The jackbox compiler: scene -> symbolic model -> cse -> plain-Python source.

Stages, one module each (the pipeline is the layout):

* :mod:`codegen.spec`    the model vocabulary (coordinates, walls, parameter
  slots); :mod:`codegen.expr` is the formula language of the models;
* :mod:`codegen.model`   derives the equations of motion and the contact gaps
  of a scene with sympy (SE(2) transforms, Lagrangian, Euler-Lagrange);
* :mod:`codegen.printer` turns one sympy expression into Python text, mapping
  symbols to local names;
* :mod:`codegen.emitter` runs one ``sympy.cse`` over every output of a model and
  lays out the functions and the file (header, constants, bodies);
* :mod:`codegen.driver`  runs the stages for a scene and writes the module into
  ``generated/`` (built-in scenes) or the user cache (any other scene).

Importing this package does not import sympy; the stages do.
"""

from .expr import FUNCTIONS as FORMULA_FUNCTIONS
from .expr import Expr, ExprError
from .expr import parse as parse_formula
from .spec import (BASE_PARAMS, BASE_SYMBOLS, BOX_COORDS, COORDS, CORNER_SIGNS, JACK_COORDS, JACK_SHAPES, RATES,
                   WALL_NORMALS, WALLS, constraint_names)
from .version import GENERATOR, model_hash

__all__ = [
    # the model vocabulary
    "COORDS", "RATES", "BOX_COORDS", "JACK_COORDS", "WALLS", "WALL_NORMALS", "CORNER_SIGNS", "JACK_SHAPES",
    "BASE_SYMBOLS", "BASE_PARAMS", "constraint_names",
    # the formula language
    "Expr", "ExprError", "parse_formula", "FORMULA_FUNCTIONS",
    "GENERATOR", "model_hash",
]
