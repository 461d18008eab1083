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
"""

from jackbox.engine.broad import bound as _bound
from jackbox.engine.gaps import speed_bound as _speed_bound
from jackbox.engine.integrator import NODES as _NODES, SCALE as _SCALE, WEIGHTS as _WEIGHTS
from jackbox.engine.records import T_EVENT as _T_EVENT, T_GAP as _T_GAP

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
    """
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


#: the helpers a binding part inlines at Numba's level (``inline="always"``)
INLINED = ("rk4_stages", "grid_step", "clearance_s", "narrow_s", "record_s")
