"""The friendly API: scene in, trajectory out.

:func:`simulate` checks its arguments, finds the scene's compiled kernel
(:mod:`jackbox.loader`), runs it in chunks (a progress bar can follow, and the
impact log grows when it fills) and wraps the arrays in a
:class:`~jackbox.trajectory.Trajectory`. :mod:`jackbox.reference` shares
:func:`prepare` and :func:`finish`, so both see the same run.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from . import __version__, loader
from . import kernel as K
from .errors import NonFiniteStateError, SimulationError
from .scene import Scene, load_scene
from .trajectory import Trajectory

CHUNK = 1 << 15          #: steps per kernel call (progress granularity)
METHODS = ("naive",)


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

    @property
    def n_samples(self) -> int:
        return self.n_steps // self.record_every + 1 + (self.n_steps % self.record_every != 0)


def prepare(scene, t_end=None, dt=None, record_every=1, params=None, method="naive") -> Run:
    """Check the arguments of a run and resolve defaults from the scene."""
    scene = load_scene(scene)
    t_end = scene.t_end if t_end is None else float(t_end)
    dt = scene.dt if dt is None else float(dt)
    if not (math.isfinite(t_end) and t_end > 0):
        raise SimulationError(f"t_end must be a positive number, got {t_end}")
    if not (math.isfinite(dt) and 0 < dt <= t_end):
        raise SimulationError(f"dt must be a positive number no larger than t_end, got {dt}")
    if isinstance(record_every, bool) or not isinstance(record_every, (int, np.integer)) or record_every < 1:
        raise SimulationError(f"record_every must be a positive integer, got {record_every!r}")
    if method not in METHODS:
        raise SimulationError(f"method must be one of {', '.join(METHODS)}, got {method!r}")
    p = scene.param_values.copy()
    for name, value in (params or {}).items():
        if name not in scene.param_names:
            raise SimulationError(f"unknown parameter {name!r} (parameters: {', '.join(scene.param_names)})")
        p[scene.param_names.index(name)] = float(value)
    if not np.all(np.isfinite(p)):
        raise SimulationError("parameters must be finite")
    # The last step ends at t_end (or just past it when dt does not divide it).
    n_steps = max(1, math.ceil(t_end / dt - 1e-9))
    first = 3 if scene.prescribed else 0
    q, qd = scene.q0[first:].copy(), scene.qd0[first:].copy()
    if not (np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
        raise SimulationError("the start state is not finite")
    return Run(scene, p, q, qd, dt, n_steps, int(record_every), method)


def finish(run: Run, t, q, qd, energy, impact_t, impact_k, extra: dict) -> Trajectory:
    scene = run.scene
    meta = {
        "jackbox": __version__, "scene": scene.name, "method": run.method, "dt": run.dt,
        "n_steps": run.n_steps, "record_every": run.record_every,
        "params": dict(zip(scene.param_names, run.p.tolist())),
        "model_hash": loader.model_hash(scene.structure()),
    } | extra
    return Trajectory(t=t, q=q, qd=qd, energy=energy, impact_t=impact_t,
                      impact_constraint=impact_k.astype(np.int64),
                      constraint_names=scene.constraint_names, scene=scene.text, meta=meta)


def simulate(scene: Scene | str, t_end: float | None = None, dt: float | None = None,
             record_every: int = 1, params: dict[str, float] | None = None, *,
             method: str = "naive", progress: bool = False, log=None) -> Trajectory:
    """Simulate a scene with its compiled kernel.

    scene: a :class:`Scene`, a built-in name or a path to a ``.toml``.
    t_end, dt: override the scene's ``[run]``; the run takes ``ceil(t_end/dt)`` steps.
    record_every: keep every k-th step (and the last one).
    params: values for parameter slots by name (``[params]`` names, ``m_box``,
    ``e`` ...); nothing is regenerated or recompiled.
    progress: show a progress bar (on stderr). log: a callable for status lines.
    """
    run = prepare(scene, t_end, dt, record_every, params, method)
    t_load = time.perf_counter()
    kernel = loader.kernel_for(run.scene, log)
    compiled = loader.compile_kernel(kernel)
    load_seconds = time.perf_counter() - t_load

    n = run.n_samples
    rec_t, rec_e = np.empty(n), np.empty(n)
    rec_q, rec_qd = np.empty((n, 6)), np.empty((n, 6))
    log_size = max(1024, 4 * kernel.N_CONTACT)
    imp_t, imp_k = np.empty(log_size), np.empty(log_size, np.int64)
    q, qd = run.q.copy(), run.qd.copy()
    i = n_rec = n_imp = 0
    bar = _progress(run.n_steps, progress)
    t_run = time.perf_counter()
    try:
        while i < run.n_steps:
            i_end = min(i + CHUNK, run.n_steps)
            i_new, n_rec, n_imp, status = kernel.integrate(
                q, qd, run.p, 0.0, run.dt, i, i_end, run.n_steps, run.record_every,
                rec_t, rec_q, rec_qd, rec_e, n_rec, imp_t, imp_k, n_imp)
            if bar is not None:
                bar.update(i_new - i)
            i = i_new
            if status == K.IMPACT_LOG_FULL:
                imp_t = np.concatenate([imp_t, np.empty_like(imp_t)])
                imp_k = np.concatenate([imp_k, np.empty_like(imp_k)])
            elif status == K.NONFINITE:
                raise NonFiniteStateError(
                    f"{run.scene.name}: the state became non-finite at step {i} (t = {i * run.dt:.6g} s); "
                    f"last recorded sample at t = {rec_t[n_rec - 1]:.6g} s. Try a smaller dt "
                    f"(now {run.dt:g}) or check the forces and parameters.")
    finally:
        if bar is not None:
            bar.close()
    run_seconds = time.perf_counter() - t_run
    extra = {"kernel": {"cache": compiled["cache"], "load_seconds": load_seconds,
                        "run_seconds": run_seconds,
                        "steps_per_second": run.n_steps / run_seconds if run_seconds > 0 else None}}
    return finish(run, rec_t[:n_rec], rec_q[:n_rec], rec_qd[:n_rec], rec_e[:n_rec],
                  imp_t[:n_imp].copy(), imp_k[:n_imp].copy(), extra)


def _progress(total: int, enabled: bool) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(total=total, unit="step", unit_scale=True, delay=0.5, leave=False)
