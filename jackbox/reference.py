"""The slow twin: the same model and the same algorithm, written to be obviously right.

The symbolic model of :mod:`codegen.model` is turned into numeric functions
with ``sympy.lambdify`` (no cse, no Numba, no generated file), and the run is
plain Python and numpy: ``qdd = solve(M, f)``, the classical RK4 tableau, and
the impact LCP by trying every active set with ``numpy.linalg``. Tests hold
the generated functions and the fused kernel against it.

    traj = jackbox.reference.simulate("shaken", t_end=0.5)

It is about a thousand times slower than the kernel: use short horizons.
"""

from __future__ import annotations

import itertools
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import sympy as sp

from codegen.model import Model, derive

from .api import Run, finish, prepare
from .errors import SimulationError
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

    def accel(self, t, q, qd, p):
        return np.linalg.solve(self.mass_matrix(p), self.forcing(t, q, qd, p))


def functions(scene: Scene) -> Functions:
    """Lambdified model functions of `scene` (derived once per model structure)."""
    key = repr(scene.structure())
    if key not in _cache:
        _cache[key] = _lambdify(scene)
    return _cache[key]


_cache: dict[str, Functions] = {}


def _lambdify(scene: Scene) -> Functions:
    m = derive(scene)
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
    )


def rk4_step(fn: Functions, t, q, qd, dt, p):
    """The classical tableau on ``y = (q, qd)``, ``y' = (qd, M^-1 f)``."""
    def deriv(tt, y):
        return np.concatenate([y[n:], fn.accel(tt, y[:n], y[n:], p)])

    n = len(q)
    y = np.concatenate([q, qd])
    k1 = deriv(t, y)
    k2 = deriv(t + dt / 2, y + dt / 2 * k1)
    k3 = deriv(t + dt / 2, y + dt / 2 * k2)
    k4 = deriv(t + dt, y + dt * k3)
    y = y + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    return y[:n], y[n:]


def solve_lcp(A: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest active set S with ``A_SS lam_S = -b_S``, ``lam >= 0`` and ``A lam + b >= 0``."""
    m = len(b)
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
    raise RuntimeError("impact LCP has no solution (A is not positive semi-definite?)")


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
    return qd, [int(k) for k, l in zip(rows, lam) if l > 0.0]


def full_state(fn: Functions, t, q, qd, p):
    """The 6 coordinates and rates (a prescribed box's from its motion)."""
    if fn.box_motion is None:
        return q, qd
    box = fn.box_motion(t, p)
    return np.concatenate([box[:3], q]), np.concatenate([box[3:], qd])


def simulate(scene: Scene | str, t_end: float | None = None, dt: float | None = None,
             record_every: int = 1, params: dict[str, float] | None = None, *,
             method: str = "naive", progress: bool = False, log=None) -> Trajectory:
    """Same signature and result as :func:`jackbox.simulate`, computed slowly."""
    run: Run = prepare(load_scene(scene), t_end, dt, record_every, params, method)
    if run.method != "naive":
        raise SimulationError(f"the reference implements method 'naive' only, not {run.method!r}")
    fn = functions(run.scene)
    p, dt = run.p, run.dt
    n_wall = fn.model.n_wall_contacts
    e_contact = np.array([p[run.scene.param_names.index("e" if k < n_wall else "e_ground")]
                          for k in range(fn.model.phi.shape[0])])
    q, qd = run.q.copy(), run.qd.copy()
    ts, qs, qds, es, imp_t, imp_k = [], [], [], [], [], []

    def keep(t):
        Q, QD = full_state(fn, t, q, qd, p)
        ts.append(t), qs.append(Q), qds.append(QD), es.append(float(fn.energy(t, q, qd, p)))

    start = time.perf_counter()
    keep(0.0)
    for i in range(run.n_steps):
        t_next = (i + 1) * dt
        q, qd = rk4_step(fn, i * dt, q, qd, dt, p)
        qd, hit = resolve_impacts(fn, t_next, q, qd, p, fn.phi(t_next, q, p), e_contact)
        imp_t += [t_next] * len(hit)
        imp_k += hit
        if (i + 1) % run.record_every == 0 or i + 1 == run.n_steps:
            keep(t_next)
    seconds = time.perf_counter() - start
    return finish(run, np.array(ts), np.array(qs), np.array(qds), np.array(es),
                  np.array(imp_t, dtype=float), np.array(imp_k, dtype=np.int64),
                  {"reference": {"run_seconds": seconds, "steps_per_second": run.n_steps / seconds}})
