"""Contact modes: which contacts are persistent (held closed), and the dynamics with them held.

Between events the state follows the dynamics with the persistent contacts R
held closed: ``qdd = M^-1 f + M^-1 J_R^T lam``, with ``lam`` solving
``(J_R M^-1 J_R^T) lam = -(J_R M^-1 f + gap_bias_R)`` (gap accelerations
zero), by a rank-revealing solve (:func:`~.impact.factor_rows`): every held
row is held, also on a redundant set, where the forces are not unique.

Contacts are held at the level where events are located, ``gap = -T_EVENT/2``
(:func:`project_rest` puts them there): a contact let go falls from that level,
not from gap 0 through the extra half band, so it comes back at the speed its
flight gives it, not at ``sqrt(|a| T_EVENT)``.

Integers passed on to other jitted functions are wrapped in ``np.int64``: a
value Numba can see as a constant (a literal 0, a global) would otherwise make
it compile the callee once more for that constant. At an event (:func:`update_contacts`) the contacts that take part get
their impulses (:mod:`jackbox.engine.impact`), then the accelerations' LCP
decides which closed, still contacts carry a force: those stay (or become)
persistent, the others are released. :func:`project_rest` removes RK4's drift
off the held contacts after each step.
"""


import numpy as np
from numba import njit

from .impact import PGS_SWEEPS, contact_matrix, factor_rows, lcp, restitution, solve_lcp, solve_rows
from .records import (ACC, BOUNCE, CAND, CARRIES, FLAGS, FOLLOWS, GS, HIT, IMPULSE, LAM, NEAR, NEWREST, PRESS, RELEASE,
                      REPASS, REPASSES, REST, RHS, RIDX, RINV, ROW_BIAS, ROW_GAP, ROW_RATE, SLOW, SLOW_AT, STILL, T_AREST, T_EVENT, T_GAP, T_VREST, VB, VREST, WINV)
from .tolerances import ZENO_TOL, rest_speed, step_of, zeno_rest_ahead


@njit(cache=True, no_cpython_wrapper=True)
def rest_index(rest, C, ridx):
    """Indices of the persistent contacts (of the first C slots of ``rest``) into ridx; returns their number.

    Those the accelerations' LCP gave a force (``rest[k] == CARRIES``) come
    first, then those it held still with none (``STILL``): the held dynamics'
    rank-revealing solve (:func:`~.impact.factor_rows`) keeps the rows in this
    order and gives the rows that depend on earlier ones no force, so on a
    redundant set (a square jack flush in a corner: four contacts, three
    degrees of freedom) the forces it finds are the LCP's, none pulling. In
    the contacts' own order the solve had put the load of a dependent contact
    on the others, one of them pulling hard (-5.8 N against a floor of
    -1.7e-5 N, a jack in a corner of the shaken box at e = 0): the release
    screen stopped every step, and the contact update held the same set again.
    The accelerations do not depend on the order (they are unique where the
    forces are not).
    """
    m = 0
    for k in range(C):
        if rest[k] == CARRIES:
            ridx[m] = k
            m += 1
    for k in range(C):
        if rest[k] == STILL:
            ridx[m] = k
            m += 1
    return m


@njit(cache=True, no_cpython_wrapper=True)
def hold_independent(model, rest, ws):
    """Mark the persistent wall contacts that the others fix by the geometry alone FOLLOWS: not rows of the held dynamics.

    A wall contact's gap depends on the jack's pose in the box alone, three
    degrees of freedom, and the rows of the walls of one direction (the floor
    and the ceiling, or the two sides) on two of them: so ``h`` rows held on
    the floor and ceiling and ``v`` on the sides have rank at most
    ``min(3, min(h, 2) + min(v, 2))`` at every pose (a square jack flush in a
    corner: four contacts, three degrees of freedom). Where more are held,
    the held rows' rank-revealing factorization (:func:`~.impact.factor_rows`,
    in :func:`rest_index`'s order, the held dynamics' own) finds the wall rows
    that depend on those before them; as many as the excess are taken out of
    the held dynamics (their forces are 0 there, their gaps follow the held
    rows' exactly), so that a step in a corner reads and factors three rows,
    not four. They stay persistent (none is free: no event, no near test),
    and the next contact update looks at them as at every held contact.
    The rows ``ws.jac`` of the held contacts must be those at the state.
    """
    C, nw = model.n_contact, model.n_wall
    per_wall = nw // 4
    h = v = 0
    for k in range(nw):
        if rest[k]:
            if (k // per_wall) % 2:
                h += 1
            else:
                v += 1
    excess = h + v - min(3, min(h, 2) + min(v, 2))
    if excess <= 0:
        return
    ridx = ws.k[RIDX]
    m = rest_index(rest, C, ridx)
    contact_matrix(ws.jac, ws.n[WINV], ridx, np.int64(m), ws.A)
    rinv = ws.c[RINV]
    factor_rows(ws.A, np.int64(m), ws.lu, rinv)
    for j in range(m):
        if excess > 0 and rinv[j] == 0.0 and ridx[j] < nw:
            rest[ridx[j]] = FOLLOWS
            excess -= 1


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def add_response(jac, winv, ridx, m, x, n, out):
    """out += M^-1 J^T x over the m contacts ``ridx[:m]`` (M diagonal: ``winv`` = diag(M^-1)).

    The body's answer to contact forces (into accelerations), position
    corrections (into coordinates) or impulses (into rates).
    """
    for d in range(n):
        s = 0.0
        for i in range(m):
            s += jac[ridx[i], d] * x[i]
        out[d] += winv[d] * s


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def accel(model, t, q, qd, p, m, a, ws):
    """Accelerations into a: the model's own (m = 0), or with the m persistent contacts held.

    Inlined where it is called, so that a free step reaches the model's
    function in one call: through :func:`contact_accel`, which is not
    inlined, each call would pass on (and count references to) a dozen arrays.
    """
    if m == 0:
        model.accel(t, q, qd, p, a)
    else:
        contact_accel(model, t, q, qd, p, m, a, ws)


@njit(cache=True, no_cpython_wrapper=True)
def contact_accel(model, t, q, qd, p, m, a, ws):
    """Accelerations with the m persistent contacts (``ws.k[RIDX]``) held closed.

    Fills a; leaves the contact forces in ``ws.c[LAM, :m]``, their matrix in
    ``ws.A`` and ``ws.jac = phi_q``.
    """
    if m == 0:
        model.accel(t, q, qd, p, a)
        return
    winv = ws.n[WINV]
    model.inverse_mass(p, winv)
    held_accel(model, t, q, qd, p, m, a, ws.k[RIDX], ws.jac, winv, ws.A, ws.lu, ws.c[RINV], ws.c[RHS], ws.c[LAM],
               np.bool_(False))


@njit(cache=True, no_cpython_wrapper=True)
def held_accel(model, t, q, qd, p, m, a, ridx, jac, winv, A, L, rinv, y, lam, factored):
    """:func:`contact_accel` on the arrays themselves, ``winv = diag(M^-1)`` already filled.

    The held step's own coding (called by :func:`jackbox.engine.integrator.rk4_rows`):
    a call that passed the scratch and model records would pass each of
    their fields, some hundred and fifty words, about 100 ns a call. The
    held contacts' rows come from one call of the model's ``contact_rows``
    (their Jacobian rows and biases only, each angle's sine and cosine once).
    y: the right-hand side, then the forward substitution's unknowns; lam:
    the forces; L, rinv: the factorization (:func:`~.impact.factor_rows`).
    factored: L and rinv already hold the factorization of the rows at q
    (:func:`settle_rows` left it), the same numbers this call would compute:
    the rows are read again (their bias is of qd), the matrix is not.
    :func:`~.impact.factor_rows` and :func:`~.impact.solve_rows` are inlined
    here as wherever they are called (their calls' arguments were some 5% of
    a held step). Inlining
    this function too into :func:`~.integrator.rk4_pass` gained 6% more, but
    rk4_pass is in every stage that steps (the crossing search's too), and
    the first result of ``jackbox run`` then took 1.1 s longer to compile
    (12.40 s against 11.30, ``jackbox bench --compile``): not kept.
    """
    model.accel(t, q, qd, p, a)
    model.contact_rows(t, q, qd, p, ridx, m, jac)
    n = model.n_dof
    if n == 6 and m == 1:
        held_solve(a, ridx, jac, winv, A, L, rinv, y, lam, factored, 1, 6)
    elif n == 6 and m == 2:
        held_solve(a, ridx, jac, winv, A, L, rinv, y, lam, factored, 2, 6)
    else:
        held_solve(a, ridx, jac, winv, A, L, rinv, y, lam, factored, m, n)


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def held_solve(a, ridx, jac, winv, A, L, rinv, y, lam, factored, m, n):
    """The forces of :func:`held_accel` (the rows read) and their response, added to a.

    Inlined where held_accel calls it, once for each of the held sets a free
    box's pair rides on most (one tip, or two, on a floor) with m and n
    constants, so that its loops are unrolled, and once for the rest: the
    same operations in the same order, so the same numbers. A held step
    riding a shaken floor on two tips took 0.89 of its time (935 ns against
    1050, ``bench.Stretch`` of shaken at e = 0); the rows' matrix over a
    constant n as well gained nothing more, and so did the same for the
    settling of the rows after a step (:func:`settle_rows`).
    """
    if not factored:
        contact_matrix(jac, winv, ridx, m, A)
        factor_rows(A, m, L, rinv)
    for i in range(m):
        k = ridx[i]
        s = jac[k, n + ROW_BIAS]
        for d in range(n):
            s += jac[k, d] * a[d]
        y[i] = -s
    solve_rows(y, m, L, rinv, y, lam)
    add_response(jac, winv, ridx, m, lam, n, a)


@njit(cache=True, no_cpython_wrapper=True)
def project_rest(model, t, q, qd, p, m, level, passes, ws):
    """Put the persistent contacts back on gap = -level and rate = 0 (removes RK4's drift).

    The smallest correction in the metric of M onto every held row (a
    redundant set included: :func:`~.impact.factor_rows`), by ``passes``
    Newton passes on the gaps: after a step of the held dynamics the drift is
    O(dt^5) and one pass leaves its square; after an event, two. The rates
    are projected with the last pass's factorization: the rows it was taken
    at differ from the final ones by the last correction, whose effect on the
    rates is of its square too.
    """
    winv = ws.n[WINV]
    model.inverse_mass(p, winv)
    project_rows(model, t, q, qd, p, m, level, passes, ws.k[RIDX], ws.jac, winv, ws.A, ws.lu, ws.c[RINV], ws.c[RHS],
                 ws.c[LAM], np.bool_(False))


@njit(cache=True, no_cpython_wrapper=True)
def project_rows(model, t, q, qd, p, m, level, passes, ridx, jac, winv, A, L, rinv, y, x, factored):
    """:func:`project_rest` on the arrays themselves (``winv`` filled), like :func:`held_accel`.

    Each pass reads the held rows (gaps and Jacobian) from one call of the
    model's ``contact_rows`` (factored: the first pass's rows and their
    factorization are in jac, L and rinv already); the rates are read at the
    corrected coordinates by one more, and projected with the last pass's
    factorization. Where a gap is still off its level by more than REPASS of
    it after the passes asked for (a drift too large for one pass to leave
    round-off), up to REPASSES more passes, from the rows already read.
    """
    n = model.n_dof
    if not factored:
        model.contact_rows(t, q, qd, p, ridx, m, jac)
        contact_matrix(jac, winv, ridx, m, A)
        factor_rows(A, m, L, rinv)
    j = 0
    while True:
        for i in range(m):
            y[i] = -(jac[ridx[i], n + ROW_GAP] + level)
        solve_rows(y, m, L, rinv, y, x)
        add_response(jac, winv, ridx, m, x, n, q)
        j += 1
        model.contact_rows(t, q, qd, p, ridx, m, jac)
        if j >= passes and (j >= passes + REPASSES or on_level(jac, ridx, m, n, level, REPASS * level, 0.0)):
            break
        contact_matrix(jac, winv, ridx, m, A)
        factor_rows(A, m, L, rinv)
    project_rates(jac, winv, ridx, m, n, L, rinv, y, x, qd)


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def project_rates(jac, winv, ridx, m, n, L, rinv, y, x, qd):
    """The held rows' rates (their ROW_RATE column in jac) to zero: qd corrected in the metric of M, by the factorization in L, rinv."""
    for i in range(m):
        y[i] = -jac[ridx[i], n + ROW_RATE]
    solve_rows(y, m, L, rinv, y, x)
    add_response(jac, winv, ridx, m, x, n, qd)


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def settle_rows(model, t, q, qd, p, m, level, drift, dt, ridx, jac, winv, A, L, rinv, y, x):
    """The held rows back on their level after a held step of length dt without events.

    Reads the rows at (t, q, qd) and factors them. Where every held gap is
    within ``drift`` of -level and no rate would move it by more in the next
    step (RK4's drift is O(dt^5): at rest, or riding a shaken box, it is
    round-off), only the rates are projected, with that factorization, which
    is left (in L and rinv) for the next step's first stage: returns True
    (see :func:`held_accel`). Otherwise one Newton pass of
    :func:`project_rows` from those rows, which moves q: False. A full
    projection after every step made a held step cost a third more.
    Inlined into :func:`~.loop.hold`, its only caller, with
    :func:`project_rates` (the calls' arguments were 5% of a held step).
    """
    n = model.n_dof
    model.contact_rows(t, q, qd, p, ridx, m, jac)
    contact_matrix(jac, winv, ridx, m, A)
    factor_rows(A, m, L, rinv)
    if not on_level(jac, ridx, m, n, level, drift, dt):
        project_rows(model, t, q, qd, p, m, level, np.int64(1), ridx, jac, winv, A, L, rinv, y, x, np.bool_(True))
        return False
    project_rates(jac, winv, ridx, m, n, L, rinv, y, x, qd)
    return True


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def on_level(jac, ridx, m, n, level, drift, dt):
    """Whether every held row in jac (its gap and rate columns) is within ``drift`` of gap = -level, and no rate moves it by more in a step dt."""
    for i in range(m):
        k = ridx[i]
        if not (abs(jac[k, n + ROW_GAP] + level) <= drift and abs(jac[k, n + ROW_RATE]) * dt <= drift):
            return False
    return True


@njit(cache=True, no_cpython_wrapper=True)
def log_event(t, k, kind, log, n_ev):
    """Append an event to the log (an Events record) if it has room; returns the new count."""
    if n_ev < log.t.shape[0]:
        log.t[n_ev] = t
        log.k[n_ev] = k
        log.kind[n_ev] = kind
    return n_ev + 1


@njit(cache=True, no_cpython_wrapper=True)
def unlog_rest_ahead(t, k, tol, log, n_ev):
    """Contact k is released at t: its rest, where logged ahead of t (:func:`update_contacts`), is moved to t
    (the cascade it ended did not finish). Only the entries of the last ZENO_TOL dt can lie ahead."""
    since = t - ZENO_TOL * step_of(tol)
    j = min(n_ev, log.t.shape[0]) - 1
    while j >= 0 and log.t[j] >= since:
        if log.k[j] == k and log.kind[j] == REST:
            log.t[j] = min(log.t[j], t)
            return
        j -= 1


@njit(cache=True, no_cpython_wrapper=True)
def near_rows(model, t, q, qd, p, near, m, jac, v):
    """The rows of the m contacts ``near[:m]`` into jac, and their rates into v.

    The impulses' right-hand sides take the rates from the same rows as the
    impulses' directions: an elastic impact then returns the energy it takes
    to round-off (rates from ``gap_rate``, the same value written otherwise,
    differ by round-off of the rates' large terms, which a fast turning jack
    makes large).
    """
    model.contact_rows(t, q, qd, p, near, np.int64(m), jac)
    n = model.n_dof
    for i in range(m):
        k = near[i]
        v[k] = jac[k, n + ROW_RATE]


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def time_resolution(t):
    """The time resolution at t: what the contact update allows for a contact's travel in the rounding of an event time."""
    return 8.0 * 2.220446049250313e-16 * max(abs(t), 1.0)


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def within_reach(g, v, dt_res, tol):
    """Whether the contact update looks at a contact of gap g and rate v: closer than T_GAP, or than it
    travels in the time resolution dt_res (:func:`time_resolution`)."""
    return g < tol[T_GAP] + abs(v) * dt_res


@njit(cache=True, no_cpython_wrapper=True)
def held_press(jac, winv, near, m, rest, pressed, ws):
    """Each free contact's press under the forces of the held ones, where ``pressed`` holds minus the near
    contacts' free gap accelerations (``near[:m]``, rows in jac).

    The held contacts' forces solve the accelerations' LCP over the held rows (forces are not unique on a
    redundant set, the accelerations they give are); a free contact's gap acceleration is its free one plus
    ``J_k M^-1 J_H^T lam``. A held contact keeps its free press (the forces that act while it flies are the
    others'); so does every contact where none is held, or the LCP is not solved.
    """
    order = ws.k[HIT]               # the held contacts first, then the free ones
    h = 0
    for i in range(m):
        if rest[near[i]]:
            order[h] = near[i]
            h += 1
    if h == 0 or h == m:
        return
    f = h
    for i in range(m):
        if not rest[near[i]]:
            order[f] = near[i]
            f += 1
    A = ws.A
    contact_matrix(jac, winv, order, np.int64(m), A)
    w0, force = ws.c[RHS], ws.c[LAM]
    for i in range(h):
        w0[i] = -pressed[order[i]]
    if not lcp(A, w0, np.int64(h), force, ws, np.int64(PGS_SWEEPS)):
        return
    for i in range(h, m):
        s = -pressed[order[i]]
        for j in range(h):
            s += A[i, j] * force[j]
        pressed[order[i]] = -s


@njit(cache=True, no_cpython_wrapper=True)
def update_contacts(model, t, q, qd, p, tol, rest, ws, log, n_ev):
    """At an event: impulses for the contacts that take part, then the persistent set.

    Contacts closer than T_GAP take part when they approach or are still.
    Approaching ones get Newton's law (restitution e, or 0 for speeds below
    the contact's rest speed: T_VREST, or what it needs to climb out of the
    event band against its own normal acceleration, under the held contacts'
    forces (:func:`held_press`); those come to rest); all
    are solved together. Then every contact that is closed and still (below
    its rest speed) gets the accelerations' LCP
    ``w = A lam + (J a + bias) >= 0, lam >= 0, w.lam = 0``: those that would
    not accelerate away (a force, or a gap acceleration below T_AREST: the
    dependent rows of a redundant set) stay (or become) persistent, the
    others are released; so are those whose force was found pulling
    (``ws.k[FLAGS, 1]``, set by :func:`~.events.first_release`) unless the LCP
    gives them a force. The accelerations are unique where the forces are
    not, so the held set does not depend on which forces the solver picked.

    After the update no free contact within T_GAP approaches or presses: each
    either leaves (a positive rate, or a positive acceleration) or is held.
    Returns ``(n_ev, m)`` with m the number of persistent contacts.
    """
    n, C = model.n_dof, model.n_contact
    jac, A = ws.jac, ws.A
    g, v = ws.c[GS], ws.c[VB]
    model.phi(t, q, p, g)
    model.gap_rate(t, q, qd, p, v)
    winv = ws.n[WINV]
    model.inverse_mass(p, winv)
    near = ws.k[NEAR]
    m = 0
    # closer than T_GAP, or than the contact travels in the time resolution at t
    dt_res = time_resolution(t)
    for k in range(C):
        if within_reach(g[k], v[k], dt_res, tol) or rest[k]:
            near[m] = k
            m += 1
    if m == 0:
        for k in range(C):
            if rest[k]:
                rest[k] = 0
        return n_ev, 0
    near_rows(model, t, q, qd, p, near, m, jac, v)
    tiny = 1e-3 * tol[T_VREST]  # normal speeds below this are round-off
    # Each contact's rest speed: T_VREST, or the speed it needs, against its own normal
    # acceleration, to rise a whole event band (T_EVENT) above the level where contacts are
    # held. A slower contact would come back without leaving the band: its flight is not an
    # event anyone can locate, and left free it was taken for a touch that no update resolved,
    # which sent the step to the fallback (a jack flung into the wall of a spinning box
    # rebounds at 1.7e-7 L/s against 37 L/s^2: back within 1e-8 s, 4e-16 L high; or leaves at
    # 2e-6 L/s from 2.7e-12 L inside the wall, against 56 L/s^2: 3e-14 L high). Such a
    # contact is at rest: its impact is plastic, and the accelerations' LCP decides whether
    # it is held. So is a contact whose flight would last less than FLIGHT_TOL dt, or whose Zeno cascade
    # would be over within ZENO_TOL dt (tolerances.rest_speed; its rest is logged where the cascade
    # would have ended: tolerances.zeno_rest_ahead, unlog_rest_ahead). (An elastic
    # contact, e = 1, bounces forever: with a rise of GAP_ROUNDOFF T_EVENT, a box corner
    # pivoting on the ground bounced 3e-13 L high every 0.49 us, 20000 events in 7 ms, in five
    # of the random drops that failed the event budget.) A free contact is pressed by its gap's
    # acceleration under the forces of the contacts held when the update starts (held_press):
    # a jack on the floor of a box held on the ground falls with the box, so by the free
    # acceleration nothing pressed it, and its Zeno cascades ran on to T_VREST (bounces 1e-8 s
    # apart at e = 0.6; an elastic jack's, 0.34 us apart, filled a step's MAX_EVENTS passes).
    a = ws.n[ACC]
    model.accel(t, q, qd, p, a)
    vrest, pressed, bounce = ws.c[VREST], ws.c[PRESS], ws.c[BOUNCE]
    for i in range(m):
        k = near[i]
        s = jac[k, n + ROW_BIAS]
        for d in range(n):
            s += jac[k, d] * a[d]
        pressed[k] = -s
    held_press(jac, winv, near, m, rest, pressed, ws)
    half = 0.5 * tol[T_EVENT]
    for i in range(m):
        k = near[i]
        rise = max(-half - g[k], 0.0) + tol[T_EVENT]
        pressed[k] = max(pressed[k], 0.0)
        bounce[k] = 0.0
        vrest[k] = rest_speed(tol, rise, pressed[k], restitution(model, p, k))
    # The impact: contacts that approach or are closed and still. A receding
    # contact takes no part: an impulse there would push it apart while the
    # others' impulses slow it, which adds energy (it may hit again later).
    hit = ws.k[HIT]
    nh = 0
    approaching = False
    slow = SLOW * tol[T_VREST]
    for i in range(m):
        k = near[i]
        if v[k] <= tiny:
            hit[nh] = k
            nh += 1
            if v[k] < -tiny:
                approaching = True
                if v[k] > -slow:
                    ws.k[FLAGS, SLOW_AT] += 1    # (a run of steps with many: jackbox.engine.loop.exact_steps)
    if approaching:
        b, lam = ws.c[RHS], ws.c[LAM]
        for i in range(nh):
            k = hit[i]
            e = restitution(model, p, k)
            b[i] = v[k] + (e * v[k] if v[k] < -vrest[k] else 0.0)
            if -vrest[k] <= v[k] < -tiny:       # at rest: the bounce it would have left with
                bounce[k] = -e * v[k]
        contact_matrix(jac, winv, hit, np.int64(nh), A)
        solve_lcp(A, b, np.int64(nh), lam, ws)
        for d in range(n):
            s = 0.0
            for i in range(nh):
                s += jac[hit[i], d] * lam[i]
            qd[d] += winv[d] * s
        for i in range(nh):
            if lam[i] * A[i, i] > tiny:
                n_ev = log_event(t, hit[i], np.int64(IMPULSE), log, n_ev)
        near_rows(model, t, q, qd, p, near, m, jac, v)
    # Contacts closed and (now) at rest: which of them carry a force?
    cand = ws.k[CAND]
    c = 0
    for i in range(m):
        if abs(v[near[i]]) < vrest[near[i]]:
            cand[c] = near[i]
            bounce[near[i]] = max(bounce[near[i]], v[near[i]])
            c += 1
    if approaching:
        model.accel(t, q, qd, p, a)
    newrest = ws.k[NEWREST]
    for k in range(C):
        newrest[k] = 0
    if c > 0:
        contact_matrix(jac, winv, cand, np.int64(c), A)
        w0, force = ws.c[RHS], ws.c[LAM]
        for i in range(c):
            k = cand[i]
            s = jac[k, n + ROW_BIAS]
            for d in range(n):
                s += jac[k, d] * a[d]
            w0[i] = s
        solve_lcp(A, w0, np.int64(c), force, ws)
        for i in range(c):
            w = w0[i]
            for j in range(c):
                w += A[i, j] * force[j]
            letting_go = ws.k[FLAGS, 1] >> cand[i] & 1
            if force[i] > 0.0:
                newrest[cand[i]] = CARRIES
            elif w < tol[T_AREST] and not letting_go:
                newrest[cand[i]] = STILL
    ws.k[FLAGS, 1] = 0
    for k in range(C):
        if newrest[k] and not rest[k]:
            # logged where the Zeno cascade that its rest ends would have come to rest (it is held from t)
            e = restitution(model, p, k)
            n_ev = log_event(t + zeno_rest_ahead(tol, bounce[k], pressed[k], e), k, np.int64(REST), log, n_ev)
        elif rest[k] and not newrest[k]:
            unlog_rest_ahead(t, k, tol, log, n_ev)
            n_ev = log_event(t, k, np.int64(RELEASE), log, n_ev)
        rest[k] = newrest[k]
    hold_independent(model, rest, ws)
    m = rest_index(rest, C, ws.k[RIDX])
    if m > 0:
        project_rest(model, t, q, qd, p, m, 0.5 * tol[T_EVENT], np.int64(2), ws)
    return n_ev, m
