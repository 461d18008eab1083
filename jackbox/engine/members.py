"""Members: many runs of one model at once, one per ``prange`` iteration (ensembles and twins),
or, for ensembles whose members share their parameters, one block of LANES members per
iteration, flying together in SIMD lanes (:func:`run_block`, :mod:`jackbox.engine.lanes`).

A member's setup is its own work too, in a parallel loop before the runs
(:func:`set_up_members`): its start, parameters, tolerance row and twin
offset from the study's :class:`~.records.Setup` and its index alone, so no
serial pass over the members precedes the parallel one, and the start gaps
are known (a start inside a wall refused) before any member steps.

A member runs :func:`~jackbox.engine.loop.integrate_exact` (its compiled
function value ``exact``, so the loop's machine code is not generated again
here) segment by segment (to each sample step, then to the end) with no recording in between.
Its result depends on its inputs only, so any split of the members over
threads, processes or machines gives the same numbers bit for bit.
"""

import math
from collections import namedtuple

import numpy as np
from numba import njit, prange

from .draws import START, TWIN, draw_normal, draw_uniform
from .gaps import speed_bound
from .modes import time_resolution, within_reach
from .records import (DERIVE_CROSS, DONE, EXACT_AT, FALLBACK, IMPACT_LOG_FULL, IMPULSE, LANES, MODE_AT, MODE_SLOTS, MODEL_AT,
                      STAGES_AT, T_BOXV, T_GAP, T_SPEED, TIME_ROWS, WARNING, BLOCK_ROWS, BOUND_ROW, E_GROUND_ROW, E_ROW, FIRST_ROW, IMPULSE_ROW, SPEED_ROW, Events, ExactType, ModelType, Samples,
                      StagesType, from_table, TWIN_FIN)
from .tolerances import set_tolerances

#: tally slots of one member: impulses so far, time of the first one (NaN if none), when the
#: fallback now running began (NaN: none runs), time spent in the fallback so far, solver warnings
TALLY_IMPULSES, TALLY_FIRST, TALLY_SINCE, TALLY_FALLBACK, TALLY_WARNINGS = range(5)
TALLY = 5
#: first size of a member's event log (it doubles when one step needs more)
LOG_SIZE = 256


@njit(cache=True, no_cpython_wrapper=True)
def new_log(size):
    return Events(np.empty(size), np.empty(size, np.int64), np.empty(size, np.int64))


@njit(cache=True, no_cpython_wrapper=True, _nrt=True)     # (returns an array: see NO_REFERENCES)
def run_segment(model, exact, stages, q, qd, rest, p, tol, dt, i, stop, out, n_rec, log, tally):
    """Steps i..stop of one member through any number of full event logs.

    Counts impulses, time in the fallback and warnings into tally; records a sample at stop (into ``out`` at
    n_rec; on the first call, with i = 0 and n_rec = 0, also the start).
    Returns ``(step reached, n_rec, status, log)``: the log is a new, bigger
    one when a single step needed more room.
    """
    while True:
        i, n_rec, n_ev, status = exact(model, stages, q, qd, rest, p, tol, 0.0, dt, i, stop, stop, stop + 1,
                                                 out, n_rec, log, 0)
        for j in range(n_ev):
            kind = log.kind[j]
            if kind == IMPULSE:
                if tally[TALLY_IMPULSES] == 0.0:
                    tally[TALLY_FIRST] = log.t[j]
                tally[TALLY_IMPULSES] += 1.0
            elif kind == FALLBACK:
                if log.k[j] >= 1:       # (entering: the reason, HANDOFF_*; leaving: 0)
                    tally[TALLY_SINCE] = log.t[j]
                else:
                    tally[TALLY_FALLBACK] += log.t[j] - tally[TALLY_SINCE]
                    tally[TALLY_SINCE] = np.nan
            elif kind == WARNING:
                tally[TALLY_WARNINGS] += 1.0
        if status != IMPACT_LOG_FULL:
            return i, n_rec, status, log
        if n_ev == 0:    # one step has more events than the log holds
            bigger = grown(log)
            if bigger.t.shape[0] == log.t.shape[0]:     # (a log of fixed size: the GPU's)
                return i, n_rec, status, log
            log = bigger


@njit(cache=True, no_cpython_wrapper=True)
def grown(log):
    """A log twice the size of ``log`` (on a GPU, where nothing is allocated, ``log`` itself)."""
    return new_log(2 * log.t.shape[0])


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def copy_to(dst, src):
    """dst[:] = src, as a loop (Numba compiles a slice assignment's shape check and error path at each use)."""
    for i in range(src.shape[0]):
        dst[i] = src[i]


@njit(cache=True, no_cpython_wrapper=True)
def new_tally():
    return clear_tally(np.empty(TALLY))


@njit(cache=True, no_cpython_wrapper=True, _nrt=True)     # (returns an array: see NO_REFERENCES)
def clear_tally(tally):
    """A tally of nothing yet (``tally`` filled and returned)."""
    for k in range(TALLY):
        tally[k] = 0.0
    tally[TALLY_FIRST] = np.nan
    tally[TALLY_SINCE] = np.nan
    return tally


@njit(cache=True, no_cpython_wrapper=True)
def fallback_time(tally, t):
    """Time spent in the fallback up to t (a stretch still running counted up to t)."""
    since = tally[TALLY_SINCE]
    return tally[TALLY_FALLBACK] + (t - since if since == since else 0.0)


@njit(cache=True, no_cpython_wrapper=True)
def new_modes(model):
    """A run's mode array (see :func:`~.loop.integrate_exact`): every contact free, the exact method on."""
    return clear_modes(np.empty(model.n_contact + MODE_SLOTS, np.int64))


@njit(cache=True, no_cpython_wrapper=True, _nrt=True)     # (returns an array: see NO_REFERENCES)
def clear_modes(rest):
    """Every contact free, the exact method on (``rest`` filled and returned)."""
    for k in range(rest.shape[0]):
        rest[k] = 0
    return rest


@njit(cache=True, no_cpython_wrapper=True)
def new_samples(n):
    return Samples(np.empty(n), np.empty((n, 6)), np.empty((n, 6)), np.empty(n))


@njit(cache=True, no_cpython_wrapper=True)
def run_member(model, exact, stages, q0, qd0, p, tol, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin):
    """One ensemble member from its start state to n_steps.

    sample_steps: ascending steps in [0, n_steps] whose (6-column) state goes
    to samp_q[s], samp_qd[s]. fin_q, fin_qd: the final state (6 columns).
    fin: [energy, impulses, first impulse time, status, step reached, seconds in
    the fallback, solver warnings].
    """
    follow_member(model, exact, stages, q0.copy(), qd0.copy(), new_modes(model), p, tol, dt, n_steps, sample_steps,
                  samp_q, samp_qd, fin_q, fin_qd, fin, new_log(LOG_SIZE), new_samples(np.int64(2)), new_tally())


@njit(cache=True, no_cpython_wrapper=True)
def start_member(model, exact, stages, q, qd, rest, p, tol, dt, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, log,
                 out, tally):
    """Step 0 of a member: the start, after any impulse a touching start state gets; its sample at step 0 and
    its final row so far. Returns ``(step reached, status, next sample, log)``."""
    clear_modes(rest)
    clear_tally(tally)
    zero = np.int64(0)
    i, _, status, log = run_segment(model, exact, stages, q, qd, rest, p, tol, dt, zero, zero, out, zero, log, tally)
    s = 0
    if s < sample_steps.shape[0] and sample_steps[s] == 0:
        copy_to(samp_q[s], out.q[0])
        copy_to(samp_qd[s], out.qd[0])
        s += 1
    copy_to(fin_q, out.q[0])
    copy_to(fin_qd, out.qd[0])
    fin[0] = out.energy[0]
    return i, status, s, log


@njit(cache=True, no_cpython_wrapper=True)
def follow_member(model, exact, stages, q, qd, rest, p, tol, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd,
                  fin, log, out, tally):
    """:func:`run_member` in the arrays it is given: the state q, qd (the start, moved on), the modes, an event
    log, two samples and a tally (the GPU's kernel hands in arrays of its own, of fixed size)."""
    i, status, s, log = start_member(model, exact, stages, q, qd, rest, p, tol, dt, sample_steps, samp_q, samp_qd,
                                     fin_q, fin_qd, fin, log, out, tally)
    while status == DONE and i < n_steps:
        stop = sample_steps[s] if s < sample_steps.shape[0] else n_steps
        i, n_rec, status, log = run_segment(model, exact, stages, q, qd, rest, p, tol, dt, i, stop, out, np.int64(1),
                                            log, tally)
        if status != DONE:
            break
        if s < sample_steps.shape[0] and stop == sample_steps[s]:
            copy_to(samp_q[s], out.q[1])
            copy_to(samp_qd[s], out.qd[1])
            s += 1
        copy_to(fin_q, out.q[1])
        copy_to(fin_qd, out.qd[1])
        fin[0] = out.energy[1]
    fin[1] = tally[TALLY_IMPULSES]
    fin[2] = tally[TALLY_FIRST]
    fin[3] = status
    fin[4] = i
    fin[5] = fallback_time(tally, i * dt)
    fin[6] = tally[TALLY_WARNINGS]


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def parts(table):
    """The model, the exact loop and its stages from a table (see :func:`~.records.from_table`)."""
    return (from_table(table, MODEL_AT, ModelType), from_table(table, EXACT_AT, ExactType),
            from_table(table, STAGES_AT, StagesType))


@njit(cache=True)
def run_members(table, Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin):
    """:func:`run_member` for every row of Q0, QD0, P, TOL, in parallel; the model and loops in ``table``."""
    model, exact, stages = parts(table)
    all_members(model, exact, stages, Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin)


@njit(cache=True, no_cpython_wrapper=True)
def spread_stride(n):
    """A stride s coprime with n near n / golden ratio: ``i -> i * s % n`` visits 0..n-1 once each, any run of
    consecutive i spread evenly over them.

    Numba's threads take a prange loop's iterations in equal runs of
    consecutive ones; a sweep's members are ordered by the swept value, and
    one end of a restitution sweep holds contacts (some 1.1 us a step) where
    the other flies (about 60 ns): run in order, the thread with the plastic
    half finished last, and two threads took 0.84 of one's time (a sweep of
    shaken, 1000 members x 5 s). Work goes to the threads in this spread
    order instead; each member's numbers are its own, whichever thread runs it.
    """
    s = max(1, int(n * 0.6180339887498949))
    while True:
        a, b = s, n
        while b:
            a, b = b, a % b
        if a == 1:
            return s
        s += 1


# (a prange loop takes its records as arguments: Numba's parfor lowering cannot rebuild one made in the same function)
@njit(cache=True, no_cpython_wrapper=True, parallel=True)
def all_members(model, exact, stages, Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin):
    N = Q0.shape[0]
    s = spread_stride(N)
    for i in prange(N):
        j = i * s % N
        run_member(model, exact, stages, Q0[j], QD0[j], P[j], TOL[j], dt, n_steps, sample_steps, samp_q[j], samp_qd[j],
                   fin_q[j], fin_qd[j], fin[j])


@njit(cache=True, no_cpython_wrapper=True)
def run_twins(model, exact, stages, q0, qd0, dq, dqd, p, tol, dt, n_steps, renorm_steps, scale, stretch, fin):
    """Twin trajectories of one member for the finite-time Lyapunov exponent.

    The twin starts at (q0 + dq, qd0 + dqd). Every renorm_steps steps the
    separation d (state difference divided by ``scale``, per coordinate) is
    measured, log(d / d0) goes to stretch[k], and the twin is put back at
    distance d0 along the current separation (Benettin's renormalisation).
    After each renormalisation the twin's contact set is found again (its
    state moved): the contact update runs at its next step, unless it would
    change nothing there (:func:`needs_update`).
    fin: [impulses of the reference, status, step reached, seconds either
    twin spent in the fallback, solver warnings of both], then from
    :data:`TWIN_FIN` the reference's six coordinates and six rates where it
    ended, as an ensemble member's (the study checks them for a pair that went
    through a wall unseen).
    """
    follow_twins(model, exact, stages, q0.copy(), qd0.copy(), q0.copy(), qd0.copy(), dq, dqd, p, tol, dt, n_steps,
                 renorm_steps, scale, stretch, fin, new_modes(model), new_modes(model), new_log(LOG_SIZE),
                 new_log(LOG_SIZE), new_samples(np.int64(2)), new_tally(), new_tally(), np.empty((2, model.n_contact)))


@njit(cache=True, no_cpython_wrapper=True)
def follow_twins(model, exact, stages, q, qd, qt, qdt, dq, dqd, p, tol, dt, n_steps, renorm_steps, scale, stretch, fin,
                 rest, rest_t, log, log_t, out, tally, tally_t, gv):
    """:func:`run_twins` in the arrays it is given (q, qd and qt, qdt: the start, twice; see :func:`follow_member`;
    gv: (2, n_contact) scratch)."""
    n = model.n_dof
    for d in range(n):
        qt[d] += dq[d]
        qdt[d] += dqd[d]
    d0 = twin_distance(dq, dqd, scale, n)
    clear_modes(rest)
    clear_modes(rest_t)
    clear_tally(tally)
    clear_tally(tally_t)
    i = 0
    i2 = 0
    status = DONE
    n_rec = 0
    k = 0
    while i < n_steps:
        stop = min(i + renorm_steps, n_steps)
        i, _, status, log = run_segment(model, exact, stages, q, qd, rest, p, tol, dt, i, stop, out, n_rec, log, tally)
        if status != DONE:
            break
        i2, _, status, log_t = run_segment(model, exact, stages, qt, qdt, rest_t, p, tol, dt, i2, stop, out, n_rec, log_t,
                                           tally_t)
        n_rec = 1
        if status != DONE:
            break
        stretch[k], _ = renormalise(model, 0.0 + stop * dt, q, qd, qt, qdt, dq, dqd, scale, d0, rest_t, p, tol, gv,
                                    np.nan)
        k += 1
    for j in range(k, stretch.shape[0]):
        stretch[j] = np.nan
    fin[0] = tally[TALLY_IMPULSES]
    fin[1] = status
    fin[2] = i
    fin[3] = fallback_time(tally, i * dt) + fallback_time(tally_t, i2 * dt)
    fin[4] = tally[TALLY_WARNINGS] + tally_t[TALLY_WARNINGS]
    # the reference's state as an ensemble member's (six coordinates: a prescribed box's from its motion,
    # gv's first row its scratch)
    off = 0
    if model.prescribed:
        box = gv[0]
        model.box_motion(0.0 + i * dt, p, box)
        for d in range(3):
            fin[TWIN_FIN + d] = box[d]
            fin[TWIN_FIN + 6 + d] = box[3 + d]
        off = 3
    for d in range(n):
        fin[TWIN_FIN + off + d] = q[d]
        fin[TWIN_FIN + 6 + off + d] = qd[d]


@njit(cache=True, no_cpython_wrapper=True)
def twin_distance(dq, dqd, scale, n):
    """The scaled length of a twin's offset (dq, dqd) of n coordinates."""
    d0 = 0.0
    for d in range(n):
        d0 += (dq[d] / scale[d]) ** 2 + (dqd[d] / scale[n + d]) ** 2
    return math.sqrt(d0)


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def renormalise(model, t, q, qd, qt, qdt, dq, dqd, scale, d0, rest_t, p, tol, gv, bound):
    """Benettin's renormalisation: the twin put back at distance d0 along its separation; returns log(d / d0)
    and a bound on the twin's gaps where it was moved to.

    NaN where the twins met (round-off): the twin restarts at its first
    offset. The twin's contact set is to be found again at its next step
    (its state moved, at time t), unless it is in the fallback, or it holds no
    contact and no contact is near enough for the exact loop's contact update
    to look at it (:func:`needs_update`, in the scratch gv).

    bound: a bound on every gap of the twin before the move, or NaN for none (:func:`follow_twins`;
    :func:`renormalise_block` moves a block's twins with their lanes' bounds). Lowered by the most the move can change a gap (each
    coordinate's change times its lever arm, ``tol[T_SPEED + d]``: the bound ``speed_bound`` puts on
    d gap / d q_d), it is returned, and where it clears the reach of the contact update by T_GAP more (the
    lanes' bounds are within a few eps of the model's gaps), :func:`needs_update` is not asked: a twin
    moved some 1e-8 off its reference in open space needs no gap computed again (NaN: none).
    """
    n = model.n_dof
    dist = 0.0
    for d in range(n):
        dist += apart(q[d], qt[d], scale[d]) + apart(qd[d], qdt[d], scale[n + d])
    dist = math.sqrt(dist)
    ok = dist > 0.0
    f = d0 / dist if ok else 0.0
    lowered = bound
    for d in range(n):
        moved = put_back(q[d], qt[d], dq[d], f, ok)
        lowered -= abs(moved - qt[d]) * tol[T_SPEED + d]
        qt[d] = moved
        qdt[d] = put_back(qd[d], qdt[d], dqd[d], f, ok)
    mark_moved(model, t, qt, qdt, speed_bound(qdt, tol), p, tol, rest_t, gv, lowered)
    return math.log(dist / d0) if ok else np.nan, lowered


@njit(cache=True, no_cpython_wrapper=True, _nrt=False, inline="always")
def apart(a, at, s):
    """A coordinate's term of the twins' squared distance (:func:`renormalise`): its difference over its scale,
    squared."""
    return ((at - a) / s) ** 2


@njit(cache=True, no_cpython_wrapper=True, _nrt=False, inline="always")
def put_back(a, at, da, f, ok):
    """A twin's coordinate at (:func:`renormalise`) its reference's a plus f times their difference (ok), or plus
    its first offset da (not ok: the twins met)."""
    return a + f * (at - a) if ok else a + da


@njit(cache=True, no_cpython_wrapper=True, _nrt=False, inline="always")
def mark_moved(model, t, qt, qdt, sb, p, tol, rest_t, gv, lowered):
    """A twin moved to (t, qt, qdt) with ``lowered`` a bound on its gaps (NaN: none) and sb on their speed: its
    contact set to be found again at its next step (``rest_t[C + MODE_AT] = -1``) unless it is in the
    fallback or :func:`needs_update` says the update would change nothing (asked only where the bound does
    not clear its reach)."""
    C = model.n_contact
    if rest_t[C + MODE_AT] == 0 and not lowered - tol[T_GAP] >= update_reach(t, sb, tol) \
            and needs_update(model, t, qt, qdt, p, tol, rest_t, gv):
        rest_t[C + MODE_AT] = -1


@njit(cache=True, no_cpython_wrapper=True, _nrt=False, inline="always")
def update_reach(t, sb, tol):
    """Twice the farthest a gap can be from contact for the contact update to look at it at time t, with sb a
    bound on the gaps' speed (``gaps.speed_bound`` of the rates; :func:`~.modes.within_reach`: T_GAP, or the
    travel in the time resolution at t): a bound on every gap above this says that the update changes
    nothing."""
    return 2.0 * (tol[T_GAP] + sb * time_resolution(t))


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def needs_update(model, t, q, qd, p, tol, rest, gv):
    """Whether the contact update (:func:`~.modes.update_contacts`) could change anything for a member moved to (t, q, qd).

    Not where the member holds no contact and no contact is near enough for
    the update to look at it: closer than T_GAP, or than it travels in the
    time resolution at t (the update's own test, :func:`~.modes.within_reach`,
    on the same numbers: the model's ``phi`` and ``gap_rate`` into ``gv``,
    (2, n_contact) scratch, unless the broad phase's bound on every gap
    clears twice that reach already). The update then finds no contact and leaves the state and the
    modes as they are, so the exact loop's next step is a plain one. A chaos
    twin renormalised off the walls (most renormalisations of a free-flight
    study) then stays in its block's lanes; before, each went through the
    exact loop alone for a step: ~100 trips a twin per 10 s of shaken,
    against its 14 impacts.
    """
    C = model.n_contact
    if not is_free(rest, C):
        return True
    dt_res = time_resolution(t)
    if model.clearance(t, q, p, tol) >= update_reach(t, speed_bound(qd, tol), tol):
        return False
    g, v = gv[0], gv[1]
    model.phi(t, q, p, g)
    model.gap_rate(t, q, qd, p, v)
    for k in range(C):
        if within_reach(g[k], v[k], dt_res, tol):
            return True
    return False


@njit(cache=True)
def run_twin_members(table, Q0, QD0, DQ, DQD, P, TOL, dt, n_steps, renorm_steps, scale, stretch, fin):
    """:func:`run_twins` for every member, in parallel; the model and loops in ``table``."""
    model, exact, stages = parts(table)
    all_twins(model, exact, stages, Q0, QD0, DQ, DQD, P, TOL, dt, n_steps, renorm_steps, scale, stretch, fin)


@njit(cache=True, no_cpython_wrapper=True, parallel=True)
def all_twins(model, exact, stages, Q0, QD0, DQ, DQD, P, TOL, dt, n_steps, renorm_steps, scale, stretch, fin):
    N = Q0.shape[0]
    s = spread_stride(N)      # (threads get members in spread order)
    for i in prange(N):
        j = i * s % N
        run_twins(model, exact, stages, Q0[j], QD0[j], DQ[j], DQD[j], P[j], TOL[j], dt, n_steps, renorm_steps, scale,
                  stretch[j], fin[j])


# ---------------------------------------------------------------------------
# blocks: LANES members that share their parameters (but for restitution), stepped together in free flight

#: a block of members in lanes: its state (rows of LANES floats, see jackbox.engine.lanes), then per lane
#: whether it steps in the lanes now, the step it is back from a stretch alone (-1: none), whether its
#: trial step was quiet, whether it runs, its status and the step it reached, its contact modes, its
#: tally, and its state while it steps alone; the lanes that go alone now (a list, see block_to); last,
#: each lane's parameters (its member's row: the members may differ in their restitution, see set_lane)
Block = namedtuple("Block", ["S", "live", "back", "quiet", "alive", "status", "reached", "rests", "tallies", "held_q",
                             "held_qd", "todo", "P"])

#: steps of a block between looks at which of its members are free (a member with a held contact or
#: in the fallback steps alone, through the exact loop, to the end of such a stretch)
CHUNK = 64
#: steps a member takes alone through the exact loop where a step of it has an event (its lane is not
#: calm: lanes.calm) before it rejoins its block's lanes: the steps near a wall without an event stay in
#: the lanes (shaken, 2000 members: 4.5e7 member-steps/s on one thread with 1, 3.1e7 with 4, 3.2e7 with 16)
ALONE = 1


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def is_free(rest, C):
    """Whether a member's modes leave it in free flight: no contact held, the exact method on, no run of dense steps.

    (A run of dense steps is counted by the exact loop only, and its quiet steps end it: a member in the
    middle of one stays there, so that its count is the one it would have alone.)
    """
    for k in range(C + MODE_SLOTS):
        if rest[k] != 0:
            return False
    return True


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def take_lane(S, lane, q, qd):
    """The q and qd of lane ``lane`` (rows 0 .. 11 of a block's state) into q, qd."""
    W = LANES
    for d in range(6):
        q[d] = S[d * W + lane]
        qd[d] = S[(6 + d) * W + lane]


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def put_lane(S, lane, q, qd):
    """q, qd into lane ``lane`` of a block's state; its bound on the gaps to be computed again."""
    W = LANES
    for d in range(6):
        S[d * W + lane] = q[d]
        S[(6 + d) * W + lane] = qd[d]
    S[BOUND_ROW * W + lane] = np.nan


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def fold_impulses(S, lane, tally):
    """The impulses lane ``lane`` took in the lanes (:func:`~.lanes.event_lane`) into its tally, as
    :func:`run_segment` counts those of a stretch alone: their count, and the first one's time where the tally
    had none. (Before any stretch alone, and before a block's caller reads the tallies.)"""
    W = LANES
    c = S[IMPULSE_ROW * W + lane]
    if c > 0.0:
        if tally[TALLY_IMPULSES] == 0.0:
            tally[TALLY_FIRST] = S[FIRST_ROW * W + lane]
        tally[TALLY_IMPULSES] += c
        S[IMPULSE_ROW * W + lane] = 0.0


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def fold_lanes(S, tallies):
    """:func:`fold_impulses` for every lane of a block, into its row of ``tallies``. No references counted: a
    row taken in a function that counts them costs an increment and a decrement of the array's count, atomic
    operations (a chaos study's blocks, folding at each renormalisation, spent a tenth of their time in them)."""
    for lane in range(LANES):
        fold_impulses(S, lane, tallies[lane])


@njit(cache=True, no_cpython_wrapper=True)
def time_table(model, p, dt, n_steps):
    """A study's terms of time, made once for every block's lanes (the model's ``time_table``): those of its
    first TIME_ROWS steps at most; empty where the model has none."""
    K = model.time_table(0.0, dt, 0, p, np.empty(0))
    tab = np.empty(min(n_steps, TIME_ROWS) * 2 * K)
    model.time_table(0.0, dt, n_steps, p, tab)
    return tab


@njit(cache=True, no_cpython_wrapper=True)
def new_block(model, n_params):
    """A block's state (rows of LANES floats, see :mod:`.lanes`) and the per-lane arrays that go with it."""
    W, C = LANES, model.n_contact
    return Block(np.zeros(BLOCK_ROWS * W), np.zeros(W, np.int64), np.zeros(W, np.int64), np.zeros(W, np.int64),
                 np.zeros(W, np.int64), np.zeros(W, np.int64), np.zeros(W, np.int64),
                 np.zeros((W, C + MODE_SLOTS), np.int64), np.empty((W, TALLY)), np.empty((W, 6)), np.empty((W, 6)),
                 np.zeros(W, np.int64), np.empty((W, n_params)))


@njit(cache=True, no_cpython_wrapper=True)
def set_lane(model, B, lane, p):
    """Lane ``lane`` of block B gets the parameters p (its member's row): those its stretches alone and its
    energy read, and its restitution (rows E_ROW, E_GROUND_ROW of the state), which its impacts in the lanes
    read (``lanes.lane_event``). The lanes' free flight reads the block's parameters, which equal every
    member's in all but the restitution (``Kernel.lanes_apply``), so a member's numbers are its own."""
    W = LANES
    copy_to(B.P[lane], p)
    B.S[E_ROW * W + lane] = p[model.e_slot]
    B.S[E_GROUND_ROW * W + lane] = p[model.e_ground_slot]      # (read at ground contacts only)


@njit(cache=True, no_cpython_wrapper=True)
def start_lane(model, exact, stages, B, lane, q, qd, p, tol, dt, out, log):
    """Lane ``lane`` of block B from (q, qd) with parameters p (:func:`set_lane`'s): its contact set found and
    its start recorded into ``out`` (step 0)."""
    set_lane(model, B, lane, p)
    copy_to(B.tallies[lane], new_tally())
    zero = np.int64(0)
    i, _, st, log = run_segment(model, exact, stages, q, qd, B.rests[lane], p, tol, dt, zero, zero, out, zero, log,
                                B.tallies[lane])
    B.status[lane] = st
    B.reached[lane] = i
    B.alive[lane] = 1 if st == DONE else 0
    put_lane(B.S, lane, q, qd)
    return log


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def mark_chunk(alive, rests, live, back, C, todo):
    """A chunk's start: each lane live (alive and free) or not, none back from a stretch alone.

    Lists in ``todo`` the lanes that are alive but not free (they go alone);
    returns how many.

    The lanes are scanned here, without reference counts, and the
    block's loop visits only the listed lanes: a loop in :func:`block_to`
    that may hand the event log on (``log = alone_to(...)``) counted a
    reference to each of its three arrays on every pass, some 200 calls into
    Numba's runtime each time the block stopped.
    """
    n = 0
    for lane in range(LANES):
        live[lane] = 1 if alive[lane] == 1 and is_free(rests[lane], C) else 0
        back[lane] = -1
        if alive[lane] == 1 and live[lane] == 0:
            todo[n] = lane
            n += 1
    return n


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def lanes_back(back, j, todo):
    """Lists in ``todo`` the lanes back from a stretch alone at step j; returns how many (see :func:`mark_chunk`)."""
    n = 0
    for lane in range(LANES):
        if back[lane] == j:
            todo[n] = lane
            n += 1
    return n


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def take_trials(S, live, quiet, todo):
    """After the lanes stopped at a step: each live lane whose trial was quiet takes it as its next state.

    Lists in ``todo`` the live lanes whose step has an event (they go
    alone); returns how many (see :func:`mark_chunk`).
    """
    W = LANES
    n = 0
    for lane in range(W):
        if not live[lane]:
            continue
        if quiet[lane]:            # the trial of the step is this lane's next state
            for d in range(12):
                S[d * W + lane] = S[(12 + d) * W + lane]
            S[BOUND_ROW * W + lane] = S[(BOUND_ROW + 1) * W + lane]
            S[SPEED_ROW * W + lane] = S[(SPEED_ROW + 1) * W + lane]
            continue
        todo[n] = lane
        n += 1
    return n


@njit(cache=True, no_cpython_wrapper=True)
def block_to(model, exact, stages, B, p, tol, tab, dt, i, stop, out, log):
    """Every live lane of block B from step i to stop; returns the log.

    Free members go through the model's lanes together (``model.lanes``): each
    step that no member has an event in is one vector step of the block. A
    member whose step has one goes alone through the exact loop for ALONE steps
    and rejoins; so does a chaos twin that its renormalisation moved near a
    wall (its contact set is found again in its next step, by the exact loop:
    :func:`needs_update`); one that holds a contact or is in the fallback goes
    alone to the end of the CHUNK. p: the parameters the lanes' free flight
    reads (every lane's, but for the restitution: each lane's own are in B.P).
    A member's numbers are those :func:`run_member` gives it, bit for bit: the
    lanes take only steps the exact loop would take as a plain RK4 step, with
    the same operations, and a call of the exact loop from any step goes on as
    one that got there itself. The lanes that go alone are listed first
    (:func:`mark_chunk`, :func:`lanes_back`, :func:`take_trials`) and taken
    in their order; no lane's stretch alone reads or writes another lane.
    """
    W, C = LANES, model.n_contact
    S, live, back, quiet, alive, rests, todo = B.S, B.live, B.back, B.quiet, B.alive, B.rests, B.todo
    while i < stop:
        end = min(stop, i + CHUNK)
        n_todo = mark_chunk(alive, rests, live, back, C, todo)
        for t in range(n_todo):            # held, in the fallback or moved: alone for a while
            lane = todo[t]
            take_lane(S, lane, B.held_q[lane], B.held_qd[lane])
            back[lane] = min(i + ALONE, end) if rests[lane, C + MODE_AT] == -1 else end
            log = alone_to(model, exact, stages, B, lane, tol, dt, i, back[lane], out, log)
        j = i
        while j < end:
            n_todo = lanes_back(back, j, todo)
            for t in range(n_todo):        # back from a stretch alone
                lane = todo[t]
                put_lane(S, lane, B.held_q[lane], B.held_qd[lane])
                back[lane] = -1
                if alive[lane] == 1 and is_free(rests[lane], C):
                    live[lane] = 1
                elif alive[lane] == 1:
                    back[lane] = end
                    log = alone_to(model, exact, stages, B, lane, tol, dt, j, end, out, log)
            j_stop = end
            n_live = 0
            for lane in range(W):
                if back[lane] > j:
                    j_stop = min(j_stop, back[lane])
                n_live += live[lane]
            if n_live == 0:
                j = j_stop
                continue
            j = model.lanes(0.0, dt, j, j_stop, S, p, tol, live, quiet, tab, model.lane_event)
            if j == j_stop:
                continue
            n_todo = take_trials(S, live, quiet, todo)
            for t in range(n_todo):        # an event in the step: alone through the exact loop for a stretch, then back
                lane = todo[t]
                take_lane(S, lane, B.held_q[lane], B.held_qd[lane])
                live[lane] = 0
                back[lane] = min(j + ALONE, end)
                log = alone_to(model, exact, stages, B, lane, tol, dt, j, back[lane], out, log)
            j += 1
        for lane in range(W):
            if back[lane] >= 0:
                put_lane(S, lane, B.held_q[lane], B.held_qd[lane])
        i = end
    fold_lanes(S, B.tallies)
    return log


@njit(cache=True, no_cpython_wrapper=True)
def run_block(model, exact, stages, Q0, QD0, P, tol, tab, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd,
              fin, first, count):
    """Members first .. first + count - 1 (count <= LANES) as one block; outputs as :func:`run_member`'s.

    The members share tol and their parameters P but for the restitution
    (each lane its own: :func:`set_lane`); the block steps them through
    :func:`block_to`. Lanes past count hold a copy of the last member's start
    and are never stepped but in the vectors (not written).
    """
    W, n = LANES, 6
    p = P[first]
    B = new_block(model, P.shape[1])
    q, qd = np.empty(n), np.empty(n)
    out = new_samples(np.int64(2))
    log = new_log(LOG_SIZE)
    n_samples = sample_steps.shape[0]
    at_zero = n_samples > 0 and sample_steps[0] == 0
    for lane in range(W):
        j = first + min(lane, count - 1)
        copy_to(q, Q0[j])
        copy_to(qd, QD0[j])
        if lane >= count:           # padding: flies along in the vectors, never stepped alone
            copy_to(B.tallies[lane], new_tally())
            set_lane(model, B, lane, P[j])
            put_lane(B.S, lane, q, qd)
            continue
        log = start_lane(model, exact, stages, B, lane, q, qd, P[j], tol, dt, out, log)
        if at_zero:
            copy_to(samp_q[j, 0], out.q[0])
            copy_to(samp_qd[j, 0], out.qd[0])
        copy_to(fin_q[j], out.q[0])
        copy_to(fin_qd[j], out.qd[0])
        fin[j, 0] = out.energy[0]
    s = 1 if at_zero else 0
    i = 0
    while i < n_steps:
        stop = sample_steps[s] if s < n_samples else n_steps
        log = block_to(model, exact, stages, B, p, tol, tab, dt, i, stop, out, log)
        i = stop
        sampled = s < n_samples and stop == sample_steps[s]
        for lane in range(count):
            if not B.alive[lane]:
                continue
            j = first + lane
            take_lane(B.S, lane, q, qd)
            if sampled:
                copy_to(samp_q[j, s], q)
                copy_to(samp_qd[j, s], qd)
            copy_to(fin_q[j], q)
            copy_to(fin_qd[j], qd)
            fin[j, 0] = model.energy(0.0 + stop * dt, q, qd, P[j])
        if sampled:
            s += 1
        n_alive = 0
        for lane in range(W):
            n_alive += B.alive[lane]
        if n_alive == 0:
            break
    for lane in range(count):
        j = first + lane
        tally = B.tallies[lane]
        done = B.alive[lane] == 1
        fin[j, 1] = tally[TALLY_IMPULSES]
        fin[j, 2] = tally[TALLY_FIRST]
        fin[j, 3] = DONE if done else B.status[lane]
        fin[j, 4] = n_steps if done else B.reached[lane]
        fin[j, 5] = fallback_time(tally, fin[j, 4] * dt)
        fin[j, 6] = tally[TALLY_WARNINGS]


@njit(cache=True, no_cpython_wrapper=True, _nrt=True)     # (returns an array: see NO_REFERENCES)
def alone_to(model, exact, stages, B, lane, tol, dt, i, end, out, log):
    """Member ``lane`` of block B alone through the exact loop from step i to end (its state in B.held_q, B.held_qd,
    its parameters in B.P)."""
    fold_impulses(B.S, lane, B.tallies[lane])
    k, _, st, log = run_segment(model, exact, stages, B.held_q[lane], B.held_qd[lane], B.rests[lane], B.P[lane], tol,
                                dt, i, end, out, np.int64(1), log, B.tallies[lane])
    if st != DONE:
        B.alive[lane], B.status[lane], B.reached[lane] = 0, st, k
    return log


@njit(cache=True)
def run_member_blocks(table, Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin):
    """:func:`run_members` in blocks of LANES members (:func:`run_block`), in parallel; the members share TOL[0] and
    P[0] but for the restitution (``Kernel.lanes_apply``)."""
    model, exact, stages = parts(table)
    tab = time_table(model, P[0], dt, n_steps)
    all_blocks(model, exact, stages, Q0, QD0, P, TOL[0], tab, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q,
               fin_qd, fin)


@njit(cache=True, no_cpython_wrapper=True, parallel=True)
def all_blocks(model, exact, stages, Q0, QD0, P, tol, tab, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd,
               fin):
    N = Q0.shape[0]
    nb = (N + LANES - 1) // LANES
    s = spread_stride(nb)     # (threads get blocks in spread order)
    for i in prange(nb):
        first = (i * s % nb) * LANES
        run_block(model, exact, stages, Q0, QD0, P, tol, tab, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q,
                  fin_qd, fin, first, min(LANES, N - first))


#: chaos twins in a block: the references in its first PAIRS lanes, their twins in the others
PAIRS = LANES // 2


@njit(cache=True, no_cpython_wrapper=True)
def run_twin_block(model, exact, stages, Q0, QD0, DQ, DQD, P, tol, tab, dt, n_steps, renorm_steps, scale, stretch,
                   fin, first, count):
    """Twins of members first .. first + count - 1 (count <= PAIRS) as one block; outputs as :func:`run_twins`'s.

    The references step in the block's first PAIRS lanes and their twins in
    the others, through :func:`block_to` up to each renormalisation, which
    moves each twin as :func:`follow_twins` does (:func:`renormalise`). A pair
    ends at the first renormalisation after either of it stopped, with what
    follow_twins reports: it runs a reference's interval before its twin's,
    so where the reference stopped, the twin's interval counts for nothing
    (its tally and step as at the interval's start). A pair's two lanes have
    its member's parameters (P's rows differ in the restitution at most: see
    :func:`run_block`).
    """
    n = 6
    p = P[first]
    B = new_block(model, P.shape[1])
    gv = np.empty((2, model.n_contact))
    q, qd, qt, qdt = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    out = new_samples(np.int64(2))
    log = new_log(LOG_SIZE)
    kept = np.empty((PAIRS, TALLY))          # each twin's tally at the interval's start
    d0 = np.empty(PAIRS)
    off = np.zeros((2 * n, PAIRS))             # each pair's first offset, a row a coordinate (renormalise_block)
    span = np.empty(PAIRS)
    k = np.zeros(PAIRS, np.int64)            # renormalisations done
    step = np.zeros(PAIRS, np.int64)         # a reference's step reached, then its twin's (pairs that ended)
    step_t = np.zeros(PAIRS, np.int64)
    status = np.zeros(PAIRS, np.int64)
    ended = np.zeros(PAIRS, np.int64)
    for r in range(PAIRS):
        j = first + min(r, count - 1)
        for d in range(n):
            q[d] = Q0[j, d]
            qd[d] = QD0[j, d]
            qt[d] = q[d] + DQ[j, d]
            qdt[d] = qd[d] + DQD[j, d]
        if r >= count:              # padding: flies along in the vectors, never stepped alone
            copy_to(B.tallies[r], new_tally())
            copy_to(B.tallies[PAIRS + r], new_tally())
            set_lane(model, B, r, P[j])
            set_lane(model, B, PAIRS + r, P[j])
            put_lane(B.S, r, q, qd)
            put_lane(B.S, PAIRS + r, qt, qdt)
            continue
        d0[r] = twin_distance(DQ[j], DQD[j], scale, n)
        for d in range(n):
            off[d, r] = DQ[j, d]
            off[n + d, r] = DQD[j, d]
        copy_to(kept[r], new_tally())
        log = start_lane(model, exact, stages, B, r, q, qd, P[j], tol, dt, out, log)
        log = start_lane(model, exact, stages, B, PAIRS + r, qt, qdt, P[j], tol, dt, out, log)
    i = 0
    n_ended = 0
    S, alive, rests, tallies = B.S, B.alive, B.rests, B.tallies     # (each B.x read in the loop counts a reference)
    while i < n_steps and n_ended < count:
        stop = min(i + renorm_steps, n_steps)
        log = block_to(model, exact, stages, B, p, tol, tab, dt, i, stop, out, log)
        for r in range(count):
            if ended[r]:
                continue
            tw = PAIRS + r
            if not alive[r] or not alive[tw]:
                ended[r] = 1
                n_ended += 1
                if not alive[r]:            # the reference stopped: its twin's interval is not run
                    status[r], step[r], step_t[r] = B.status[r], B.reached[r], i
                    copy_to(tallies[tw], kept[r])
                else:
                    status[r], step[r], step_t[r] = B.status[tw], stop, B.reached[tw]
                alive[r] = 0
                alive[tw] = 0
        renormalise_block(model, 0.0 + stop * dt, S, first, count, ended, k, stretch, off, d0, scale, span, rests,
                          P, tol, gv, qt, qdt, kept, tallies)
        i = stop
    for r in range(count):
        j = first + r
        if not ended[r]:
            status[r], step[r], step_t[r] = DONE, n_steps, n_steps
        for m in range(k[r], stretch.shape[1]):
            stretch[j, m] = np.nan
        tally, tally_t = B.tallies[r], B.tallies[PAIRS + r]
        fin[j, 0] = tally[TALLY_IMPULSES]
        fin[j, 1] = status[r]
        fin[j, 2] = step[r]
        fin[j, 3] = fallback_time(tally, step[r] * dt) + fallback_time(tally_t, step_t[r] * dt)
        fin[j, 4] = tally[TALLY_WARNINGS] + tally_t[TALLY_WARNINGS]
        take_lane(B.S, r, q, qd)          # (a free box: lanes are for free boxes only)
        for d in range(n):
            fin[j, TWIN_FIN + d] = q[d]
            fin[j, TWIN_FIN + 6 + d] = qd[d]


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def renormalise_block(model, t, S, first, count, ended, k, stretch, off, d0, scale, span, rests, P, tol, gv, qt,
                      qdt, kept, tallies):
    """The pairs of a twin block that have not ended renormalised at time t, in the block's state: each as
    :func:`renormalise` moves a twin, the same operations on the same numbers (pair r: member first + r, its
    reference in lane r, its twin in lane PAIRS + r; off[:, r] its first offset, d0[r] that offset's
    length), log(d / d0) into ``stretch[j, k[r]]`` and k[r] counted, the twin's tally kept as its next
    interval's start (kept[r]). span, qt, qdt: scratch.

    The pairs' distances and moves first, in one loop over the block's rows with no call and no branch (the
    processor overlaps one pair's chain of divisions and square root with the next's), for every pair up to
    count (an ended pair's lanes are not live and nothing reads them again); then, pair by pair, the
    logarithm, the tallies and the contact test. (A call per pair that took its two lanes out into arrays
    and back, :func:`renormalise` on them and back again, was a tenth of a shaken chaos study in lanes by
    perf, most of it in passing the arrays; this is 3%.) The twin's bound on its gaps (BOUND_ROW) is
    lowered by what the move can change a gap, not computed again (NaN stays NaN: the lanes compute it),
    and its bound on their speed is its new rates'. A bound lower than the gaps is all the lanes ask of
    it: it decides which of their tests a step takes, never its numbers (each of those tests gives the
    exact loop's bits).
    """
    W, n, C = LANES, 6, model.n_contact
    for r in range(count):
        tw = PAIRS + r
        dist = 0.0
        for d in range(n):
            dist += apart(S[d * W + r], S[d * W + tw], scale[d]) + apart(S[(n + d) * W + r], S[(n + d) * W + tw],
                                                                         scale[n + d])
        dist = math.sqrt(dist)
        ok = dist > 0.0
        f = d0[r] / dist if ok else 0.0
        lowered = S[BOUND_ROW * W + tw]
        for d in range(n):
            at = S[d * W + tw]
            moved = put_back(S[d * W + r], at, off[d, r], f, ok)
            lowered -= abs(moved - at) * tol[T_SPEED + d]
            S[d * W + tw] = moved
            S[(n + d) * W + tw] = put_back(S[(n + d) * W + r], S[(n + d) * W + tw], off[n + d, r], f, ok)
        S[BOUND_ROW * W + tw] = lowered
        S[SPEED_ROW * W + tw] = speed_bound((S[n * W + tw], S[(n + 1) * W + tw], S[(n + 2) * W + tw],
                                             S[(n + 3) * W + tw], S[(n + 4) * W + tw], S[(n + 5) * W + tw]), tol)
        span[r] = dist
    for r in range(count):
        if ended[r]:
            continue
        j = first + r
        tw = PAIRS + r
        dist = span[r]
        stretch[j, k[r]] = math.log(dist / d0[r]) if dist > 0.0 else np.nan
        k[r] += 1
        for x in range(TALLY):
            kept[r, x] = tallies[tw, x]
        if rests[tw, C + MODE_AT] == 0:
            for d in range(n):
                qt[d] = S[d * W + tw]
                qdt[d] = S[(n + d) * W + tw]
            mark_moved(model, t, qt, qdt, S[SPEED_ROW * W + tw], P[j], tol, rests[tw], gv, S[BOUND_ROW * W + tw])


@njit(cache=True)
def run_twin_member_blocks(table, Q0, QD0, DQ, DQD, P, TOL, dt, n_steps, renorm_steps, scale, stretch, fin):
    """:func:`run_twin_members` in blocks of PAIRS twin pairs (:func:`run_twin_block`), in parallel; the members share
    TOL[0] and P[0] but for the restitution (``Kernel.lanes_apply``)."""
    model, exact, stages = parts(table)
    tab = time_table(model, P[0], dt, n_steps)
    all_twin_blocks(model, exact, stages, Q0, QD0, DQ, DQD, P, TOL[0], tab, dt, n_steps, renorm_steps, scale,
                    stretch, fin)


@njit(cache=True, no_cpython_wrapper=True, parallel=True)
def all_twin_blocks(model, exact, stages, Q0, QD0, DQ, DQD, P, tol, tab, dt, n_steps, renorm_steps, scale, stretch,
                    fin):
    N = Q0.shape[0]
    nb = (N + PAIRS - 1) // PAIRS
    s = spread_stride(nb)     # (threads get blocks in spread order)
    for i in prange(nb):
        first = (i * s % nb) * PAIRS
        run_twin_block(model, exact, stages, Q0, QD0, DQ, DQD, P, tol, tab, dt, n_steps, renorm_steps, scale, stretch,
                       fin, first, min(PAIRS, N - first))


# ---------------------------------------------------------------------------
# a member's setup: its own work, in parallel, from the study's Setup and its index alone


@njit(cache=True, no_cpython_wrapper=True)
def grid_index(i, axis, n_axes, side):
    """Coordinate ``axis`` (0 .. side - 1) of point i of a grid of side^n_axes points (the last axis fastest)."""
    for _ in range(n_axes - 1 - axis):
        i //= side
    return i % side


@njit(cache=True, no_cpython_wrapper=True)
def derive_inertias(derive, p):
    """The inertias a member's swept masses and sizes move (``Setup.derive``), computed again in p.

    The scene file's own formulas, operation for operation
    (``jackbox.scene.frame_inertia`` and ``jack_inertia``): a member's
    parameters are those ``simulate(params=...)`` gives the same values.
    """
    if derive.shape[0] == 0:
        return
    if derive[0] >= 0:
        L, w = p[derive[2]], p[derive[3]]
        so, si = 2.0 * (L + w), 2.0 * L
        p[derive[0]] = p[derive[1]] * (so * so + si * si) / 6.0
    if derive[4] >= 0:
        m, a = p[derive[5]], p[derive[6]]
        p[derive[4]] = m * a * a if derive[7] == DERIVE_CROSS else 2.0 * m * a * a / 3.0


@njit(cache=True, no_cpython_wrapper=True)
def set_up_member(model, setup, i, q, qd, p, tol, offset):
    """Member i's start (q, qd), parameters p, tolerance row and chaos twin's offset; returns its start gap.

    Everything comes from ``setup`` and i: the random numbers are draws of
    (seed, i) (:mod:`.draws`), so any member is set up alone, in any order,
    on any thread, with the same bits. offset: 2 n_dof slots (coordinates, then
    rates) when the study has twins (setup.d0 > 0), else none. The gap is the
    smallest of the start state (negative: inside a wall).
    """
    n = model.n_dof
    copy_to(q, setup.q)
    copy_to(qd, setup.qd)
    copy_to(p, setup.p)
    k = setup.perturb_at.shape[0]
    for j in range(k):
        if setup.grid == 0:
            u = draw_uniform(setup.seed, i, START, j)
        elif setup.grid > 1:
            u = 2.0 * grid_index(i, j, k, setup.grid) / (setup.grid - 1) - 1.0
        else:
            u = 0.0
        at = setup.perturb_at[j]
        if at < n:
            q[at] += setup.perturb_by[j] * u
        else:
            qd[at - n] += setup.perturb_by[j] * u
    side = setup.sweep_side
    for s in range(setup.sweep_at.shape[0]):
        a = setup.sweep_axis[s]
        lo, hi = setup.sweep_lo[a], setup.sweep_hi[a]
        c = grid_index(i, a, setup.sweep_lo.shape[0], side)
        p[setup.sweep_at[s]] = lo + (hi - lo) * c / (side - 1) if side > 1 else lo
    derive_inertias(setup.derive, p)
    if setup.sweep_at.shape[0] == 0:        # the shared parameters: the shared row
        copy_to(tol, setup.tol)
    else:
        # (a swept box motion's bound: the study's over its range, jackbox.ensemble._study_box_speed)
        set_tolerances(model, p, setup.jack_factor, setup.n_points, setup.dt, setup.tol[T_BOXV], tol)
    if setup.d0 > 0.0:
        # a random direction in the scaled state space (normal draws, normalised), d0 long
        norm = 0.0
        for d in range(2 * n):
            offset[d] = draw_normal(setup.seed, i, TWIN, d)
            norm += offset[d] * offset[d]
        norm = math.sqrt(norm)
        for d in range(2 * n):
            offset[d] = setup.d0 * (offset[d] / norm) * setup.scale[d]
    gap = np.empty(model.n_contact)
    model.phi(0.0, q, p, gap)
    return gap.min()


@njit(cache=True)
def set_up_members(table, setup, Q0, QD0, P, TOL, OFFSET, GAP):
    """:func:`set_up_member` for members setup.first + j into row j of each array, in parallel."""
    all_setups(from_table(table, MODEL_AT, ModelType), setup, Q0, QD0, P, TOL, OFFSET, GAP)


@njit(cache=True, no_cpython_wrapper=True, parallel=True)
def all_setups(model, setup, Q0, QD0, P, TOL, OFFSET, GAP):
    for j in prange(Q0.shape[0]):
        GAP[j] = set_up_member(model, setup, setup.first + j, Q0[j], QD0[j], P[j], TOL[j], OFFSET[j])
