"""The loops: a run from step to step. A step reads: integrate, look, locate, resolve, record.

:func:`integrate_exact` (method "exact") integrates a step (:mod:`.integrator`,
or :mod:`.flight` far from every wall), looks at the gaps at both of its ends,
locates the first event inside it (:mod:`.events`), resolves it (impulses and
the persistent set, :mod:`.modes`) and steps on from there; samples are
recorded on the grid. :func:`integrate` (method "naive": the model's free_step on floats) applies impulses at
the end of the step in which a gap went negative.

Both loops are compiled once for every model, as ``cfunc`` values of the
signatures ``EXACT`` and ``NAIVE`` (:mod:`jackbox.engine.records`); whatever
runs a loop (:func:`run_exact` and :func:`run_naive` for Python callers, the
members of :mod:`jackbox.engine.members`) calls it through that value. So
their machine code is generated once, not again inside every entry point
that runs them (Numba would link and re-optimise the whole call tree into
each caller). For the same reason the exact loop reaches its heavy stages
(the integrator's step, the contact update, the two event searches) through
a :class:`~jackbox.engine.records.Stages` record of function values.
"""

import math

from numba import njit

from .impact import resolve_impacts
from .modes import project_rest, rest_index
from .records import (DONE, GA, GB, IMPACT_LOG_FULL, NONFINITE, Q0, QB, QD0, QDB, QDS, QS, REST0, RIDX,
                      STALLED, MAX_EVENTS, T_EVENT, EXACT_AT, MODEL_AT, NAIVE_AT, STAGES_AT, ExactType, ModelType,
                      NaiveType, StagesType, Events, Samples, borrow, from_table, keep, scratch)
from .gaps import step_reach


@njit(cache=True)
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


@njit(cache=True)
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
        model.free_step(t, q, qd, dt, p, q, qd)      # nothing is ever held: the model's own RK4 on floats
        model.phi(t_next, q, p, gap)
        n_imp = resolve_impacts(model, t_next, q, qd, p, gap, 0.0, ws, log, n_imp)
        for d in range(model.n_dof):
            if not (math.isfinite(q[d]) and math.isfinite(qd[d])):
                return i + 1, n_rec, n_imp, NONFINITE
        if (i + 1) % record_every == 0 or i + 1 == n_total:
            record(model, t_next, q, qd, p, n_rec, out, ws.box)
            n_rec += 1
    return i_end, n_rec, n_imp, DONE


@njit(cache=True, inline="always")
def advance(model, stages, ta, tb, q, qd, p, tol, rest, m, ws, log, n_ev, trial):
    """Take the state from ta to tb through every event in between.

    On entry ``ws.c[GA]`` holds the gaps at (ta, q); on return those at (tb, q).
    trial: the RK4 step from ta to tb and its gaps are already in
    ``ws.n[QB]``, ``ws.n[QDB]`` and ``ws.c[GB]``. Returns ``(n_ev, m, status)``.
    """
    n = model.n_dof
    target = tb
    releasing = False
    stuck = 0
    qb, qdb = ws.n[QB], ws.n[QDB]
    ga, gb = ws.c[GA], ws.c[GB]
    for _ in range(MAX_EVENTS):
        if not trial:
            stages.step(model, ta, q, qd, target - ta, p, qb, qdb, m, ws)
        if m > 0 and not releasing:
            tr = stages.release(model, stages.step, ta, target, q, qd, p, tol, m, ws)
            if tr == ta:       # a persistent contact already pulls: let it go now
                n_ev, m = stages.update(model, ta, q, qd, p, tol, rest, ws, log, n_ev, 1.0)
                model.phi(ta, q, p, ga)
                continue
            if tr > ta:        # step to where it lets go (gaps are checked on the way)
                target = tr
                releasing = True
                continue
        if not trial:
            model.phi(target, qb, p, gb)
        trial = False
        if stuck >= 3:
            return n_ev, m, STALLED
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
            # An event at the same instant that changed nothing: a contact
            # touching at round-off level with no resolvable motion. Next time
            # treat every slow contact as at rest; if that changes nothing
            # either, stop (STALLED) rather than let a body through a wall.
            n0, m0 = n_ev, m
            n_ev, m = stages.update(model, ta, q, qd, p, tol, rest, ws, log, n_ev,
                                      1.0 if stuck < 2 else 1e6)
            if n_ev != n0 or m != m0:
                stuck = 0
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
            project_rest(model, ta, q, qd, p, m, ws)
            model.phi(ta, q, p, ga)
        else:
            for k in range(model.n_contact):
                ga[k] = gb[k]
        if releasing:          # arrived where a persistent contact lets go
            n_ev, m = stages.update(model, ta, q, qd, p, tol, rest, ws, log, n_ev, 1.0)
            model.phi(ta, q, p, ga)
            target = tb
            releasing = False
            continue
        if ta == tb:
            return n_ev, m, DONE
    return n_ev, m, STALLED


def integrate_exact(model, stages, q, qd, rest, p, tol, t0, dt, i_begin, i_end, n_total, record_every,
                    out, n_rec, log, n_ev):
    """Method "exact": like :func:`integrate`, with every contact event located.

    rest: (n_contact,) 0/1 persistent contacts, carried between calls. tol: the
    ``T_*`` slots. log: the event log (time, contact, IMPULSE/REST/RELEASE).
    Returns ``(step reached, n_rec, n_ev, status)``.

    Every array goes on to the stages as a borrowed view: the arguments live
    as long as this call, the scratch as long as ``keep`` holds it.
    """
    own = scratch(model)
    result = exact_steps(model, stages, borrow(q), borrow(qd), borrow(rest), borrow(p), borrow(tol), t0, dt,
                         i_begin, i_end, n_total, record_every, borrow(out), n_rec, borrow(log), n_ev, borrow(own))
    keep(own)
    return result


@njit(cache=True)
def exact_steps(model, stages, q, qd, rest, p, tol, t0, dt, i_begin, i_end, n_total, record_every, out, n_rec,
                log, n_ev, ws):
    """The body of :func:`integrate_exact`, on borrowed views and its scratch ``ws``."""
    n, C = model.n_dof, model.n_contact
    m = rest_index(rest, ws.k[RIDX])
    if i_begin == 0 and n_rec == 0:   # (not again when resumed after a full log)
        n_ev, m = stages.update(model, t0, q, qd, p, tol, rest, ws, log, n_ev, 1.0)
        record(model, t0, q, qd, p, n_rec, out, ws.box)
        n_rec += 1
    ga, gb = ws.c[GA], ws.c[GB]
    qb, qdb = ws.n[QB], ws.n[QDB]
    q0, qd0, rest0 = ws.n[Q0], ws.n[QD0], ws.k[REST0]
    model.phi(t0 + i_begin * dt, q, p, ga)
    ga_ok = True             # ga holds the gaps of the current state
    clear = model.clearance(t0 + i_begin * dt, q, p, tol)      # a bound on every gap
    half = 0.5 * tol[T_EVENT]
    next_rec = (i_begin // record_every + 1) * record_every
    i = i_begin
    while i < i_end:
        if m == 0:
            # Free flight far from every wall: the lean loop, on floats only.
            i_stop = min(i_end, next_rec)
            i_fly, clear = model.fly(t0, dt, i, i_stop, q, qd, p, tol, clear, qb, qdb)
            if i_fly > i:
                ga_ok = False
                i = i_fly
                if i == next_rec or i == n_total:
                    record(model, t0 + i * dt, q, qd, p, n_rec, out, ws.box)
                    n_rec += 1
                    if i == next_rec:
                        next_rec += record_every
                if i == i_end:
                    break
            if i_fly == i_stop:    # stopped only to record: fly on
                continue
        t = t0 + i * dt
        t_next = t0 + (i + 1) * dt
        # The step with gap rows: quiet when every gap, at both ends of the
        # step, is further from contact than the step can move it.
        quiet = False
        if m == 0:             # fly() stopped before this step and left its trial in qb, qdb
            band = step_reach(qd, qdb, dt, tol) - half
            if not ga_ok:
                model.phi(t, q, p, ga)
                ga_ok = True
            model.phi(t_next, qb, p, gb)
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
            if not ga_ok:
                model.phi(t, q, p, ga)
                ga_ok = True
            for d in range(n):
                q0[d] = q[d]
                qd0[d] = qd[d]
            for k in range(C):
                rest0[k] = rest[k]
            n_before = n_ev
            n_ev, m, status = advance(model, stages, t, t_next, q, qd, p, tol, rest, m, ws, log, n_ev, m == 0)
            if n_ev > log.t.shape[0]:   # the log overflowed: undo the step, the caller grows it
                for d in range(n):
                    q[d] = q0[d]
                    qd[d] = qd0[d]
                for k in range(C):
                    rest[k] = rest0[k]
                return i, n_rec, n_before, IMPACT_LOG_FULL
            if status != DONE:
                return i, n_rec, n_ev, status
        clear = model.clearance(t_next, q, p, tol)
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
