"""An ensemble block's lanes: LANES members stepped together in free flight, compiled with each model.

Like :mod:`jackbox.engine.flight`, this file is not imported as it stands:
:func:`jackbox.loader.binding_parts` copies what :func:`lanes` reaches (the
hot path's ``rk4_stages``, the model's tuple functions and its
``clearance_v``) into the model's ``lanes`` binding part, compiled when a
study first needs it.

A block's state is one array of rows of LANES floats (the members of the
block side by side, :data:`jackbox.engine.records.BLOCK_ROWS` rows): the main
loop over the lanes has a fixed trip count, no call and no branch, so LLVM
(its SLP vectoriser, which :func:`jackbox.engine.bind_part` turns on for this
part) can pack lanes into vector instructions; it packs only part of the loop
so far (README, "Ensembles in lanes"). The terms of time (a shaking force's
sine) are the block's: its members share their parameters, so each is
computed once per stage time for all of them. Each lane's step is the hot path's RK4 step
(``rk4_stages``, the same operations in the same order), so a member stepped
here has the bits it would have had alone.

A step is taken for the block only if it is quiet for every live lane: every
gap, at both ends, further from contact than the step can move it, by the
margin the exact loop asks (``step_reach``) plus T_GAP. The gaps come from the
model's ``clearance_v`` with the sines and cosines of :func:`sincos` (a
polynomial that LLVM can vectorise, within 2 eps of the library's): the extra
T_GAP, a thousand times what that difference can move a gap, keeps a lane's
"quiet" from ever being the exact loop's "not quiet". Otherwise the lanes stop
before that step and say which are quiet (:mod:`jackbox.engine.members` takes
the others through the exact loop, alone).
"""

import math

from jackbox.engine.gaps import speed_bound as _speed_bound
from jackbox.engine.integrator import NODES as _NODES
from jackbox.engine.records import BOUND_ROW as _BOUND, LANES as _W, T_EVENT as _T_EVENT_L, T_GAP as _T_GAP_L

# sin and cos: Cody-Waite reduction by pi/2 (its first part has 33 bits, so k * _PIO2_HI is exact for
# |k| < 2^20, angles up to 1.6e6 rad) and the classical minimax polynomials on [-pi/4, pi/4]
_TWO_OVER_PI = 0.6366197723675814
_PIO2_HI = 1.57079632673412561417e+00
_PIO2_LO = 6.07710050650619224932e-11
_S1, _S2, _S3 = -1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04
_S4, _S5, _S6 = 2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10
_C1, _C2, _C3 = 4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05
_C4, _C5, _C6 = -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11


def sincos(x):
    """(sin x, cos x) without a call or a branch (selects by arithmetic on the quadrant)."""
    k = math.floor(x * _TWO_OVER_PI + 0.5)
    r = (x - k * _PIO2_HI) - k * _PIO2_LO
    z = r * r
    s = r + r * z * (_S1 + z * (_S2 + z * (_S3 + z * (_S4 + z * (_S5 + z * _S6)))))
    c = 1.0 - 0.5 * z + z * z * (_C1 + z * (_C2 + z * (_C3 + z * (_C4 + z * (_C5 + z * _C6)))))
    n = int(k) & 3
    odd = float(n & 1)
    sign_s = 1.0 - 2.0 * float(n >> 1)                  # quadrants 2, 3
    sign_c = 1.0 - 2.0 * float(((n + 1) >> 1) & 1)      # quadrants 1, 2
    return (s + odd * (c - s)) * sign_s, (c + odd * (s - c)) * sign_c


def lane_bound(t, q, p):
    """A bound on every gap of a lane at (t, q), within a few eps of the exact loop's."""
    sb, cb = sincos(q[2])
    sj, cj = sincos(q[5])
    return clearance_v(t, q, p, (sb, cb, sj, cj))


def lane_state(S, at, lane):
    """The six numbers of lane ``lane`` from row ``at`` of S on."""
    return (S[at + lane], S[at + _W + lane], S[at + 2 * _W + lane], S[at + 3 * _W + lane], S[at + 4 * _W + lane],
            S[at + 5 * _W + lane])


def lanes(t0, dt, i, i_stop, S, p, tol, live, quiet):
    """Steps i, i+1, ... of the block's live lanes together while each step is quiet for every live lane.

    S: the block's state (rows q, qd, trial q, trial qd, then per lane a bound
    on every gap at the start, NaN where the caller has moved the lane and it
    is to be computed again, the same at the trial's end, and the trial
    step's band). Returns the step reached: i_stop, or the step before which
    some live lane is not quiet; then the trial of that step is in S for
    every lane and quiet[lane] says whether that lane may take it. A lane that
    is not live is stepped too (its numbers are not used). Free boxes only: six
    coordinates, box first.

    As in the hot path's ``fly``, a lane's bound is lowered by each step's
    band and computed again (every gap: :func:`lane_bound`) only when that
    leaves too little, in a second loop over the few lanes that need it; the
    first loop, over every lane, has no call and no branch.
    """
    QV, QB, QVB, GA, GB, BAND = 6 * _W, 12 * _W, 18 * _W, _BOUND * _W, (_BOUND + 1) * _W, (_BOUND + 2) * _W
    margin = 2.0 * tol[_T_GAP_L] - 0.5 * tol[_T_EVENT_L]
    t = t0 + i * dt
    for lane in range(_W):
        if S[GA + lane] != S[GA + lane]:        # NaN: a lane whose state the caller changed
            S[GA + lane] = lane_bound(t, lane_state(S, 0, lane), p)
    tt = accel_time_s(t, p)
    while i < i_stop:
        t = t0 + i * dt
        tm = t + _NODES[1] * dt
        t_next = t0 + (i + 1) * dt
        ttm = accel_time_s(tm, p)
        tt_next = accel_time_s(t_next, p)
        short = 0
        for lane in range(_W):
            qd = lane_state(S, QV, lane)
            qn, vn = rk4_stages(lane_state(S, 0, lane), qd, dt, p, t, tt, tm, ttm, t_next, tt_next)
            S[QB + lane], S[QB + _W + lane], S[QB + 2 * _W + lane] = qn[0], qn[1], qn[2]
            S[QB + 3 * _W + lane], S[QB + 4 * _W + lane], S[QB + 5 * _W + lane] = qn[3], qn[4], qn[5]
            S[QVB + lane], S[QVB + _W + lane], S[QVB + 2 * _W + lane] = vn[0], vn[1], vn[2]
            S[QVB + 3 * _W + lane], S[QVB + 4 * _W + lane], S[QVB + 5 * _W + lane] = vn[3], vn[4], vn[5]
            band = dt * max(_speed_bound(qd, tol), _speed_bound(vn, tol)) + margin     # as in fly
            total = qn[0] + qn[1] + qn[2] + qn[3] + qn[4] + qn[5] + vn[0] + vn[1] + vn[2] + vn[3] + vn[4] + vn[5]
            c = S[GA + lane] - band
            S[GB + lane] = c
            S[BAND + lane] = band
            # quiet at the start (and finite: min and max hide a NaN) and, by the lowered bound, at the end
            start = (S[GA + lane] >= band) & (total - total == 0.0)
            ok = start & (c >= band)
            quiet[lane] = ok
            short += start & (1 - ok)
        if short:          # the bound at the end of some lanes is too low: every gap there, for those
            for lane in range(_W):
                if quiet[lane] == 0 and S[GA + lane] >= S[BAND + lane]:
                    g = lane_bound(t_next, lane_state(S, QB, lane), p)
                    S[GB + lane] = g
                    quiet[lane] = g >= S[BAND + lane]
        stop = 0
        for lane in range(_W):
            stop += live[lane] & (1 - quiet[lane])
        if stop:
            return i
        for k in range(6 * _W):
            S[k] = S[QB + k]
            S[QV + k] = S[QVB + k]
        for lane in range(_W):
            S[GA + lane] = S[GB + lane]
        tt = tt_next
        i += 1
    return i


#: the helpers a lanes part inlines at Numba's level (``inline="always"``): a loop over the lanes
#: with a call left in it is not vectorised (``lane_bound`` is called from scalar loops only)
INLINED = ("sincos", "lane_state", "clearance_v")
