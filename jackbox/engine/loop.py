"""The loops: a run from step to step. A step reads: integrate, look, locate, resolve, record.

:func:`integrate_exact` (method "exact") integrates a step (:mod:`.integrator`,
or :mod:`.flight` far from every wall), looks at the gaps at both of its ends,
locates the first event inside it (:mod:`.events`), resolves it (impulses and
the persistent set, :mod:`.modes`) and steps on from there; a step it cannot
resolve (no progress, or too many contact mode changes) is undone and taken,
with those after it until the contacts are stable, by Moreau-Jean
time-stepping (:mod:`.fallback`); samples are recorded on the grid. :func:`integrate` (method "naive": the model's free_step on floats) applies impulses at
the end of the step in which a gap went negative.

Both loops are compiled once for every model, as ``cfunc`` values of the
signatures ``EXACT`` and ``NAIVE`` (:mod:`jackbox.engine.records`); whatever
runs a loop (:func:`run_exact` and :func:`run_naive` for Python callers, the
members of :mod:`jackbox.engine.members`) calls it through that value. So
their machine code is generated once, not again inside every entry point
that runs them (Numba would link and re-optimise the whole call tree into
each caller). For the same reason the exact loop reaches its heavy stages
(the integrator's step, the contact update, the two event searches, the
fallback, the held loop) through a :class:`~jackbox.engine.records.Stages`
record of function values. Three of them are compiled on first need only: a
run with no held contact never needs the release search nor the held loop,
nor one the exact method resolves throughout the fallback; the loop then
hands the step back (MISSING) and the caller compiles them and calls again.

Where contacts are held and nothing happens to them, :func:`hold` takes the
steps in one call, as the model's ``fly`` does in free flight: a step through
:func:`advance` makes some ten calls that pass the model and scratch records
(each of their fields a word of its own, about 100 ns a call), more than the
held step's own solves. A body at rest there coasts (moves on at its rates),
in stretches of up to :data:`CHUNK` steps looked at at their ends
(:func:`coast_chunk`).
"""

import math

import numpy as np
from numba import njit

from .impact import resolve_impacts
from .integrator import held_passes, rk4_rows
from .modes import held_accel, log_event, on_level, project_rest, rest_index, settle_rows
from .records import (AF, COAST, DENSE_AT, DENSE_SLOW, DENSE_FLOOR, DENSE_SCORE, DONE, DRIFT, EXACT_AT, FALLBACK, FLAGS, GA, GB,
                      HANDOFF, HANDOFF_AT, HANDOFF_DENSE, HANDOFF_EVENTS, HANDOFF_MODES, HANDOFF_STUCK, HANDOFF_ZENO,
                      IMPACT_LOG_FULL, INSIDE, LAM, LS, MAX_EVENTS, MISSING, MODE_AT, MODE_BUDGET, MODE_SLOTS, MODEL_AT, NAIVE_AT,
                      NEED_FALLBACK, NEED_HOLD, NEED_RELEASE, NONFINITE, PASSES_AT, Q0, QB, QD0, QDB, QDS, QS, RELEASE,
                      RIDE_F, RIDE_K,
                      RHS, RIDX, RINV, SET_AT, SLOW_AT, STAGES_AT, SWAP_BUDGET, T_AREST, T_EVENT, T_RBOX, T_SPEED, T_WALL, THROUGH, WARN_LCP, WARN_LOCATE,
                      WARNING, WINV, ZENO_PASSES, ZENO_SPAN, Events, ExactType, ModelType, NaiveType, Samples, StagesType,
                      borrow, from_table, keep, scratch)
from .gaps import step_reach


#: the most steps :func:`hold` lets coast as one stretch (:func:`coast_chunk`): a body resting on flat walls
#: then reads and solves its held rows once a stretch instead of once a step. A stretch that does not
#: coast to its end is stepped again one step at a time (its steps' arithmetic is wasted)
CHUNK = 32


@njit(cache=True, no_cpython_wrapper=True)
def complete_samples(model, p, out, n0, n1, ws):
    """The box's columns (a prescribed box) and the energy of samples n0..n1-1, recorded by the model's fly.

    The same numbers as :func:`record` (the same functions of the same state).
    """
    off = 0
    if model.prescribed:
        off = 3
        for k in range(n0, n1):
            model.box_motion(out.t[k], p, ws.box)
            for i in range(3):
                out.q[k, i] = ws.box[i]
                out.qd[k, i] = ws.box[3 + i]
    qs, qds = ws.n[QS], ws.n[QDS]
    for k in range(n0, n1):
        for i in range(model.n_dof):
            qs[i] = out.q[k, off + i]
            qds[i] = out.qd[k, off + i]
        out.energy[k] = model.energy(out.t[k], qs, qds, p)


@njit(cache=True, no_cpython_wrapper=True)
def record(model, t, q, qd, p, n, out, box):
    """Store sample n of ``out`` (a Samples record): time, the 6 coordinates and rates, the energy."""
    out.t[n] = t
    off = 0
    if model.prescribed:
        model.box_motion(t, p, box)
        for i in range(3):
            out.q[n, i] = box[i]
            out.qd[n, i] = box[3 + i]
        off = 3
    for i in range(model.n_dof):
        out.q[n, off + i] = q[i]
        out.qd[n, off + i] = qd[i]
    out.energy[n] = model.energy(t, q, qd, p)


def integrate(model, q, qd, p, t0, dt, i_begin, i_end, n_total, record_every, out, n_rec, log, n_imp):
    """Method "naive": advance from step ``i_begin`` to ``i_end`` (time ``t0 + i dt``).

    q, qd: the state, updated in place. Samples are recorded at every step
    ``i`` with ``i % record_every == 0`` and at ``n_total``, into ``out`` from
    index ``n_rec``; impulses are logged into ``log`` from ``n_imp``.
    Returns ``(step reached, n_rec, n_imp, status)``.
    """
    own = scratch(model)
    result = naive_steps(model, borrow(q), borrow(qd), borrow(p), t0, dt, i_begin, i_end, n_total,
                         record_every, borrow(out), n_rec, borrow(log), n_imp, borrow(own))
    keep(own)
    return result


@njit(cache=True, no_cpython_wrapper=True)
def naive_steps(model, q, qd, p, t0, dt, i_begin, i_end, n_total, record_every, out, n_rec, log, n_imp, ws):
    """The body of :func:`integrate`, on borrowed views (:func:`~.records.borrow`) and its scratch ``ws``."""
    gap = ws.c[GA]
    if i_begin == 0 and n_rec == 0:   # (not again when resumed after a full log)
        record(model, t0, q, qd, p, n_rec, out, ws.box)
        n_rec += 1
    for i in range(i_begin, i_end):
        if n_imp + model.n_contact > log.t.shape[0]:
            return i, n_rec, n_imp, IMPACT_LOG_FULL
        t = t0 + i * dt
        t_next = t0 + (i + 1) * dt
        model.free_step(t, t_next, q, qd, dt, p, q, qd)   # nothing is ever held: the model's own RK4 on floats
        model.phi(t_next, q, p, gap)
        n_imp = resolve_impacts(model, t_next, q, qd, p, gap, 0.0, ws, log, n_imp)
        for d in range(model.n_dof):
            if not (math.isfinite(q[d]) and math.isfinite(qd[d])):
                return i + 1, n_rec, n_imp, NONFINITE
        if (i + 1) % record_every == 0 or i + 1 == n_total:
            record(model, t_next, q, qd, p, n_rec, out, ws.box)
            n_rec += 1
    return i_end, n_rec, n_imp, DONE


@njit(cache=True, no_cpython_wrapper=True)
def let_go(model, stages, t, q, qd, p, tol, rest, m, ws, log, n_ev, changes):
    """The contact update where a persistent contact's force pulls; the gaps at t into ``ws.c[GA]``.

    Returns ``(n_ev, m, changes, watch)``: a mode change counted, or, when the
    update held every contact (the accelerations' LCP finds them still), no
    more release watching in this step.
    """
    m0 = m
    n_ev, m = stages.update(model, t, q, qd, p, tol, rest, ws, log, n_ev)
    model.phi(t, q, p, ws.c[GA])
    if m == m0:
        return n_ev, m, changes, False
    return n_ev, m, changes + 1, True


@njit(cache=True, no_cpython_wrapper=True)
def advance(model, stages, ta, tb, q, qd, p, tol, rest, m, ws, log, n_ev, trial):
    """Take the state from ta to tb through every event in between.

    On entry ``ws.c[GA]`` holds the gaps at (ta, q); on return those at (tb, q).
    trial: the RK4 step from ta to tb and its gaps are already in
    ``ws.n[QB]``, ``ws.n[QDB]`` and ``ws.c[GB]``. Returns ``(n_ev, m, status)``:
    DONE, or HANDOFF when the step is for the fallback (:mod:`.fallback`): an
    event made no progress twice, the contact modes changed more than
    MODE_BUDGET times (or the held set was exchanged for another of its size
    more than SWAP_BUDGET times), ZENO_PASSES passes advanced by less than ZENO_SPAN of
    the step (Zeno in several contacts), or MAX_EVENTS passes did not reach tb;
    MISSING when it needs the release stage and that is not compiled.
    """
    n = model.n_dof
    C = model.n_contact
    level = 0.5 * tol[T_EVENT]
    target = tb
    releasing = False
    watch_release = True     # off for the rest of the step once a release changed nothing
    stuck = 0
    changes = 0
    swaps = 0
    t_mark = ta
    span = ZENO_SPAN * (tb - ta)
    qb, qdb = ws.n[QB], ws.n[QDB]
    ga, gb = ws.c[GA], ws.c[GB]
    ws.k[FLAGS, PASSES_AT] = held_passes(qd, tb - ta, n, tol[T_WALL])    # (the step's held steps: integrator.rk4)
    for passes in range(1, MAX_EVENTS + 1):
        if passes % ZENO_PASSES == 0:
            if ta - t_mark < span:
                ws.k[FLAGS, HANDOFF_AT] = HANDOFF_ZENO
                return n_ev, m, HANDOFF
            t_mark = ta
        if not trial:
            stages.step(model, ta, q, qd, target - ta, p, qb, qdb, m, ws)
        if m > 0 and watch_release and not releasing:
            if stages.missing & NEED_RELEASE:
                return n_ev, m, MISSING
            tr = stages.release(model, stages.step, ta, target, q, qd, p, tol, m, ws)
            if tr == ta:       # a persistent contact already pulls: the contact update decides
                n_ev, m, changes, watch_release = let_go(model, stages, ta, q, qd, p, tol, rest, m, ws, log, n_ev,
                                                         changes)
                trial = False
                continue
            if tr > ta:        # step to where it lets go (gaps are checked on the way)
                target = tr
                releasing = True
                trial = False
                continue
        if not trial:
            model.phi(target, qb, p, gb)
        trial = False
        if stuck >= 2 or changes > MODE_BUDGET or swaps > SWAP_BUDGET:
            ws.k[FLAGS, HANDOFF_AT] = HANDOFF_STUCK if stuck >= 2 else HANDOFF_MODES
            return n_ev, m, HANDOFF
        te = stages.crossing(model, stages.step, ta, target, q, qd, p, tol, rest, m, ws)
        if te >= 0.0:
            if te > ta:
                qs, qds = ws.n[QS], ws.n[QDS]
                for d in range(n):
                    q[d] = qs[d]
                    qd[d] = qds[d]
                ta = te
                stuck = 0
            else:
                stuck += 1
            # An event at the same instant that changes nothing (a contact
            # touching at round-off level with no resolvable motion) twice
            # running: the step goes to the fallback.
            n0, m0, held0 = n_ev, m, held_set(rest, C)
            ws.k[FLAGS, 1] = 0       # an impact before the release: nothing is being let go
            n_ev, m = stages.update(model, ta, q, qd, p, tol, rest, ws, log, n_ev)
            if n_ev != n0 or m != m0:
                stuck = 0
            if m != m0:
                changes += 1
            elif held_set(rest, C) != held0:    # one held set for another of its size
                swaps += 1
            model.phi(ta, q, p, ga)
            target = tb
            releasing = False
            continue
        stuck = 0
        for d in range(n):
            q[d] = qb[d]
            qd[d] = qdb[d]
        ta = target
        if m > 0:
            project_rest(model, ta, q, qd, p, m, level, np.int64(1), ws)
            model.phi(ta, q, p, ga)
        else:
            for k in range(C):
                ga[k] = gb[k]
        if releasing:          # arrived where a persistent contact lets go
            n_ev, m, changes, watch_release = let_go(model, stages, ta, q, qd, p, tol, rest, m, ws, log, n_ev, changes)
            target = tb
            releasing = False
            continue
        if ta == tb:
            return n_ev, m, DONE
    ws.k[FLAGS, HANDOFF_AT] = HANDOFF_EVENTS
    return n_ev, m, HANDOFF


@njit(cache=True, no_cpython_wrapper=True)
def hold(model, t0, dt, i, i_stop, q, qd, p, tol, rest, m, ws, out, n_rec, record_every, n_total):
    """Steps i, i+1, ... with the m persistent contacts held, while nothing happens in them.

    The resting counterpart of the model's ``fly``: one call for a stretch of
    quiet steps, each the arithmetic of :func:`advance` on a step with no
    event (:func:`~.integrator.rk4`, the release screen of
    :func:`~.events.first_release`, the near test of
    :func:`~.events.first_crossing`) but for its end: :func:`~.modes.settle_rows`
    projects the gaps only where they drifted past round-off and hands its
    factorization to the next step, where advance projects every time (the
    same in advance cost a second of the first run's compiling; the two
    differ at round-off, and which loop takes a step depends on the state alone),
    on the scratch's arrays taken out once: each of those calls would pass
    the model and scratch records, some hundred and fifty words, which cost
    more than a held step's own solves. Stops at i_stop, or before a step
    whose forces might pull (any stage's force below the release floor),
    whose free contacts come within its reach, or whose end is not finite:
    :func:`advance` takes that one. The free contacts' gaps are computed only
    where a bound on them (their smallest at the last look, lowered by each
    step's band and by what each projection moved) says one could be near:
    a contact resting on a floor with the others far from the walls takes
    no gap row at all.

    With one to four contacts held, the model's ``ride`` takes the steps it can
    first (:func:`jackbox.engine.flight.ride`: the same step on floats, the
    same numbers); the steps it stops before come back here, and one it hands
    over integrated (a pull, a non-finite end, a free contact near) is
    returned as this loop returns its own (trial 1).

    Each step's first RK4 stage is taken here (the same call RK4 makes).
    Where its accelerations vanish (below COAST of T_AREST on every
    coordinate's lever, a hundred times their round-off at rest), the step
    is tried as uniform motion, every coordinate moving on at its rate
    (what RK4's stages give when the accelerations they sample are zero):
    the rows are read and factored once, at its end, and it *coasts* if the
    accelerations vanish there too and the held rows are on their level
    (nothing to project); its end's accelerations and forces are the next
    step's first stage. Otherwise RK4 takes the step from that first stage.
    A resting or sliding body (the settled drop: the jack slides along the
    floor of a box that slides on frictionless ground) takes a fifth of a
    held step's time; a step that coasted and stops the loop is handed back
    to be integrated again (trial 0). After a step that coasted, the steps
    up to CHUNK ahead are tried as one stretch (:func:`coast_chunk`: the held
    rows read once, at its end); a stretch that does not coast to its end
    goes one step at a time. Which steps coast, and their numbers, depend on
    the state alone. The gaps at the state reached are left in
    ``ws.c[GA]``. The samples on the way (steps that are multiples of
    record_every, and n_total) go into ``out`` from n_rec. Returns ``(i,
    trial, n_rec)``: trial 1 when the step it stopped before is already
    integrated (``ws.n[QB]``, ``ws.n[QDB]``, its gaps in ``ws.c[GB]`` and its
    forces in ``ws.c[LS:]``), as :func:`advance` takes it.
    """
    n, C = model.n_dof, model.n_contact
    ridx, jac, A, L, w = ws.k[RIDX], ws.jac, ws.A, ws.lu, ws.work
    winv, rinv, y, lam = ws.n[WINV], ws.c[RINV], ws.c[RHS], ws.c[LAM]
    ls = ws.c[LS:LS + 4]
    qb, qdb = ws.n[QB], ws.n[QDB]
    ga, gb = ws.c[GA], ws.c[GB]
    half = 0.5 * tol[T_EVENT]
    deep = half + tol[T_EVENT]
    arest = tol[T_AREST]
    drift = DRIFT * tol[T_EVENT]      # a held gap off its level by less is round-off (modes.settle_rows)
    still = COAST * arest             # held accelerations that move no gap by more are none (coasting)
    model.inverse_mass(p, winv)
    model.phi(t0 + i * dt, q, p, ga)
    fresh = True                 # whether ga holds the gaps at (t, q)
    factored = False             # whether L, rinv hold the factorization of the held rows at q
    low = lowest_free(ga, rest, C)
    a_end = ws.n[AF]
    started = False              # whether w[5], ls[0] hold the accelerations and forces at (t, q, qd)
    single_until = 0             # the steps before this one go one at a time (a stretch that did not coast)
    rode = -1                    # the step the model's ride stopped before (taken here)
    while i < i_stop:
        if not started and m <= 4 and rode != i:
            # one to four rows held: the model's ride takes the steps it can on floats (the same numbers)
            n0 = n_rec
            io_f, io_k = ws.n[RIDE_F], ws.k[RIDE_K]
            io_f[0], io_k[0] = low, n_rec
            io_k[2], io_k[3] = ridx[min(m, 3) - 1], ridx[m - 1]     # (the third and fourth rows, where m > 2)
            rode = model.ride(t0, dt, i, i_stop, q, qd, p, tol, rest, m, ridx[0], ridx[min(m, 2) - 1], winv, io_f, out.t,
                              out.q, out.qd, io_k, record_every, n_total, qb, qdb, ga, gb, ls, A)
            low, n_rec = io_f[0], io_k[0]
            if n_rec > n0:
                complete_samples(model, p, out, n0, n_rec, ws)
            if io_k[1]:         # its next step comes near a free contact: integrated, for advance
                return rode, 1, n_rec
            if rode > i:
                i = rode
                fresh = False
                factored = False
                if i == i_stop:
                    break
        ta = t0 + i * dt
        tb = t0 + (i + 1) * dt
        h = tb - ta
        if not started:          # the step's first RK4 stage, taken here to see whether it may coast
            held_accel(model, ta, q, qd, p, m, w[5], ridx, jac, winv, A, L, rinv, y, lam, factored)
            for j in range(m):
                ls[0, j] = lam[j]
        if started and i >= single_until:
            # coasting: the steps up to CHUNK ahead as one stretch of uniform motion, looked at at its end
            k, kept, n_rec, low = coast_chunk(model, t0, dt, i, min(i_stop, i + CHUNK), q, qd, p, tol, rest, m, ws,
                                              out, n_rec, record_every, n_total, low, half, deep, drift, still, arest,
                                              ridx, jac, winv, A, L, rinv, y, lam, qb, qdb, a_end)
            if kept:
                for d in range(n):
                    q[d] = qb[d]
                    w[5, d] = a_end[d]
                for j in range(m):
                    for s in range(4):
                        ls[s, j] = lam[j]
                i = k
                factored = True
                fresh = False
                continue
            if k > i:                  # tried: its steps go one at a time, and L, rinv hold its end's rows
                single_until = k
                factored = False
        coasted = False
        if vanish(w[5], n, tol, still):
            # no acceleration at the start: the step is uniform motion (RK4's stages all have the
            # start's rates) if there is none at its end either, where its rows are read once; it
            # coasts if they are on their level there (nothing to project, as in free flight)
            for d in range(n):
                qb[d] = q[d] + h * qd[d]
                qdb[d] = qd[d]
            held_accel(model, tb, qb, qdb, p, m, a_end, ridx, jac, winv, A, L, rinv, y, lam, np.bool_(False))
            coasted = vanish(a_end, n, tol, still) and on_level(jac, ridx, m, n, half, drift, h)
            if coasted:
                for j in range(m):
                    for s in range(1, 4):
                        ls[s, j] = lam[j]
        if not coasted:
            rk4_rows(model, ta, q, qd, h, p, qb, qdb, m, w, ls, ridx, jac, winv, A, L, rinv, y, lam,
                     held_passes(qd, h, n, tol[T_WALL]), factored, np.bool_(True))
        stop = False
        for j in range(m):
            floor = -arest / A[j, j]
            for s in range(4):
                if not ls[s, j] >= floor:
                    stop = True
        for d in range(n):
            if not (math.isfinite(qb[d]) and math.isfinite(qdb[d])):
                stop = True
        band = step_reach(qd, qdb, h, tol)
        looked = False
        if stop or low - band + deep < band:
            # some free gap may come within the step's reach: first_crossing's own near test, on the gaps
            if not fresh:
                model.phi(ta, q, p, ga)
                fresh = True
            model.phi(tb, qb, p, gb)
            looked = True
            for k in range(C):
                if not rest[k] and min(ga[k], gb[k]) + deep < band:
                    stop = True
        if stop:       # (a step that coasted is taken again, by RK4)
            return i, 0 if coasted else 1, n_rec
        low = lowest_free(gb, rest, C) if looked else low - band    # (a bound on the free gaps at tb)
        for d in range(n):
            q[d] = qb[d]
            qd[d] = qdb[d]
        if coasted:    # on its level: the next step's first stage is its end's
            for d in range(n):
                w[5, d] = a_end[d]
            for j in range(m):
                ls[0, j] = ls[1, j]
            factored = True
        else:
            factored = settle_rows(model, tb, q, qd, p, m, half, drift, h, ridx, jac, winv, A, L, rinv, y, lam)
            for d in range(n):       # what the projection moved any gap by, at most
                low -= abs(q[d] - qb[d]) * tol[T_SPEED + d]
        started = coasted
        fresh = False
        i += 1
        if i % record_every == 0 or i == n_total:
            record(model, tb, q, qd, p, n_rec, out, ws.box)
            n_rec += 1
    if not fresh:
        model.phi(t0 + i * dt, q, p, ga)
    return i, 0, n_rec


@njit(cache=True, no_cpython_wrapper=True)
def coast_chunk(model, t0, dt, i, k_end, q, qd, p, tol, rest, m, ws, out, n_rec, record_every, n_total, low, half,
                deep, drift, still, arest, ridx, jac, winv, A, L, rinv, y, lam, qb, qdb, a_end):
    """Steps i .. k_end-1 of :func:`hold` as one stretch of uniform motion, from a step that coasted.

    Each step of the stretch is what a step that coasts does (every
    coordinate moves on at its rate over the step's own length, the free
    gaps' bound lowered by its band), so the states are those steps' bit for
    bit; the held rows are read, factored and solved once, at the stretch's
    end. Its steps are kept if there the accelerations vanish, the held rows
    are on their level, no force is below the release floor and the state is
    finite; the samples on the way are written from n_rec (and written again
    by the steps one at a time if not). Where the angles do not turn (their
    rates times the stretch's length move no gap by more than ``drift``) the
    held gaps and rates are affine in time and the held accelerations are
    those of a body at rest on flat walls, so what holds at both ends holds
    between them: a step that coasted at the start and the look at the end
    stand for the looks of every step. Returns ``(k, kept, n_rec, low)``: k
    the stretch's end (i where it was not tried), low the bound on the free
    gaps at k (unchanged where not kept).
    """
    n = model.n_dof
    if k_end - i < 2:
        return i, False, n_rec, low
    span = (k_end - i) * dt
    turn = 0.0
    for d in range(2, n, 3):
        turn += abs(qd[d]) * span * tol[T_SPEED + d]
    if model.prescribed:          # (a box moved by a hand turns the walls of the rows held on it)
        model.box_motion(t0 + i * dt, p, ws.box)
        turn += abs(ws.box[5]) * span * tol[T_RBOX]
    if not turn <= drift:
        return i, False, n_rec, low
    for d in range(n):
        qb[d] = q[d]
        qdb[d] = qd[d]
    n0 = n_rec
    lo = low
    for j in range(i, k_end):
        ta = t0 + j * dt
        tb = t0 + (j + 1) * dt
        h = tb - ta
        band = step_reach(qd, qd, h, tol)
        if lo - band + deep < band:        # a free gap may come near: hold's own test, step by step
            return j + 1, False, n0, low
        lo -= band
        for d in range(n):
            qb[d] = qb[d] + h * qd[d]
        if (j + 1) % record_every == 0 or j + 1 == n_total:
            record(model, tb, qb, qdb, p, n_rec, out, ws.box)
            n_rec += 1
    tb = t0 + k_end * dt
    held_accel(model, tb, qb, qdb, p, m, a_end, ridx, jac, winv, A, L, rinv, y, lam, np.bool_(False))
    kept = vanish(a_end, n, tol, still) and on_level(jac, ridx, m, n, half, drift, tb - (t0 + (k_end - 1) * dt))
    for j in range(m):
        if not lam[j] >= -arest / A[j, j]:
            kept = False
    for d in range(n):
        if not math.isfinite(qb[d]):
            kept = False
    if not kept:
        return k_end, False, n0, low
    return k_end, True, n_rec, lo


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def held_set(rest, C):
    """The persistent contacts as a bit mask (contact k: bit k; C <= 63)."""
    mask = 0
    for k in range(C):
        if rest[k]:
            mask |= np.int64(1) << k
    return mask


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def vanish(a, n, tol, still):
    """Whether the accelerations a move no gap by more than ``still`` (each times its coordinate's lever ``tol[T_SPEED + d]``)."""
    for d in range(n):
        if not abs(a[d]) * tol[T_SPEED + d] <= still:
            return False
    return True


@njit(cache=True, no_cpython_wrapper=True)
def went_through(g, C, tol):
    """Whether one of the gaps g is more than THROUGH L below contact: the run went through a wall unseen."""
    deep = -THROUGH * tol[T_WALL]
    for k in range(C):
        if g[k] < deep:
            return True
    return False


@njit(cache=True, no_cpython_wrapper=True)
def lowest_free(g, rest, C):
    """The smallest of the gaps g of the contacts that are not held (inf if every one is)."""
    low = math.inf
    for k in range(C):
        if not rest[k]:
            low = min(low, g[k])
    return low


@njit(cache=True, no_cpython_wrapper=True)
def enter_fallback(t, reason, rest, C, log, n_ev):
    """Log the hand-over to the fallback at t and why (HANDOFF_*): the persistent contacts are let go."""
    n_ev = log_event(t, reason, np.int64(FALLBACK), log, n_ev)
    for k in range(C):
        if rest[k]:
            n_ev = log_event(t, k, np.int64(RELEASE), log, n_ev)
            rest[k] = 0
    rest[C + MODE_AT] = 1
    rest[C + SET_AT] = -1
    rest[C + DENSE_AT] = 0
    return n_ev


@njit(cache=True, no_cpython_wrapper=True)
def log_warnings(t, ws, log, n_ev):
    """A WARNING event for each solver failure flagged in ``ws.k[FLAGS, 0]`` since the last call."""
    flags = ws.k[FLAGS, 0]
    if flags:
        for code in (WARN_LCP, WARN_LOCATE):
            if flags & code:
                n_ev = log_event(t, code, np.int64(WARNING), log, n_ev)
        ws.k[FLAGS, 0] = 0
    return n_ev


def integrate_exact(model, stages, q, qd, rest, p, tol, t0, dt, i_begin, i_end, n_total, record_every,
                    out, n_rec, log, n_ev):
    """Method "exact": like :func:`integrate`, with every contact event located.

    rest: (n_contact + MODE_SLOTS,) the contacts' modes (0 free, 1 persistent)
    and the fallback's state, carried between calls. tol: the ``T_*`` slots.
    log: the event log (time, contact, IMPULSE/REST/RELEASE/FALLBACK/WARNING).
    Returns ``(step reached, n_rec, n_ev, status)``; MISSING (the step
    undone) when a step needs a stage that ``stages.missing`` says is not
    compiled: the release (a contact is held) or the fallback.

    Every array goes on to the stages as a borrowed view: the arguments live
    as long as this call, the scratch as long as ``keep`` holds it.
    """
    own = scratch(model)
    result = exact_steps(model, stages, borrow(q), borrow(qd), borrow(rest), borrow(p), borrow(tol), t0, dt,
                         i_begin, i_end, n_total, record_every, borrow(out), n_rec, borrow(log), n_ev, borrow(own))
    keep(own)
    return result


@njit(cache=True, no_cpython_wrapper=True, _nrt=False)
def exact_steps(model, stages, q, qd, rest, p, tol, t0, dt, i_begin, i_end, n_total, record_every, out, n_rec,
                log, n_ev, ws):
    """The body of :func:`integrate_exact`, on borrowed views and its scratch ``ws``."""
    n, C = model.n_dof, model.n_contact
    m = rest_index(rest, C, ws.k[RIDX])
    if i_begin == 0 and n_rec == 0:   # (not again when resumed after a full log)
        rest[C + MODE_AT] = 0
        n_ev, m = stages.update(model, t0, q, qd, p, tol, rest, ws, log, n_ev)
        n_ev = log_warnings(t0, ws, log, n_ev)
        record(model, t0, q, qd, p, n_rec, out, ws.box)
        n_rec += 1
    ga, gb = ws.c[GA], ws.c[GB]
    qb, qdb = ws.n[QB], ws.n[QDB]
    q0, qd0, rest0 = ws.n[Q0], ws.n[QD0], ws.rest0
    ga_ok = False            # whether ga holds the gaps of the current state
    clear = model.clearance(t0 + i_begin * dt, q, p, tol)      # a bound on every gap
    half = 0.5 * tol[T_EVENT]
    next_rec = (i_begin // record_every + 1) * record_every
    i = i_begin
    capacity = log.t.shape[0]
    band = -math.inf         # the last free step's band (-inf after any other)
    while i < i_end:
        have_trial = False
        held_trial = False
        # near a wall (the bound on every gap below the last free step's band) fly would stop
        # before its first step: the step is taken here, without the call (a third of drop's steps)
        near = m == 0 and not clear >= band
        band = -math.inf
        if rest[C + MODE_AT] == 0 and not near:
            # A stretch of quiet steps in one call: free flight far from every wall (the
            # model's lean loop, on floats only), or resting with nothing happening to the
            # held contacts. Each stops before a step that needs care, its trial in qb, qdb.
            if m > 0 and stages.missing & NEED_HOLD:
                return i, n_rec, n_ev, MISSING
            if m == 0:      # (fly and hold record the samples on their way: a call per sample cost a step)
                n0 = n_rec
                i_quiet, clear, n_rec = model.fly(t0, dt, i, i_end, q, qd, p, tol, clear, qb, qdb, out.t, out.q,
                                                  out.qd, n_rec, next_rec, record_every, n_total)
                have_trial = True
                if n_rec > n0:
                    complete_samples(model, p, out, n0, n_rec, ws)
                if i_quiet > i:
                    ga_ok = False
                    rest[C + DENSE_AT] = 0      # (quiet steps: no events)
                    i = i_quiet
                    next_rec = (i // record_every + 1) * record_every
                    if i == i_end:
                        break
            else:
                i_quiet, trial_left, n_rec = stages.hold(model, t0, dt, i, i_end, q, qd, p, tol, rest, m, ws, out,
                                                         n_rec, record_every, n_total)
                held_trial = trial_left == 1
                ga_ok = True
                if i_quiet > i:
                    for d in range(n):
                        if not (math.isfinite(q[d]) and math.isfinite(qd[d])):
                            return i_quiet, n_rec, n_ev, NONFINITE
                    rest[C + DENSE_AT] = 0
                    i = i_quiet
                    next_rec = (i // record_every + 1) * record_every
                    if i == i_end:
                        break
        if rest[C + MODE_AT] > 0 and stages.missing & NEED_FALLBACK:
            return i, n_rec, n_ev, MISSING
        t = t0 + i * dt
        t_next = t0 + (i + 1) * dt
        for d in range(n):
            q0[d] = q[d]
            qd0[d] = qd[d]
        for k in range(C + MODE_SLOTS):
            rest0[k] = rest[k]
        n_before = n_ev
        ws.k[FLAGS, SLOW_AT] = 0
        if rest[C + MODE_AT] == -1:       # find the contact set again (a chaos twin was moved)
            rest[C + MODE_AT] = 0
            n_ev, m = stages.update(model, t, q, qd, p, tol, rest, ws, log, n_ev)
            ga_ok = False
            have_trial = False
        if rest[C + MODE_AT] > 0:
            model.phi(t, q, p, gb)
            if went_through(gb, C, tol):
                return i, n_rec, n_ev, INSIDE
            n_ev, m = stages.fallback(model, stages.update, t, dt, q, qd, p, tol, rest, ws, log, n_ev)
            ga_ok = False
        else:
            # The step with gap rows: quiet when every gap, at both ends of the
            # step, is further from contact than the step can move it.
            if not ga_ok:
                model.phi(t, q, p, ga)
                ga_ok = True
            if went_through(ga, C, tol):      # (on it would go inside the wall, slowly)
                return i, n_rec, n_ev, INSIDE
            quiet = False
            trial = held_trial
            if m == 0:
                if not have_trial:     # (the same numbers as fly's first step)
                    model.free_step(t, t_next, q, qd, dt, p, qb, qdb)
                band = step_reach(qd, qdb, dt, tol) - half
                model.phi(t_next, qb, p, gb)
                trial = True
                quiet = True
                for k in range(C):
                    if min(ga[k], gb[k]) < band:
                        quiet = False
                        break
            if quiet:
                for d in range(n):
                    q[d] = qb[d]
                    qd[d] = qdb[d]
                for k in range(C):
                    ga[k] = gb[k]
            else:
                n_ev, m, status = advance(model, stages, t, t_next, q, qd, p, tol, rest, m, ws, log, n_ev, trial)
                if status == HANDOFF and stages.missing & NEED_FALLBACK:
                    status = MISSING
                if status != DONE:       # undo the step: the fallback takes it, or the caller compiles a stage
                    for d in range(n):
                        q[d] = q0[d]
                        qd[d] = qd0[d]
                    for k in range(C + MODE_SLOTS):
                        rest[k] = rest0[k]
                    if status == MISSING:
                        return i, n_rec, n_before, MISSING
                    n_ev = enter_fallback(t, ws.k[FLAGS, HANDOFF_AT], rest, C, log, n_before)
                    n_ev, m = stages.fallback(model, stages.update, t, dt, q, qd, p, tol, rest, ws, log, n_ev)
                    ga_ok = False
        if rest[C + MODE_AT] == 0:
            # a bounce that neither shrinks nor stops: a run of dense steps that scores DENSE_SCORE hands
            # the next steps to the fallback
            slow = ws.k[FLAGS, SLOW_AT]
            if slow < DENSE_SLOW:
                rest[C + DENSE_AT] = 0
            else:
                rest[C + DENSE_AT] += max(slow, DENSE_FLOOR)
                if rest[C + DENSE_AT] >= DENSE_SCORE:
                    n_ev = enter_fallback(t_next, np.int64(HANDOFF_DENSE), rest, C, log, n_ev)
                    m = 0
                    ga_ok = False
        if ws.k[FLAGS, 0]:        # (a call per step otherwise: the flags are almost always clear)
            n_ev = log_warnings(t_next, ws, log, n_ev)
        if n_ev > capacity:   # the log overflowed: undo the step, the caller grows it
            for d in range(n):
                q[d] = q0[d]
                qd[d] = qd0[d]
            for k in range(C + MODE_SLOTS):
                rest[k] = rest0[k]
            return i, n_rec, n_before, IMPACT_LOG_FULL
        # a bound on the gaps for the next step's free flight (read only with no contact held): the
        # smallest of this step's own gap rows where ga holds them, for nothing
        clear = lowest_free(ga, rest, C) if ga_ok else model.clearance(t_next, q, p, tol)
        i += 1
        for d in range(n):
            if not (math.isfinite(q[d]) and math.isfinite(qd[d])):
                return i, n_rec, n_ev, NONFINITE
        if i == next_rec or i == n_total:
            record(model, t_next, q, qd, p, n_rec, out, ws.box)
            n_rec += 1
            if i == next_rec:
                next_rec += record_every
    return i_end, n_rec, n_ev, DONE


@njit(cache=True)
def run_exact(table, q, qd, rest, p, tol, t0, dt, i_begin, i_end, n_total, record_every,
              rec_t, rec_q, rec_qd, rec_energy, n_rec, ev_t, ev_k, ev_kind, n_ev):
    """:func:`integrate_exact` for Python callers: the model, the stages and the loop come in ``table``.

    The samples (rec_*) and the event log (ev_*) come as arrays; records of
    them, like records of function values, would cost Numba a type inference
    in Python on every call.
    """
    exact = from_table(table, EXACT_AT, ExactType)
    return exact(from_table(table, MODEL_AT, ModelType), from_table(table, STAGES_AT, StagesType), q, qd, rest, p,
                 tol, t0, dt, i_begin, i_end, n_total, record_every, Samples(rec_t, rec_q, rec_qd, rec_energy), n_rec,
                 Events(ev_t, ev_k, ev_kind), n_ev)


@njit(cache=True)
def run_naive(table, q, qd, p, t0, dt, i_begin, i_end, n_total, record_every,
              rec_t, rec_q, rec_qd, rec_energy, n_rec, ev_t, ev_k, ev_kind, n_imp):
    """:func:`integrate` for Python callers, like :func:`run_exact`."""
    naive = from_table(table, NAIVE_AT, NaiveType)
    return naive(from_table(table, MODEL_AT, ModelType), q, qd, p, t0, dt, i_begin, i_end, n_total, record_every,
                 Samples(rec_t, rec_q, rec_qd, rec_energy), n_rec, Events(ev_t, ev_k, ev_kind), n_imp)
