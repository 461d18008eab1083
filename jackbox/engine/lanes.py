"""An ensemble block's lanes: LANES members stepped together in free flight, compiled with each model.

Like :mod:`jackbox.engine.flight`, this file is not imported as it stands:
:func:`jackbox.loader.binding_parts` copies what :func:`lanes` reaches (the
hot path's ``rk4_stages``, the model's tuple functions and its
``clearance_v``) into the model's ``lanes`` binding part, compiled when a
study first needs it.

A block's state is one array of rows of LANES floats (the members of the
block side by side, :data:`jackbox.engine.records.BLOCK_ROWS` rows). Each
loop over the lanes is written for LLVM's loop vectoriser: no call, no
branch, the parameters and tolerances read into registers before it
(``params_of``), and a trip count read at run time (a constant one of LANES is
unrolled whole before the vectoriser sees it), so a loop becomes vector
instructions of four lanes (LLVM's 256-bit vectors here: :data:`PAD`). The terms of time (a shaking force's sine) are
the study's: its members share their parameters, so they are computed once
per stage time for all of them, into a table (:func:`time_table`) that every
block reads (computed per block-step, they were a tenth of a shaken study's
time). Each lane's step is the hot path's RK4 step
(``rk4_stages``, the same operations in the same order), so a member stepped
here has the bits it would have had alone.

A step is taken for the block only if it is quiet for every live lane: every
gap, at both ends, further from contact than the step can move it, by the
margin the exact loop asks (``step_reach``) plus T_GAP. As in the hot path's
``fly``, a lane's bound on its gaps is lowered by each step's band, and it
is computed again (every gap: the model's ``clearance_v`` with the sines and
cosines of :func:`sincos`, a polynomial that LLVM can vectorise, within 2
eps of the library's) only in a step where it runs low, for the lanes whose
bound runs low alone (:func:`rebound`): the extra T_GAP, a thousand times
what that difference can move a gap, keeps a lane's "quiet" from ever being
the exact loop's "not quiet".
A lane that is not quiet takes the step if the exact loop would find no
event in it: its bounds at both ends (the bound at the end computed again
for it) may say so already (:func:`calm_by_bounds`: no gap within the
step's reach and low enough for the exact loop to read its rates), else
:func:`calm` asks the exact loop's question of the gaps; or it takes the exact loop's impact step itself,
on floats, where it is a plain one (:func:`event_lane`, in the model's
``lane_event`` part). Otherwise the lanes stop before that step and say
which are quiet (:mod:`jackbox.engine.members` takes the others through the
exact loop, alone).
"""

import math

from numba import uint64 as _u8
from numba.cpython.unsafe.numbers import trailing_zeros as _trailing_zeros

from jackbox.engine.events import (LOCATE_PROBES as _LOCATE_PROBES, cubic_root as _cubic_root, first_dip as _first_dip,
                                   first_hump as _first_hump, illinois_keep as _illinois_keep,
                                   illinois_probe as _illinois_probe, time_tolerance as _time_tolerance)
from jackbox.engine.gaps import (cubic_error as _cubic_error, dip_free as _dip_free, speed_bound as _speed_bound,
                                 step_reach as _step_reach)
from jackbox.engine.integrator import NODES as _NODES
from jackbox.engine.modes import time_resolution as _time_resolution, within_reach as _within_reach
from jackbox.engine.records import (BOUND_ROW as _BOUND, FIRST_ROW as _FIRST, GAP_ROUNDOFF as _GAP_ROUNDOFF,
                                    E_GROUND_ROW as _EG, E_ROW as _E, IMPULSE_ROW as _IMPULSES, LANES as _W,
                                    PACK_ROW as _PACK,
                                    SCRATCH_ROW as _SCRATCH,
                                    SPEED_ROW as _SPEED, T_EVENT as _T_EVENT_L,
                                    T_GAP as _T_GAP_L, T_VREST as _T_VREST_L)
from jackbox.engine.stacked import stacked as _stacked
from jackbox.engine.tolerances import rest_speed as _rest_speed

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
    """A bound on every gap of a lane at (t, q), within a few eps of the exact loop's (p: ``params_of``)."""
    sb, cb = sincos(q[2])
    sj, cj = sincos(q[5])
    return clearance_v(t, q, p, (sb, cb, sj, cj))


def lane_state(S, at, lane):
    """The six numbers of lane ``lane`` from row ``at`` of S on (unsigned indices: see :func:`step_block`)."""
    return (S[_u8(at + lane)], S[_u8(at + _W + lane)], S[_u8(at + 2 * _W + lane)], S[_u8(at + 3 * _W + lane)],
            S[_u8(at + 4 * _W + lane)], S[_u8(at + 5 * _W + lane)])


def put_lane_state(S, at, lane, x):
    """The six numbers x into lane ``lane`` from row ``at`` of S on (:func:`lane_state`'s rows)."""
    S[_u8(at + lane)], S[_u8(at + _W + lane)], S[_u8(at + 2 * _W + lane)] = x[0], x[1], x[2]
    S[_u8(at + 3 * _W + lane)], S[_u8(at + 4 * _W + lane)], S[_u8(at + 5 * _W + lane)] = x[3], x[4], x[5]


def tolerances_of(tol):
    """The tolerance slots a lane reads, up to the six coordinates' lever arms, as a tuple (held in registers)."""
    return (tol[0], tol[1], tol[2], tol[3], tol[4], tol[5], tol[6], tol[7], tol[8], tol[9], tol[10], tol[11],
            tol[12], tol[13])


def finite(qn, vn):
    """Whether a lane's twelve numbers are all finite, without a branch (a NaN or an infinity spreads to the sum).

    Summed as a tree, four additions deep: a chain of eleven, each waiting
    for the one before (LLVM may not reorder them), was the lanes' step's
    longest path (perf laid a fifth of the loop's samples on it)."""
    q = ((qn[0] + qn[1]) + qn[2]) + ((qn[3] + qn[4]) + qn[5])
    v = ((vn[0] + vn[1]) + vn[2]) + ((vn[3] + vn[4]) + vn[5])
    total = q + v
    return total - total == 0.0


def calm(t, t_next, q, qd, qn, vn, p, tol, ext):
    """Whether the exact loop finds no event in a step that is not quiet by the bounds; and the smallest gap at its end.

    The step from (t, q, qd) to its trial (t_next, qn, vn) of a free member
    (no contact held). The exact loop looks for a crossing in it
    (``events.first_crossing``) and, finding none, takes the trial: the bits a
    lane's plain step gives. This asks the same questions of the same numbers,
    computed by the same functions (the model's ``phi_s`` and ``gap_rate_s``
    have the terms of ``phi`` and ``gap_rate``, operation for operation): no
    gap near enough to look at, or for each that is, no crossing at the step's
    end and no dip of its cubic that the exact loop would step to. Where the
    exact loop would step into the step (to a dip, to locate a crossing),
    this says no: the member goes through the exact loop; so it does for a
    contact that starts the step below the held level without approaching
    (its event level is the exact loop's to choose, and may change within the
    step). Returns ``(calm, smallest gap at t_next)``. (:func:`step_block`
    asks :func:`calm_by_bounds` first: in a shaken run, two steps in three
    near a wall need no gap read.)
    """
    if not finite(qn, vn):
        return False, 0.0
    h = t_next - t
    half = 0.5 * tol[_T_EVENT_L]
    deep = half + tol[_T_EVENT_L]
    ga = _stacked(phi_s(t, q, p))     # (read by a run-time index: see jackbox.engine.stacked)
    gb = _stacked(phi_s(t_next, qn, p))
    band = _step_reach(qd, vn, h, tol)
    dip = _cubic_error(qd, vn, h, tol)
    clear = _dip_free(band, dip, tol)       # (the exact loop's test for a look at the rates)
    smallest = gb[0]
    near = False
    for k in range(N_CONTACT):
        smallest = min(smallest, gb[k])
        g = min(ga[k], gb[k])
        if g + deep < band and g + half < clear:
            near = True
    if not near:
        return True, smallest
    va = _stacked(gap_rate_s(t, q, qd, p))
    vb = _stacked(gap_rate_s(t_next, qn, vn, p))
    tiny = 1e-3 * tol[_T_VREST_L]
    for k in range(N_CONTACT):
        if ga[k] + half < 0.0 and va[k] >= -tiny:
            return False, smallest      # a deep start (its level changes in the step): the exact loop's own
        fa, fb = ga[k] + half, gb[k] + half
        if min(fa, fb) >= band:
            continue
        if fb < 0.0:
            return False, smallest
        if _first_dip(fa, fb, h * va[k], h * vb[k], dip, -1.0, ext) >= 0.0:
            return False, smallest
    return True, smallest


def calm_by_bounds(t, t_next, qd, vn, bound_a, bound_b, tol):
    """Whether :func:`calm` would say yes with no gap read: bounds on every gap at both ends of the step (the
    lane's: :func:`lane_bound`'s, within a few eps of the model's ``phi_s``, or lower), less T_GAP, above
    what its near test asks (the exact loop's: a gap within reach and below ``gaps.dip_free``), so none is
    near. A NaN says no.
    """
    h = t_next - t
    half = 0.5 * tol[_T_EVENT_L]
    deep = half + tol[_T_EVENT_L]
    band = _step_reach(qd, vn, h, tol)
    clear = _dip_free(band, _cubic_error(qd, vn, h, tol), tol)
    a, b = bound_a - tol[_T_GAP_L], bound_b - tol[_T_GAP_L]
    return ((a + deep >= band) | (a + half >= clear)) & ((b + deep >= band) | (b + half >= clear))


# ---------------------------------------------------------------------------
# A lane's event step: the exact loop's impact step of a free member, on floats (see event_lane)

#: what a lane's event step says: taken (its end and impulses in S), no event after all (the trial
#: stands), or a case it leaves to the exact loop (the member goes alone, as before)
TAKEN, NO_EVENT, ALONE_CASE = 1, 0, -1

#: lanes a vector of the loops over them holds (LLVM's choice here: 256 bits, four floats)
PAD = 4


def restep(ta, tta, q, qd, s, p):
    """The exact loop's re-step from (ta, q, qd) to time s (``integrator.rk4`` with nothing held: the model's
    ``free_step`` from ta to ``ta + (s - ta)``), on tuples; tta: the time terms at ta (``accel_time_s``, read
    once for every re-step from ta). Returns ``(q, qd)`` at s."""
    h = s - ta
    qs, vs, _ = grid_step(ta, ta + h, tta, q, qd, h, p)
    return qs, vs


def probe(ta, tta, q, qd, s, p):
    """:func:`restep` to s and the gaps there (``events.event_value`` of a free lane): ``(q, qd, gaps)``."""
    qs, vs = restep(ta, tta, q, qd, s, p)
    return qs, vs, phi_s(s, qs, p)


def gaps_rates_at(t, q, qd, p):
    """The model's ``phi_s`` and ``gap_rate_s`` together: LLVM reads the sine and cosine of each angle once for
    both (:func:`calm` does the same). A lane's event step spent a third of its time in the library's sines."""
    return phi_s(t, q, p), gap_rate_s(t, q, qd, p)


def row_at(t, q, qd, p, pose, k):
    """The model's ``contact_row_s``, a function of its own (inlined at each of the event step's calls, the
    model's rows took seconds of compiling)."""
    return contact_row_s(t, q, qd, p, pose, k)


def locate_lane(k, ta, tta, q, qd, g0, tl, fl, tr, fr, guess, half, p, tol):
    """``events.locate`` for gap k of a free lane (its event function: the gap plus ``half`` at a re-step's end),
    the same operations in their order. Returns ``(converged, tl, tr, last, q, qd, gaps)``: the last probe's
    time (-1: none) and its state and gaps (where none, q, qd and g0)."""
    side = 0
    last = -1.0
    ttol = _time_tolerance(ta, tr)
    ftol = _GAP_ROUNDOFF * tol[_T_EVENT_L]
    t_start = tl
    done = False
    qs, vs, gs = q, qd, g0
    for it in range(_LOCATE_PROBES):
        if tr - tl <= ttol or (tl > t_start and fl <= ftol):
            done = True
            break
        s = _illinois_probe(it, tl, fl, tr, fr, guess, ttol)
        qs, vs, gs = probe(ta, tta, q, qd, s, p)
        last = s
        tl, fl, tr, fr, side = _illinois_keep(s, gs[k] + half, tl, fl, tr, fr, side)
    return done or not tr - tl > ttol, tl, tr, last, qs, vs, gs


def crossing_lane(ta, tb, q, qd, qb, vb, ga, gb, va, vr, p, tol, ext):
    """``events.first_crossing`` for a free lane (no contact held), the same operations in their order.

    (q, qd) at ta, the step's trial (qb, vb) at tb, their gaps ga, gb and
    gap rates va, vr.
    Returns ``(what, te, q, qd)``: NO_EVENT; TAKEN with the state just
    before the first crossing and its time te; or ALONE_CASE where the exact
    loop would do what this does not: a contact starting the step deep
    (its own level), a touch at the step's start, a location that did not
    converge, or a second gap already past its level at the first crossing.
    """
    h = tb - ta
    half = 0.5 * tol[_T_EVENT_L]
    deep = half + tol[_T_EVENT_L]
    band = _step_reach(qd, vb, h, tol)
    gas, gbs = _stacked(ga), _stacked(gb)       # (read by a run-time index: see jackbox.engine.stacked)
    near = False
    for k in range(N_CONTACT):
        if min(gas[k], gbs[k]) + deep < band:
            near = True
    if not near:
        return NO_EVENT, -1.0, q, qd
    vas, vrs = _stacked(va), _stacked(vr)
    tiny = 1e-3 * tol[_T_VREST_L]
    for k in range(N_CONTACT):
        if gas[k] + half < 0.0 and vas[k] >= -tiny:
            return ALONE_CASE, -1.0, q, qd
    dip = _cubic_error(qd, vb, h, tol)
    tta = accel_time_s(ta, p)
    at = -1.0                       # the time of the last re-step, its state and gaps
    qa, vat, gat = q, qd, ga
    best_l = -1.0
    best_k = -1
    t_hi = tb
    for k in range(N_CONTACT):
        da, db = h * vas[k], h * vrs[k]
        fa, fb = gas[k] + half, gbs[k] + half
        if min(fa, fb) >= band:
            continue
        sr = -1.0
        fr = 0.0
        if fb < 0.0:
            sr, fr = 1.0, fb
        s = _first_dip(fa, fb, da, db, dip, sr, ext)
        if s >= 0.0:
            sr = s
            at = ta + sr * h
            qa, vat, gat = probe(ta, tta, q, qd, at, p)
            fr = gat[k] + half
            if fr >= 0.0:
                sr = 1.0 if fb < 0.0 else -1.0
                fr = fb
        if sr < 0.0:
            continue
        tr = ta + sr * h
        if best_k >= 0 and tr > t_hi:
            continue
        tl, fl = ta, fa             # events.left_bracket
        s = _first_hump(fa, fb, da, db, sr, ext)
        if s >= 0.0:
            at = ta + s * h
            qa, vat, gat = probe(ta, tta, q, qd, at, p)
            f = gat[k] + half
            if f > fl:
                tl, fl = at, f
        if fl <= 0.0:
            return ALONE_CASE, -1.0, q, qd
        guess = ta + h * _cubic_root(fa, fb, da, db, (tl - ta) / h, sr)
        ok, tl, tr, last, qs, vs, gs = locate_lane(k, ta, tta, q, qd, ga, tl, fl, tr, fr, guess, half, p,
                                                   tol)
        if not ok:
            return ALONE_CASE, -1.0, q, qd
        if last >= 0.0:
            at, qa, vat, gat = last, qs, vs, gs
        if best_k < 0 or tl < best_l:
            best_l, best_k = tl, k
            t_hi = tr
    if best_k < 0:
        return NO_EVENT, -1.0, q, qd
    if at != best_l:
        qa, vat, gat = probe(ta, tta, q, qd, best_l, p)
    gats = _stacked(gat)
    for k in range(N_CONTACT):
        if gats[k] + half < 0.0:
            return ALONE_CASE, -1.0, q, qd
    return TAKEN, best_l, qa, vat


def impact_lane(t, q, qd, p, tol, w, vrest, e_wall, e_ground):
    """``modes.update_contacts`` at an event of a free lane where one contact approaches and none comes to rest.

    The same operations in their order: the contacts within reach, their
    rows, rest speeds (into the array vrest) and Newton's law on the one that
    approaches (its LCP of one row, as ``impact.lcp`` solves it); w:
    diag M^-1; e_wall, e_ground: the lane's restitution (its parameters' e
    and e_ground, which p, the block's, need not hold). Returns ``(taken, qd after, impulses logged, the gaps at (t,
    q))``; not taken where the exact update would do more: no contact or
    several that take part, one closed and still, a contact left still after
    the impulse (the accelerations' LCP), or an LCP the enumeration does not
    solve. (A slow approach the exact loop counts for its runs of dense
    steps, but one a step never makes a run.)
    """
    g, v = gaps_rates_at(t, q, qd, p)
    gs, vs = _stacked(g), _stacked(v)       # (read by a run-time index: see jackbox.engine.stacked)
    dt_res = _time_resolution(t)
    pose = contact_pose_s(t, q, p)
    a = accel_s(t, q, qd, p, accel_time_s(t, p))
    half = 0.5 * tol[_T_EVENT_L]
    tiny = 1e-3 * tol[_T_VREST_L]
    hits = 0
    kh = -1
    rh = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    for k in range(N_CONTACT):
        if not _within_reach(gs[k], vs[k], dt_res, tol):
            continue
        r = row_at(t, q, qd, p, pose, k)
        s = row_dot_s(r, a)
        rise = max(-half - gs[k], 0.0) + tol[_T_EVENT_L]
        press = max(-s, 0.0)
        vrest[k] = _rest_speed(tol, rise, press, e_wall if k < N_WALL_CONTACT else e_ground)
        vk = r[8]
        if vk <= tiny:
            hits += 1
            kh, rh = k, r
            if not vk < -tiny:          # (closed and still: the accelerations' LCP)
                return False, qd, 0, g
    if hits != 1:                   # (none within reach, several, or none approaching)
        return False, qd, 0, g
    vk = rh[8]
    e = e_wall if kh < N_WALL_CONTACT else e_ground
    b = vk + (e * vk if vk < -vrest[kh] else 0.0)
    if not b < 0.0:                 # (impact.lcp: nothing approaches, no impulse)
        return False, qd, 0, g
    A = wdot_s(rh, w, rh)
    # impact.lcp on one row: the set {kh} by solve_dense, kept if its impulse passes the tolerance
    if not abs(A) > 1e-12 * abs(A):
        return False, qd, 0, g
    x = -b / A
    if x < -(1e-10 * abs(b)) / max(A, 1e-300):
        return False, qd, 0, g
    lam = max(x, 0.0)
    qd = respond_s(qd, w, rh, lam)
    logged = 1 if lam * A > tiny else 0
    for k in range(N_CONTACT):      # the rows again at the new rates: none comes to rest
        if not _within_reach(gs[k], vs[k], dt_res, tol):
            continue
        if abs(row_at(t, q, qd, p, pose, k)[8]) < vrest[k]:
            return False, qd, 0, g
    return True, qd, logged, g


def event_lane(t, t_next, dt, q, qd, qn, vn, p, tol, sc, e_wall, e_ground):
    """The exact loop's step of a free member from (t, q, qd), its trial (qn, vn) at t_next, where it has an
    event: ``loop.exact_steps``' quiet test, then ``loop.advance``'s passes (a crossing, the update, the
    re-step to t_next, no second crossing), on floats, the same numbers. Returns ``(what, q, qd at t_next,
    impulses logged, the impact's time, smallest gap at t_next)`` (what: :data:`TAKEN` or
    :data:`NO_EVENT`, or :data:`ALONE_CASE` for a step that only the exact loop takes). sc: a row of
    scratch (a cubic's stationary points, M^-1's diagonal, the rest speeds); e_wall, e_ground: the
    member's restitution (:func:`impact_lane`).
    """
    if not finite(qn, vn):
        return ALONE_CASE, qn, vn, 0, t, 0.0
    ext = sc[0:2]
    ga, va = gaps_rates_at(t, q, qd, p)
    gb, vr = gaps_rates_at(t_next, qn, vn, p)
    gas, gbs = _stacked(ga), _stacked(gb)       # (read by a run-time index: see jackbox.engine.stacked)
    low = gbs[0]
    for k in range(N_CONTACT):
        low = min(low, gbs[k])
    band = _step_reach(qd, vn, dt, tol) - 0.5 * tol[_T_EVENT_L]
    quiet = True
    for k in range(N_CONTACT):
        if min(gas[k], gbs[k]) < band:
            quiet = False
    if quiet:
        return NO_EVENT, qn, vn, 0, t, low
    what, te, qs, vs = crossing_lane(t, t_next, q, qd, qn, vn, ga, gb, va, vr, p, tol, ext)
    if what != TAKEN:
        return what, qn, vn, 0, t, low
    if not te > t:
        return ALONE_CASE, qn, vn, 0, t, low
    inverse_mass(p, sc[2:2 + N_DOF])
    taken, vs, logged, ge = impact_lane(te, qs, vs, p, tol, tuple_of(sc[2:2 + N_DOF]), sc[2 + N_DOF:], e_wall,
                                        e_ground)
    if not taken:
        return ALONE_CASE, qn, vn, 0, t, low
    qb, vb = restep(te, accel_time_s(te, p), qs, vs, t_next, p)
    gb, vr = gaps_rates_at(t_next, qb, vb, p)
    what, _, _, _ = crossing_lane(te, t_next, qs, vs, qb, vb, ge, gb, gap_rate_s(te, qs, vs, p), vr, p, tol, ext)
    if what != NO_EVENT:
        return ALONE_CASE, qn, vn, 0, t, low
    gbs = _stacked(gb)
    low = gbs[0]
    for k in range(N_CONTACT):
        low = min(low, gbs[k])
    return TAKEN, qb, vb, logged, te, low


def lane_event(t, t_next, dt, S, lane, at, to, p, tol):
    """A lane's event step (the model's ``lane_event``, passed to :func:`lanes`): :func:`event_lane` for lane
    ``lane`` of the block state S, from its state in the rows from ``at`` to its trial in those from ``to``.

    Where taken, the step's end goes into the trial's rows, the smallest gap
    there into the scratch row's first slot, and an impulse into the lane's
    count (IMPULSE_ROW, FIRST_ROW). The lane's restitution is read from its
    rows E_ROW, E_GROUND_ROW (p is the block's: its members may differ in
    those two alone). Returns what :func:`event_lane` says.
    Its own binding part, so the lanes' part links none of it: compiled
    into theirs it cost them 7 s more to compile (14.7 s against 7.5).
    """
    QV = 6 * _W
    sc = S[_SCRATCH * _W:(_SCRATCH + 1) * _W]
    what, qb, vb, logged, te, g = event_lane(t, t_next, dt, lane_state(S, at, lane), lane_state(S, at + QV, lane),
                                             lane_state(S, to, lane), lane_state(S, to + QV, lane), p, tol, sc,
                                             S[_E * _W + lane], S[_EG * _W + lane])
    if what != ALONE_CASE:
        put_lane_state(S, to, lane, qb)
        put_lane_state(S, to + QV, lane, vb)
        sc[0] = g
        if logged:
            if S[_IMPULSES * _W + lane] == 0.0:
                S[_FIRST * _W + lane] = te
            S[_IMPULSES * _W + lane] += 1.0
    return what


def time_table(t0, dt, n, p, out):
    """The terms of time (``accel_time_s``) of steps 0 .. n - 1 at the two stage times a step computes them
    (:func:`step_block`: its middle and its end, the same operations), into ``out``: row i, ``out[2 K i:2 K (i +
    1)]``, the middle's K terms and the end's; as many rows as fit. Returns K (with n = 0: K alone)."""
    K = len(accel_time_s(t0, p))
    rows = min(n, out.shape[0] // (2 * K)) if K > 0 else 0
    for i in range(rows):
        t = t0 + i * dt
        ttm = accel_time_s(t + _NODES[1] * dt, p)
        tt_next = accel_time_s(t0 + (i + 1) * dt, p)
        for k in range(K):
            out[2 * K * i + k] = ttm[k]
            out[2 * K * i + K + k] = tt_next[k]
    return K


def lanes(t0, dt, i, i_stop, S, p, tol, live, quiet, tab, event):
    """Steps i, i+1, ... of the block's live lanes together while each step is quiet for every live lane.

    S: the block's state (rows q, qd, trial q, trial qd, then per lane a bound
    on every gap at the start, NaN where the caller has moved the lane and it
    is to be computed again, the same at the trial's end, the trial step's
    band, and the bounds on the gaps' speed at the start and the trial's
    end). Returns the step reached: i_stop, or the step before which some
    live lane is not quiet; then the trial of that step is in S for every
    lane and quiet[lane] says whether that lane may take it. A lane that is
    not live is stepped too (its numbers are not used). Free boxes only: six
    coordinates, box first.

    tab: the study's terms of time (:func:`time_table`, made with the same t0
    and dt), read for the steps it covers and computed for the others.

    A live lane near a wall takes the step if the exact loop would find no
    event in it (:func:`calm`), or if ``event`` (the model's
    :func:`lane_event`, a function value) takes the exact loop's step with
    its one impact on floats; the lanes stop only before a step that needs
    more (a contact coming to rest, several at once, a second impact in it).

    The state and the trial trade rows from one step to the next instead of
    the trial being copied over the state (that copy was a quarter of the
    lanes' time): two steps a turn, each :func:`step_block` inlined with its
    rows as constants; on return they are where the caller reads them
    (:func:`trade`). (With the rows in variables swapped at each step the
    step took 11.8 ns a lane-step against 4.5.)
    """
    QV, QB = 6 * _W, 12 * _W
    GA, GB, SA, SB = _BOUND * _W, (_BOUND + 1) * _W, _SPEED * _W, (_SPEED + 1) * _W
    n = live.shape[0]       # (LANES, read at run time: see the module's docstring)
    pt = params_of(p)
    tl = tolerances_of(tol)
    t = t0 + i * dt
    for lane in range(n):
        if S[GA + lane] != S[GA + lane]:        # NaN: a lane whose state the caller changed
            S[GA + lane] = lane_bound(t, lane_state(S, 0, lane), pt)
            S[SA + lane] = _speed_bound(lane_state(S, QV, lane), tl)
    tt = accel_time_s(t, p)
    while i < i_stop:
        stop, tt = step_block(t0, dt, i, S, p, tol, live, quiet, pt, tl, tt, tab, 0, QB, GA, GB, SA, SB, event)
        if stop:
            return i
        i += 1
        if i == i_stop:
            trade(S, n)     # the state is in the trial's rows
            return i
        stop, tt = step_block(t0, dt, i, S, p, tol, live, quiet, pt, tl, tt, tab, QB, 0, GB, GA, SB, SA, event)
        if stop:
            trade(S, n)     # the state is in the trial's rows and the trial in the state's
            return i
        i += 1
    return i


def rebound(t, S, at, GA, GB, BAND, runs_low, quiet, pt):
    """The bound on every gap at time t (:func:`lane_bound`) computed again for the live lanes whose lowered
    bound runs low in a step (GB, lowered by the band), those whose bound at the step's start (GA) is low too
    included: their steps go to :func:`calm`, which reads their bounds at both ends first.

    A vector loop over those lanes alone (runs_low: bit ``lane`` set for
    each, by the step's own loop; an int64, so LANES is at most 64): their indices listed in the PACK_ROW
    rows' eighth, their coordinates (from row ``at`` on) packed side
    by side into its first six, padded with the last to a whole number of
    vectors (:data:`PAD`: a loop's remainder runs a lane at a time, at five
    times a vector lane's cost), their bounds into its seventh and from there
    back into GB; each of them quiet where its bound says so and its end is
    finite, and its bound at the start clears the band too. (Computed again for every lane of the block at once, a shaken
    study's lanes spent a sixth of their time on bounds: four lanes ran low
    at a time, out of 32.) A lane that was not quiet at the start gets its
    bound at the end all the same: with the start's, it lets :func:`calm`
    see, in most steps near a wall, that no gap is near enough for the
    exact loop to look at, without reading one. Called with at least one bit set; returns how
    many of those lanes are quiet after all.
    """
    n = quiet.shape[0]
    at_index, at_bound = (_PACK + 7) * _W, (_PACK + 6) * _W
    m = 0
    while runs_low:
        S[_u8(at_index + m)] = _trailing_zeros(runs_low)
        m += 1
        runs_low &= runs_low - 1
    padded = min(n, (m + PAD - 1) // PAD * PAD)
    for j in range(m, padded):
        S[_u8(at_index + j)] = S[_u8(at_index + m - 1)]
    for j in range(padded):
        put_lane_state(S, _PACK * _W, j, lane_state(S, at, int(S[_u8(at_index + j)])))
    for j in range(padded):
        S[_u8(at_bound + j)] = lane_bound(t, lane_state(S, _PACK * _W, j), pt)
    back = 0
    for j in range(m):
        lane = int(S[_u8(at_index + j)])
        g = S[_u8(at_bound + j)]
        S[_u8(GB + lane)] = g
        band = S[_u8(BAND + lane)]
        ok = (S[_u8(GA + lane)] >= band) & (g >= band) & finite(lane_state(S, at, lane), lane_state(S, at + 6 * _W, lane))
        quiet[lane] = ok
        back += ok
    return back


def step_block(t0, dt, i, S, p, tol, live, quiet, pt, tl, tt, tab, A, B, GA, GB, SA, SB, event):
    """Step i of every lane from the state in rows A.. to its trial in rows B.. (bounds: GA, SA to GB, SB).

    Returns (how many live lanes are not calm: 0 if the step is taken, the
    terms of time at the step's end). The rows are read and written through
    unsigned indices: with a signed one Numba wraps a negative index around at
    each access, and LLVM left a loop over the lanes that copied rows scalar.
    """
    QV = 6 * _W
    BAND = (_BOUND + 2) * _W
    n = live.shape[0]
    margin = 2.0 * tl[_T_GAP_L] - 0.5 * tl[_T_EVENT_L]
    t = t0 + i * dt
    tm = t + _NODES[1] * dt
    t_next = t0 + (i + 1) * dt
    K = len(tt)
    if 2 * K * (i + 1) <= tab.shape[0]:     # (the study's table: read, not computed)
        ttm, tt_next = time_of(tab, 2 * K * i), time_of(tab, 2 * K * i + K)
    else:
        ttm, tt_next = accel_time_s(tm, p), accel_time_s(t_next, p)
    low = 0
    stop = 0
    for lane in range(n):
        qn, vn = rk4_stages(lane_state(S, A, lane), lane_state(S, A + QV, lane), dt, pt, t, tt, tm, ttm, t_next,
                            tt_next)
        put_lane_state(S, B, lane, qn)
        put_lane_state(S, B + QV, lane, vn)
        sb = _speed_bound(vn, tl)
        band = dt * max(S[_u8(SA + lane)], sb) + margin       # as in fly
        ga = S[_u8(GA + lane)]
        c = ga - band
        S[_u8(SB + lane)] = sb
        S[_u8(BAND + lane)] = band
        S[_u8(GB + lane)] = c
        # quiet at both ends, and finite (min and max hide a NaN)
        ok = (ga >= band) & (c >= band) & finite(qn, vn)
        quiet[lane] = ok
        stop += live[lane] & (1 - ok)
        low |= (live[lane] & (c < band)) << lane
    if low:        # some live lanes' lowered bounds run low: every gap of those at the trial's end
        stop -= rebound(t_next, S, B, GA, GB, BAND, low, quiet, pt)
    if stop:       # a live lane near a wall: the exact loop's own test for an event in the step
        stop = 0
        sc = S[_SCRATCH * _W:(_SCRATCH + 1) * _W]
        for lane in range(n):
            if live[lane] and not quiet[lane]:
                vn = lane_state(S, B + QV, lane)
                if calm_by_bounds(t, t_next, lane_state(S, A + QV, lane), vn, S[_u8(GA + lane)], S[_u8(GB + lane)], tl):
                    quiet[lane] = 1     # (its bound at the end stays)
                    continue
                ok, g = calm(t, t_next, lane_state(S, A, lane), lane_state(S, A + QV, lane), lane_state(S, B, lane),
                             vn, p, tol, sc)
                if ok:
                    quiet[lane] = 1
                    S[_u8(GB + lane)] = g
                    continue
                # an event in the step: the exact loop's impact step, on floats, where it is a plain one
                if event(t, t_next, dt, S, lane, A, B, p, tol) == ALONE_CASE:
                    stop += 1
                    continue
                quiet[lane] = 1
                S[_u8(GB + lane)] = sc[0]
                S[_u8(SB + lane)] = _speed_bound(lane_state(S, B + QV, lane), tl)
    return stop, tt_next


def trade(S, n):
    """The state's rows and the trial's, and their bounds, trade places (see :func:`lanes`)."""
    for lane in range(n):
        for r in range(12):
            a, b = _u8(r * _W + lane), _u8((12 + r) * _W + lane)
            S[a], S[b] = S[b], S[a]
        for row in (_BOUND, _SPEED):
            a, b = _u8(row * _W + lane), _u8((row + 1) * _W + lane)
            S[a], S[b] = S[b], S[a]


#: the helpers a lanes part inlines at Numba's level (``inline="always"``): a loop over the lanes
#: with a call left in it is not vectorised
INLINED = ("sincos", "lane_state", "put_lane_state", "clearance_v", "lane_bound", "params_of", "tolerances_of", "finite", "step_block",
           "rebound", "calm_by_bounds")
