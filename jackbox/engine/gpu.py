"""The engine on a GPU (numba-cuda): one thread per member, the exact method's own code.

Nothing here is a second engine. The functions of the other stages
(:mod:`.loop`, :mod:`.events`, :mod:`.modes`, :mod:`.impact`, :mod:`.fallback`
...) are compiled for the CUDA target from their own Python source
(:func:`device`): each is cloned with its module's globals in which every
engine function is replaced by its device version, and the three things a
GPU thread cannot do are replaced by what it can (:data:`SUBSTITUTES`: a
borrowed view is the array itself, a log cannot grow). A model comes in as
device versions of its generated functions and the free-flight hot path
(:mod:`.flight`), in the same :class:`~.records.Model` record the CPU engine
takes, so the loops call ``model.accel`` as they do there.

A kernel file holds one model: its generated text, the hot path's text and
the kernels (:data:`KERNELS`), named by a hash of all three and of the
engine's digest and numba-cuda's version; numba-cuda caches its machine code
beside it, so it is compiled once per machine and never served stale. Each
thread runs one member (:func:`~.members.follow_member`) or one pair of
chaos twins (:func:`~.members.follow_twins`) with scratch of fixed size in
its own local memory: no allocation, and an event log of LOG_SIZE entries
that cannot grow (a member whose single step needs more ends with the status
IMPACT_LOG_FULL, never silently).

Under ``NUMBA_ENABLE_CUDASIM=1`` (numba-cuda's simulator) the same kernels run
as Python on the CPU: the tests check the GPU's code path there against the
CPU engine on machines without a GPU.
"""

from __future__ import annotations

import hashlib
import importlib.util
import os
import sys
import time
import types as pytypes
from collections import namedtuple
from pathlib import Path

import numba
import numpy as np

from . import cache
from .loop import exact_steps, lowest_free, record
from .members import (LOG_SIZE, TALLY, TALLY_FIRST, TALLY_IMPULSES, TALLY_WARNINGS, copy_to, fallback_time, grown,
                      is_free, run_segment, start_member)
from .records import DONE, MODE_SLOTS, ROW_EXTRA, SC, SK, SN, SIGNATURES, Stages, borrow, keep

#: members per thread block
BLOCK = 64
#: the stages of the exact loop in a kernel's Stages record, with the scratch the loop steps in
GpuStages = namedtuple("GpuStages", Stages._fields + ("ws",))


def unavailable() -> str | None:
    """Why no study can run on a GPU here (one line), or None if one can (or the simulator is on)."""
    if importlib.util.find_spec("numba_cuda") is None:
        return ("device 'cuda' needs the numba-cuda package, which is not installed: "
                "pip install 'jackbox[cuda]' (or use device 'cpu')")
    if _simulated():
        return None
    try:
        if not _cuda().is_available():
            return "device 'cuda': no CUDA GPU or driver was found on this machine (use device 'cpu')"
    except Exception as exc:        # a broken driver install: say what it said, on one line
        return f"device 'cuda': the CUDA driver could not be used ({str(exc).splitlines()[0]})"
    return None


def _simulated() -> bool:
    """Whether numba-cuda's simulator stands in for a GPU (``NUMBA_ENABLE_CUDASIM=1``)."""
    return os.environ.get("NUMBA_ENABLE_CUDASIM", "0") not in ("", "0")


# ---------------------------------------------------------------------------
# engine functions as device functions


def _same(x):
    return x


def _nothing(x):
    return None


#: what a GPU thread does instead: a view that holds no reference is the array itself (nothing is
#: counted there), nothing needs keeping alive, and a log cannot grow (see members.run_segment)
SUBSTITUTES = {id(borrow): _same, id(keep): _nothing, id(grown): _same}
_devices: dict = {}
_shadows: dict = {}


def _cuda():
    _numpy_for_numba_cuda()
    from numba import cuda
    return cuda


def _numpy_for_numba_cuda() -> None:
    """NumPy 2.5 removed ``np.row_stack`` (an alias of ``np.vstack``), which numba-cuda 0.30 still registers
    when it first compiles or loads a kernel: every launch failed there with an AttributeError deep in
    numba-cuda (seen on a GPU machine with NumPy 2.5.2). The alias is put back where it is missing."""
    if not hasattr(np, "row_stack"):
        np.row_stack = np.vstack


#: the functions kept out of line in the GPU's code, as the CPU engine keeps them (its function values,
#: jackbox.engine.LOOPS): NVVM would inline the whole call tree into the kernel and take minutes
#: optimising it (7.5 min for the members kernel, against 27 s with these out of line)
OUT_OF_LINE = ("rk4", "update_contacts", "first_crossing", "first_release", "fallback_step", "hold", "run_segment")
#: more functions kept out of line: the engine's small solvers and the model's generated functions, each
#: called from many places. Inlined at each, they were most of the ``alone`` kernel's code (shaken: 110k PTX
#: instructions against 41k) and of its compile time: on an H100 machine, 12 kernels cold side by side,
#: ``alone`` took 130-144 s inlined and 56 s so, with the same speed (shaken 1e6 members 3.13-3.17e9
#: member-steps/s inlined, 3.17-3.19e9 so; drop e = 0.6 1.60-1.61e8 and 1.57-1.60e8) and the same numbers
#: (benchmarks/results/gpu_outline.json). ``accel`` stays inline: every stage of every step calls it.
#: ``JACKBOX_GPU_OUT_OF_LINE`` (names, comma-separated; empty for none) replaces them (benchmarks/gpu_outline.py);
#: a kernel file names them, so kernels compiled with others are other files
HELPERS_OUT_OF_LINE = ("contact_rows", "phi", "inverse_mass", "gap_rate", "held_accel", "held_solve", "project_rows",
                       "lcp", "enumerate_sets", "solve_dense", "factor_rows", "solve_rows", "contact_matrix",
                       "add_response")
MORE_OUT_OF_LINE = tuple(name.strip() for name in os.environ.get("JACKBOX_GPU_OUT_OF_LINE",
                                                                  ",".join(HELPERS_OUT_OF_LINE)).split(",")
                         if name.strip())


def device(fn):
    """The device version of an engine function (a CPU dispatcher or a plain function), made once."""
    py = getattr(fn, "py_func", fn)
    key = id(py)
    if key not in _devices:
        if id(fn) in SUBSTITUTES:
            _devices[key] = _cuda().jit(device=True)(SUBSTITUTES[id(fn)])
        else:
            clone = pytypes.FunctionType(py.__code__, _shadow(py.__module__), py.__name__, py.__defaults__,
                                         py.__closure__)
            clone.__module__, clone.__qualname__, clone.__doc__ = py.__module__, py.__qualname__, py.__doc__
            _devices[key] = _typed_once(_cuda().jit(device=True)(clone),
                                        py.__name__ in OUT_OF_LINE or py.__name__ in MORE_OUT_OF_LINE)
    return _devices[key]


def _typed_once(dispatcher, out_of_line: bool):
    """A device function compiled once for its argument types, constants among them taken as their type.

    numba-cuda compiles a device function again for each literal value it is
    called with (``run_segment(..., 0, ...)`` and ``(..., 1, ...)``: two
    copies of everything below); here every argument is widened first. With
    out_of_line the function is marked ``noinline`` for NVVM.
    """
    if _simulated():
        return dispatcher
    from numba.core import types
    compile_device = dispatcher.compile_device

    def compile_widened(args, return_type=None):
        args = tuple(types.unliteral(a) for a in args)
        new = args not in dispatcher.overloads
        cres = compile_device(args, return_type)
        if new and out_of_line:
            cres.library.get_function(cres.fndesc.llvm_func_name).attributes.add("noinline")
        return cres

    dispatcher.compile_device = compile_widened
    return dispatcher


def _is_engine_function(value) -> bool:
    return isinstance(value, numba.core.dispatcher.Dispatcher) or id(value) in SUBSTITUTES


def _shadow(module_name: str) -> dict:
    """The globals of an engine module with each engine function in them replaced by its device version."""
    if module_name not in _shadows:
        shadow = _shadows[module_name] = dict(vars(sys.modules[module_name]))
        for name, value in list(shadow.items()):
            if _is_engine_function(value) or (isinstance(value, pytypes.FunctionType)
                                               and value.__module__ == module_name):
                shadow[name] = device(value)
    return _shadows[module_name]


def to_device(namespace: dict) -> None:
    """Every function of a kernel file's namespace as a device function, in place (see :data:`KERNELS`).

    Its own functions (the model's and the hot path's, which call each other
    by name) are wrapped where they are; the engine's it imported are
    replaced by their device versions.
    """
    cuda = _cuda()
    for name, value in list(namespace.items()):
        if name.startswith("__"):
            continue
        if _is_engine_function(value):
            namespace[name] = device(value)
        elif isinstance(value, pytypes.FunctionType) and value.__module__ == namespace["__name__"]:
            namespace[name] = cuda.jit(device=True)(value)
            if name in MORE_OUT_OF_LINE:
                namespace[name] = _typed_once(namespace[name], True)


def exact_on(model, stages, q, qd, rest, p, tol, t0, dt, i_begin, i_end, n_total, record_every, out, n_rec, log,
             n_ev):
    """The exact loop as :func:`~.loop.integrate_exact` is called, in the scratch the kernel put in ``stages``.

    The scratch is zeroed first, as the CPU's is made (``np.zeros``) for each
    call: a GPU's local memory starts with whatever was there.
    """
    ws = stages.ws
    for a in (ws.work, ws.jac, ws.c, ws.n, ws.A, ws.sub, ws.lu):
        for i in range(a.shape[0]):
            for j in range(a.shape[1]):
                a[i, j] = 0.0
    for i in range(ws.k.shape[0]):
        for j in range(ws.k.shape[1]):
            ws.k[i, j] = 0
    for i in range(ws.rest0.shape[0]):
        ws.rest0[i] = 0
    for a in (ws.ext, ws.box):
        for i in range(a.shape[0]):
            a[i] = 0.0
    return exact_steps(model, stages, q, qd, rest, p, tol, t0, dt, i_begin, i_end, n_total, record_every, out, n_rec,
                       log, n_ev, ws)


def lanes_none(t0, dt, i, i_stop, S, p, tol, live, quiet, tab, lane_event):
    """(a kernel's model has no lanes: a GPU's member is a thread)"""
    return i


def time_table_none(t0, dt, n, p, out):
    """(nor their table of terms of time)"""
    return 0


def lane_event_none(t, t_next, dt, S, lane, at, to, p, tol):
    """(nor a lane's event step)"""
    return -1


def ride_none(t0, dt, i, i_stop, q, qd, p, tol, rest, m, k1, k2, winv, io_f, rec_t, rec_q, rec_qd, io_k,
              record_every, n_total, qb, qdb, ga, gb, ls, A):
    """(a kernel's model takes its held steps through the held loop's arrays: the same numbers, one function
    less to compile for the GPU)"""
    io_k[1] = 0
    return i


# ---------------------------------------------------------------------------
# an ensemble in rounds: every member flies while it is quiet, then those that need the exact loop take it


#: steps a member flies in one round (a round ends with the launch that takes the others through the
#: exact loop: they wait no longer than this), and takes in the exact loop while held; steps a member near
#: contact takes through the exact loop before it flies again (an approach, its impacts and the departure).
#: Kernel arguments, read at each launch (benchmarks/gpu_probe.py tries others)
CHUNK, ALONE = 256, 4
#: steps a held member (or one in the fallback) takes through the exact loop in a turn, and a member
#: whose next step likely has an event (a gap below zero at its end): kernel arguments too. On an H100
#: (benchmarks/results/gpu_probe.json, one sample each) drop e = 0.6 (1e5 members x 3 s) ran at 1.32e8
#: member-steps/s with these four against 8.0e7 with EVENT_TURN = ALONE = 16, HELD_TURN = 256 (9.8e7 with
#: 1, 1, 16); shaken (1e6 x 10 s) at 1.89e9 against 1.86e9 (its steps in the exact loop are dear, not
#: for divergence alone: 1.72e9 with turns of one step)
HELD_TURN, EVENT_TURN = 32, 1
#: where a round takes the steps that are not quiet but calm (the exact loop would find no event in them),
#: as an ensemble block's lanes do on the CPU, instead of listing the member for ``alone``; a kernel
#: argument. 0: nowhere (a flight stops at a step that is not quiet). 1 (APART): every member flies in the
#: lean ``flying``, which stops there, and those it listed near contact go on in ``calming`` (the flight
#: with the calm test, for up to ``chunk`` steps more), packed into warps of their own: the calm test's code
#: (255 registers where the lean flight needs 156-182) slows only the members that need it. 3 (SHORT): as
#: APART, but ``calming`` takes the calm steps only: a member quiet again after them (the step after them
#: one the lean flight would take, taken there) is handed back to ``flying``, listed, to the end of its
#: round (STATE's AT_END); at most PASSES hand-backs a round (the members still listed then fly on in the
#: next round's ``flying``). 2 (IN_FLIGHT): every member flies in ``calming``. Models without lanes (a
#: prescribed box) have no calm test: their flights stop there. On an H100 with these kernels
#: (benchmarks/results/gpu_calm.json, one process, one sample each) shaken (1e6 x 10 s) ran at 4.16e9 and
#: 4.09e9 member-steps/s SHORT, 3.41e9 and 3.42e9 APART, 3.11e9 in the flight; traced, APART flew 3.05e9
#: of the 1e10 steps in ``calming`` (1.28 s of the study there), SHORT 1.3e8 (0.77 s); drop e = 0.6 (1e5 x
#: 3 s) 1.60-1.64e8 every way (its time is the held turns). PASSES 2 and 32 ran shaken as 8 did (4.19e9,
#: 4.11e9); a chunk of 512 or 1024 steps slower (3.86e9, 3.77e9)
NOWHERE, APART, IN_FLIGHT, SHORT = 0, 1, 2, 3
CALM = SHORT
PASSES = 8
#: a list to append one row a round to (what each launch took and how many members it ran;
#: benchmarks/gpu_probe.py), or None. Tracing synchronises after every launch, so it is for diagnosis only
TRACE = None
#: columns of a member's row of integers: step reached, status, next sample; then counts that the trace
#: reads (calm tests, the calm steps they found, steps flown with the calm test: ``calming``'s share)
AT_STEP, AT_STATUS, AT_SAMPLE, AT_CALM_TESTS, AT_CALM_STEPS, AT_CALM_FLOWN = 0, 1, 2, 3, 4, 5
#: and the step at which the member's round ends (set where a round's flight starts; kept by SHORT's
#: ``calming`` and its hand-backs, set again by APART's and IN_FLIGHT's)
AT_END = 6
STATE_COLUMNS = 7
#: what member_fly says of a member: finished (or stopped), flown (quiet to the round's end or its sample),
#: in want of the exact loop near contact, held in a contact, or with an event in its next step (the
#: three take it in warps of their own, so that the threads of a warp take the same branches: an event's
#: location and impact cost many quiet steps, and a warp whose members meet their events at different
#: steps pays for each of them); or quiet again after calm steps (CALM = SHORT: the lean flight goes on)
FINISHED, FLOWN, NEEDS_CARE, HELD, EVENT, QUIET_AGAIN = 0, 1, 2, 3, 4, 5


def next_stop(state, sample_steps, n_steps):
    """The step a member runs to next: its next sample step, or the end."""
    s = state[AT_SAMPLE]
    return sample_steps[s] if s < sample_steps.shape[0] else n_steps


def arrive(model, t, q, qd, p, state, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, out, box):
    """A member at its next stop: its state recorded (as the exact loop records it) into its sample and final rows."""
    record(model, t, q, qd, p, np.int64(0), out, box)
    s = state[AT_SAMPLE]
    if s < sample_steps.shape[0] and sample_steps[s] == state[AT_STEP]:
        copy_to(samp_q[s], out.q[0])
        copy_to(samp_qd[s], out.qd[0])
        state[AT_SAMPLE] = s + 1
    copy_to(fin_q, out.q[0])
    copy_to(fin_qd, out.qd[0])
    fin[0] = out.energy[0]


def settle(state, tally, dt, fin):
    """The member's counts into its final row (as :func:`~.members.follow_member` ends)."""
    fin[1] = tally[TALLY_IMPULSES]
    fin[2] = tally[TALLY_FIRST]
    fin[3] = state[AT_STATUS]
    fin[4] = state[AT_STEP]
    fin[5] = fallback_time(tally, state[AT_STEP] * dt)
    fin[6] = tally[TALLY_WARNINGS]


def member_start(model, exact, stages, q, qd, rest, p, tol, tally, state, dt, n_steps, sample_steps, samp_q,
                 samp_qd, fin_q, fin_qd, fin, log, out):
    """A member's step 0 (:func:`~.members.start_member`), its state row set."""
    i, status, s, log = start_member(model, exact, stages, q, qd, rest, p, tol, dt, sample_steps, samp_q, samp_qd,
                                     fin_q, fin_qd, fin, log, out, tally)
    state[AT_STEP], state[AT_STATUS], state[AT_SAMPLE] = i, status, s
    settle(state, tally, dt, fin)


def member_fly(model, calm, q, qd, rest, p, tol, tally, state, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q,
               fin_qd, fin, qb, qdb, out, box, gaps, ext, chunk, go_calm, keep_end):
    """One round of a member in free flight: the model's ``fly`` from the smallest gap (``gaps``: scratch of
    a row a contact), as the exact loop goes on after a step of its own, so that a member a turn has taken
    away from a wall flies again at once; to ``chunk`` steps on, or with keep_end to the end of the round
    it is in (STATE's AT_END: SHORT's ``calming`` and its hand-backs). With go_calm, a step that is not
    quiet but calm (the lanes' :func:`~.lanes.calm`: the exact loop's own test finds no event in it, so it
    would take the trial) is taken here and the flight goes on; with go_calm 2 only the calm steps and one
    quiet step after them (``fly``'s, which it takes as the lean flight would), then QUIET_AGAIN. Returns
    FINISHED, FLOWN, NEEDS_CARE (a step that is not quiet), EVENT (a step that is not quiet with a gap below
    zero at its end: the trial's gaps, computed here, sort the member only), HELD (a held contact) or
    QUIET_AGAIN."""
    i = state[AT_STEP]
    if state[AT_STATUS] != DONE or i >= n_steps:
        return FINISHED
    if not is_free(rest, model.n_contact):
        return HELD
    stop = next_stop(state, sample_steps, n_steps)
    if keep_end == 0:
        state[AT_END] = i + chunk
    end = min(stop, state[AT_END])
    never = np.int64(-1)        # (the member's samples are its own: arrive)
    model.phi(i * dt, q, p, gaps)
    clear = lowest_free(gaps, rest, model.n_contact)
    tests = calmed = 0          # (counted here, written once: the trace reads them)
    again = False
    while True:
        until = min(end, i + 1) if go_calm == 2 and calmed > 0 else end
        i, _, _ = model.fly(0.0, dt, i, until, q, qd, p, tol, clear, qb, qdb, out.t, out.q, out.qd, np.int64(0),
                            never, np.int64(1), never)
        if i == end or go_calm == 0:
            break
        if i == until:          # (go_calm 2) a quiet step after the calm ones: the lean flight goes on
            again = True
            break
        quiet, clear = calm(i * dt, (i + 1) * dt, q, qd, qb, qdb, p, tol, ext)
        tests += 1
        if not quiet:
            break
        calmed += 1
        for d in range(model.n_dof):
            q[d] = qb[d]
            qd[d] = qdb[d]
        i += 1
    if go_calm != 0:
        state[AT_CALM_TESTS] += tests
        state[AT_CALM_STEPS] += calmed
        state[AT_CALM_FLOWN] += i - state[AT_STEP]
    state[AT_STEP] = i
    if i == stop:
        arrive(model, i * dt, q, qd, p, state, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, out, box)
        settle(state, tally, dt, fin)
    if i == end:
        return FLOWN
    if again:
        return QUIET_AGAIN
    model.phi((i + 1) * dt, qb, p, gaps)
    return EVENT if not lowest_free(gaps, rest, model.n_contact) >= 0.0 else NEEDS_CARE


def member_alone(model, exact, stages, q, qd, rest, p, tol, tally, state, dt, n_steps, sample_steps, samp_q,
                 samp_qd, fin_q, fin_qd, fin, log, out, chunk, turn):
    """A member through the exact loop: ``turn`` steps (free) or ``chunk`` (held, or in the fallback)."""
    i = state[AT_STEP]
    stop = next_stop(state, sample_steps, n_steps)
    end = min(stop, i + (turn if is_free(rest, model.n_contact) else chunk))
    i, _, status, log = run_segment(model, exact, stages, q, qd, rest, p, tol, dt, i, end, out, np.int64(1), log, tally)
    state[AT_STEP], state[AT_STATUS] = i, status
    if status == DONE and i == stop:
        arrive(model, i * dt, q, qd, p, state, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, out, stages.ws.box)
    settle(state, tally, dt, fin)


# ---------------------------------------------------------------------------
# the kernel file of a model

#: what follows the model's and the hot path's text in a kernel file: {N_DOF} ... are the model's; the
#: helpers that make local arrays are inlined by Numba (``inline="always"``), so the arrays are the kernel's
KERNELS = '''

# ---------------------------------------------------------------------------
# the kernels (jackbox.engine.gpu): one thread per member
from numba import cuda as _cuda, float64 as _f8, int64 as _i8
from jackbox.engine import gpu as _gpu
from jackbox.engine.members import follow_member as _follow_member, follow_twins as _follow_twins
from jackbox.engine.records import Events as _Events, Model as _Model, Samples as _Samples, Scratch as _Scratch

_gpu.to_device(globals())
_exact = _gpu.device(_gpu.exact_on)
_time_table = _gpu.device(_gpu.time_table_none)
_lane_event = _gpu.device(_gpu.lane_event_none)
_lanes = _gpu.device(_gpu.lanes_none)
_ride = _gpu.device(_gpu.ride_none)
_step, _update, _crossing, _release, _fallback, _hold = _gpu.stage_devices()
_gpu_start, _gpu_alone, _gpu_fly = (_gpu.device(f) for f in (_gpu.member_start, _gpu.member_alone, _gpu.member_fly))
_N, _C, _NP, _NT, _NR = {N_DOF}, {N_CONTACT}, {N_PARAM}, {N_TOL}, {N_REST}
_HAS_CALM = {HAS_CALM}


@_cuda.jit(device=True, inline="always")
def _model():
    return _Model({N_DOF}, {N_CONTACT}, {N_WALL}, {E_SLOT}, {E_GROUND_SLOT}, {PRESCRIBED}, {HAS_GROUND},
                  {FUNCTIONS}, _time_table, _lane_event, _lanes, _ride)


@_cuda.jit(device=True, inline="always")
def _stages():
    ws = _Scratch(_cuda.local.array((9, _N), _f8), _cuda.local.array((_C, {ROW}), _f8),
                  _cuda.local.array(({SC}, _C), _f8), _cuda.local.array(({SN}, _N), _f8),
                  _cuda.local.array(({SK}, _C), _i8), _cuda.local.array(_NR, _i8),
                  _cuda.local.array((_C, _C), _f8), _cuda.local.array((_C, _C), _f8),
                  _cuda.local.array((_C, _C), _f8), _cuda.local.array(2, _f8), _cuda.local.array(6, _f8))
    return _gpu.GpuStages(_step, _update, _crossing, _release, _fallback, _hold, 0, ws)


@_cuda.jit(device=True, inline="always")
def _log():
    return _Events(_cuda.local.array({LOG_SIZE}, _f8), _cuda.local.array({LOG_SIZE}, _i8),
                   _cuda.local.array({LOG_SIZE}, _i8))


@_cuda.jit(device=True, inline="always")
def _samples():
    return _Samples(_cuda.local.array(2, _f8), _cuda.local.array((2, 6), _f8), _cuda.local.array((2, 6), _f8),
                    _cuda.local.array(2, _f8))


@_cuda.jit(device=True, inline="always")
def _copy(dst, src):
    for i in range(src.shape[0]):
        dst[i] = src[i]
    return dst


@_cuda.jit(device=True, inline="always")
def _rows(Q, QD, P, TOL, j):
    """Member j's rows in local memory (read at every stage: coalesced there, and cached)."""
    return (_copy(_cuda.local.array(_N, _f8), Q[j]), _copy(_cuda.local.array(_N, _f8), QD[j]),
            _copy(_cuda.local.array(_NP, _f8), P[j]), _copy(_cuda.local.array(_NT, _f8), TOL[j]))


@_cuda.jit(cache=True)
def members(Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin):
    """Each member from start to end in one thread (ROUNDS False)."""
    j = _cuda.grid(1)
    if j < Q0.shape[0]:
        q, qd, p, tol = _rows(Q0, QD0, P, TOL, j)
        _follow_member(_model(), _exact, _stages(), q, qd, _cuda.local.array(_NR, _i8), p, tol, dt, n_steps,
                       sample_steps, samp_q[j], samp_qd[j], fin_q[j], fin_qd[j], fin[j], _log(), _samples(),
                       _cuda.local.array({TALLY}, _f8))


@_cuda.jit(cache=True)
def alone(Q, QD, P, TOL, REST, TALLY, STATE, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, LIST,
          first, n_listed, chunk, turn):
    """Members through the exact loop: every member's start (n_listed < 0), else the n_listed in LIST from
    ``first`` on (:func:`member_alone`: chunk and turn, its steps held and free)."""
    k = _cuda.grid(1)
    if k >= (Q.shape[0] if n_listed < 0 else n_listed):
        return
    j = k if n_listed < 0 else LIST[first + k]
    q, qd, p, tol = _rows(Q, QD, P, TOL, j)
    rest, tally = _copy(_cuda.local.array(_NR, _i8), REST[j]), _copy(_cuda.local.array({TALLY}, _f8), TALLY[j])
    model, stages, log, samples = _model(), _stages(), _log(), _samples()      # one scratch for either branch
    if n_listed < 0:
        _gpu_start(model, _exact, stages, q, qd, rest, p, tol, tally, STATE[j], dt, n_steps, sample_steps,
                   samp_q[j], samp_qd[j], fin_q[j], fin_qd[j], fin[j], log, samples)
    else:
        _gpu_alone(model, _exact, stages, q, qd, rest, p, tol, tally, STATE[j], dt, n_steps, sample_steps,
                   samp_q[j], samp_qd[j], fin_q[j], fin_qd[j], fin[j], log, samples, chunk, turn)
    _copy(Q[j], q)
    _copy(QD[j], qd)
    _copy(REST[j], rest)
    _copy(TALLY[j], tally)


@_cuda.jit(device=True)
def _calm_none(t, t_next, q, qd, qn, vn, p, tol, ext):
    """(the lean flight has no calm test: it stops at a step that is not quiet)"""
    return False, 0.0


@_cuda.jit(device=True, inline="always")
def _fly(Q, QD, P, TOL, REST, TALLY, STATE, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, j,
         calm_test, chunk, go_calm, keep_end):
    """Member j's flight (:func:`member_fly`), its rows written back where it still runs: what it needs next."""
    q, qd, p, tol = _rows(Q, QD, P, TOL, j)
    how = _gpu_fly(_model(), calm_test, q, qd, REST[j], p, tol, TALLY[j], STATE[j], dt, n_steps, sample_steps,
                   samp_q[j], samp_qd[j], fin_q[j], fin_qd[j], fin[j], _cuda.local.array(_N, _f8),
                   _cuda.local.array(_N, _f8), _samples(), _cuda.local.array(6, _f8), _cuda.local.array(_C, _f8),
                   _cuda.local.array(2, _f8), chunk, go_calm, keep_end)
    if how != {FINISHED}:
        _copy(Q[j], q)
        _copy(QD[j], qd)
    return how


@_cuda.jit(device=True, inline="always")
def _list(how, j, n, LIST, COUNT, care_back):
    """Member j on the list of what it needs (LIST has three parts of n): near contact from LIST's start
    (COUNT[0]; with care_back, back from the end of its second part, COUNT[4]), held back from the end of
    its first part (COUNT[2]), an event in its next step from its second part on (COUNT[3]), quiet again
    after calm steps from its third part on (COUNT[5])."""
    if how == {NEEDS_CARE}:
        if care_back:
            LIST[2 * n - 1 - _cuda.atomic.add(COUNT, 4, 1)] = j
        else:
            LIST[_cuda.atomic.add(COUNT, 0, 1)] = j
    elif how == {HELD}:
        LIST[n - 1 - _cuda.atomic.add(COUNT, 2, 1)] = j
    elif how == {EVENT}:
        LIST[n + _cuda.atomic.add(COUNT, 3, 1)] = j
    elif how == {QUIET_AGAIN}:
        LIST[2 * n + _cuda.atomic.add(COUNT, 5, 1)] = j


@_cuda.jit(cache=True)
def flying(Q, QD, P, TOL, REST, TALLY, STATE, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, LIST,
           COUNT, n_listed, first, chunk):
    """A round of free flight, the lean one (no calm test), for every member (n_listed < 0: those still
    running counted, COUNT[1]) or for the n_listed in LIST from ``first`` on (handed back by ``calming``: to
    the end of their round); those that need more are listed (:func:`_list`)."""
    k = _cuda.grid(1)
    if k >= (Q.shape[0] if n_listed < 0 else n_listed):
        return
    j = k if n_listed < 0 else LIST[first + k]
    how = _fly(Q, QD, P, TOL, REST, TALLY, STATE, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, j,
               _calm_none, chunk, 0, 0 if n_listed < 0 else 1)
    if n_listed < 0 and how != {FINISHED}:
        _cuda.atomic.add(COUNT, 1, 1)
    _list(how, j, Q.shape[0], LIST, COUNT, False)


@_cuda.jit(cache=True)
def calming(Q, QD, P, TOL, REST, TALLY, STATE, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, LIST,
            COUNT, n_listed, chunk, short):
    """The flight with the calm test (steps that are not quiet but calm are taken here): for the n_listed
    members at LIST's start (those the lean flight listed near contact; the ones still near contact listed
    back from the end of LIST's second part), or for every member (n_listed < 0: a round's flight, listed as
    ``flying`` lists). With ``short``, the calm steps only, to the end of the member's round: those quiet
    again after them are listed for the lean flight (LIST's third part)."""
    k = _cuda.grid(1)
    if k >= (Q.shape[0] if n_listed < 0 else n_listed):
        return
    j = k if n_listed < 0 else LIST[k]
    how = _fly(Q, QD, P, TOL, REST, TALLY, STATE, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, j,
               calm, chunk, 2 if short != 0 else 1, short)
    if n_listed < 0 and how != {FINISHED}:
        _cuda.atomic.add(COUNT, 1, 1)
    _list(how, j, Q.shape[0], LIST, COUNT, n_listed >= 0)


@_cuda.jit(cache=True)
def smallest_gaps(Q, P, t, OUT):
    """Each member's smallest gap at time t, its state a row of Q (six numbers, the integrated coordinates
    last, as a study's final states): the check that no member went through a wall unseen, asked here of
    the model's phi (on the host, NumPy's took 0.44 s of a 1e6-member study's 2.4 s). NaN if a gap is."""
    j = _cuda.grid(1)
    if j < Q.shape[0]:
        q, g = _cuda.local.array(_N, _f8), _cuda.local.array(_C, _f8)
        for d in range(_N):
            q[d] = Q[j, 6 - _N + d]
        phi(t, q, P[j], g)
        low = g[0]
        for k in range(1, _C):
            if g[k] < low or g[k] != g[k]:
                low = g[k]
        OUT[j] = low


@_cuda.jit(cache=True)
def twins(Q0, QD0, DQ, DQD, P, TOL, dt, n_steps, renorm_steps, scale, stretch, fin):
    j = _cuda.grid(1)
    if j < Q0.shape[0]:
        q, qd = _copy(_cuda.local.array(_N, _f8), Q0[j]), _copy(_cuda.local.array(_N, _f8), QD0[j])
        qt, qdt = _copy(_cuda.local.array(_N, _f8), Q0[j]), _copy(_cuda.local.array(_N, _f8), QD0[j])
        p, tol = _copy(_cuda.local.array(_NP, _f8), P[j]), _copy(_cuda.local.array(_NT, _f8), TOL[j])
        _follow_twins(_model(), _exact, _stages(), q, qd, qt, qdt, DQ[j], DQD[j], p, tol, dt, n_steps, renorm_steps,
                      scale, stretch[j], fin[j], _cuda.local.array(_NR, _i8), _cuda.local.array(_NR, _i8), _log(),
                      _log(), _samples(), _cuda.local.array({TALLY}, _f8), _cuda.local.array({TALLY}, _f8),
                      _cuda.local.array((2, _C), _f8))
'''


def stage_devices():
    """The device versions of the exact loop's stages, in the order of :class:`~.records.Stages`."""
    from . import LOOPS
    out = []
    for name in Stages._fields[:-1]:
        module, function, _, _ = LOOPS[name]
        out.append(device(getattr(importlib.import_module(f"{__package__}.{module}"), function)))
    return tuple(out)


#: a model without lanes (a prescribed box) has no calm test in its kernel file: no step is calm
CALM_STUB = """

def calm(t, t_next, q, qd, qn, vn, p, tol, ext):
    return False, 0.0
"""


def calm_text(model_text: str) -> str:
    """The lanes' :func:`~.lanes.calm` (with ``finite`` and the imports of its module) for a model with lanes."""
    import ast

    from ..loader import LANES_SOURCE, has_lanes
    if not has_lanes(model_text):
        return CALM_STUB
    source = LANES_SOURCE.read_text()
    kept = [ast.get_source_segment(source, node) for node in ast.parse(source).body
            if isinstance(node, (ast.Import, ast.ImportFrom))
            or (isinstance(node, ast.FunctionDef) and node.name in ("finite", "calm"))]
    return "\n\n" + "\n\n\n".join(kept) + "\n"


def kernel_text(model_text: str, flight_text: str, constants: dict) -> str:
    """The text of a model's kernel file (see :data:`KERNELS`): the model's text (with the loader's stubs for
    what it lacks), the hot path's, the lanes' calm test, the kernels."""
    functions = ", ".join(name for name in SIGNATURES if name not in ("time_table", "lane_event", "lanes", "ride"))
    filled = KERNELS
    for key, value in {**constants, "FUNCTIONS": functions, "SC": SC, "SN": SN, "SK": SK, "MODE_SLOTS": MODE_SLOTS,
                       "ROW": constants["N_DOF"] + ROW_EXTRA,
                       "LOG_SIZE": LOG_SIZE, "TALLY": TALLY, "FINISHED": FINISHED, "NEEDS_CARE": NEEDS_CARE,
                       "HELD": HELD, "EVENT": EVENT, "QUIET_AGAIN": QUIET_AGAIN}.items():
        filled = filled.replace("{" + key + "}", str(value))
    calm_test = calm_text(model_text)
    filled += f"\n# also out of line: {', '.join(MORE_OUT_OF_LINE) or '(nothing)'}\n"
    return model_text + "\n\n" + flight_text + calm_test + filled.replace("{HAS_CALM}", str(calm_test != CALM_STUB))


def kernel_constants(module) -> dict:
    """The model's sizes a kernel file fixes (its local arrays have constant shapes)."""
    from .records import T_SPEED
    return {"N_DOF": module.N_DOF, "N_CONTACT": module.N_CONTACT, "N_PARAM": module.N_PARAM,
            "N_TOL": T_SPEED + module.N_DOF, "N_WALL": module.N_WALL_CONTACT, "E_SLOT": module.E_SLOT,
            "E_GROUND_SLOT": module.E_GROUND_SLOT, "PRESCRIBED": int(module.PRESCRIBED),
            "HAS_GROUND": int(module.HAS_GROUND), "N_REST": module.N_CONTACT + MODE_SLOTS}


def kernel_path(text: str) -> Path:
    """Where a kernel file lives: named by a hash of its text, the engine's digest and numba-cuda's version."""
    from importlib.metadata import version
    key = hashlib.sha256("\0".join([text, cache.DIGEST, version("numba-cuda")]).encode()).hexdigest()[:16]
    return cache.cache_dir() / "gpu" / f"kernel_{key}.py"


_kernels: dict = {}


def load_kernels(model_text: str, flight_text: str, module):
    """The kernel module of a model (written to the cache on first use; compiled by numba-cuda on first launch).

    model_text: the generated model's text with the loader's stubs; module: the model as a module (its sizes).
    """
    from ..fileio import write_atomic
    _numpy_for_numba_cuda()
    text = kernel_text(model_text, flight_text, kernel_constants(module))
    path = kernel_path(text)
    if path in _kernels:
        return _kernels[path]
    if not path.exists() or path.read_text() != text:
        path.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(path, text)
    spec = importlib.util.spec_from_file_location(f"jackbox_gpu_{path.stem}", path)
    kernels = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = kernels
    spec.loader.exec_module(kernels)
    _kernels[path] = kernels
    return kernels


def _signatures():
    """The argument types of each kernel, as :func:`run_members` and :func:`run_twin_members` pass them."""
    from numba.core import types
    f8, i8 = types.float64, types.int64
    V1, V2, V3 = (types.Array(f8, d, "C") for d in (1, 2, 3))
    I1, I2 = types.Array(i8, 1, "C"), types.Array(i8, 2, "C")
    rounds = (V2, V2, V2, V2, I2, V2, I2, f8, i8, I1, V3, V3, V2, V2, V2, I1)
    return {"members": (V2, V2, V2, V2, f8, i8, I1, V3, V3, V2, V2, V2), "alone": rounds + (i8, i8, i8, i8),
            "flying": rounds + (I1, i8, i8, i8), "calming": rounds + (I1, i8, i8, i8), "smallest_gaps": (V2, V2, f8, V1),
            "twins": (V2, V2, V2, V2, V2, V2, f8, i8, i8, V1, V2, V2)}


#: how an ensemble runs: False, each member from start to end in one thread (kernel ``members``); True,
#: in rounds (kernels ``flying`` and ``alone``, :func:`run_rounds`), so that members near contact do not
#: hold up the others of their warp. On an H200 at f1430e9 (the README's history) rounds ran shaken (1e6 members
#: x 10 s) at 1.42e9 member-steps/s against 9.9e8 in one go, drop e = 0.6 (1e5 x 3 s) at 4.4e7 against
#: 1.76e7, with the same numbers (the same impulse counts; states within 1e-12 of the CPU's either way)
ROUNDS = True


#: the kernels of a kernel file
KERNEL_NAMES = ("members", "alone", "flying", "calming", "smallest_gaps", "twins")


def calm_mode(kernels) -> int:
    """Where a model's rounds take their calm steps (:data:`CALM`; NOWHERE for a model without a calm test)."""
    if CALM not in (NOWHERE, APART, IN_FLIGHT, SHORT):
        raise ValueError(f"gpu.CALM must be NOWHERE, APART, IN_FLIGHT or SHORT (0, 1, 2, 3), got {CALM!r}")
    return CALM if kernels._HAS_CALM else NOWHERE


def kind_kernels(kind: str, rounds: bool | None = None, calm: int | None = None) -> tuple[str, ...]:
    """The kernels a study of this kind runs ("ensemble" or "chaos"; a kernel's name: that kernel), for a
    model whose rounds take their calm steps as ``calm`` says (None: :data:`CALM`)."""
    if kind in KERNEL_NAMES:
        return (kind,)
    if kind == "chaos":
        return ("twins",)
    if not (ROUNDS if rounds is None else rounds):
        return ("members", "smallest_gaps")
    calm = CALM if calm is None else calm
    if calm == IN_FLIGHT:
        return ("alone", "calming", "smallest_gaps")
    return ("alone", "flying", "calming", "smallest_gaps") if calm else ("alone", "flying", "smallest_gaps")


def is_cached(kernels, kind: str, rounds: bool | None = None) -> bool:
    """Whether the kernel of a study of this kind is compiled here or in numba-cuda's cache (where its cache
    locator looks: a ``NUMBA_CACHE_DIR`` first, else beside the kernel file)."""
    if _simulated():
        return True
    path = Path(kernels.__file__)

    def cached(name):
        kernel = getattr(kernels, name)
        index = getattr(getattr(getattr(kernel, "_cache", None), "_cache_file", None), "_index_path", None)
        if index is not None:
            return Path(index).exists()
        return any(path.parent.glob(f"__pycache__/{path.stem}.{name}-*.nbi"))      # (another numba-cuda)

    return all(getattr(kernels, name).overloads or cached(name) for name in kind_kernels(kind, rounds,
                                                                                          calm_mode(kernels)))


def prepare(kernels, kind: str, rounds: bool | None = None) -> str:
    """Compile (or load from the cache) the kernel of a study of this kind: "memory", "hit" or "miss"."""
    if _simulated():
        return "simulator"
    names = kind_kernels(kind, rounds, calm_mode(kernels))
    if all(getattr(kernels, name).overloads for name in names):
        return "memory"
    from . import collector_paused

    hit = is_cached(kernels, kind, rounds)
    with collector_paused():
        for name in names:
            getattr(kernels, name).compile(_signatures()[name])
    return "hit" if hit else "miss"


def compile_offline(kernels, name: str, cc=(9, 0), output: str = "ptx"):
    """A kernel compiled for compute capability ``cc`` with no GPU at hand: "llvm" (typed and lowered, which
    needs no CUDA toolkit: what tests/test_gpu.py checks on every machine) or "ptx" (NVVM's output, which
    needs its library: ``jackbox[cuda]``). Returns the compile result, or the PTX text.

    The simulator runs the kernels' Python, so it cannot see a kernel the CUDA target would refuse (a local
    array whose shape is not a constant, say); this can. numba-cuda asks the current device for its compute
    capability when it compiles a device function: here the answer is ``cc``, for the call's duration.
    """
    from types import SimpleNamespace

    _numpy_for_numba_cuda()
    from numba.cuda import compiler, dispatcher

    from . import collector_paused

    asked = dispatcher.get_current_device
    dispatcher.get_current_device = lambda: SimpleNamespace(compute_capability=tuple(cc))
    try:
        fn, sig = getattr(kernels, name).py_func, _signatures()[name]
        with collector_paused():
            if output == "llvm":
                return compiler.compile_cuda(fn, None, sig, cc=tuple(cc))
            return compiler.compile_ptx(fn, sig, cc=tuple(cc))[0]
    finally:
        dispatcher.get_current_device = asked


def device_name() -> str:
    """The GPU's name (numba-cuda's simulator says so)."""
    if _simulated():
        return "numba-cuda simulator"
    name = _cuda().get_current_device().name
    return name.decode() if isinstance(name, bytes) else str(name)


def run_members(kernels, Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin,
                rounds: bool | None = None) -> np.ndarray:
    """:func:`jackbox.engine.members.run_members` on the GPU: the outputs' rows filled, one thread a member.

    rounds: in rounds (:func:`run_rounds`) or each member in one go (None: :data:`ROUNDS`). Returns each
    member's smallest gap at its final state, at the end time (kernel ``smallest_gaps``; the caller's
    check of the final states: meaningless for a member that stopped early).
    """
    gaps = np.empty(Q0.shape[0])
    if ROUNDS if rounds is None else rounds:
        run_rounds(kernels, Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin, gaps)
    else:
        _launch(kernels.members, Q0.shape[0], (Q0, QD0, P, TOL), (float(dt), int(n_steps)), (sample_steps,),
                (samp_q, samp_qd, fin_q, fin_qd, fin))
        _launch(kernels.smallest_gaps, Q0.shape[0], (fin_q, P), (float(n_steps * dt),), (), (gaps,))
    return gaps


def run_rounds(kernels, Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin,
               gaps) -> None:
    """:func:`run_members` in rounds (gaps: each member's smallest gap at the end, filled).

    In rounds, so that a member near contact does not hold up the 31 others
    of its warp: every member flies while it is quiet (kernel ``flying``, at most
    CHUNK steps), those it stopped near contact fly on with the calm test
    (kernel ``calming``, :data:`CALM`), then the members that need the exact loop take it, listed
    and packed into warps of their own (kernel ``alone``): those with an
    event in their next step for EVENT_TURN steps, those near contact for
    ALONE steps, those held in a contact for HELD_TURN steps, each list in a
    launch of its own so that a warp's members take the same branches and
    turns of one length. A member's numbers are those of one
    call of the exact loop from its start (:func:`member_fly` starts ``fly``
    as the exact loop starts a call); the rounds end when every member has.
    """
    n = Q0.shape[0]
    if n == 0:
        return
    cuda = _cuda()
    stream = cuda.stream()
    dev = [cuda.to_device(np.ascontiguousarray(a), stream=stream) for a in (Q0, QD0, P, TOL)]
    REST = cuda.to_device(np.zeros((n, kernels._NR), np.int64), stream=stream)
    TALLY_ = cuda.to_device(np.zeros((n, TALLY)), stream=stream)
    STATE = cuda.to_device(np.zeros((n, STATE_COLUMNS), np.int64), stream=stream)
    steps = cuda.to_device(np.ascontiguousarray(sample_steps, np.int64), stream=stream)
    outs = [cuda.to_device(a, stream=stream) for a in (samp_q, samp_qd, fin_q, fin_qd, fin)]
    LIST = cuda.to_device(np.zeros(3 * n, np.int64), stream=stream)
    count, zero = np.zeros(6, np.int64), np.zeros(6, np.int64)
    COUNT = cuda.to_device(count, stream=stream)
    args = (*dev, REST, TALLY_, STATE, float(dt), int(n_steps), steps, *outs, LIST)
    grid = (n + BLOCK - 1) // BLOCK
    trace, clock = TRACE, time.perf_counter
    t0 = clock()
    calm = calm_mode(kernels)
    kernels.alone[grid, BLOCK, stream](*args, 0, -1, HELD_TURN, ALONE)
    while True:
        COUNT.copy_to_device(zero, stream=stream)
        if trace is not None:
            stream.synchronize()
            t1 = clock()
            row = {"start": t1 - t0}
        if calm == IN_FLIGHT:
            kernels.calming[grid, BLOCK, stream](*args, COUNT, -1, CHUNK, 0)
        else:
            kernels.flying[grid, BLOCK, stream](*args, COUNT, -1, 0, CHUNK)
        COUNT.copy_to_host(count, stream=stream)
        stream.synchronize()
        if trace is not None:
            t0 = clock()
            row.update(fly=t0 - t1, running=int(count[1]), free=int(count[0]), held=int(count[2]),
                       event=int(count[3]))
            trace.append(row)
        if count[1] == 0:
            break
        near, first_near = int(count[0]), 0
        if calm in (APART, SHORT) and near > 0:         # those near contact fly on with the calm test
            calm_listed = passes = 0
            while True:
                calm_listed += near
                kernels.calming[(near + BLOCK - 1) // BLOCK, BLOCK, stream](*args, COUNT, near, CHUNK,
                                                                             int(calm == SHORT))
                COUNT.copy_to_host(count, stream=stream)
                stream.synchronize()
                again = int(count[5])
                if again == 0 or passes == PASSES:
                    break
                # (SHORT) those quiet again fly on in the lean flight to their round's end; the ones it
                # stops near contact are listed from LIST's start again, for the calm test
                passes += 1
                count[0] = count[5] = 0
                COUNT.copy_to_device(count, stream=stream)
                kernels.flying[(again + BLOCK - 1) // BLOCK, BLOCK, stream](*args, COUNT, again, 2 * n, CHUNK)
                COUNT.copy_to_host(count, stream=stream)
                stream.synchronize()
                near = int(count[0])
                if near == 0:
                    break
                count[5] = 0
                COUNT.copy_to_device(count, stream=stream)
            near, first_near = int(count[4]), 2 * n - int(count[4])
            if trace is not None:
                t1, t0 = t0, clock()
                row.update(calming=t0 - t1, calm=calm_listed, passes=passes, event=int(count[3]))
        held, event = int(count[2]), int(count[3])
        for first, listed, turn, key in ((n, event, EVENT_TURN, "alone_event"), (first_near, near, ALONE, "alone_free"),
                                         (n - held, held, ALONE, "alone_held")):
            if listed > 0:
                kernels.alone[(listed + BLOCK - 1) // BLOCK, BLOCK, stream](*args, first, listed, HELD_TURN, turn)
                if trace is not None:
                    stream.synchronize()
                    t1, t0 = t0, clock()
                    row[key] = t0 - t1
        if trace is not None:
            row["free"] = near
    OUT = cuda.device_array(n, stream=stream)
    kernels.smallest_gaps[grid, BLOCK, stream](outs[2], dev[2], float(n_steps * dt), OUT)
    OUT.copy_to_host(gaps, stream=stream)
    for host, out in zip((samp_q, samp_qd, fin_q, fin_qd, fin), outs):
        out.copy_to_host(host, stream=stream)
    if trace is not None:       # the members' counts, summed into the last round's row
        counts = STATE.copy_to_host(stream=stream)
        stream.synchronize()
        row.update(calm_tests=int(counts[:, AT_CALM_TESTS].sum()), calm_steps=int(counts[:, AT_CALM_STEPS].sum()),
                   calm_flown=int(counts[:, AT_CALM_FLOWN].sum()))
    stream.synchronize()


def run_twin_members(kernels, Q0, QD0, DQ, DQD, P, TOL, dt, n_steps, renorm_steps, scale, stretch, fin) -> None:
    """:func:`jackbox.engine.members.run_twin_members` on the GPU, one thread a pair of twins."""
    _launch(kernels.twins, Q0.shape[0], (Q0, QD0, DQ, DQD, P, TOL), (float(dt), int(n_steps), int(renorm_steps)),
            (scale,), (stretch, fin))


def _launch(kernel, n: int, inputs, scalars, shared, outputs) -> None:
    """``kernel`` over n members (one thread each): inputs and outputs copied to the GPU, outputs back."""
    if n == 0:
        return
    cuda = _cuda()
    stream = cuda.stream()
    ins = [cuda.to_device(np.ascontiguousarray(a), stream=stream) for a in (*inputs, *shared)]
    outs = [cuda.to_device(a, stream=stream) for a in outputs]
    args = ins[:len(inputs)] + list(scalars) + ins[len(inputs):] + outs
    kernel[(n + BLOCK - 1) // BLOCK, BLOCK, stream](*args)
    for host, dev in zip(outputs, outs):
        dev.copy_to_host(host, stream=stream)
    stream.synchronize()
