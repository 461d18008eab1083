"""The broad phase: a lower bound on every gap from bounding circles, without a gap row.

The jack's bounding circle (radius ``tol[T_RJACK]`` about its centre) against
the box's inner walls (half-width ``tol[T_WALL]``), and, with a ground, the
box's bounding circle (``tol[T_RBOX]``) against the ground: one sine and one
cosine. Far from every wall the free-flight loop (:mod:`jackbox.engine.flight`)
looks at no gap row at all while this bound exceeds what a step can move a gap.
"""

import math

from numba import njit

from .records import T_RBOX, T_RJACK, T_WALL


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def bound(xb, yb, th, xj, yj, tol, has_ground):
    """A lower bound on every gap of a box at (xb, yb, th) with the jack's centre at (xj, yj)."""
    c, s = math.cos(th), math.sin(th)
    dx, dy = xj - xb, yj - yb
    u, v = c * dx + s * dy, c * dy - s * dx
    g = tol[T_WALL] - max(abs(u), abs(v)) - tol[T_RJACK]
    if has_ground:
        g = min(g, yb - tol[T_RBOX])
    return g
