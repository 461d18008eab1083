"""The fallback: Moreau-Jean time-stepping, for the stretches the exact method cannot resolve.

When a step of the exact method sees more contact mode changes than
MODE_BUDGET, more passes than MAX_EVENTS, or an event that makes no progress
(a contact touching at round-off level that neither an impulse nor the
accelerations' LCP moves on), the loop (:mod:`.loop`) undoes the step and
integrates it, and those after it, by Moreau-Jean time-stepping: first order,
but it cannot stall. So it does the steps after a run of dense steps (a
bounce that neither shrinks nor stops: :data:`~.records.DENSE_SCORE`). Each of
its steps is (Moreau's midpoint rule, theta = 1/2)

* ``q_m = q + h/2 qd``; free rates ``u = qd + h M^-1 f(t + h/2, q_m, qd)``;
* the contacts within reach (gap at q_m, less what the step can close, below
  T_GAP) get one velocity-level LCP with Newton's law: ``w = J u' + e v- >= 0``,
  ``lam >= 0``, ``w . lam = 0``, with v- the normal rates at the step's start
  and ``u' = u + M^-1 J^T lam``; all contacts together, so simultaneous and
  redundant contacts are no special case. Restitution acts on an approach
  faster than the rest speed plus twice what the step's forces add to it
  (a contact at rest gains ``-a h`` each step: bouncing that would chatter);
  a slower one is plastic, as in the exact method. A contact receding at the
  start may end the step approaching as fast (``w = J u' + v-``): the
  impulses act at the midpoint, where their work is ``lam (v- + v+) / 2``, so
  each contact's is zero or negative and no step gains energy from them;
* ``q+ = q_m + h/2 u'``, then any gap below the event level is projected back
  onto it (a position LCP on the contacts within T_GAP).

The exact method takes over again once the set of closed contacts has been
the same for STABLE_STEPS steps; the contact update
(:func:`~.modes.update_contacts`) then finds the persistent set from the
accelerations' LCP. The loop logs both hand-overs (FALLBACK events), so a
trajectory shows where it was first order.
"""

import math

import numpy as np
from numba import njit

from .impact import contact_matrix, lcp, restitution, solve_lcp
from .modes import add_response, log_event, project_rest, rest_index
from .records import (ACC, AF, CAND, FALLBACK, GS, HIT, LAM, LAMB, MODE_AT, NEAR, QDS, QS, RHS, RIDX, SET_AT,
                      STABLE_STEPS, T_EVENT, T_GAP, T_VREST, T_WALL, VA, VB, VT, WINV)

#: Newton passes of the position projection (each a position LCP; it stops once no gap is below the
#: level). Four left a box rocking under a jack 1e4 times its mass 1e-8 L inside the ground after a
#: correction of 0.02 L; eight bring it to the level
PROJECTION_PASSES = 8
#: a step whose own motion would close a gap by more than this many L (the box's half-width) in half its
#: length is not one the fallback resolves (forces or masses far beyond what a step of dt can follow: at
#: g = 1e20 a step falls 1e14 L). Every contact is then within reach, and the velocity LCP over all of them
#: held the box hovering where it started, its energy rising, and the run ended done. The state is made
#: NaN instead: the run stops there with the status NONFINITE ("the state became non-finite ... try a
#: smaller dt or check the forces"). The hardest random scenes' steps close about 1 L
UNRESOLVED_REACH = 1e3
#: Gauss-Seidel sweeps for the projection that keeps the angular momentum, when its matrix is too
#: degenerate to enumerate (:func:`project_gaps`); beyond them the plain projection is taken
KEPT_SWEEPS = 200


@njit(cache=True, no_cpython_wrapper=True)
def moreau_step(model, t, h, q, qd, p, tol, ws):
    """One Moreau-Jean step from (t, q, qd) of length h, in place.

    Returns the set of contacts closed at its end (within reach, no normal
    rate left), as a bit mask.
    """
    n, C = model.n_dof, model.n_contact
    qm, u, uf, a = ws.n[QS], ws.n[QDS], ws.n[ACC], ws.n[AF]
    tm = t + 0.5 * h
    for d in range(n):
        qm[d] = q[d] + 0.5 * h * qd[d]
    model.accel(tm, qm, qd, p, a)
    for d in range(n):
        uf[d] = qd[d] + h * a[d]
        u[d] = uf[d]
    # gaps at the midpoint; normal rates at the start, free, and after the impulses
    g, v0, vf, v1 = ws.c[GS], ws.c[VA], ws.c[VB], ws.c[LAMB]
    model.phi(tm, qm, p, g)
    model.gap_rate(tm, qm, qd, p, v0)
    model.gap_rate(tm, qm, uf, p, vf)
    rows, member = ws.k[HIT], ws.k[CAND]
    far = 0.0
    for k in range(C):
        member[k] = g[k] + 0.5 * h * min(vf[k], v0[k], 0.0) < tol[T_GAP]
        far = max(far, -0.5 * h * min(vf[k], v0[k], 0.0))
    if far > UNRESOLVED_REACH * tol[T_WALL]:       # (see UNRESOLVED_REACH)
        for d in range(n):
            q[d] = np.nan
            qd[d] = np.nan
        return 0
    jac, A, winv = ws.jac, ws.A, ws.n[WINV]
    model.inverse_mass(p, winv)
    b, lam = ws.c[RHS], ws.c[LAM]
    na = 0
    for _ in range(C):
        # The LCP over the contacts within reach; a contact the others' impulses bring within
        # reach (a jack on a floor that the ground stops) joins, and the LCP is solved again.
        na = 0
        for k in range(C):
            if member[k]:
                rows[na] = k
                na += 1
        if na == 0:
            break
        for i in range(na):
            k = rows[i]
            e = restitution(model, p, k)
            # Newton's law for an approach faster than the step's own forces give it (and the rest
            # speed): a contact at rest gains -a h each step, and restitution on that would bounce it
            # A contact receding at the step's start may end it approaching as fast: with the
            # impulses acting at the midpoint they then do no work, where holding it would add energy.
            slow = tol[T_VREST] + 2.0 * abs(vf[k] - v0[k])
            b[i] = vf[k] + (v0[k] if v0[k] > 0.0 else e * v0[k] if v0[k] < -slow else 0.0)
        model.contact_rows(tm, qm, qd, p, rows, np.int64(na), jac)
        contact_matrix(jac, winv, rows, np.int64(na), A)
        solve_lcp(A, b, np.int64(na), lam, ws)
        for d in range(n):
            u[d] = uf[d]
        add_response(jac, winv, rows, na, lam, n, u)
        model.gap_rate(tm, qm, u, p, v1)
        joined = False
        for k in range(C):
            if not member[k] and g[k] + 0.5 * h * min(v1[k], 0.0) < tol[T_GAP]:
                member[k] = 1
                joined = True
        if not joined:
            break
    # the contacts that end the step closed (no normal rate after the impulses): unique where the
    # impulses are not (a redundant set), so the set does not flicker between equivalent choices
    mask = 0
    tiny = 1e-3 * tol[T_VREST]
    for i in range(na):
        w = b[i]
        for j in range(na):
            w += A[i, j] * lam[j]
        if w <= tiny:
            mask |= np.int64(1) << rows[i]
    for d in range(n):
        qd[d] = u[d]
        q[d] = qm[d] + 0.5 * h * u[d]
    before = model.energy(t + h, q, qd, p)
    project_gaps(model, t + h, q, qd, p, tol, ws)
    pay_from_motion(model, t + h, q, qd, p, before, winv)
    return mask


@njit(cache=True, no_cpython_wrapper=True)
def centre_of_mass_velocity(qd, winv):
    """The box's and the jack's masses and their centre of mass's velocity (a free box; winv filled)."""
    mb, mj = 1.0 / winv[0], 1.0 / winv[3]
    return mb, mj, (mb * qd[0] + mj * qd[3]) / (mb + mj), (mb * qd[1] + mj * qd[4]) / (mb + mj)


@njit(cache=True, no_cpython_wrapper=True)
def angular_momentum(model, q, qd, winv):
    """The pair's angular momentum about the origin (a free box: six coordinates; winv filled); 0 otherwise."""
    if model.prescribed or model.n_dof != 6:
        return 0.0
    total = 0.0
    for b in range(2):
        total += (q[3 * b] * qd[3 * b + 1] - q[3 * b + 1] * qd[3 * b]) / winv[3 * b] + qd[3 * b + 2] / winv[3 * b + 2]
    return total


@njit(cache=True, no_cpython_wrapper=True)
def keep_angular_momentum(model, t, q, qd, p, before, winv):
    """Undo what the hand-over's projection did to the angular momentum, where nothing outside the pair acts.

    With no ground and a free box, moving the whole pair (both bodies, at fixed rates) changes no gap, no
    rate, no energy and no linear momentum, and changes the angular momentum about the origin by
    ``M (dx vy - dy vx)`` (M the pair's mass, v its centre of mass's velocity): the shift across v that
    restores it. The hand-over's projection (:func:`~.modes.project_rest`) moves the bodies at fixed rates,
    which changed it by up to 5.3e-6 of its scale at omega dt 3.4 (the tests allow 2e-10 a held step); the
    fallback's own projections keep it (:func:`project_gaps`). A pair at rest has nothing to restore with,
    and a pair whose energy the shift would change (gravity, a spring to a fixed point: then the angular
    momentum is not kept by the dynamics either) is left as it is.
    """
    if model.has_ground or model.prescribed or model.n_dof != 6:
        return
    drift = angular_momentum(model, q, qd, winv) - before
    mb, mj, vx, vy = centre_of_mass_velocity(qd, winv)
    mass = mb + mj
    speed2 = vx * vx + vy * vy
    if not (speed2 > 0.0 and drift != 0.0):
        return
    s = -drift / (mass * speed2)        # (dx, dy) = s (vy, -vx): M (dx vy - dy vx) = s M speed2 = -drift
    energy = model.energy(t, q, qd, p)
    xb, yb, xj, yj = q[0], q[1], q[3], q[4]
    for b in range(2):
        q[3 * b] += s * vy
        q[3 * b + 1] -= s * vx
    if model.energy(t, q, qd, p) != energy:
        q[0], q[1], q[3], q[4] = xb, yb, xj, yj


@njit(cache=True, no_cpython_wrapper=True)
def pay_from_motion(model, t, q, qd, p, before, winv):
    """Take what a position correction added to the energy out of the motion about the centre of mass.

    A correction that lifts a body out of the ground, or out of a wall while
    gravity or a potential acts, raises the potential energy at fixed rates,
    by as much as the first-order drift it undoes: over a stretch of the
    fallback with a body spinning against a wall this was seen to pump energy
    (2.2e-5 of the scale in one step, against nothing that could supply it).
    The rise is paid from the kinetic energy relative to the centre of mass:
    the rates about it are scaled down, which keeps the linear momentum and
    leaves closed wall contacts closed (their normal rates scale too). Where
    that energy does not suffice the rates about the centre of mass stop and,
    with a ground, the rest is paid from the centre of mass's vertical motion
    (its speed scaled down: the ground and gravity act vertically only, so the
    horizontal momentum is kept; a pair whose plastic impacts had just locked
    it, a box rocking under a jack 190 and 1400 times its mass, was seen to
    gain 1.4e-4 and 4.2e-4 of the scale in one step with nothing left about
    its centre of mass). What neither can pay stays; a prescribed box (energy
    supplied from outside) is left as it is.
    """
    if model.prescribed or model.n_dof != 6:
        return
    rise = model.energy(t, q, qd, p) - before
    if not rise > 0.0:
        return
    mb, mj, vx, vy = centre_of_mass_velocity(qd, winv)
    about = 0.5 * (mb * ((qd[0] - vx) ** 2 + (qd[1] - vy) ** 2) + qd[2] ** 2 / winv[2]
                   + mj * ((qd[3] - vx) ** 2 + (qd[4] - vy) ** 2) + qd[5] ** 2 / winv[5])
    s = math.sqrt(1.0 - rise / about) if rise < about else 0.0
    wy = vy
    if rise > about and model.has_ground:
        rest = rise - about
        along = 0.5 * (mb + mj) * vy * vy
        wy = vy * math.sqrt(1.0 - rest / along) if rest < along else 0.0
    for b in range(2):
        qd[3 * b] = vx + s * (qd[3 * b] - vx)
        qd[3 * b + 1] = wy + s * (qd[3 * b + 1] - vy)
        qd[3 * b + 2] *= s


@njit(cache=True, no_cpython_wrapper=True)
def project_gaps(model, t, q, qd, p, tol, ws):
    """Move q the least (in the metric of M) so that no gap is below the event level.

    Newton on a position LCP over the contacts below the level and those
    within a few times the deepest penetration of it (which the correction
    could close), kept from pass to pass so that fixing one contact does not
    push another in.

    A shift of position at fixed rates changes the angular momentum about the
    origin, ``sum m (x vy - y vx) + J omega``, by ``sum m (dx vy - dy vx)``:
    where nothing outside the pair acts at a contact (no ground, a free box)
    the shift is kept to the directions that leave it unchanged. That
    momentum is linear in q at fixed rates, with gradient c, so this is the
    M-orthogonal projection of each correction off ``W c`` (a rank-one change
    of the contact matrix), and it is kept exactly. Where no correction can
    keep it (a contact whose only way out is along ``W c``: that LCP is then
    singular and its solver does not finish in KEPT_SWEEPS), the pass takes
    the plain projection. Without this, every projection of a jack sliding
    along a wall moved the angular momentum by its depth times the sliding
    speed: 5e-6 of its scale per step was seen.
    """
    n, C = model.n_dof, model.n_contact
    level = 0.5 * tol[T_EVENT]
    g = ws.c[GS]
    rows, member = ws.k[HIT], ws.k[NEAR]
    jac, A, winv = ws.jac, ws.A, ws.n[WINV]
    model.inverse_mass(p, winv)
    # W c: the rates turned a quarter (x, y) -> (vy, -vx) for each body; c^T W c = sum m |v|^2
    wc, cwc = ws.n[ACC], 0.0
    keep_momentum = not model.has_ground and not model.prescribed and n == 6
    if keep_momentum:
        for b in range(2):
            wc[3 * b] = qd[3 * b + 1]
            wc[3 * b + 1] = -qd[3 * b]
            wc[3 * b + 2] = 0.0
            cwc += (wc[3 * b] ** 2 + wc[3 * b + 1] ** 2) / winv[3 * b]
        keep_momentum = cwc > 0.0
    jw = ws.c[VT]
    for k in range(C):
        member[k] = 0
    last = math.inf
    for _ in range(PROJECTION_PASSES):
        model.phi(t, q, p, g)
        depth = 0.0
        for k in range(C):
            depth = max(depth, -(g[k] + level))
        if depth <= 0.0:
            return
        # A pass that did not halve the depth starts its members afresh: the LCP's tolerance scales with
        # its largest right-hand side, and members kept from a deep first pass (gaps 1e-2 L up) let it
        # accept a corner 1.7e-12 L below the level, pass after pass (a campaign draw, seed 59)
        fresh = depth > 0.5 * last
        last = depth
        na = 0
        for k in range(C):
            if fresh:
                member[k] = 0
            if g[k] < tol[T_GAP] + 4.0 * depth:
                member[k] = 1
            if member[k]:
                rows[na] = k
                na += 1
        model.contact_rows(t, q, qd, p, rows, np.int64(na), jac)
        b, x = ws.c[RHS], ws.c[LAM]
        for i in range(na):
            b[i] = g[rows[i]] + level
        contact_matrix(jac, winv, rows, np.int64(na), A)
        kept = False
        if keep_momentum:
            for i in range(na):
                s = 0.0
                for d in range(n):
                    s += jac[rows[i], d] * wc[d]
                jw[i] = s
            for i in range(na):
                for j in range(na):
                    A[i, j] -= jw[i] * jw[j] / cwc
            kept = lcp(A, b, np.int64(na), x, ws, np.int64(KEPT_SWEEPS))
            if not kept:           # no way out that keeps it: the plain projection
                contact_matrix(jac, winv, rows, np.int64(na), A)
        if not kept:
            solve_lcp(A, b, np.int64(na), x, ws)
        add_response(jac, winv, rows, na, x, n, q)
        if kept:
            s = 0.0
            for i in range(na):
                s += jw[i] * x[i]
            for d in range(n):
                q[d] -= wc[d] * s / cwc


@njit(cache=True, no_cpython_wrapper=True)
def fallback_step(model, update, t, h, q, qd, p, tol, rest, ws, log, n_ev):
    """One Moreau-Jean step (:mod:`.fallback`); hands back to the exact method once the contacts are stable.

    At the hand-over the contacts the fallback ended closed are put exactly
    on the event level with no normal rate (its first-order state leaves them
    a little off, and the exact method would see a fall and a new Zeno
    cascade), with any contact that this pushes below the level, and the
    contact update finds the persistent set from the accelerations' LCP.
    Returns ``(n_ev, m)``: m the persistent contacts the exact method starts
    with (0 while the fallback goes on).
    """
    C = model.n_contact
    mask = moreau_step(model, t, h, q, qd, p, tol, ws)
    if mask == rest[C + SET_AT]:
        rest[C + MODE_AT] += 1
    else:
        rest[C + MODE_AT] = 1
        rest[C + SET_AT] = mask
    if rest[C + MODE_AT] <= STABLE_STEPS:
        return n_ev, 0
    rest[C + MODE_AT] = 0
    rest[C + SET_AT] = 0
    t_next = t + h
    n_ev = log_event(t_next, np.int64(0), np.int64(FALLBACK), log, n_ev)
    if mask:
        for k in range(C):
            rest[k] = mask >> k & 1
        before = model.energy(t_next, q, qd, p)
        turn = angular_momentum(model, q, qd, ws.n[WINV])
        # a contact the projection pushes below the level joins it (a box corner the last step left hovering
        # 2e-4 L above the ground, put on the level, turned the box and pushed its jack 5.6e-6 L into a wall)
        half = 0.5 * tol[T_EVENT]
        g = ws.c[GS]
        for _ in range(C):
            project_rest(model, t_next, q, qd, p, rest_index(rest, C, ws.k[RIDX]), half, np.int64(2), ws)
            model.phi(t_next, q, p, g)
            joined = False
            for k in range(C):
                if not rest[k] and g[k] + half < 0.0:
                    rest[k] = 1
                    joined = True
            if not joined:
                break
        keep_angular_momentum(model, t_next, q, qd, p, turn, ws.n[WINV])
        pay_from_motion(model, t_next, q, qd, p, before, ws.n[WINV])
        for k in range(C):
            rest[k] = 0
    return update(model, t_next, q, qd, p, tol, rest, ws, log, n_ev)
