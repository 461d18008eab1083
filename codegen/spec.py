"""What the compiler is given: the model vocabulary and :class:`ModelSpec`.

The vocabulary names what every model has: the coordinates and their rates, the
walls and the box's corners (the order of the gap rows), the jack shapes and the
built-in parameter slots. A :class:`ModelSpec` is one model's structure as plain
data (names and formula strings, no numbers and no sympy): all the compiler reads.
Whoever describes a model (the runtime's scene files) builds one; equal specs,
names aside, give equal code.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

COORDS = ("x_box", "y_box", "theta_box", "x_jack", "y_jack", "theta_jack")
RATES = tuple(f"{c}_dot" for c in COORDS)
BOX_COORDS, JACK_COORDS = COORDS[:3], COORDS[3:]
WALLS = ("right", "top", "left", "bottom")
#: outward normals of the inner walls, in the box frame (in the order of WALLS)
WALL_NORMALS = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))
#: the box's outer corners (+,+), (-,+), (-,-), (+,-), as multiples of L + w
CORNER_SIGNS = ((1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0))
#: cross: 4 tips at (+-a, 0), (0, +-a); square: 4 corners at (+-a, +-a); polygon: its vertices
JACK_SHAPES = ("cross", "square", "polygon")

#: Symbols every formula may use besides ``t``, ``pi``, the user's parameters and the state.
BASE_SYMBOLS = ("g", "m_box", "m_jack", "J_box", "J_jack", "L")
#: Parameter slots of every model, in array order; the jack's size slots (``a_jack``,
#: or a polygon's ``jack_x<i>``, ``jack_y<i>``) and the user's parameters follow.
BASE_PARAMS = ("m_box", "J_box", "L", "w_box", "m_jack", "J_jack", "g", "e", "e_ground")


def constraint_names(n_points: int, ground: bool) -> tuple[str, ...]:
    """The gap rows: ``"<wall>:<point>"`` wall-major, then ``"ground:<corner>"`` when there is a ground."""
    names = [f"{wall}:{i}" for wall in WALLS for i in range(n_points)]
    return tuple(names + ([f"ground:{i}" for i in range(4)] if ground else []))


@dataclass(frozen=True)
class ModelSpec:
    """One model's structure, as plain data: what the compiler compiles in.

    Formulas are strings of the expression language (:mod:`codegen.expr`) that
    may name ``t``, ``pi``, :data:`BASE_SYMBOLS`, ``user_params`` and (except the
    motion) the coordinates and rates. ``potential`` and ``forces`` are kept as
    tuples of ``(name, formula)`` sorted by name (a mapping is accepted too).
    """

    name: str                       #: the model's name, written into its module
    command: str                    #: the command that regenerates the module (its header)
    param_names: tuple[str, ...]    #: parameter slots, in array order (BASE_PARAMS first)
    user_params: tuple[str, ...]    #: the scene's own parameters, usable in formulas
    prescribed: bool                #: the box moves by ``motion`` (3 DOFs) rather than freely (6)
    motion: tuple[str, str, str]    #: x, y, theta formulas of a prescribed box (functions of t)
    shape: str                      #: one of JACK_SHAPES
    n_points: int                   #: the jack's contact points (vertices of a polygon)
    ground: bool                    #: box corner/ground gap rows (a free box over a ground)
    potential: tuple[tuple[str, str], ...] = ()   #: extra potential energy terms
    forces: tuple[tuple[str, str], ...] = ()      #: generalized forces, by coordinate (non-zero only)

    def __post_init__(self):
        for key in ("potential", "forces"):
            value = getattr(self, key)
            items = value.items() if isinstance(value, Mapping) else value
            object.__setattr__(self, key, tuple(sorted((str(k), str(v)) for k, v in items)))
        for key in ("param_names", "user_params", "motion"):
            object.__setattr__(self, key, tuple(getattr(self, key)))

    @property
    def dof_names(self) -> tuple[str, ...]:
        """The integrated coordinates: the jack's for a prescribed box, else all six."""
        return JACK_COORDS if self.prescribed else COORDS

    @property
    def constraint_names(self) -> tuple[str, ...]:
        """The names of the gap rows, in the order of the generated ``phi``."""
        return constraint_names(self.n_points, self.ground)

    def structure(self) -> dict:
        """What is compiled in (all but the name and the command), for the model hash."""
        return {
            "dofs": list(self.dof_names),
            "motion": list(self.motion) if self.prescribed else None,
            "shape": self.shape,
            "n_points": self.n_points,
            "ground": self.ground,
            "potential": list(self.potential),
            "forces": list(self.forces),
            "params": list(self.param_names),
        }
