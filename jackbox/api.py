"""The friendly API: scene in, trajectory out.

:func:`simulate` checks its arguments, finds the scene's compiled kernel
(:mod:`jackbox.loader`), runs it in chunks (a progress bar can follow, and the
impact log grows when it fills) and wraps the arrays in a
:class:`~jackbox.trajectory.Trajectory`. :mod:`jackbox.reference` shares
:func:`prepare` and :func:`finish`, so both see the same run.
"""

from __future__ import annotations

import math
import os
import time
import uuid
import warnings
from dataclasses import dataclass

import numba
import numpy as np

from . import __version__, loader
from . import engine as K
from .engine.tolerances import EVENT_TOL, FLIGHT_TOL, GAP_TOL, REST_TOL, ZENO_TOL  # noqa: F401  (relative to L; FLIGHT_TOL, ZENO_TOL to dt)
from .errors import NonFiniteStateError, RunStoppedError, SimulationError, SolverWarning
from .progress import progress_bar
from .scene import Scene, contact_gaps, contact_gaps_many, is_number, jack_points, load_scene, param_array
from .trajectory import Trajectory

CHUNK = 1 << 15          #: steps per kernel call (progress granularity)
LOG_SIZE = 1024          #: first size of the event log (it doubles when full)
#: "exact" locates every contact event; "naive" applies impulses at the end of
#: the step in which a gap went negative (the original designs' method)
METHODS = ("exact", "naive")
#: the most steps one run may take: step indices stay exact in float64 (2^53) far below it
MAX_STEPS = 1e15
#: bytes a recorded sample holds: t, q (6), qd (6), energy
RECORD_BYTES = 14 * 8
#: bytes per logged contact event: time, contact, kind
EVENT_BYTES = 3 * 8


@dataclass
class Run:
    """Everything a run needs besides the scene: the dynamic half (Brax's State)."""

    scene: Scene
    p: np.ndarray           #: (P,) parameter values
    q: np.ndarray           #: (n,) start coordinates of the integrated DOFs
    qd: np.ndarray
    dt: float
    n_steps: int
    record_every: int
    method: str
    #: a prescribed box's speed bound to use instead of its own parameters' (a member of a study that sweeps
    #: the box's motion: the study's, over the swept range); None: from p
    box_speed: float | None = None

    @property
    def n_samples(self) -> int:
        return self.n_steps // self.record_every + 1 + (self.n_steps % self.record_every != 0)


#: names that set several parameter slots at once (in params and in a sweep)
ALIASES = {"restitution": ("e", "e_ground")}


def param_slots(scene: Scene, name, what: str = "params") -> tuple[str, ...]:
    """The parameter slots that `name` sets: itself, or an alias's (:data:`ALIASES`); else a
    SimulationError naming `what` (``"params"``, ``"sweep"``) and the names there are."""
    if name in ALIASES:
        return ALIASES[name]
    if name not in scene.param_names:
        raise SimulationError(f"{what}: unknown parameter {name!r} (parameters: {', '.join(ALIASES)}, "
                              f"{', '.join(scene.param_names)})")
    return (name,)


def slot_values(scene: Scene, params: dict) -> dict:
    """`params` by parameter slot, aliases spread over their slots; a slot set twice (``e`` and
    ``restitution``) is refused."""
    values, given_as = {}, {}
    for name, value in params.items():
        for slot in param_slots(scene, name):
            if slot in values:
                raise SimulationError(f"params: {given_as[slot]!r} and {name!r} both set {slot}: give it once")
            values[slot], given_as[slot] = value, name
    return values


def prepare(scene, t_end=None, dt=None, record_every=1, params=None, method="exact",
            where: str = "simulate(params=...)") -> Run:
    """Check the arguments of a run and resolve defaults from the scene.

    where: how `params` were given, named in a refusal.
    """
    scene = load_scene(scene)
    for name, value in (("t_end", t_end), ("dt", dt)):
        if value is not None and not is_number(value):
            raise SimulationError(f"{name} must be a number of seconds, got {value!r}")
    if params is not None and not isinstance(params, dict):
        raise SimulationError(f"params must be a dict of parameter names and values, got {params!r}")
    t_end = scene.t_end if t_end is None else float(t_end)
    dt = scene.dt if dt is None else float(dt)
    if not (math.isfinite(t_end) and t_end > 0):
        raise SimulationError(f"t_end must be a positive number, got {t_end}")
    if not (math.isfinite(dt) and dt > 0):
        raise SimulationError(f"dt must be a positive number, got {dt}")
    if dt > t_end:
        raise SimulationError(f"t_end ({t_end:g} s) is shorter than one step (dt = {dt:g} s): "
                              "give a longer t_end or a smaller dt")
    if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 1:
        raise SimulationError(f"record_every must be a positive integer, got {record_every!r}")
    if method not in METHODS:
        raise SimulationError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    values = slot_values(scene, params or {})
    # the scene format's rules (e in [0, 1], masses > 0, a start outside the walls ...)
    p = param_array(scene, values, where)
    # The last step ends at t_end (or just past it when dt does not divide it).
    if t_end / dt > MAX_STEPS:
        raise SimulationError(f"t_end / dt = {t_end / dt:.3g} steps (dt = {dt:g} s) is more than a run "
                              f"can take ({MAX_STEPS:.0e}): raise dt or shorten t_end")
    n_steps = max(1, math.ceil(t_end / dt - 1e-9))
    record_every = min(int(record_every), n_steps)    # keeps the first and last state either way
    first = 3 if scene.prescribed else 0
    q, qd = scene.q0[first:].copy(), scene.qd0[first:].copy()
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
        raise SimulationError("the start state is not finite")
    run = Run(scene, p, q, qd, dt, n_steps, record_every, method)
    check_memory(run.n_samples * RECORD_BYTES, f"recording {run.n_samples:,} samples",
                 "record fewer (record_every, --record-every) or raise dt")
    return run


def available_memory() -> int | None:
    """Bytes of memory the system can still give (Linux' MemAvailable), or None if unknown."""
    try:
        with open("/proc/meminfo", encoding="ascii") as fh:
            for line in fh:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    try:
        return os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(nbytes: int, what: str, remedy: str) -> None:
    """Refuse, before allocating, work that will not fit in the memory available now."""
    free = available_memory()
    if free is not None and nbytes > free:
        raise SimulationError(f"{what} needs {nbytes / 2**30:.3g} GiB, more than the "
                              f"{free / 2**30:.3g} GiB available: {remedy}")


def tolerances(run: Run, kernel) -> np.ndarray:
    """The tolerance array of the exact method (slots ``T_*`` of jackbox/engine/records.py).

    Computed by the engine (:mod:`jackbox.engine.tolerances`, where the rules
    are), which fills an ensemble member's row the same way: a member and its
    single run get the same tolerances to the last bit (a prescribed box's
    speed bound, :func:`box_speed_bound`, too).
    """
    factor, n_points = jack_radius_rule(run.scene)
    speed = run.box_speed
    if speed is None:
        speed = float(box_speed_bound(run.scene, run.p, run.n_steps * run.dt)[0]) if run.scene.prescribed else 0.0
    return kernel.tolerances(run.p, factor, n_points, run.dt, speed)


def box_speed_bound(scene: Scene, P: np.ndarray, t_end: float, ranges: dict | None = None) -> np.ndarray:
    """(m,) bounds on the speed of any point of a prescribed box over [0, t_end], one per parameter row of P.

    ranges: ``{name: (lo, hi)}``, parameters that take every value in a range
    (a study's sweep: one bound for all its members) instead of P's.

    From the motion's formulas on intervals of time (:mod:`jackbox.intervals`):
    ``|(x', y')| + |theta'| r_box`` on each piece, r_box the box's outer
    half-diagonal; for all t >= 0 where that is finite, so that the tolerance
    row does not depend on t_end (the engine's rule), else over [0, t_end]
    (a box accelerating for ever); infinite where a formula may be undefined
    or unbounded there (every gap is then looked at every step). Rounded up onto a coarse grid
    (a last-bit difference of the inputs gives the same bound). Checked
    against the motion sampled finely in tests/test_intervals.py.
    """
    from codegen import BASE_SYMBOLS, parse_formula

    from .intervals import rate_bounds, round_up

    P = np.atleast_2d(np.asarray(P, float))
    values = dict(zip(scene.param_names, P.T)) | {name: (float(lo), float(hi)) for name, (lo, hi) in
                                                  (ranges or {}).items()}
    constants = set(BASE_SYMBOLS) | set(scene.user_params) | {"t"}
    formulas = [parse_formula(f, constants) for f in scene.motion]
    high = {name: np.asarray(v[1] if isinstance(v, tuple) else v, float) for name, v in values.items()}
    r_box = math.sqrt(2.0) * (high["L"] + high["w_box"])

    def bound(horizon):
        x, y, theta = (rate_bounds(f, horizon, values) for f in formulas)
        with np.errstate(over="ignore", invalid="ignore"):
            speed = np.hypot(x, y) + theta * r_box[:, None]
        return round_up(np.where(np.isnan(speed), np.inf, speed).max(axis=1))

    # for all time where that is finite (a periodic or bounded motion), so that the bound, and with it which
    # loop takes a held step near a wall, does not depend on t_end; else up to t_end
    forever = bound(math.inf)
    if np.all(np.isfinite(forever)):
        return forever
    return np.where(np.isfinite(forever), forever, bound(t_end))


def jack_radius_rule(scene: Scene) -> tuple[float, int]:
    """How the engine finds the jack's bounding radius: ``(factor, 0)``, a_jack times factor, or
    ``(0, n)``, the farthest of the polygon's n vertices (parameters jack_x0, jack_y0, ...)."""
    if "a_jack" in scene.param_names:
        return (math.sqrt(2.0) if scene.shape == "square" else 1.0), 0
    return 0.0, len(scene.points)


def finish(run: Run, t, q, qd, energy, impact_t, impact_k, extra: dict,
           contact_t=None, contact_k=None, contact_kind=None, fallback=None) -> Trajectory:
    scene = run.scene
    meta = {
        # one id per run: its trajectory, time series and animation all carry it
        "run_id": uuid.uuid4().hex[:16],
        "jackbox": __version__, "scene": scene.name, "method": run.method, "dt": run.dt,
        "n_steps": run.n_steps, "record_every": run.record_every,
        "params": dict(zip(scene.param_names, run.p.tolist())),
        "model_hash": loader.model_hash(scene.structure()),
        # the scene's tables after --set overrides: the run's shapes, not just the file's
        "scene_tables": scene.raw,
    } | extra
    empty = np.empty(0)
    return Trajectory(t=t, q=q, qd=qd, energy=energy, impact_t=impact_t,
                      impact_constraint=impact_k.astype(np.int64),
                      constraint_names=scene.constraint_names, scene=scene.text, meta=meta,
                      contact_t=empty if contact_t is None else contact_t,
                      contact_constraint=(empty if contact_k is None else contact_k).astype(np.int64),
                      contact_event=(empty if contact_kind is None else contact_kind).astype(np.int64),
                      fallback_t=np.empty((0, 2)) if fallback is None else fallback)


def simulate(scene: Scene | str, t_end: float | None = None, dt: float | None = None,
             record_every: int = 1, params: dict[str, float] | None = None, *,
             method: str = "exact", progress: bool = False, log=None) -> Trajectory:
    """Simulate a scene with its compiled kernel.

    scene: a :class:`Scene`, a built-in name or a path to a ``.toml``.
    t_end, dt: override the scene's ``[run]``; the run takes ``ceil(t_end/dt)`` steps.
    record_every: keep every k-th step (and the last one).
    params: values for parameter slots by name (``[params]`` names, ``m_box``,
    ``e`` ..., or ``restitution`` for both ``e`` and ``e_ground``); nothing is
    regenerated or recompiled.
    method: ``"exact"`` (every impact located in time, simultaneous contacts
    solved together, resting contact) or ``"naive"`` (impulse at the end of
    the step in which a gap went negative, first order at impacts).
    progress: show a progress bar (on stderr). log: a callable for status lines.
    """
    check_progress_log(progress, log)
    run = prepare(scene, t_end, dt, record_every, params, method)
    return run_prepared(run, progress=progress, log=log)


def check_progress_log(progress, log) -> None:
    """Refuse a ``progress`` that is not a bool and a ``log`` that cannot be called with a line (before any work)."""
    if not isinstance(progress, (bool, np.bool_)):
        raise SimulationError(f"progress must be True or False, got {progress!r}")
    if log is not None and not callable(log):
        raise SimulationError(f"log must be a function that takes a line of text (print, say) or None, got {log!r}")


def run_prepared(run: Run, *, progress: bool = False, log=None) -> Trajectory:
    """:func:`simulate` for a checked :class:`Run` (an ensemble member re-run in full, say)."""
    t_load = time.perf_counter()
    kernel = loader.kernel_for(run.scene, log, run.method)
    if log and not numba.config.DISABLE_JIT and not loader.is_cached(kernel, run.method):
        log(f"compiling the {run.method} kernel of {run.scene.name} (first use only) ...")
    compiled = loader.compile_kernel(kernel, run.method)
    load_seconds = time.perf_counter() - t_load

    n = run.n_samples
    rec_t, rec_e = np.empty(n), np.empty(n)
    rec_q, rec_qd = np.empty((n, 6)), np.empty((n, 6))
    log_size = max(LOG_SIZE, 8 * kernel.N_CONTACT)
    ev_t, ev_k, ev_kind = np.empty(log_size), np.empty(log_size, np.int64), np.zeros(log_size, np.int64)
    q, qd = run.q.copy(), run.qd.copy()
    exact = run.method == "exact"
    if exact:
        rest = np.zeros(kernel.N_CONTACT + K.MODE_SLOTS, np.int64)
        tol = tolerances(run, kernel)
    i = n_rec = n_ev = 0
    bar = progress_bar(run.n_steps, progress, "step")
    t_run = time.perf_counter()
    try:
        while i < run.n_steps:
            i_end = min(i + CHUNK, run.n_steps)
            if exact:
                i_new, n_rec, n_ev, status = kernel.integrate_exact(
                    q, qd, rest, run.p, tol, 0.0, run.dt, i, i_end, run.n_steps, run.record_every,
                    rec_t, rec_q, rec_qd, rec_e, n_rec, ev_t, ev_k, ev_kind, n_ev, log=log)
            else:
                i_new, n_rec, n_ev, status = kernel.integrate(
                    q, qd, run.p, 0.0, run.dt, i, i_end, run.n_steps, run.record_every,
                    rec_t, rec_q, rec_qd, rec_e, n_rec, ev_t, ev_k, n_ev)
            bar.update(i_new - i)
            i = i_new
            if status == K.IMPACT_LOG_FULL:
                # the log doubles: refused, with what to change, where it would not fit
                check_memory(2 * len(ev_t) * EVENT_BYTES,
                             f"an event log of {2 * len(ev_t):,} contact events (t = {i * run.dt:.6g} s of "
                             f"{run.n_steps * run.dt:.6g} s)",
                             "shorten t_end, or look at why this scene has so many events (a jack rattling "
                             "in a wedge, a chattering contact)")
                ev_t, ev_k, ev_kind = (np.concatenate([a, np.zeros_like(a)]) for a in (ev_t, ev_k, ev_kind))
            elif status == K.NONFINITE:
                raise NonFiniteStateError(
                    f"{run.scene.name}: the state became non-finite at step {i} (t = {i * run.dt:.6g} s); "
                    f"last recorded sample at t = {rec_t[n_rec - 1]:.6g} s. Try a smaller dt "
                    f"(now {run.dt:g}) or check the forces and parameters.")
            elif status == K.INSIDE:        # (a gap THROUGH L below contact: it stopped there)
                pose = q
                if kernel.PRESCRIBED:       # (q: the jack's alone; the box's from its motion)
                    box = np.empty(6)
                    kernel.jit("box_motion")(i * run.dt, run.p, box)
                    pose = np.concatenate([box[:3], q])
                raise RunStoppedError(through_a_wall(run, i * run.dt, pose))
            elif status != K.DONE:
                raise RunStoppedError(f"{run.scene.name}: the kernel stopped at step {i} (t = {i * run.dt:.6g} s) "
                                      f"with status {status}")
    finally:
        bar.close()
    run_seconds = time.perf_counter() - t_run
    extra = {"kernel": {"cache": compiled["cache"], "load_seconds": load_seconds,
                        "run_seconds": run_seconds,
                        "steps_per_second": run.n_steps / run_seconds if run_seconds > 0 else None}}
    if exact:
        extra["tolerances"] = {"gap": tol[K.T_GAP], "event": tol[K.T_EVENT], "v_rest": tol[K.T_VREST]}
        check_inside(run, rec_t[:n_rec], rec_q[:n_rec])
    ev_t, ev_k, ev_kind = ev_t[:n_ev], ev_k[:n_ev], ev_kind[:n_ev]
    hit = ev_kind == K.IMPULSE
    mode = (ev_kind == K.REST) | (ev_kind == K.RELEASE)
    fallback = fallback_intervals(ev_t[ev_kind == K.FALLBACK], ev_k[ev_kind == K.FALLBACK], run.n_steps * run.dt)
    if exact:
        extra["fallback_seconds"] = float(np.sum(fallback[:, 1] - fallback[:, 0]))
        entered = ev_k[(ev_kind == K.FALLBACK) & (ev_k >= 1)]
        extra["fallback_reasons"] = [HANDOFF_REASONS.get(int(code), f"code {int(code)}") for code in entered]
        extra["solver_warnings"] = report_warnings(run, ev_t[ev_kind == K.WARNING], ev_k[ev_kind == K.WARNING])
    # a rest is logged where the Zeno cascade it ended would have come to rest, up to ZENO_TOL dt past the
    # update that held it (jackbox.engine.modes.update_contacts): in time order, none past the run's end
    mode_t = np.minimum(ev_t[mode], run.n_steps * run.dt)
    order = np.argsort(mode_t, kind="stable")
    return finish(run, rec_t[:n_rec], rec_q[:n_rec], rec_qd[:n_rec], rec_e[:n_rec],
                  ev_t[hit].copy(), ev_k[hit].copy(), extra,
                  mode_t[order], ev_k[mode][order], ev_kind[mode][order], fallback)


#: the deepest any gap of an exact run may be at a recorded sample, as a fraction of the box's half-width L:
#: held contacts sit at -T_EVENT/2 and the fallback's projection leaves them within 1e-9 L, so a jack found
#: deeper went through a wall unseen (forces or masses far beyond what the step resolves: g = 1e20)
INSIDE_LIMIT = 1e-6
#: recorded samples looked at for it (evenly spread, the last always)
INSIDE_SAMPLES = 101


#: states :func:`inside` checks at once (1e6 members' final states in one block took 1.1 s on 2 cores)
INSIDE_BLOCK = 4096


def beyond_a_wall(smallest: np.ndarray, L) -> np.ndarray:
    """Which smallest gaps (of states, box half-widths L) are below -INSIDE_LIMIT L: went through a wall unseen
    (NaN too)."""
    return ~(smallest >= -INSIDE_LIMIT * L)


def inside(scene: Scene, Q: np.ndarray, P: dict) -> np.ndarray:
    """Which of the states Q (n, 6) have a gap below -INSIDE_LIMIT L; P: parameter values, floats or (n,) rows."""
    n = Q.shape[0]
    points = np.broadcast_to(jack_points(scene, P), (n, len(scene.points), 2))
    L, w = (np.broadcast_to(np.asarray(P[k], float), (n,)) for k in ("L", "w_box"))
    out = np.empty(n, bool)
    with np.errstate(invalid="ignore"):
        for a in range(0, n, INSIDE_BLOCK):        # (in blocks: the temporaries stay in the cache)
            b = a + INSIDE_BLOCK
            gaps = contact_gaps_many(Q[a:b], points[a:b], L[a:b], w[a:b], scene.has_ground_contacts)
            out[a:b] = beyond_a_wall(gaps.min(axis=1), L[a:b])
    return out


def check_inside(run: Run, t: np.ndarray, q: np.ndarray) -> None:
    """Refuse an exact run whose jack ended up inside a wall or the box under the ground (see INSIDE_LIMIT)."""
    if len(t) == 0:
        return
    scene = run.scene
    P = dict(zip(scene.param_names, run.p.tolist()))
    looked = np.unique(np.linspace(0, len(t) - 1, min(len(t), INSIDE_SAMPLES)).round().astype(int))
    bad = looked[inside(scene, q[looked], P)]
    if len(bad):
        raise RunStoppedError(through_a_wall(run, t[bad[0]], q[bad[0]]))


def through_a_wall(run: Run, t: float, q: np.ndarray) -> str:
    """What to tell a user whose run was found at time t in the state q, inside a wall or under the ground."""
    scene = run.scene
    P = dict(zip(scene.param_names, run.p.tolist()))
    gaps = contact_gaps(q, jack_points(scene, P), P["L"], P["w_box"], scene.has_ground_contacts)
    worst, L = int(np.argmin(gaps)), P["L"]
    return (f"{scene.name}: at t = {t:.6g} s contact {scene.constraint_names[worst]!r} is "
            f"{-gaps[worst]:.3g} inside ({-gaps[worst] / L:.3g} L): the run went through a wall unseen. "
            f"Its forces or masses are beyond what a step of dt = {run.dt:g} s resolves: try a smaller dt "
            f"or check the parameters")


#: what each WARNING code of the engine means, for a user
WARNINGS = {K.WARN_LCP: ("lcp", "an iterative contact solve stopped before it converged"),
            K.WARN_LOCATE: ("locate", "an event's time was not located to round-off")}


#: why the exact method handed a stretch to the fallback (meta["fallback_reasons"], one per stretch)
HANDOFF_REASONS = {K.HANDOFF_STUCK: "an event made no progress", K.HANDOFF_MODES: "too many contact mode changes",
                   K.HANDOFF_ZENO: "Zeno in several contacts", K.HANDOFF_EVENTS: "too many events in one step",
                   K.HANDOFF_DENSE: "a bounce that neither shrinks nor stops"}


def fallback_intervals(t, k, t_end: float) -> np.ndarray:
    """(F, 2) start and end of each stretch the fallback integrated, from its FALLBACK events (in: the reason,
    HANDOFF_*, at least 1; out: 0)."""
    out = []
    for time_, into in zip(t.tolist(), k.tolist()):
        if into:
            out.append([time_, t_end])
        elif out:
            out[-1][1] = time_
    return np.array(out, dtype=float).reshape(-1, 2)


def report_warnings(run: Run, t, code) -> dict[str, int]:
    """Count the engine's solver warnings by kind, and say so (a SolverWarning) if there were any."""
    counts = {name: int(np.sum(code == c)) for c, (name, _) in WARNINGS.items()}
    if len(t):
        first = ", ".join(f"{np.sum(code == c)} times {text}" for c, (_, text) in WARNINGS.items() if np.any(code == c))
        warnings.warn(SolverWarning(f"{run.scene.name}: {first} (first at t = {t.min():.6g} s); the run went on, "
                                    f"but check the trajectory there"), stacklevel=3)
    return counts
