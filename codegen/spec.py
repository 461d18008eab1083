"""The model vocabulary: what every model has, by name.

The coordinates and their rates, the walls and the box's corners (the order of
the gap rows), the jack shapes and the built-in parameter slots. The compiler
derives its models in these terms; the runtime's scene checker uses the same names.
"""

from __future__ import annotations

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
