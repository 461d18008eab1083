"""The free-flight hot path, compiled with each model (the only per-model code besides its functions).

This file is not imported as it stands: :func:`jackbox.loader.binding_parts`
copies the pieces of it a function reaches into that function's binding
part, after the generated model's tuple functions (``accel_s``,
``accel_time_s``, ``phi_s``, ``box_motion_s``) and constants (``N_DOF``,
``N_CONTACT``, ``PRESCRIBED``, ``HAS_GROUND``) it calls, so that they are
globals of the same file, inlined, with the state in registers. :func:`fly`
and :func:`free_step` are compiled together (one part, "flight"),
:func:`clearance` alone, as ``cfunc`` values of the signatures in
:mod:`jackbox.engine.records`; the engine calls them through the model
record.

Far from every wall the exact loop hands over to :func:`fly`, which
integrates on floats only and looks at no gap row: the broad phase
(:mod:`jackbox.engine.broad`) bounds them, so a quiet step costs one RK4 step.

With one to four contacts held, the held loop (:func:`jackbox.engine.loop.hold`)
hands its steps to :func:`ride`, the same step on floats (the model's
``contact_pose_s`` and ``contact_row_s`` and the held solve on tuples): its
own part, compiled when a run first holds a contact
(``jackbox.loader.Kernel.ride``; until then a stub that takes no step). A step
riding a shaken floor on two tips took 0.45 of its time on the held loop's
arrays, and one of a jack held in a corner of the shaken box on four 0.65.
"""

import math

from jackbox.engine.broad import bound as _bound
from jackbox.engine.gaps import speed_bound as _speed_bound, step_reach as _step_reach
from jackbox.engine.impact import RANK_TOL as _RANK_TOL
from jackbox.engine.integrator import NODES as _NODES, SCALE as _SCALE, WEIGHTS as _WEIGHTS, held_passes as _held_passes
from jackbox.engine.records import (COAST as _COAST, DRIFT as _DRIFT, REPASS as _REPASS, REPASSES as _REPASSES,
                                    T_AREST as _T_AREST, T_EVENT as _T_EVENT, T_GAP as _T_GAP, T_SPEED as _T_SPEED,
                                    T_WALL as _T_WALL)

#: skip the gap rows of steps whose bounding circles are far from contact
#: (the benchmark compiles a copy with False to show the gain)
BROAD_PHASE = True


def rk4_stages(q, qd, dt, p, ta, tta, tm, ttm, tb, ttb):
    """One classical RK4 step of ``q' = qd, qd' = accel(t, q, qd)`` on tuples.

    The tableau is :mod:`jackbox.engine.integrator`'s (``_NODES``, ``_WEIGHTS``,
    ``_SCALE``; the inner stages share their node).
    Stage times ta, tm, tb come with their time terms ``tt* = accel_time_s(t*,
    p)`` (a shaking force's sine, 1/m), computed once per stage time.
    Returns ``(q, qd)``.

    Where the model's accelerations are functions of time alone
    (``ACCEL_OF_TIME``: free bodies under given forces, as in shaken and drop)
    the stages' states are not needed: with a2 = a3 (one node) the step is
    ``q + dt (qd + dt/6 (a1 + 2 a2))`` and ``qd + dt/6 (a1 + 4 a2 + a4)``, the
    same RK4 step, the sum the tableau's weights give, in fewer operations
    (different round-off): in an ensemble block, whose lanes share the time
    terms' part, 24 a lane-step against 60 (the whole lane-step 48 against
    87: ``benchmarks/lane_step.py``).
    """
    if ACCEL_OF_TIME:
        a1 = accel_s(ta, q, qd, p, tta)
        a2 = accel_s(tm, q, qd, p, ttm)
        a4 = accel_s(tb, q, qd, p, ttb)
        h = dt / _SCALE
        return (axpy_s(dt, axpy_s(h, axpy_s(2.0, a2, a1), qd), q),
                axpy_s(h, axpy_s(1.0, a4, axpy_s(4.0, a2, a1)), qd))
    h2 = _NODES[1] * dt
    h3 = _NODES[2] * dt
    h4 = _NODES[3] * dt
    a1 = accel_s(ta, q, qd, p, tta)
    v2 = axpy_s(h2, a1, qd)
    a2 = accel_s(tm, axpy_s(h2, qd, q), v2, p, ttm)
    v3 = axpy_s(h3, a2, qd)
    a3 = accel_s(tm, axpy_s(h3, v2, q), v3, p, ttm)
    v4 = axpy_s(h4, a3, qd)
    a4 = accel_s(tb, axpy_s(h4, v3, q), v4, p, ttb)
    h = dt / _SCALE
    return wsum_s(q, h, _WEIGHTS, qd, v2, v3, v4), wsum_s(qd, h, _WEIGHTS, a1, a2, a3, a4)


def grid_step(t, t_next, tt, q, qd, dt, p):
    """A whole step of the time grid from t to t_next, on tuples; tt: the time terms at t.

    Returns ``(q, qd, time terms at t_next)``, so consecutive steps share them.
    """
    tm = t + _NODES[1] * dt
    tt_next = accel_time_s(t_next, p)
    qn, vn = rk4_stages(q, qd, dt, p, t, tt, tm, accel_time_s(tm, p), t_next, tt_next)
    return qn, vn, tt_next


def clearance_s(t, q, p, tol):
    """The broad phase's bound on every gap (q: a tuple or an array of the integrated coordinates)."""
    if PRESCRIBED:
        box = box_motion_s(t, p)
        return _bound(box[0], box[1], box[2], q[0], q[1], tol, HAS_GROUND)
    return _bound(q[0], q[1], q[2], q[3], q[4], tol, HAS_GROUND)


def narrow_s(t, q, p):
    """The smallest gap at (t, q): every gap row."""
    g = phi_s(t, q, p)
    c = g[0]
    for k in range(1, N_CONTACT):
        c = min(c, g[k])
    return c


def clearance(t, q, p, tol):
    """A lower bound on every gap at (t, q): the broad phase, or the smallest gap without it.

    (Within :func:`fly`, where the broad phase's bound is too low for a step,
    the gap rows themselves; the exact loop, after a step it takes itself, the
    smallest of that step's rows.)
    """
    if BROAD_PHASE:
        return clearance_s(t, q, p, tol)
    return narrow_s(t, q, p)


def fly(t0, dt, i, i_stop, q_io, qd_io, p, tol, clear, qn_out, vn_out, rec_t, rec_q, rec_qd, n_rec, next_rec,
        record_every, n_total):
    """Steps i, i+1, ... of free flight while the broad phase shows them quiet, recording the samples on the way.

    ``clear`` is a lower bound on every gap at the start; each step lowers it
    by the step's band (twice the travel bound) and only when that leaves too
    little is the clearance computed again, so far from the walls a step costs
    one RK4 step on floats and a speed bound. Stops before the first step that
    might come near contact or at i_stop. q_io, qd_io: the state, updated;
    qn_out, vn_out: the trial state of the step it stopped before (the caller
    need not redo it). The samples at step next_rec, next_rec + record_every,
    ... and n_total go into the rec_* rows from n_rec (:func:`record_s`; the
    caller completes them): returning to the caller for each cost as much as
    a step. Returns ``(i, clear, n_rec)``.
    """
    q, qd = tuple_of(q_io), tuple_of(qd_io)
    margin = tol[_T_GAP] - 0.5 * tol[_T_EVENT]
    qn, vn = q, qd
    tt = accel_time_s(t0 + i * dt, p)
    sa = _speed_bound(qd, tol)
    quiet = True
    while quiet and i < i_stop:
        # steps to the next sample (a negative next_rec or n_total: none), then the sample: the
        # step loop itself tests nothing but the state (a test per step there cost 10-15%)
        seg = i_stop
        if i < next_rec < seg:
            seg = next_rec
        if i < n_total < seg:
            seg = n_total
        while i < seg:
            t_next = t0 + (i + 1) * dt
            qn, vn, tt_next = grid_step(t0 + i * dt, t_next, tt, q, qd, dt, p)
            sb = _speed_bound(vn, tol)
            band = dt * max(sa, sb) + margin      # step_reach(qd, vn, dt, tol) - T_EVENT / 2
            if not clear >= band:        # (also stops on a non-finite state)
                quiet = False
                break
            if BROAD_PHASE:
                c = clear - band
                if c < band:
                    c = clearance_s(t_next, qn, p, tol)
                    if c < band:         # the jack's disc near a wall: its points may not be
                        c = narrow_s(t_next, qn, p)
            else:                        # every gap row, every step
                c = narrow_s(t_next, qn, p)
            if not c >= band:
                quiet = False
                break
            q, qd, clear, tt, sa = qn, vn, c, tt_next, sb
            i += 1
        if i == next_rec or i == n_total:
            record_s(t0 + i * dt, q, qd, n_rec, rec_t, rec_q, rec_qd)
            n_rec += 1
            if i == next_rec:
                next_rec += record_every
    for d in range(N_DOF):
        q_io[d] = q[d]
        qd_io[d] = qd[d]
        qn_out[d] = qn[d]
        vn_out[d] = vn[d]
    return i, clear, n_rec


def record_s(t, q, qd, n, rec_t, rec_q, rec_qd):
    """Sample n at time t: the time and the integrated coordinates and rates (after a prescribed box's three).

    The box's columns and the energy are the caller's (:func:`jackbox.engine.loop.complete_samples`,
    with the model's own functions): they would compile them into the hot path of every model.
    """
    rec_t[n] = t
    off = 3 if PRESCRIBED else 0
    for d in range(N_DOF):
        rec_q[n, off + d] = q[d]
        rec_qd[n, off + d] = qd[d]


def free_step(t, t_next, q_in, qd_in, dt, p, q_out, qd_out):
    """One RK4 step of free flight from t to t_next (dt apart) on floats: the naive method's step, and the exact one's near a wall.

    The stage times are t, t + dt/2 and t_next, as in :func:`fly` (t_next the
    grid's ``t0 + (i + 1) dt``): from the same state the two give the same
    numbers, so a step does not depend on which of them took it.
    """
    q, qd = tuple_of(q_in), tuple_of(qd_in)
    qn, vn, _ = grid_step(t, t_next, accel_time_s(t, p), q, qd, dt, p)
    for d in range(N_DOF):
        q_out[d] = qn[d]
        qd_out[d] = vn[d]


def factor2(A11, A12, A22):
    """The factorization of a held pair's 2 x 2 matrix as :func:`jackbox.engine.impact.factor_rows` makes it:
    (1 / D11 or 0, L21, 1 / D22 or 0), a row that depends on the one before it (what is left of its diagonal
    below RANK_TOL of it) given no force."""
    g1, L21, u21, g2 = 0.0, 0.0, 0.0, 0.0
    if A11 > _RANK_TOL * A11:
        g1 = 1.0 / A11
        u21 = A12
        L21 = A12 * g1
    d = A22 - L21 * u21
    if d > _RANK_TOL * A22:
        g2 = 1.0 / d
    return g1, L21, g2


def solve2(g1, L21, g2, b1, b2):
    """``x`` for ``A x = b`` with A factored by :func:`factor2` (:func:`jackbox.engine.impact.solve_rows`)."""
    y2 = b2 - L21 * b1
    x2 = y2 * g2
    return b1 * g1 - L21 * x2, x2


def factor4(w, m, r1, r2, r3, r4):
    """The held rows' matrix (:func:`jackbox.engine.impact.contact_matrix`, entry by entry) for three or four
    rows (m; r4 is r3 again where m = 3), factored as :func:`jackbox.engine.impact.factor_rows` factors it, its
    operations in their order. Returns ``((g1, g2, g3, g4, L21, L31, L32, L41, L42, L43), A11, A22, A33, A44)``:
    g the reciprocals of D, 0 for a row that depends on those before it (a redundant set: a jack flush in a
    corner) and its column of L 0; where m = 3, row 4's reciprocal and entries of L are 0 (and A14..A44,
    1.0, are read by nothing). The u are L's entries before their scaling (factor_rows' upper triangle)."""
    A11, A12, A13 = wdot_s(r1, w, r1), wdot_s(r1, w, r2), wdot_s(r1, w, r3)
    A22, A23, A33 = wdot_s(r2, w, r2), wdot_s(r2, w, r3), wdot_s(r3, w, r3)
    A14 = A24 = A34 = A44 = 1.0
    if m == 4:
        A14, A24, A34, A44 = wdot_s(r1, w, r4), wdot_s(r2, w, r4), wdot_s(r3, w, r4), wdot_s(r4, w, r4)
    g1 = g2 = g3 = g4 = 0.0
    L21 = L31 = L32 = L41 = L42 = L43 = 0.0
    u21 = u31 = u32 = u41 = u42 = u43 = 0.0
    if A11 > _RANK_TOL * A11:
        g1 = 1.0 / A11
        u21, u31 = A12, A13
        L21, L31 = A12 * g1, A13 * g1
        if m == 4:
            u41 = A14
            L41 = A14 * g1
    d = A22 - L21 * u21
    if d > _RANK_TOL * A22:
        g2 = 1.0 / d
        u32 = A23 - L31 * u21
        L32 = u32 * g2
        if m == 4:
            u42 = A24 - L41 * u21
            L42 = u42 * g2
    d = A33 - L31 * u31
    d -= L32 * u32
    if d > _RANK_TOL * A33:
        g3 = 1.0 / d
        if m == 4:
            u43 = A34 - L41 * u31
            u43 -= L42 * u32
            L43 = u43 * g3
    if m == 4:
        d = A44 - L41 * u41
        d -= L42 * u42
        d -= L43 * u43
        if d > _RANK_TOL * A44:
            g4 = 1.0 / d
    return (g1, g2, g3, g4, L21, L31, L32, L41, L42, L43), A11, A22, A33, A44


def solve4(m, f, b1, b2, b3, b4):
    """``x`` for ``A x = b`` with A factored by :func:`factor4` (:func:`jackbox.engine.impact.solve_rows`, the same
    operations in their order); x4 is 0 where m = 3, and where row 4 depends on those before it (g4 = 0: a
    jack flush in a corner), as solve_rows gives it for a finite b4, whose terms are then left out (b4 is not
    read: the terms of an x4 of 0 move none of the others, but for the sign of a zero)."""
    g1, g2, g3, g4, L21, L31, L32, L41, L42, L43 = f
    y2 = b2 - L21 * b1
    y3 = b3 - L31 * b1
    y3 -= L32 * y2
    if m == 4 and g4 != 0.0:
        y4 = b4 - L41 * b1
        y4 -= L42 * y2
        y4 -= L43 * y3
        x4 = y4 * g4
        x3 = y3 * g3 - L43 * x4
        x2 = y2 * g2 - L32 * x3
        x2 -= L42 * x4
        x1 = b1 * g1 - L21 * x2
        x1 -= L31 * x3
        return x1 - L41 * x4, x2, x3, x4
    x3 = y3 * g3
    x2 = y2 * g2 - L32 * x3
    x1 = b1 * g1 - L21 * x2
    return x1 - L31 * x3, x2, x3, 0.0


def held_rows(t, q, qd, p, pose, m, k1, k2, k3, k4):
    """The held rows k1..km at (t, q, qd), from ``pose = contact_pose_s(t, q, p)``: returns ``(r1, r2, r3, r4)``,
    r2 r1 again where m = 1, r3 and r4 r2 again where m = 2, r4 r3 again where m = 3."""
    r1 = contact_row_s(t, q, qd, p, pose, k1)
    r2 = contact_row_s(t, q, qd, p, pose, k2) if m > 1 else r1
    r3 = r4 = r2
    for c in range(2, m):   # (one call in a loop: the row's body is compiled once for the two)
        r = contact_row_s(t, q, qd, p, pose, k3 if c == 2 else k4)
        if c == 2:
            r3 = r4 = r
        else:
            r4 = r
    return r1, r2, r3, r4


def factor_held(w, m, r1, r2, r3, r4):
    """The held rows' matrix factored (:func:`factor2` for one or two rows, :func:`factor4` for three or four):
    ``(f, A11, A22, A33, A44)``, f as :func:`factor4` gives it (for two rows: ``(g1, g2, 0, 0, L21, 0, ...)``),
    the diagonal 1.0 past the m rows. It depends on the rows' Jacobians alone, so on the pose alone."""
    if m <= 2:
        A11 = wdot_s(r1, w, r1)
        A12, A22 = (wdot_s(r1, w, r2), wdot_s(r2, w, r2)) if m == 2 else (0.0, 1.0)
        f1, L21, f2 = factor2(A11, A12, A22)
        return (f1, f2, 0.0, 0.0, L21, 0.0, 0.0, 0.0, 0.0, 0.0), A11, A22, 1.0, 1.0
    return factor4(w, m, r1, r2, r3, r4)


def held_push(a, w, m, f, r1, r2, r3, r4, b1, b2, b3, b4):
    """The held rows' response to right-hand sides b (their forces for accelerations, their impulses for rates,
    their corrections for gaps), with the rows factored as f (:func:`factor_held`): returns ``(a + M^-1 J^T x,
    x1, x2, x3, x4)``, x 0 past the m rows (the operations of :func:`jackbox.engine.modes.held_accel`'s solve
    and response, in their order)."""
    if m == 1:
        x1 = b1 * f[0]
        return respond_s(a, w, r1, x1), x1, 0.0, 0.0, 0.0
    if m == 2:
        x1, x2 = solve2(f[0], f[4], f[1], b1, b2)
        return respond2_s(a, w, r1, x1, r2, x2), x1, x2, 0.0, 0.0
    x1, x2, x3, x4 = solve4(m, f, b1, b2, b3, b4)
    return respond4_s(a, w, r1, x1, r2, x2, r3, x3, r4, x4), x1, x2, x3, x4


def held_stage(t, q, qd, p, tt, w, m, r1, r2, r3, r4, f):
    """An RK4 stage of a held step: the accelerations with the m rows r1.. held, factored as f
    (:func:`factor_held`). The operations of :func:`jackbox.engine.modes.held_accel` (the model's
    accelerations, the solve and the response) in their order, on tuples: the same numbers. A fourth row
    that depends on the others (no pivot in f: a jack flush in a corner) has no gap acceleration read, as
    :func:`solve4` reads none (with factor4 inlined, so that the test is on values in registers, the two
    skips take a tenth off a corner's step, and the inlining another tenth).
    Returns ``(accelerations, forces 1..4)``."""
    a = accel_s(t, q, qd, p, tt)
    b3 = b4 = 0.0
    if m > 2:
        b3 = -row_dot_s(r3, a)
        if m == 4 and f[3] != 0.0:
            b4 = -row_dot_s(r4, a)
    b2 = -row_dot_s(r2, a) if m > 1 else 0.0
    return held_push(a, w, m, f, r1, r2, r3, r4, -row_dot_s(r1, a), b2, b3, b4)


def settle(t, q, qd, p, w, m, k1, k2, k3, k4, level, drift, h):
    """:func:`jackbox.engine.modes.settle_rows` on tuples, for one to four held rows.

    The rows at (t, q, qd), factored; where a gap drifted past round-off, one
    Newton pass on the gaps (:func:`jackbox.engine.modes.project_rows`) and the
    rows read again where it ends, and where a gap is still off its level by
    more than REPASS of it, up to REPASSES more passes, each from the rows
    read last, factored; the rates projected with the last factorization.
    Returns ``(q, qd, pose, f, on)``: the pose's terms where it ends
    (``contact_pose_s``), the factorization and whether it is that pose's
    (on: no Newton pass), for the next step's first stage.
    """
    gap, rate = N_DOF + 1, N_DOF + 2
    pose = contact_pose_s(t, q, p)
    r1, r2, r3, r4 = held_rows(t, q, qd, p, pose, m, k1, k2, k3, k4)
    f = factor_held(w, m, r1, r2, r3, r4)
    on = True
    for r in (r1, r2, r3, r4):      # (past the m rows, a row again)
        on = on and abs(r[gap] + level) <= drift and abs(r[rate]) * h <= drift
    if not on:
        repass = _REPASS * level
        for j in range(_REPASSES + 1):
            q = held_push(q, w, m, f[0], r1, r2, r3, r4, -(r1[gap] + level), -(r2[gap] + level),
                          -(r3[gap] + level), -(r4[gap] + level))[0]
            pose = contact_pose_s(t, q, p)
            r1, r2, r3, r4 = held_rows(t, q, qd, p, pose, m, k1, k2, k3, k4)
            again = False
            for r in (r1, r2, r3, r4):
                again = again or not abs(r[gap] + level) <= repass
            if j == _REPASSES or not again:
                break
            f = factor_held(w, m, r1, r2, r3, r4)
    qd = held_push(qd, w, m, f[0], r1, r2, r3, r4, -r1[rate], -r2[rate], -r3[rate], -r4[rate])[0]
    return q, qd, pose, f, on


def ride(t0, dt, i, i_stop, q_io, qd_io, p, tol, rest, m, k1, k2, winv, io_f, rec_t, rec_q, rec_qd, io_k,
         record_every, n_total, qb_out, qdb_out, ga_out, gb_out, ls, A):
    """Steps i, i+1, ... of a body riding on one to four held contacts (m of them), on floats.

    k1, k2: the held loop's first two rows (k2 = k1 where m = 1); ``io_k[2]``,
    ``io_k[3]``: its third and fourth where m > 2 (the fourth the third again
    where m = 3), a jack in a corner, a redundant set among them.

    The held loop's own step (:func:`jackbox.engine.loop.hold`: its first RK4
    stage, :func:`jackbox.engine.integrator.rk4_rows` in one pass, the release
    screen, the near test, :func:`jackbox.engine.modes.settle_rows`) with the
    same operations in the same order, so the same numbers, with the state in
    registers: the array code passes each stage's rows, forces and
    factorization through memory. It stops *before* any step that needs more
    than that (left to the held loop, which takes it from the same state):
    one whose accelerations vanish at its start (the held loop lets it
    coast) or that takes more than one RK4 pass. One whose forces might pull,
    whose end is not finite, or in which a free contact comes within reach it
    hands over as the held loop would, integrated (its end in qb_out,
    qdb_out, the gaps at both ends in ga_out, gb_out, the stages' forces in
    ``ls`` and the diagonal of their last matrix in A), for the exact loop's
    event search (:func:`jackbox.engine.loop.advance`).
    ``io_f[0]``: the held loop's bound on the free gaps at step i, then at the
    step reached. The samples on the way go into the rec_* rows from
    ``io_k[0]`` (:func:`record_s`; the caller completes them), which is left
    at the next; ``io_k[1]``: 1 where the step reached is handed over.
    Returns the step reached.

    The four stages are one loop (its body, with the rows' terms, is compiled
    once: written out four times it took 10 s to compile, against 3.8 s). A
    step reads its pose's sines four times (five where its projection takes a
    Newton pass), where reading the rows took five to twelve: a stage reads
    all its rows from one pose (:func:`held_rows`), and the first stage takes
    the pose the last step's projection ended on, and that projection's
    factorization where it moved no row (:func:`settle`). With that and the
    factorization's square roots gone (L D L^T), a step in a corner takes
    725 ns against 1000 before, one riding the floor 470 against 510; with
    :func:`factor4` inlined and a dependent fourth row's gap acceleration and
    solve skipped (:func:`held_stage`), one in a corner 0.8 of that.
    """
    io_k[1] = 0
    low, n_rec = io_f[0], io_k[0]
    half = 0.5 * tol[_T_EVENT]
    deep = half + tol[_T_EVENT]
    arest = tol[_T_AREST]
    drift = _DRIFT * tol[_T_EVENT]
    still = _COAST * arest
    w = tuple_of(winv)
    q, qd = tuple_of(q_io), tuple_of(qd_io)
    k3, k4 = io_k[2], io_k[3]
    t_end = math.nan                   # the last step's last stage time, and its terms of time
    tt_end = accel_time_s(t0 + i * dt, p)
    # the pose's terms where the last step's projection ended, and the rows' factorization there where the
    # projection moved no row (factored), for the next step's first stage: to begin with, step i's pose
    factored = False
    pose = contact_pose_s(t0 + i * dt, q, p)
    f = (1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    A11 = A22 = A33 = A44 = 1.0
    while i < i_stop:
        ta = t0 + i * dt
        tb = t0 + (i + 1) * dt
        h = tb - ta
        if _held_passes(qd_io, h, N_DOF, tol[_T_WALL]) != 1:
            break
        tt = tt_end if ta == t_end else accel_time_s(ta, p)
        # the stages: a1..a4 their accelerations, v2..v4 their rates; their forces into ls
        a1 = a2 = a3 = a4 = v2 = v3 = v4 = qd
        coast = False
        for s in range(4):
            hs = _NODES[s] * h
            if s == 0:
                ts, qs, vs = ta, q, qd
            elif s == 1:
                tt = accel_time_s(ta + hs, p)
                ts, qs, vs = ta + hs, axpy_s(hs, qd, q), axpy_s(hs, a1, qd)
            elif s == 2:
                ts, qs, vs = ta + hs, axpy_s(hs, v2, q), axpy_s(hs, a2, qd)
            else:
                t_end = ta + hs
                tt_end = accel_time_s(t_end, p)
                tt = tt_end
                ts, qs, vs = t_end, axpy_s(hs, v3, q), axpy_s(hs, a3, qd)
            # the rows, their pose's terms and their factorization: at the first stage, those of the last
            # step's projection where it ended (the same pose: the same numbers)
            if s > 0:
                pose = contact_pose_s(ts, qs, p)
            r1, r2, r3, r4 = held_rows(ts, qs, vs, p, pose, m, k1, k2, k3, k4)
            if not (s == 0 and factored):
                f, A11, A22, A33, A44 = factor_held(w, m, r1, r2, r3, r4)
            a, x1, x2, x3, x4 = held_stage(ts, qs, vs, p, tt, w, m, r1, r2, r3, r4, f)
            for j in range(m):
                ls[s, j] = x1 if j == 0 else x2 if j == 1 else x3 if j == 2 else x4
            if s == 0:
                a1 = a
                coast = True
                for d in range(N_DOF):
                    if not abs(a[d]) * tol[_T_SPEED + d] <= still:
                        coast = False
                if coast:
                    break
            elif s == 1:
                a2, v2 = a, vs
            elif s == 2:
                a3, v3 = a, vs
            else:
                a4, v4 = a, vs
        if coast:
            break
        hs = h / _SCALE
        qb = wsum_s(q, hs, _WEIGHTS, qd, v2, v3, v4)
        qdb = wsum_s(qd, hs, _WEIGHTS, a1, a2, a3, a4)
        # a force that might pull (any stage's, NaN too), or an end that is not finite: the exact loop's step
        stop = False
        for j in range(m):
            floor = -arest / (A11 if j == 0 else A22 if j == 1 else A33 if j == 2 else A44)
            for s in range(4):
                if not ls[s, j] >= floor:
                    stop = True
        for d in range(N_DOF):
            if not (math.isfinite(qb[d]) and math.isfinite(qdb[d])):
                stop = True
        band = _step_reach(qd, qdb, h, tol)
        if stop or low - band + deep < band:   # a free gap may come within the step's reach: the gaps themselves
            ga = phi_s(ta, q, p)
            gb = phi_s(tb, qb, p)
            low = math.inf
            for k in range(N_CONTACT):
                if not rest[k]:
                    low = min(low, gb[k])
                    if min(ga[k], gb[k]) + deep < band:
                        stop = True
            if stop:       # the step is the exact loop's: handed over, integrated
                for d in range(N_DOF):
                    qb_out[d] = qb[d]
                    qdb_out[d] = qdb[d]
                for k in range(N_CONTACT):
                    ga_out[k] = ga[k]
                    gb_out[k] = gb[k]
                for j in range(m):
                    A[j, j] = A11 if j == 0 else A22 if j == 1 else A33 if j == 2 else A44
                io_f[0], io_k[0], io_k[1] = low, n_rec, 1
                return i
        else:
            low -= band
        # the rows back on their level (jackbox.engine.modes.settle_rows): where a gap drifted past
        # round-off, one Newton pass on the gaps and the rates from the rows there; else the rates only
        q, qd, pose, fac, factored = settle(tb, qb, qdb, p, w, m, k1, k2, k3, k4, half, drift, h)
        f, A11, A22, A33, A44 = fac
        for d in range(N_DOF):        # what the projection moved any gap by, at most
            low -= abs(q[d] - qb[d]) * tol[_T_SPEED + d]
        for d in range(N_DOF):
            q_io[d] = q[d]
            qd_io[d] = qd[d]
        i += 1
        if i % record_every == 0 or i == n_total:
            record_s(tb, q, qd, n_rec, rec_t, rec_q, rec_qd)
            n_rec += 1
    io_f[0], io_k[0] = low, n_rec
    return i


#: the helpers a binding part inlines at Numba's level (``inline="always"``)
INLINED = ("rk4_stages", "grid_step", "clearance_s", "narrow_s", "record_s")
