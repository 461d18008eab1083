"""Gaps in time: how fast a gap can change, and the cubic through a gap at both ends of a step.

A step needs a look at its gap rows only if some gap could come within its
travel of contact (:func:`step_reach`); a gap positive at both ends of a step
can still dip below zero inside it (a grazing corner): the cubic Hermite
interpolant through its values and rates at both ends shows where
(:func:`hermite_extrema`, :func:`hermite`), to within :func:`cubic_error`.
"""

import math

from numba import njit

from .records import T_BOXV, T_GAP, T_RBOX, T_SPEED


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def speed_bound(qd, tol):
    """A bound on how fast any gap can change at rates qd (a tuple or an array)."""
    s = tol[T_BOXV]
    for d in range(len(qd)):
        s += abs(qd[d]) * tol[T_SPEED + d]
    return s


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def step_reach(qd_a, qd_b, h, tol):
    """How close to contact a gap must come, at one end of a step of length h, to need a look.

    A gap positive at both ends can only dip below zero inside the step if one
    end is within half the step's travel of contact. The travel is bounded by
    h times the larger of the two ends' speed bounds (each |qd_i| times the
    most a unit rate can move any gap, plus the prescribed box's speed); the
    band is twice the half, for the speed's change within the step.
    """
    return h * max(speed_bound(qd_a, tol), speed_bound(qd_b, tol)) + tol[T_GAP]


#: how far the cubic through a gap's values and rates at a step's ends can sag below the lower end, per unit of
#: the step's travel bound h max(speed_bound): its Hermite weights on the two rates, s (1 - s)^2 and
#: -s^2 (1 - s), add up in size to s (1 - s), at most 1/4 (at s = 1/2: both ends' rates at the bound, the
#: first towards the wall, the second away), and each rate is within the bound
SAG = 0.25


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def dip_free(band, dip, tol):
    """The level above which a gap at both ends of a step (on its event level) needs no look at its rates.

    band: :func:`step_reach` of the step, dip: :func:`cubic_error`. A gap
    at least this far above its level at both ends has a cubic (the values and
    the rates h v at the ends, each |v| within the speed bound) that stays
    above ``dip`` by T_GAP (a million times the round-off of the cubic's
    value): no end below the level, no dip the event search would step to
    (:func:`jackbox.engine.events.first_dip`), whatever its rates are. A step
    whose gaps within its reach are all this far up is taken without
    computing a rate (in a shaken run, about a quarter of the steps near a wall had some gap nearer).
    """
    return SAG * (band - tol[T_GAP]) + dip + tol[T_GAP]


@njit(cache=True, no_cpython_wrapper=True)
def cubic_error(qd_a, qd_b, h, tol):
    """How far a gap can stray from the cubic through its values and rates at both ends of a step.

    The cubic Hermite interpolant is off by at most h^4 / 384 times the gap's
    largest fourth derivative. For bodies turning at rates w (every third
    coordinate is an angle, with lever arm ``tol[T_SPEED + d]``) that is about
    r W^4 + 4 V W^3, W the sum of the turning rates, V that of the other
    rates (a turning wall's normal swept along the jack's travel) and r the
    largest lever arm of an angle or, where the box is free, its outer radius
    (a point inside the box turns about its centre on a circle no larger:
    the box angle's lever arm bounds a wall gap's slope only). Returned
    with a factor 16 to spare (the rates change within the step; the larger
    of the two ends is taken): 1e-6 r at w h = 0.1, where a grazing corner's
    cubic stays 1e-7 r above zero while the corner dips 1e-8 L into the wall.
    """
    w = 0.0
    v = 0.0
    r = tol[T_RBOX] if len(qd_a) == 6 else 0.0      # (see above: a free box's angle is the third of six)
    for d in range(len(qd_a)):
        rate = max(abs(qd_a[d]), abs(qd_b[d]))
        if d % 3 == 2:
            w += rate
            r = max(r, tol[T_SPEED + d])
        else:
            v += rate
    wh = w * h
    return (r * wh + 4.0 * v * h) * wh * wh * wh / 24.0


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def hermite_slope(fa, fb, da, db):
    """The slope of the cubic with values fa, fb and slopes da, db at 0 and 1: (A, B, C), A s^2 + B s + C."""
    a3 = 2.0 * fa + da - 2.0 * fb + db
    a2 = -3.0 * fa - 2.0 * da + 3.0 * fb - db
    return 3.0 * a3, 2.0 * a2, da


@njit(cache=True, no_cpython_wrapper=True)
def hermite_extrema(fa, fb, da, db, ext):
    """Interior stationary points s in (0, 1) of the cubic with values fa, fb and slopes da, db.

    Writes up to two of them into ext (ascending); returns their number.
    """
    A_, B_, C_ = hermite_slope(fa, fb, da, db)
    n = 0
    if abs(A_) < 1e-300:
        if abs(B_) > 1e-300:
            s = -C_ / B_
            if 0.0 < s < 1.0:
                ext[0] = s
                n = 1
        return n
    disc = B_ * B_ - 4.0 * A_ * C_
    if disc < 0.0:
        return 0
    r = math.sqrt(disc)
    qq = -0.5 * (B_ + math.copysign(r, B_))
    s1 = qq / A_
    s2 = C_ / qq if qq != 0.0 else s1
    lo, hi = min(s1, s2), max(s1, s2)
    if 0.0 < lo < 1.0:
        ext[n] = lo
        n += 1
    if 0.0 < hi < 1.0 and hi != lo:
        ext[n] = hi
        n += 1
    return n


@njit(cache=True, no_cpython_wrapper=True)
def hermite(fa, fb, da, db, s):
    """The cubic with values fa, fb and slopes da, db at 0 and 1, at s."""
    s2 = s * s
    s3 = s2 * s
    return ((2 * s3 - 3 * s2 + 1) * fa + (s3 - 2 * s2 + s) * da
            + (-2 * s3 + 3 * s2) * fb + (s3 - s2) * db)
