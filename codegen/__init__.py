"""The jackbox compiler: scene -> symbolic model -> cse -> plain-Python source.

Stages, one module each (the pipeline is the layout):

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

from .version import GENERATOR, model_hash

__all__ = ["GENERATOR", "model_hash"]
