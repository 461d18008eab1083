"""Event location: when, inside a step, a free gap first closes or a held contact's force turns.

A step that would end with a free gap below zero, or whose cubic through the
gaps and rates at both ends dips below zero (a grazing corner), is re-stepped
from its start with shorter steps (Illinois iteration on the step length) to
the first crossing, so the state at the event is an RK4 state and the method
keeps order four. Likewise a persistent contact whose force would turn
negative is released where it is zero.

The re-steps go through ``step``, the integrator's compiled function value
(:data:`jackbox.engine.records.STEP`), so neither :func:`first_crossing` nor
:func:`first_release` carries a copy of it.
"""

import math

import numpy as np
from numba import njit

from .gaps import cubic_error, dip_free, hermite, hermite_extrema, hermite_slope, step_reach
from .modes import accel, contact_accel
from .records import (AF, DLEV, FLAGS, GA, GAP_ROUNDOFF, GB, GS, HUMP, LAM, LAMA, LAMB, LEV, LR, LS, QB, QDB, QDS, QS, RIDX,
                      T_AREST, T_EVENT, T_VREST, VA, VB, WARN_LOCATE)

#: the deepest level (in T_EVENT below the held level) at which a free contact's event is looked for
DEEPEST = 4.0
# kinds of event function (passed as np.int64: a bare literal would make Numba
# compile one specialisation per value)
GAP_EVENT = 0           #: a gap plus its level (``ws.c[LEV]``) reaches zero
FORCE_EVENT = 1         #: a persistent contact's force reaches zero
#: the probes :func:`locate` (and a lane's ``lanes.locate_lane``) takes at most
LOCATE_PROBES = 200


@njit(cache=True, no_cpython_wrapper=True)
def event_value(model, step, kind, pos, ta, q, qd, s, p, tol, m, ws):
    """Re-step from (ta, q, qd) to time s; the event function there.

    kind GAP_EVENT: gap ``pos`` plus its level ``ws.c[LEV, pos]``; FORCE_EVENT: the force of
    persistent contact ``ws.k[RIDX][pos]``. The state at s is left in
    ``ws.n[QS]``, ``ws.n[QDS]``.
    """
    qs, qds = ws.n[QS], ws.n[QDS]
    step(model, ta, q, qd, s - ta, p, qs, qds, m, ws)
    if kind == GAP_EVENT:
        g = ws.c[GS]
        model.phi(s, qs, p, g)
        return g[pos] + ws.c[LEV, pos]
    accel(model, s, qs, qds, p, m, ws.n[AF], ws)
    return ws.c[LAM, pos]


@njit(cache=True, no_cpython_wrapper=True)
def locate(model, step, kind, pos, ta, q, qd, tl, fl, tr, fr, guess, p, tol, m, ws):
    """Illinois iteration for the root of the event function in [tl, tr] (fl >= 0 > fr).

    guess: a first probe (the root of the gap's cubic through the step), or
    outside (tl, tr) for none. No probe comes closer than half the tolerance
    to an end of the bracket: once one end's value is at round-off (the
    secant then lands on that end), the next probe just inside it closes the
    bracket, where a bisection would crawl there in some fifteen halvings.
    Returns (tl, tr) with f(tl) >= 0 > f(tr) and tr - tl near machine
    precision, or, for a gap, as soon as a probe finds it within GAP_ROUNDOFF
    of T_EVENT above its level: the state there is at the event to round-off,
    and below that a gap's sign is noise (a slow approach would otherwise
    take some twenty probes of noise to narrow the bracket). Not the
    bracket's own left end: a gap that starts the step that close to its
    level (let go there, or leaving) has its event later in the step, and
    taking it at the start made no progress (the step then went to the
    fallback, three times as often). If LOCATE_PROBES do not get there,
    sets WARN_LOCATE in ``ws.k[FLAGS, 0]``. Returns ``(tl, tr, last)``: last is
    the time of the last probe, whose state is left in ``ws.n[QS]``,
    ``ws.n[QDS]`` (-1: no probe, nothing left there).
    """
    side = 0
    last = -1.0
    ttol = time_tolerance(ta, tr)
    ftol = GAP_ROUNDOFF * tol[T_EVENT] if kind == GAP_EVENT else -1.0
    t_start = tl
    done = False
    for it in range(LOCATE_PROBES):
        if tr - tl <= ttol or (tl > t_start and fl <= ftol):
            done = True
            break
        s = illinois_probe(it, tl, fl, tr, fr, guess, ttol)
        f = event_value(model, step, kind, pos, ta, q, qd, s, p, tol, m, ws)
        last = s
        tl, fl, tr, fr, side = illinois_keep(s, f, tl, fl, tr, fr, side)
    if not done and tr - tl > ttol:
        ws.k[FLAGS, 0] |= WARN_LOCATE
    return tl, tr, last


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def time_tolerance(ta, tr):
    """How close :func:`locate` brackets an event in a step from ta (tr: the bracket's right end)."""
    return 4.0 * 2.220446049250313e-16 * max(abs(tr), tr - ta)


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def illinois_probe(it, tl, fl, tr, fr, guess, ttol):
    """:func:`locate`'s probe number ``it`` in the bracket (tl, tr): the guess first, then the secant's root (the
    middle where that is outside or NaN, fl = fr), at least half the tolerance inside each end."""
    if it == 0 and tl < guess < tr:
        s = guess
    else:
        s = (tl * fr - tr * fl) / (fr - fl)
        if not (tl <= s <= tr):       # (NaN: fl = fr)
            s = 0.5 * (tl + tr)
    return min(max(s, tl + 0.5 * ttol), tr - 0.5 * ttol)


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def illinois_keep(s, f, tl, fl, tr, fr, side):
    """The bracket after a probe at s of value f: ``(tl, fl, tr, fr, side)``, the end kept a second time running
    halved (Illinois), side the end the probe replaced (-1 the left, 1 the right)."""
    if f >= 0.0:
        tl, fl = s, f
        if side == -1:
            fr *= 0.5
        side = -1
    else:
        tr, fr = s, f
        if side == 1:
            fl *= 0.5
        side = 1
    return tl, fl, tr, fr, side


@njit(cache=True, no_cpython_wrapper=True)
def cubic_root(fa, fb, da, db, sl, sr):
    """The root in (sl, sr) of the cubic with values fa, fb and slopes da, db at 0 and 1, or -1.

    Where the cubic is positive at sl and negative at sr; on the polynomial
    alone (no step of the model). Where it falls all the way from sl to sr
    (its slope negative on the whole bracket: one root), by Newton's method
    kept inside the bracket, to the last bit: five or six evaluations where a
    bisection takes fifty-odd (it was 6-10% of an ensemble's time in lanes).
    Otherwise (it may cross three times) the bracket is halved, keeping the
    sign change, only until it falls all the way (then Newton's method on
    it: the root that halving to the last bit would reach, since a bracket
    that falls all the way holds one root), at most to the last bit. The
    cubic is RK4's own gap to O(h^4), so its root is a first probe close to
    the event.
    """
    hl, hr = hermite(fa, fb, da, db, sl), hermite(fa, fb, da, db, sr)
    if not (hl >= 0.0 > hr):
        return -1.0
    A, B, C = hermite_slope(fa, fb, da, db)
    for _ in range(60):
        if falls(A, B, C, sl, sr):
            return newton_root(fa, fb, da, db, A, B, C, sl, sr, hl, hr)
        mid = 0.5 * (sl + sr)
        if not sl < mid < sr:
            break
        h = hermite(fa, fb, da, db, mid)
        if h >= 0.0:
            sl, hl = mid, h
        else:
            sr, hr = mid, h
    return 0.5 * (sl + sr)


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def falls(A, B, C, sl, sr):
    """Whether the slope A s^2 + B s + C is negative on all of [sl, sr] (its largest value: an end or the vertex)."""
    top = max((A * sl + B) * sl + C, (A * sr + B) * sr + C)
    if A < 0.0:
        vertex = -B / (2.0 * A)
        if sl < vertex < sr:
            top = max(top, (A * vertex + B) * vertex + C)
    return top < 0.0


@njit(cache=True, no_cpython_wrapper=True)
def newton_root(fa, fb, da, db, A, B, C, sl, sr, hl, hr):
    """:func:`cubic_root` on a bracket the cubic falls all the way across (hl >= 0 > hr its ends' values)."""
    s = sl + (sr - sl) * hl / (hl - hr)      # the secant's root: inside the bracket
    for _ in range(100):
        if not sl < s < sr:
            s = 0.5 * (sl + sr)
            if not sl < s < sr:              # no float left between the ends
                break
        f = hermite(fa, fb, da, db, s)
        if f >= 0.0:
            sl = s
        else:
            sr = s
        step = f / ((A * s + B) * s + C)
        if not abs(step) < 0.5 * (sr - sl):  # too long (or NaN): bisect the bracket instead
            s = 0.5 * (sl + sr)
        elif s - step == s:                  # converged: the step is below the last bit of s
            return s
        else:
            s = s - step
    return 0.5 * (sl + sr)


@njit(cache=True, no_cpython_wrapper=True)
def left_bracket(model, step, k, ta, h, fa, fb, da, db, sr, q, qd, p, tol, m, ws):
    """Left end of the bracket of gap k's first crossing before ta + sr h.

    The step's start, or, for a gap that is opening at the start (just after a
    bounce, fa near zero), the hump of the cubic through its values and rates
    at both ends, when the RK4 state there is further from contact. Returns
    ``(tl, fl, probe)``: probe is the time of the re-step to the hump, whose
    state is left in ``ws.n[QS]`` (-1: none, nothing left there).
    """
    tl, fl = ta, fa
    probe = -1.0
    s = first_hump(fa, fb, da, db, sr, ws.ext)
    if s >= 0.0:
        probe = ta + s * h
        f = event_value(model, step, np.int64(GAP_EVENT), k, ta, q, qd, probe, p, tol, m, ws)
        if f > fl:
            tl, fl = probe, f
    return tl, fl, probe


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def first_hump(fa, fb, da, db, sr, ext):
    """Where :func:`left_bracket` looks (in units of the step, before sr): the first stationary point of a gap's
    cubic above its start, for a gap opening at the start (da > 0); -1 for none."""
    if da > 0.0:
        for j in range(hermite_extrema(fa, fb, da, db, ext)):
            if ext[j] < sr and hermite(fa, fb, da, db, ext[j]) > fa:
                return ext[j]
    return -1.0


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def first_dip(fa, fb, da, db, error, sr, ext):
    """Where :func:`first_crossing` steps into a step (in units of it) to look: the first stationary point of a
    gap's cubic below zero, or below both ends by more than the cubic's error, before sr (sr < 0: anywhere);
    -1 for none."""
    for j in range(hermite_extrema(fa, fb, da, db, ext)):
        hv = hermite(fa, fb, da, db, ext[j])
        # (a dip: the cubic falls below both ends by more than its error; a contact sitting
        # at its level, its cubic flat within round-off, is not looked at every step)
        if (hv < 0.0 or hv < error < min(fa, fb) - hv) and (sr < 0.0 or ext[j] < sr):
            return ext[j]
    return -1.0


@njit(cache=True, no_cpython_wrapper=True)
def first_crossing(model, step, ta, tb, q, qd, p, tol, rest, m, ws):
    """The earliest time in (ta, tb] where a free gap crosses its event level, or -1.

    The level is -T_EVENT/2, where persistent contacts are held, except for a
    contact that starts the step at or below it without approaching (the
    contact update left it there, leaving or closed by round-off): its event is
    a return to T_EVENT below where it starts (and at least T_EVENT below the
    held level, at most DEEPEST T_EVENT), so that it takes no event to leave,
    also from a little deeper (where a projection of the other contacts moved it
    when they were let go). Such a contact that rises above the held level
    inside the step (its cubic's hump above the level by more than the
    cubic's error) has its return there as an event at the held level, from
    the hump on: with the deep level for the whole step, one that flew off
    and came back within it was taken up to 4 T_EVENT deep (a box corner
    chattering on an elastic ground, a recorded sample 3.85e-12 L deep).

    Uses the trial state at tb in ``ws.n[QB]``, ``ws.n[QDB]`` and its gaps
    ``ws.c[GB]``; the gaps at ta are ``ws.c[GA]``. On success the state just
    before the crossing (every free gap above its level) is left in
    ``ws.n[QS]``, ``ws.n[QDS]`` and the returned value is its time; returns
    ta when a contact is already closing at ta with nothing to separate it (a
    touch).
    """
    C = model.n_contact
    h = tb - ta
    half = 0.5 * tol[T_EVENT]
    deep = half + tol[T_EVENT]
    gap_kind = np.int64(GAP_EVENT)
    ga, gb, va, vb, lev = ws.c[GA], ws.c[GB], ws.c[VA], ws.c[VB], ws.c[LEV]
    hump, dlev = ws.c[HUMP], ws.c[DLEV]
    band = step_reach(qd, ws.n[QDB], h, tol)
    # a dip whose cubic stays above zero by less than the cubic's own error is looked at (one
    # re-step to its bottom): a corner turning fast can dip below zero where its cubic does not
    dip = cubic_error(qd, ws.n[QDB], h, tol)
    # no free gap within the step's reach, or none that its rates could take below dip_free: no event
    clear = dip_free(band, dip, tol)
    near = False
    for k in range(C):
        g = min(ga[k], gb[k])
        if not rest[k] and g + deep < band and g + half < clear:
            near = True
            break
    if not near:
        return -1.0
    model.gap_rate(ta, q, qd, p, va)
    model.gap_rate(tb, ws.n[QB], ws.n[QDB], p, vb)
    tiny = 1e-3 * tol[T_VREST]
    for k in range(C):
        # (a contact the update left inside the band without approaching: its event is a
        # return to T_EVENT below where it starts; at a fixed level one that starts below it,
        # leaving, was a touch at the step's start that no update resolved)
        lev[k] = (min(max(deep, tol[T_EVENT] - ga[k]), DEEPEST * tol[T_EVENT])
                  if ga[k] + half < 0.0 and va[k] >= -tiny else half)
        dlev[k] = lev[k]
        hump[k] = -math.inf      # (the time from which lev[k] holds: the whole step)
    ext = ws.ext
    # the time whose RK4 state (and gaps) the last re-step left in ws.n[QS] (and ws.c[GS]); -1: none
    # known. The state just before the crossing is stepped to again only where it is not that one
    # (locate's last probe is its bracket's left end whenever it stops at the event to round-off)
    at = -1.0
    best_l = -1.0
    best_k = -1
    t_hi = tb
    for k in range(C):
        if rest[k]:
            continue
        da, db = h * va[k], h * vb[k]
        if lev[k] > half and da > 0.0:
            # a deep start rising: above the held level at its cubic's hump, by more than the cubic's
            # error (so RK4's state there is too), its return is an event at the held level from there on
            if hermite_extrema(ga[k] + half, gb[k] + half, da, db, ext) > 0 and \
                    hermite(ga[k] + half, gb[k] + half, da, db, ext[0]) > dip:
                lev[k] = half
                hump[k] = ta + ext[0] * h
        fa, fb = ga[k] + lev[k], gb[k] + lev[k]
        if min(fa, fb) >= band:
            continue
        # right end of the bracket: the step's end, or a dip of the cubic below its error
        sr = -1.0
        fr = 0.0
        if fb < 0.0:
            sr, fr = 1.0, fb
        s = first_dip(fa, fb, da, db, dip, sr, ext)
        if s >= 0.0:
            sr = s
            fr = event_value(model, step, gap_kind, k, ta, q, qd, ta + sr * h, p, tol, m, ws)
            at = ta + sr * h
            if fr >= 0.0:
                sr = 1.0 if fb < 0.0 else -1.0
                fr = fb
        if sr < 0.0:
            continue
        tr = ta + sr * h
        if best_k >= 0 and tr > t_hi:
            # a later bracket: only matters if this gap is already negative at the best time
            continue
        tl, fl, probe = left_bracket(model, step, k, ta, h, fa, fb, da, db, sr, q, qd, p, tol, m, ws)
        if probe >= 0.0:
            at = probe
        if fl <= 0.0:
            return ta  # touching now, with no resolvable flight before the crossing
        guess = ta + h * cubic_root(fa, fb, da, db, (tl - ta) / h, sr)
        tl, tr, last = locate(model, step, gap_kind, k, ta, q, qd, tl, fl, tr, fr, guess, p, tol, m, ws)
        if last >= 0.0:
            at = last
        if best_k < 0 or tl < best_l:
            best_l, best_k = tl, k
            t_hi = tr
    if best_k < 0:
        return -1.0
    # The state just before the first crossing; any other gap already below
    # its level there crossed earlier: locate it within [ta, best].
    for _ in range(C):
        if at != best_l:
            event_value(model, step, gap_kind, np.int64(best_k), ta, q, qd, best_l, p, tol, m, ws)
            at = best_l
        g = ws.c[GS]
        worst = -1
        low = 0.0
        for k in range(C):
            lk = lev[k] if best_l >= hump[k] else dlev[k]     # (before its hump, a deep start's own level)
            if not rest[k] and g[k] + lk < 0.0 and (worst < 0 or g[k] + lk < low):
                worst = k
                low = g[k] + lk
        if worst < 0:
            return best_l
        if best_l < hump[worst]:     # below its deep level before its hump: that level for the whole step
            lev[worst] = dlev[worst]
            hump[worst] = -math.inf
        fr = g[worst] + lev[worst]
        fa, fb = ga[worst] + lev[worst], gb[worst] + lev[worst]
        sr = (best_l - ta) / h
        tl, fl, probe = left_bracket(model, step, np.int64(worst), ta, h, fa, fb, h * va[worst], h * vb[worst], sr,
                                     q, qd, p, tol, m, ws)
        if probe >= 0.0:
            at = probe
        if fl <= 0.0:
            return ta
        guess = ta + h * cubic_root(fa, fb, h * va[worst], h * vb[worst], (tl - ta) / h, sr)
        tl, tr, last = locate(model, step, gap_kind, np.int64(worst), ta, q, qd, tl, fl, best_l, fr, guess, p, tol,
                              m, ws)
        if last >= 0.0:
            at = last
        best_l, best_k = tl, worst
    return best_l


@njit(cache=True, no_cpython_wrapper=True)
def first_release(model, step, ta, tb, q, qd, p, tol, m, ws):
    """When the earliest persistent contact's force turns negative in (ta, tb], or -1.

    A force pulls when it would accelerate its gap away faster than T_AREST
    (below that the contact is still: round-off on a redundant set). The
    step's own forces, at the integrator's four stages (``ws.c[LS + s]``, left
    by the step from ta to tb that the caller has just taken), screen it: where
    none pulls, nothing is computed. Otherwise the forces at ta (the first
    stage's) and then at tb decide, or, where neither pulls, those at the
    step's middle (a pull that lasts less than the step: a floor that shakes
    faster than dt resolves). Returns the time just after the sign change (the
    force is negative there), or ta when a force already pulls at ta. The
    contacts whose force pulls there go to the contact update as a bit mask
    in ``ws.k[FLAGS, 1]``: it lets them go unless the accelerations' LCP
    gives them a force (at the located zero of a force its acceleration is
    zero too, and would count as still).
    """
    lam_a, lam_b, floor = ws.c[LAMA], ws.c[LAMB], ws.c[LR]
    for i in range(m):
        floor[i] = -tol[T_AREST] / ws.A[i, i]      # the force that pulls the gap away at T_AREST
    screened = False
    for s in range(4):
        for i in range(m):
            if not ws.c[LS + s, i] >= floor[i]:     # (NaN too, as the force's minimum would)
                screened = True
    if not screened:
        return -1.0
    ridx = ws.k[RIDX]
    pulls = 0
    for i in range(m):
        lam_a[i] = ws.c[LS, i]           # stage 1: the forces at (ta, q, qd)
        if not lam_a[i] >= floor[i]:
            pulls |= np.int64(1) << ridx[i]
    if pulls:                            # pulling already: the contact update decides, now
        ws.k[FLAGS, 1] = pulls
        return ta
    t_hi = tb
    for probe in range(2):
        if probe == 0:
            contact_accel(model, tb, ws.n[QB], ws.n[QDB], p, m, ws.n[AF], ws)
        else:                            # no pull at tb: the middle of the step
            t_hi = 0.5 * (ta + tb)
            step(model, ta, q, qd, t_hi - ta, p, ws.n[QS], ws.n[QDS], m, ws)
            contact_accel(model, t_hi, ws.n[QS], ws.n[QDS], p, m, ws.n[AF], ws)
        for i in range(m):
            lam_b[i] = ws.c[LAM, i]
            floor[i] = -tol[T_AREST] / ws.A[i, i]
            if not lam_b[i] >= floor[i]:
                pulls |= np.int64(1) << ridx[i]
        if pulls:
            break
    if not pulls:
        return -1.0
    ws.k[FLAGS, 1] = pulls
    best = -1.0
    for i in range(m):
        if lam_b[i] >= floor[i]:
            continue
        tl, tr, _ = locate(model, step, np.int64(FORCE_EVENT), np.int64(i), ta, q, qd, ta, max(lam_a[i], 0.0), t_hi,
                           lam_b[i], -1.0, p, tol, m, ws)
        if best < 0.0 or tr < best:
            best = tr
    return best
