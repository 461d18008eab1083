"""The slow twin: the same model and the same algorithm, written to be obviously right.

The compiler's symbolic model (:func:`codegen.derive`) is turned into numeric functions
with ``sympy.lambdify`` (no cse, no Numba, no generated file), and the run is
plain Python and numpy: ``qdd = solve(M, f)``, the classical RK4 tableau, and
the impact LCP by trying every active set with ``numpy.linalg``. Tests hold
the generated functions and the compiled engine against it.

    traj = jackbox.reference.simulate("shaken", t_end=0.5)                  # method "naive"
    traj = jackbox.reference.simulate("shaken", t_end=0.5, method="exact")  # scipy

Method ``"naive"`` is the kernel's naive method step for step. Method
``"exact"`` (:func:`solve_exact`) is an independent solution of the same
model: ``scipy.integrate.solve_ivp`` (DOP853 at ``rtol=1e-12`` by default)
with one terminal event function per contact gap, the impact LCP at each
event, and a restart. It does not do resting contact: it stops with
:class:`SimulationError` when the impacts pile up. It is about a thousand
times slower than the kernel: use short horizons.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import sympy as sp

from codegen import Model, derive

from .api import GAP_TOL, REST_TOL, Run, finish, prepare
from .engine.integrator import NODES, SCALE, WEIGHTS
from .errors import NonFiniteStateError, SimulationError
from .scene import Scene, load_scene
from .trajectory import Trajectory


@dataclass
class Functions:
    """The model's numeric functions, each taking flat numpy arrays."""

    model: Model
    mass_matrix: Callable   #: (p) -> (n, n)
    forcing: Callable       #: (t, q, qd, p) -> (n,)
    phi: Callable           #: (t, q, p) -> (C,)
    phi_q: Callable         #: (t, q, p) -> (C, n)
    phi_t: Callable | None  #: (t, q, p) -> (C,)
    energy: Callable        #: (t, q, qd, p) -> float
    box_motion: Callable | None  #: (t, p) -> (6,)
    gap_bias: Callable | None = None  #: (t, q, qd, p) -> (C,): d^2 phi/dt^2 at qdd = 0 (tests of the compiler)

    def accel(self, t, q, qd, p):
        M, f = self.mass_matrix(p), self.forcing(t, q, qd, p)
        if not (np.all(np.isfinite(M)) and np.all(np.isfinite(f))):
            return np.full(len(f), np.nan)     # (LAPACK would print a complaint for each one it is handed)
        return np.linalg.solve(M, f)


def functions(scene: Scene) -> Functions:
    """Lambdified model functions of `scene` (derived once per model structure)."""
    key = repr(scene.structure())
    if key not in _cache:
        _cache[key] = _lambdify(scene)
    return _cache[key]


_cache: dict[str, Functions] = {}


def _lambdify(scene: Scene) -> Functions:
    m = derive(scene.model_spec())
    t, q, qd, p = m.t, m.q, m.qd, m.p

    def lam(args, expr, shape):
        f = sp.lambdify(args, expr, modules="numpy", cse=False)
        return lambda *a: np.asarray(f(*a), dtype=float).reshape(shape)

    n, C = len(q), m.phi.shape[0]
    return Functions(
        model=m,
        mass_matrix=lam([p], m.M, (n, n)),
        forcing=lam([t, q, qd, p], m.f, (n,)),
        phi=lam([t, q, p], m.phi, (C,)),
        phi_q=lam([t, q, p], m.phi_q, (C, n)),
        phi_t=lam([t, q, p], m.phi_t, (C,)) if m.phi_t is not None else None,
        energy=lam([t, q, qd, p], m.energy, ()),
        box_motion=lam([t, p], m.box_motion, (6,)) if m.box_motion is not None else None,
        gap_bias=lam([t, q, qd, p], m.gap_bias, (C,)),
    )


def rk4_step(fn: Functions, t, q, qd, dt, p):
    """The engine's tableau (:mod:`jackbox.engine.integrator`) on ``y = (q, qd)``, ``y' = (qd, M^-1 f)``."""
    def deriv(tt, y):
        return np.concatenate([y[n:], fn.accel(tt, y[:n], y[n:], p)])

    n = len(q)
    y = np.concatenate([q, qd])
    total, k = np.zeros_like(y), None
    for node, weight in zip(NODES, WEIGHTS):
        k = deriv(t + node * dt, y if k is None else y + node * dt * k)
        total += weight * k
    y = y + dt / SCALE * total
    return y[:n], y[n:]


def solve_lcp(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest active set S with ``A_SS lam_S = -b_S``, ``lam >= 0`` and ``A lam + b >= 0``."""
    m = len(b)
    if not (np.all(np.isfinite(A)) and np.all(np.isfinite(b))):
        raise NonFiniteStateError("the reference's impact has non-finite terms (speeds beyond a float's range)")
    tol = 1e-10 * np.abs(b).max()
    for size in range(1, m + 1):
        for S in itertools.combinations(range(m), size):
            S = list(S)
            sub = A[np.ix_(S, S)]
            if np.linalg.matrix_rank(sub, tol=1e-12 * np.abs(np.diag(sub)).max()) < size:
                continue
            lam = np.zeros(m)
            lam[S] = np.linalg.solve(sub, -b[S])
            if np.any(lam[S] * np.diag(sub) < -tol):
                continue
            lam = np.maximum(lam, 0.0)
            if np.all((A @ lam + b) >= -tol):
                return lam
    raise SimulationError("the reference's impact LCP has no solution (its contact matrix is not positive "
                          "semi-definite to round-off: speeds or sizes far beyond the scene's scales?)")


def resolve_impacts(fn: Functions, t, q, qd, p, gap, e_contact):
    """Impulses at the end of a step for the contacts with ``gap < 0`` (method 'naive')."""
    rows = np.flatnonzero(gap < 0.0)
    if len(rows) == 0:
        return qd, []
    J = fn.phi_q(t, q, p)[rows]
    v = J @ qd + (fn.phi_t(t, q, p)[rows] if fn.phi_t else 0.0)
    if not np.any(v < 0.0):
        return qd, []
    Winv = np.linalg.inv(fn.mass_matrix(p))
    A = J @ Winv @ J.T
    b = v + e_contact[rows] * np.minimum(v, 0.0)
    lam = solve_lcp(A, b)
    qd = qd + Winv @ J.T @ lam
    return qd, [int(k) for k, impulse in zip(rows, lam) if impulse > 0.0]


def full_state(fn: Functions, t, q, qd, p):
    """The 6 coordinates and rates (a prescribed box's from its motion)."""
    if fn.box_motion is None:
        return q, qd
    box = fn.box_motion(t, p)
    return np.concatenate([box[:3], q]), np.concatenate([box[3:], qd])


def restitution(scene: Scene, fn: Functions, p) -> np.ndarray:
    """(C,) restitution per contact: ``e`` for the walls, ``e_ground`` for the ground."""
    n_wall = fn.model.n_wall_contacts
    return np.array([p[scene.param_names.index("e" if k < n_wall else "e_ground")]
                     for k in range(fn.model.phi.shape[0])])


def sample_times(run: Run) -> np.ndarray:
    """The times at which the kernel records: every ``record_every`` steps, and the last step."""
    steps = [i for i in range(run.n_steps + 1) if i % run.record_every == 0 or i == run.n_steps]
    return np.array(steps) * run.dt


def scales(run: Run) -> tuple[float, float]:
    """The scene's length L (inner half-width of the box) and speed sqrt(g L), as in api.tolerances."""
    P = dict(zip(run.scene.param_names, run.p))
    L, g = P["L"], abs(P["g"])
    return L, (math.sqrt(g * L) if g > 0 else L / (run.n_steps * run.dt))


@dataclass
class ExactSolution:
    """What :func:`solve_exact` computed: samples of the integrated DOFs and the impacts."""

    t: np.ndarray           #: (N,) sample times (those of the kernel, :func:`sample_times`)
    q: np.ndarray           #: (N, n) coordinates of the integrated DOFs (n = 3 or 6)
    qd: np.ndarray          #: (N, n)
    impact_t: np.ndarray    #: (I,) time of each impulse
    impact_k: np.ndarray    #: (I,) its contact
    nfev: int               #: right-hand side evaluations, over all segments
    n_segments: int         #: solve_ivp calls (one more than the number of impact events)


#: the impacts pile up (resting contact) when this many happen within BURST_TIME sqrt(L/g)
MAX_BURST, BURST_TIME = 50, 1e-6


def solve_exact(run: Run, fn: Functions | None = None, *, rtol: float = 1e-12, atol: float | None = None,
                integrator: str = "DOP853", max_step: float | None = None) -> ExactSolution:
    """Integrate `run` with ``scipy.integrate.solve_ivp``, stopping at every contact.

    Each contact gap ``phi_k`` is a terminal event function of direction -1
    (it fires when the gap goes from positive to negative), located by scipy
    on its dense output. At an event the contacts closer than ``GAP_TOL * L``
    take part in one impact LCP (Newton's law per contact, as
    :func:`resolve_impacts`), and the integration restarts from the event with
    the new rates. Right after an impact every gap that took part is ~0, of
    either sign, and opening faster than ``REST_TOL * sqrt(g L)``. scipy fires
    on a change from ``>= 0`` to ``<= 0`` across a step and puts the event at
    the root in between: a gap of exactly 0 at the restart would fire there
    again, one of -1e-16 would miss a bounce shorter than the first step. So at
    the restart point (and only there) those gaps count as open (``GAP_TOL * L``).

    Resting contact is refused with :class:`SimulationError`: when a contact
    closes slower than ``REST_TOL * sqrt(g L)``, when a contact in touch does
    not open that fast after the impulses, or when ``MAX_BURST`` impacts happen
    within ``BURST_TIME * sqrt(L/g)``. So are steps too long to see every
    crossing, when an event finds a gap deeper than ``GAP_TOL * L`` or a gap
    that opens (a crossing missed earlier); one that dips below zero and back
    within a step goes unseen, which the default max_step makes unlikely.

    run: from :func:`jackbox.api.prepare` (its dt and record_every give the sample times).
    fn: the model's functions (default: the lambdified ones); anything with the
    attributes of :class:`Functions` will do (a benchmark may pass compiled ones).
    rtol, atol: solve_ivp's tolerances; atol defaults to ``rtol * L``.
    integrator: a solve_ivp method (``"DOP853"``, ``"RK45"`` ...).
    max_step: solve_ivp's largest step; defaults to the run's dt, so a step
    never jumps over a gap dip the kernel would see.
    """
    from scipy.integrate import solve_ivp

    fn = functions(run.scene) if fn is None else fn
    p, n = run.p, len(run.q)
    L, v_scale = scales(run)
    gap_tol, v_rest = GAP_TOL * L, REST_TOL * v_scale
    atol = rtol * L if atol is None else atol
    max_step = run.dt if max_step is None else max_step
    e_contact = restitution(run.scene, fn, p)
    names = run.scene.constraint_names
    ts = sample_times(run)
    t_end = ts[-1]

    def rhs(t, y):
        return np.concatenate([y[n:], fn.accel(t, y[:n], y[n:], p)])

    # scipy calls every event function at the same (t, y) in turn: compute phi once there
    last = {"key": None, "gap": None}
    restart = {"t": None, "touching": ()}

    def gaps(t, y):
        key = (t, y.tobytes())
        if key != last["key"]:
            last["key"], last["gap"] = key, fn.phi(t, y[:n], p)
            if t == restart["t"]:
                # At the restart point the contacts just in touch have a gap of ~0, of
                # either sign (round-off): count them as open there, so that scipy sees
                # their next change from open to closed (even a bounce shorter than the
                # first step) and never the restart point itself.
                last["gap"] = last["gap"].copy()
                last["gap"][restart["touching"]] = gap_tol
        return last["gap"]

    def event(k):
        def gap_k(t, y):
            return gaps(t, y)[k]
        gap_k.terminal, gap_k.direction = True, -1
        return gap_k

    events = [event(k) for k in range(len(names))]

    def resting(k, t, speed, what):
        return SimulationError(
            f"{run.scene.name}: contact {names[k]} {what} at t = {t:.9g} s with normal speed {speed:.3g} m/s "
            f"(at rest below {v_rest:.3g}): the contacts are coming to rest, and the scipy reference does "
            f"not do resting contact; use a shorter t_end, or the kernel (jackbox.simulate, method 'exact')")

    def missed(k, t, what):
        return SimulationError(
            f"{run.scene.name}: at the event at t = {t:.9g} s, contact {names[k]} {what}: scipy's steps were "
            f"too long to see every crossing of the gaps; use a smaller rtol or max_step")

    def impact(t, q, qd, trigger):
        """Impulses of the contacts that take part at (t, q); refuses a contact coming to rest."""
        gap = fn.phi(t, q, p)
        if gap.min() < -gap_tol:
            raise missed(int(gap.argmin()), t, f"is {-gap.min():.3g} m deep")
        if trigger is not None:
            speed = normal_speeds(fn, t, q, qd, p)[trigger]
            if speed > 0.0:
                raise missed(trigger, t, f"is opening (normal speed {speed:.3g} m/s) where it was found to close")
            if -speed < v_rest:
                raise resting(trigger, t, speed, "closes")
        near = np.flatnonzero(gap < gap_tol)
        restart["t"], restart["touching"] = t, near
        qd, hits = impulses(fn, t, q, qd, p, near, e_contact, 1e-3 * v_rest)
        # Every contact in touch must now open: one that stays (a gap ~0, not opening) is
        # resting, and a sign-change event cannot follow it (its gap may even start at -1e-16).
        speed = normal_speeds(fn, t, q, qd, p)
        for k in near:
            if speed[k] < v_rest:
                raise resting(k, t, speed[k], "stays closed")
        return qd, hits

    t0, q, qd = 0.0, run.q.copy(), run.qd.copy()
    qd, hits = impact(t0, q, qd, None)      # contacts already closing at the start, as the kernel
    imp_t, imp_k = [t0] * len(hits), hits
    out_t, out_y = [], []
    nfev = n_segments = 0
    while True:
        todo = ts[ts >= t0] if n_segments == 0 else ts[ts > t0]
        res = solve_ivp(rhs, (t0, t_end), np.concatenate([q, qd]), method=integrator, t_eval=todo,
                        events=events, rtol=rtol, atol=atol, max_step=max_step)
        n_segments += 1
        nfev += res.nfev
        if res.status < 0:
            raise SimulationError(f"{run.scene.name}: solve_ivp failed after t = {t0:.9g} s: {res.message}")
        out_t.append(res.t)
        out_y.append(np.reshape(res.y, (2 * n, -1)).T)    # (2n, 0) when no sample is left
        if res.status == 0:
            break
        k = next(k for k, te in enumerate(res.t_events) if len(te))
        t0 = float(res.t_events[k][0])
        q, qd = res.y_events[k][0][:n].copy(), res.y_events[k][0][n:].copy()
        qd, hits = impact(t0, q, qd, k)
        imp_t += [t0] * len(hits)
        imp_k += hits
        if len(imp_t) > MAX_BURST and t0 - imp_t[-MAX_BURST] < BURST_TIME * L / v_scale:
            raise SimulationError(
                f"{run.scene.name}: {MAX_BURST} impacts within {t0 - imp_t[-MAX_BURST]:.3g} s before "
                f"t = {t0:.9g} s: the contacts are coming to rest, and the scipy reference does not do "
                f"resting contact; use a shorter t_end, or the kernel (jackbox.simulate, method 'exact')")
        if t0 >= t_end:
            break
    y = np.concatenate(out_y)
    return ExactSolution(t=np.concatenate(out_t), q=y[:, :n], qd=y[:, n:],
                         impact_t=np.array(imp_t, dtype=float), impact_k=np.array(imp_k, dtype=np.int64),
                         nfev=nfev, n_segments=n_segments)


def normal_speeds(fn: Functions, t, q, qd, p) -> np.ndarray:
    """(C,) rates of every gap, ``phi_q qd + phi_t``."""
    return fn.phi_q(t, q, p) @ qd + (fn.phi_t(t, q, p) if fn.phi_t else 0.0)


def impulses(fn: Functions, t, q, qd, p, rows, e_contact, tiny):
    """The impact LCP over the contacts `rows` (method 'exact'): new qd and the contacts hit.

    Nothing happens unless one of them approaches faster than `tiny`. A
    contact counts as hit when its impulse changes its own normal speed by
    more than `tiny` (as the kernel logs them).
    """
    if len(rows) == 0:
        return qd, []
    J = fn.phi_q(t, q, p)[rows]
    v = J @ qd + (fn.phi_t(t, q, p)[rows] if fn.phi_t else 0.0)
    if not np.any(v < -tiny):
        return qd, []
    Winv = np.linalg.inv(fn.mass_matrix(p))
    A = J @ Winv @ J.T
    lam = solve_lcp(A, v + e_contact[rows] * np.minimum(v, 0.0))
    return qd + Winv @ J.T @ lam, [int(k) for k, impulse, a in zip(rows, lam, np.diag(A)) if impulse * a > tiny]


def simulate(scene: Scene | str, t_end: float | None = None, dt: float | None = None,
             record_every: int = 1, params: dict[str, float] | None = None, *,
             method: str = "naive", progress: bool = False, log=None, rtol: float = 1e-12,
             atol: float | None = None, integrator: str = "DOP853", max_step: float | None = None
             ) -> Trajectory:
    """Same signature and result as :func:`jackbox.simulate`, computed slowly.

    method: ``"naive"`` (the default; the kernel's naive method step for step,
    RK4 with the impulse at the end of the step) or ``"exact"``: scipy's
    solve_ivp with located events (:func:`solve_exact`), sampled at the same
    times as the kernel (every ``record_every`` steps of ``dt``; dt only sets
    the sample times, and the default max_step).
    rtol, atol, integrator, max_step: solve_ivp's, for method ``"exact"`` only
    (defaults: 1e-12, ``rtol * L`` with L the box's inner half-width, DOP853,
    dt). Method ``"exact"`` raises :class:`SimulationError` when contacts come
    to rest: it does not do resting contact.
    """
    run: Run = prepare(load_scene(scene), t_end, dt, record_every, params, method)
    if run.method == "exact":
        return _simulate_exact(run, rtol=rtol, atol=atol, integrator=integrator, max_step=max_step)
    if run.method != "naive":
        raise SimulationError(f"the reference implements methods 'naive' and 'exact' only, not {run.method!r}")
    fn = functions(run.scene)
    p, dt = run.p, run.dt
    e_contact = restitution(run.scene, fn, p)
    q, qd = run.q.copy(), run.qd.copy()
    ts, qs, qds, es, imp_t, imp_k = [], [], [], [], [], []

    def keep(t):
        Q, QD = full_state(fn, t, q, qd, p)
        ts.append(t), qs.append(Q), qds.append(QD), es.append(float(fn.energy(t, q, qd, p)))

    start = time.perf_counter()
    keep(0.0)
    for i in range(run.n_steps):
        t_next = (i + 1) * dt
        with np.errstate(all="ignore"):
            q, qd = rk4_step(fn, i * dt, q, qd, dt, p)
        if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            # (as the kernel says it; LAPACK would go on to complain of every NaN it is handed)
            raise NonFiniteStateError(
                f"{run.scene.name}: the state became non-finite at step {i + 1} (t = {t_next:.6g} s) "
                f"in the reference; last recorded sample at t = {ts[-1]:.6g} s")
        qd, hit = resolve_impacts(fn, t_next, q, qd, p, fn.phi(t_next, q, p), e_contact)
        imp_t += [t_next] * len(hit)
        imp_k += hit
        if (i + 1) % run.record_every == 0 or i + 1 == run.n_steps:
            keep(t_next)
    seconds = time.perf_counter() - start
    return finish(run, np.array(ts), np.array(qs), np.array(qds), np.array(es),
                  np.array(imp_t, dtype=float), np.array(imp_k, dtype=np.int64),
                  {"reference": {"run_seconds": seconds, "steps_per_second": run.n_steps / seconds}})


def _simulate_exact(run: Run, **options) -> Trajectory:
    fn = functions(run.scene)
    start = time.perf_counter()
    sol = solve_exact(run, fn, **options)
    seconds = time.perf_counter() - start
    full = [full_state(fn, t, q, qd, run.p) for t, q, qd in zip(sol.t, sol.q, sol.qd)]
    energy = np.array([float(fn.energy(t, q, qd, run.p)) for t, q, qd in zip(sol.t, sol.q, sol.qd)])
    L, _ = scales(run)
    options["atol"] = options["rtol"] * L if options["atol"] is None else options["atol"]
    options["max_step"] = run.dt if options["max_step"] is None else options["max_step"]
    return finish(run, sol.t, np.array([Q for Q, _ in full]), np.array([QD for _, QD in full]), energy,
                  sol.impact_t, sol.impact_k,
                  {"reference": {"run_seconds": seconds, "solve_ivp": options, "nfev": sol.nfev,
                                 "segments": sol.n_segments}})
