"""Ensembles and chaos studies: many members of one scene, on every core (or a Dask cluster).

A study is a static, picklable :class:`EnsembleSpec` (the scene, the run, how
the members differ, the seed) and a pure function of a member's index: the
engine sets member ``i`` up (its start state, parameters, tolerances, a chaos
twin's offset) from a few small arrays and ``(seed, i)`` alone, as the first
part of the member's own parallel work (``prange``), then runs the members
independently. So any split of the members, over threads, chunks, processes or
machines, gives the same numbers bit for bit; :func:`run_chunk` is the unit of
work that a progress bar or a Dask task sees, and :func:`member_inputs` the
setup alone.

Members differ by

* a perturbation of the start state (``perturb={"theta_jack": 1e-6}``):
  uniform in ``[-s, s]`` per named coordinate or rate, random from a hash of
  ``(seed, i)`` (:mod:`jackbox.engine.draws`: these draws replaced
  ``numpy.random.default_rng([seed, i])``, so a seed gives other members than
  it did before), or on an even grid;
* parameter values (``sweep={"e": (0.5, 1.0)}``): evenly spaced over the
  members for one parameter, a square grid for two; ``restitution`` sets both
  ``e`` and ``e_ground``. Parameters are runtime values: nothing recompiles.

Per member the study keeps only what it needs: the final state, the impulse
count, the time of the first impulse, the status, and the state at chosen
sample times. :meth:`Ensemble.trajectory` re-runs one member in full.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from codegen import BASE_SYMBOLS, parse_formula

from . import __version__, api, loader
from . import engine as K
from .engine.records import DERIVE_CROSS, DERIVE_SQUARE
from .errors import SimulationError
from .fileio import write_atomic
from .progress import progress_bar
from .scene import COORDS, RATES, Scene, check_param, derived_inertia_inputs, is_number, load_scene

#: members per kernel call when the progress bar is on (each call is parallel inside)
CHUNK_MEMBERS = 1024
#: members per GPU launch with a progress bar (a launch fills the GPU from some 10^5 members)
GPU_CHUNK = 1 << 18
STATUS_NAMES = {K.DONE: "done", K.NONFINITE: "non-finite", K.STALLED: "stalled",
                K.INSIDE: "through a wall unseen (forces or masses beyond what the step resolves)",
                K.IMPACT_LOG_FULL: "event log full (a GPU member's step had more events than it holds)"}
#: a perturbed start may touch a wall, but not reach into it by more than this times L
START_TOL = 1e-9


@dataclass(frozen=True, eq=False)
class EnsembleSpec:
    """Everything that defines a study; members are functions of (spec, index)."""

    scene: Scene
    n: int
    dt: float
    n_steps: int
    seed: int
    perturb: tuple[tuple[str, float], ...]          #: (coordinate or rate name, half-width)
    grid: bool                                      #: perturbations on a grid, not random
    params: tuple[tuple[str, float], ...]           #: values for every member
    sweep: tuple[tuple[str, float, float], ...]     #: (parameter, first, last)
    sample_steps: tuple[int, ...]
    renorm_steps: int = 0                           #: chaos study: steps between renormalisations
    d0: float = 0.0                                 #: chaos study: twin separation (scaled)
    lanes: bool | None = None                       #: blocks of lanes for members that share their parameters
                                                    #: but for the restitution (None: where it pays, see use_lanes)
    device: str = "cpu"                             #: "cpu", or "cuda": one GPU thread per member (jackbox.engine.gpu)

    @property
    def t_end(self) -> float:
        return self.n_steps * self.dt

    @property
    def sample_times(self) -> np.ndarray:
        return np.asarray(self.sample_steps, float) * self.dt


def plan(scene, n: int, perturb: dict[str, float] | None = None, params: dict[str, float] | None = None,
         sweep: dict[str, tuple[float, float]] | None = None, t_end: float | None = None,
         dt: float | None = None, seed: int = 0, grid: bool = False, samples=None) -> EnsembleSpec:
    """Check a study's arguments and describe it (nothing runs)."""
    scene = load_scene(scene)
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 1:
        raise SimulationError(f"n must be a positive integer, got {n!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or not 0 <= seed < 2**63:
        raise SimulationError(f"seed must be an integer from 0 to 2^63 - 1, got {seed!r}")
    for what, value in (("perturb", perturb), ("params", params), ("sweep", sweep)):
        if value is not None and not isinstance(value, dict):
            raise SimulationError(f"{what} must be a dict of names and values, got {value!r}")
    run = api.prepare(scene, t_end, dt, params=params, where="params")
    params = api.slot_values(scene, params or {})     # by slot: ``restitution`` is ``e`` and ``e_ground``
    names = [*COORDS, *RATES]
    movable = scene.dof_names + tuple(f"{c}_dot" for c in scene.dof_names)
    pert = []
    for name, scale in (perturb or {}).items():
        if name not in names:
            raise SimulationError(f"perturb: unknown coordinate {name!r} (one of {', '.join(names)})")
        if name not in movable:
            raise SimulationError(f"perturb: {name!r} is not a degree of freedom: the box's motion is prescribed")
        if not (is_number(scale) and math.isfinite(scale) and scale >= 0):
            raise SimulationError(f"perturb: the size for {name!r} must be a finite number >= 0, got {scale!r}")
        pert.append((name, float(scale)))
    if grid and pert and _side(n, len(pert)) is None:
        raise SimulationError(f"a grid over {len(pert)} coordinates needs n = m^{len(pert)} members, got n = {n}")
    sw = []
    swept = {}                                 # parameter slot name -> the sweep's name for it
    for name, rng in (sweep or {}).items():
        slots = _param_slots(scene, name)      # refuses an unknown name
        _check_swept(scene, name, slots, swept, params)
        try:
            if isinstance(rng, (str, bytes, dict)):    # (two letters, or two keys, would unpack)
                raise TypeError
            lo, hi = rng
        except (TypeError, ValueError):
            raise SimulationError(f"sweep: {name} needs (first, last), got {rng!r}") from None
        # both ends by the scene format's rules (every rule is a range: the members between pass too)
        for slot in slots:
            lo, hi = (check_param(scene.param_names[slot], v, f"sweep {name}") for v in (lo, hi))
        sw.append((name, lo, hi))
    if len(sw) > 2:
        raise SimulationError("sweep: at most two parameters (a line or a grid)")
    if len(sw) == 2 and _side(n, 2) is None:
        raise SimulationError(f"a sweep over two parameters is a square grid: n must be m^2, got n = {n}")
    steps = _sample_steps(samples, run)
    return EnsembleSpec(scene=run.scene, n=int(n), dt=run.dt, n_steps=run.n_steps, seed=int(seed),
                        perturb=tuple(pert), grid=bool(grid),
                        params=tuple((k, float(v)) for k, v in params.items()),
                        sweep=tuple(sw), sample_steps=steps)


def member_inputs(spec: EnsembleSpec, start: int, stop: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start coordinates, rates (integrated DOFs) and parameters of members start..stop-1.

    The engine's setup of those members, the same code (and numbers) as a study's own.
    """
    rows = _set_up(spec, _kernel(spec), start, stop)
    return rows["q0"], rows["qd0"], rows["params"]


#: member-steps from which a study compiles its lanes when they are not compiled yet: they take a
#: member-step about 20 ns less than a member alone on each of two threads (shaken, this 2-core
#: machine: 1.5e8 against 3.2e7 member-steps/s), and compiling them costs about 14 s once (the block
#: loop once per machine; the lanes and their event step once per model, 7-8 s in two processes)
LANES_WORTH = 1e9


def use_lanes(spec: EnsembleSpec, kernel) -> bool:
    """Whether a study's members that share their parameters (but for the restitution) go in blocks of lanes.

    As asked (``spec.lanes`` True or False); else (None) where it pays: when
    the lanes of the model and the block loop are compiled (or cached)
    already, or the study is big enough (LANES_WORTH member-steps) to win back
    their compile time. The numbers are the same either way.
    """
    if spec.lanes is not None:
        return spec.lanes
    twins = spec.renorm_steps > 0
    return (spec.n * spec.n_steps * (2 if twins else 1) >= LANES_WORTH
            or kernel.lanes_ready("run_twin_member_blocks" if twins else "run_member_blocks"))


def run_chunk(spec: EnsembleSpec, start: int, stop: int) -> dict[str, np.ndarray]:
    """Run members start..stop-1; every array returned has stop - start rows.

    The unit of work of a progress bar or a Dask task. Loads (compiling on
    first use in this process, else from Numba's cache) the scene's kernel.
    """
    kernel = _kernel(spec)
    rows = _set_up(spec, kernel, start, stop)
    _check_starts(spec, rows, start)
    m, S = stop - start, len(spec.sample_steps)
    # samples a member never reaches stay NaN (the kernel writes the ones it reaches)
    samp_q, samp_qd = np.full((m, S, 6), np.nan), np.full((m, S, 6), np.nan)
    fin_q, fin_qd, fin = np.zeros((m, 6)), np.zeros((m, 6)), np.zeros((m, 7))
    gaps = kernel.run_members(rows["q0"], rows["qd0"], rows["params"], rows["tol"], spec.dt, spec.n_steps,
                              np.asarray(spec.sample_steps, np.int64), samp_q, samp_qd, fin_q, fin_qd, fin,
                              lanes=spec.device == "cpu" and use_lanes(spec, kernel), device=spec.device)
    lost, inside = _unfinished(spec.scene, fin[:, 3], fin_q, fin_qd, rows["params"], gaps)
    fin[lost | inside, 0] = np.nan
    # (columns copied: a study of one part keeps these arrays as they are, contiguous, without all of fin)
    return {"q": fin_q, "qd": fin_qd, "energy": fin[:, 0].copy(), "impacts": fin[:, 1].astype(np.int64),
            "first_impact_t": fin[:, 2].copy(), "status": fin[:, 3].astype(np.int64),
            "steps": fin[:, 4].astype(np.int64), "fallback": fin[:, 5].copy(), "warnings": fin[:, 6].astype(np.int64),
            "samples_q": samp_q, "samples_qd": samp_qd,
            "q0": rows["q0"], "qd0": rows["qd0"], "params": rows["params"]}


def _unfinished(scene: Scene, status: np.ndarray, Q: np.ndarray, QD: np.ndarray, P: np.ndarray,
                gaps: np.ndarray | None = None):
    """Members that did not complete, said so in place; returns the masks (stopped early, ended inside a wall).

    One that stopped early has no final state: NaN in Q and QD, not its last
    sample (the step it reached is kept in ``steps``). One whose final state Q
    (with parameter rows P) has a gap below -api.INSIDE_LIMIT L went through a
    wall unseen (forces far beyond what a step resolves): status INSIDE, NaN.
    gaps: each member's smallest gap at its final state, where the GPU computed
    them (:func:`jackbox.engine.gpu.run_members`), else :func:`jackbox.api.inside` asks.
    """
    lost = status != K.DONE
    Q[lost], QD[lost] = np.nan, np.nan
    if gaps is None:
        inside = ~lost & api.inside(scene, Q, dict(zip(scene.param_names, P.T)))
    else:
        inside = ~lost & api.beyond_a_wall(gaps, P[:, scene.param_names.index("L")])
    status[inside] = K.INSIDE
    Q[inside], QD[inside] = np.nan, np.nan
    return lost, inside


def run_chaos_chunk(spec: EnsembleSpec, start: int, stop: int) -> dict[str, np.ndarray]:
    """Twin trajectories of members start..stop-1: log stretch per renormalisation interval."""
    kernel = _kernel(spec)
    rows = _set_up(spec, kernel, start, stop)
    _check_starts(spec, rows, start)
    n_dof = rows["q0"].shape[1]
    offset = rows["offset"]
    m = stop - start
    n_intervals = -(-spec.n_steps // spec.renorm_steps)
    stretch, fin = np.zeros((m, n_intervals)), np.zeros((m, K.TWIN_FIN + 12))
    kernel.run_twin_members(rows["q0"], rows["qd0"], np.ascontiguousarray(offset[:, :n_dof]),
                            np.ascontiguousarray(offset[:, n_dof:]), rows["params"], rows["tol"], spec.dt,
                            spec.n_steps, spec.renorm_steps, _chaos_scale(spec), stretch, fin,
                            lanes=spec.device == "cpu" and use_lanes(spec, kernel), device=spec.device)
    status = fin[:, 1].astype(np.int64)
    fin_q = fin[:, K.TWIN_FIN:K.TWIN_FIN + 6].copy()      # (six coordinates, a prescribed box's included)
    fin_qd = fin[:, K.TWIN_FIN + 6:].copy()
    # a pair that went through a wall unseen (the loop stopped it there, or its reference ended inside one:
    # _unfinished marks both INSIDE) has stretches that measure that, not the dynamics (the twin is put back
    # next to the reference at each renormalisation, so the reference's final state speaks for both)
    _unfinished(spec.scene, status, fin_q, fin_qd, rows["params"])
    stretch[status == K.INSIDE] = np.nan
    return {"stretch": stretch, "impacts": fin[:, 0].astype(np.int64), "status": status,
            "steps": fin[:, 2].astype(np.int64), "fallback": fin[:, 3].copy(), "warnings": fin[:, 4].astype(np.int64),
            "q": fin_q, "qd": fin_qd,
            "q0": rows["q0"], "qd0": rows["qd0"], "params": rows["params"], "offset": offset}


@dataclass
class Ensemble:
    """The result of :func:`ensemble`: one row per member."""

    spec: EnsembleSpec
    q: np.ndarray                 #: (n, 6) final coordinates (a prescribed box's from its motion); NaN: not completed
    qd: np.ndarray                #: (n, 6) final rates (NaN: not completed)
    energy: np.ndarray            #: (n,) final energy (NaN: not completed)
    impacts: np.ndarray           #: (n,) contact impulses
    first_impact_t: np.ndarray    #: (n,) time of the first impulse (NaN: none)
    status: np.ndarray            #: (n,) 0 done, 2 non-finite
    steps: np.ndarray             #: (n,) steps completed (t_reached = steps * dt)
    fallback: np.ndarray          #: (n,) simulated seconds integrated by the fallback (first order; 0: none)
    warnings: np.ndarray          #: (n,) solver warnings (a contact solve or event location that did not converge)
    samples_q: np.ndarray         #: (n, S, 6) state at spec.sample_times (NaN: not reached)
    samples_qd: np.ndarray
    q0: np.ndarray                #: (n, DOF) start coordinates of the integrated DOFs
    qd0: np.ndarray
    params: np.ndarray            #: (n, P) parameter values
    meta: dict

    @property
    def n(self) -> int:
        return len(self.q)

    @property
    def sample_times(self) -> np.ndarray:
        return self.spec.sample_times

    @property
    def completed(self) -> np.ndarray:
        """(n,) True for the members that reached t_end."""
        return self.status == K.DONE

    @property
    def t_reached(self) -> np.ndarray:
        """(n,) the time each member reached (t_end for the completed ones)."""
        return self.steps * self.spec.dt

    def __repr__(self) -> str:
        return (f"<Ensemble {self.spec.scene.name}: {self.n} members over {self.spec.t_end:g} s, "
                f"{_outcome(self.status)}>")

    def trajectory(self, i: int, record_every: int = 1):
        """Member i in full (the same kernel, the same numbers), as a Trajectory."""
        if not 0 <= i < self.n:
            raise SimulationError(f"member {i} is not in this ensemble of {self.n}")
        return member_trajectory(self.spec, i, record_every)

    def summary(self) -> str:
        ok = self.status == K.DONE
        hit = np.isfinite(self.first_impact_t)
        rate = self.meta.get("member_steps_per_second")
        lines = [f"{self.spec.scene.name}: {self.n} members over {self.spec.t_end:g} s "
                 f"(dt {self.spec.dt:g}, {self.spec.n_steps} steps each)"]
        if rate:
            lines.append(f"  {rate:.3g} member-steps/s on {_where(self.meta)}, {self.meta['run_seconds']:.2f} s")
        if ok.any():    # over the members that completed: a stopped one's count is partial
            done = self.impacts[ok]
            lines.append(f"  impulses per member{'' if ok.all() else ' (completed)'}: median "
                         f"{np.median(done):.0f}, range {done.min()}..{done.max()}")
        if hit.any():
            lines.append(f"  first impulse: {hit.sum()} members, median t = {np.median(self.first_impact_t[hit]):.4g} s")
        lines += _fallback_lines(self.fallback, self.warnings)
        if not ok.all():
            lines.append(f"  NOT COMPLETED: {_lost(self.status)}, between t = {self.t_reached[~ok].min():.4g} "
                         f"and {self.t_reached[~ok].max():.4g} s; their final states and the samples they "
                         f"never reached are NaN (.completed, .t_reached)")
        return "\n".join(lines)

    def save(self, path) -> Path:
        arrays = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)
                  if isinstance(getattr(self, f.name), np.ndarray)}
        return _save(path, arrays | {"sample_t": self.sample_times}, self.spec, self.meta)


@dataclass
class ChaosStudy:
    """The result of :func:`chaos`: log stretches of twin pairs, and the FTLE estimate."""

    spec: EnsembleSpec
    times: np.ndarray             #: (K,) ends of the renormalisation intervals
    stretch: np.ndarray           #: (n, K) log(d / d0) over each interval (NaN: not reached)
    impacts: np.ndarray
    status: np.ndarray
    steps: np.ndarray
    fallback: np.ndarray          #: (n,) simulated seconds either twin spent in the fallback
    warnings: np.ndarray          #: (n,) solver warnings of both twins
    q: np.ndarray                 #: (n, 6) the reference's final coordinates (NaN: not completed)
    qd: np.ndarray                #: (n, 6) and rates
    q0: np.ndarray
    qd0: np.ndarray
    params: np.ndarray
    offset: np.ndarray            #: (n, 2 DOF) the twin's start offset (coordinates, then rates)
    meta: dict

    @property
    def growth(self) -> np.ndarray:
        """(n, K) log of the separation an unrenormalised pair would have: cumulative stretches."""
        return np.cumsum(self.stretch, axis=1)

    @property
    def ftle(self) -> np.ndarray:
        """(n,) finite-time Lyapunov exponent of each member, 1/s (NaN for failed members)."""
        done = self.status == K.DONE
        value = np.nansum(self.stretch, axis=1) / self.spec.t_end
        return np.where(done, value, np.nan)

    @property
    def completed(self) -> np.ndarray:
        """(n,) True for the members whose twins both reached t_end."""
        return self.status == K.DONE

    def __repr__(self) -> str:
        return (f"<ChaosStudy {self.spec.scene.name}: {len(self.stretch)} twin pairs over "
                f"{self.spec.t_end:g} s, {_outcome(self.status)}>")

    def summary(self) -> str:
        f = self.ftle[np.isfinite(self.ftle)]
        lines = [f"{self.spec.scene.name}: {len(self.stretch)} twin pairs over {self.spec.t_end:g} s, "
                 f"d0 = {self.spec.d0:g}, renormalised every {self.spec.renorm_steps * self.spec.dt:g} s"]
        if not self.completed.all():
            lines.append(f"  NOT COMPLETED: {_lost(self.status)}; their FTLE is NaN and left out below")
        lines += _fallback_lines(self.fallback, self.warnings)
        if len(f):
            lo, med, hi = np.percentile(f, [10, 50, 90])
            lines.append(f"  FTLE: mean {f.mean():.4g} 1/s, std {f.std(ddof=1) if len(f) > 1 else 0.0:.3g}, "
                         f"median {med:.4g} (10-90%: {lo:.4g}..{hi:.4g})")
        rate = self.meta.get("member_steps_per_second")
        if rate:
            lines.append(f"  {rate:.3g} member-steps/s (two trajectories per member) on "
                         f"{_where(self.meta)}, {self.meta['run_seconds']:.2f} s")
        return "\n".join(lines)

    def save(self, path) -> Path:
        arrays = {"times": self.times, "stretch": self.stretch, "growth": self.growth, "ftle": self.ftle,
                  "impacts": self.impacts, "status": self.status, "steps": self.steps, "fallback": self.fallback,
                  "warnings": self.warnings, "q": self.q, "qd": self.qd, "q0": self.q0,
                  "qd0": self.qd0, "params": self.params, "offset": self.offset}
        return _save(path, arrays, self.spec, self.meta)


def ensemble(scene, n: int, perturb=None, params=None, t_end=None, dt=None, seed: int = 0, *,
             sweep=None, grid: bool = False, samples=None, chunk: int | None = None, threads: int | None = None,
             scheduler: str | None = None, dask_local: int | None = None, progress: bool = False,
             log=None, lanes: bool | None = None, device: str = "cpu") -> Ensemble:
    """Run n members of a scene in parallel; see the module docstring for how they differ.

    samples: times (s) at which to keep every member's state (rounded to whole steps).
    seed: member i's random perturbation is a hash of (seed, i) (jackbox.engine.draws), not
    numpy's ``default_rng([seed, i])`` as before: the same seed now gives other members.
    threads: Numba threads in this process (default: all cores). scheduler:
    ``"tcp://host:port"`` of a running Dask scheduler; dask_local: start a
    Dask LocalCluster with that many worker processes instead. Results are
    the same bit for bit whichever way the members are split.
    lanes: members that share their parameters (no sweep, or one of the
    restitution alone: each lane has its own) are stepped in blocks of
    ``engine.LANES``, together in vector instructions while they fly free
    (:mod:`jackbox.engine.lanes`): the same numbers, faster. None (the
    default): where it pays (:func:`use_lanes`); True: always; False: each
    member alone.
    device: ``"cpu"`` (default), or ``"cuda"``: each member one thread of an
    NVIDIA GPU (:mod:`jackbox.engine.gpu`), the same method and, to round-off,
    the same numbers; it needs the numba-cuda package (``jackbox[cuda]``).
    """
    device = _device(device, scheduler, dask_local, lanes)
    spec = dataclasses.replace(plan(scene, n, perturb, params, sweep, t_end, dt, seed, grid, samples),
                               lanes=None if lanes is None else bool(lanes), device=device)
    # what the study will hold once every member is back: states, samples, starts, params
    S, dof = len(spec.sample_steps), len(spec.scene.dof_names)
    per_member = 8 * (12 * S + 12 + 5 + 2 * dof + len(spec.scene.param_names))
    api.check_memory(spec.n * per_member, f"{spec.n:,} members with {S} samples each",
                     "fewer members (n, --n) or fewer samples (--samples)")
    parts, meta = _execute(run_chunk, spec, chunk, threads, scheduler, dask_local, progress, log)
    return Ensemble(spec=spec, meta=meta, **parts)


#: the smallest twin separation a chaos study takes (scaled: coordinates by L, rates by sqrt(g L)): the
#: states' own round-off is some 1e-16 of their scale, so a separation of 1e-12 is known to about 1e-4
D0_MIN = 1e-12


def chaos(scene, n: int, d0: float = 1e-8, renorm: float | None = None, perturb=None, params=None, t_end=None,
          dt=None, seed: int = 0, *, sweep=None, grid: bool = False, chunk: int | None = None,
          threads: int | None = None, scheduler: str | None = None, dask_local: int | None = None,
          progress: bool = False, log=None, lanes: bool | None = None, device: str = "cpu") -> ChaosStudy:
    """Finite-time Lyapunov exponents of n members from renormalised twin trajectories.

    Each member (start state perturbed as in :func:`ensemble`) runs with a
    twin at scaled distance d0 in a random direction (normal draws of a hash of
    (seed, i), jackbox.engine.draws: not numpy's generators as before, so the
    same seed now gives other directions and starts); every ``renorm`` seconds
    (default: 100 steps) the separation's growth is logged and the twin is
    pulled back to d0 along it (a run shorter than 100 steps: once, at
    its end). Coordinates are scaled by the box's inner
    half-width L (angles by 1 rad), rates by sqrt(g L) (or L / t_end).

    Across an impact the twins can lie on two sides of it for a moment, which
    shows as a jump of the separation; a small d0 keeps that window short.
    lanes: as for :func:`ensemble`: the references and their twins in the
    lanes of blocks of ``engine.LANES // 2`` pairs (the same numbers).
    device: as for :func:`ensemble` (a GPU thread runs a pair of twins).
    """
    device = _device(device, scheduler, dask_local, lanes)
    spec = dataclasses.replace(plan(scene, n, perturb, params, sweep, t_end, dt, seed, grid, None),
                               lanes=None if lanes is None else bool(lanes), device=device)
    if not (is_number(d0) and math.isfinite(d0) and D0_MIN <= d0 < 1e-2):
        raise SimulationError(f"d0 must be a small positive number, from {D0_MIN:g} (twins any closer differ by "
                              f"round-off of their states, and their stretches measure it) to below 1e-2, got {d0!r}")
    if renorm is not None and not (is_number(renorm) and math.isfinite(renorm)):
        raise SimulationError(f"renorm must be a time between dt ({spec.dt:g} s) and t_end "
                              f"({spec.t_end:g} s), got {renorm!r}")
    renorm_steps = min(100, spec.n_steps) if renorm is None else round(float(renorm) / spec.dt)
    if not 1 <= renorm_steps <= spec.n_steps:
        raise SimulationError(f"renorm must be between dt ({spec.dt:g} s) and t_end ({spec.t_end:g} s), got {renorm}")
    spec = dataclasses.replace(spec, renorm_steps=int(renorm_steps), d0=float(d0))
    intervals = -(-spec.n_steps // spec.renorm_steps)
    api.check_memory(spec.n * 8 * (intervals + 3), f"{spec.n:,} twin pairs logging {intervals:,} stretches each",
                     "fewer members (n, --n) or a longer renormalisation interval (renorm, --renorm)")
    parts, meta = _execute(run_chaos_chunk, spec, chunk, threads, scheduler, dask_local, progress, log,
                           steps_per_member=2 * spec.n_steps)
    k = parts["stretch"].shape[1]
    times = np.minimum(np.arange(1, k + 1) * spec.renorm_steps, spec.n_steps) * spec.dt
    return ChaosStudy(spec=spec, times=times, meta=meta, **parts)


def member_trajectory(spec: EnsembleSpec, i: int, record_every: int = 1):
    """Member i of a study run in full through :func:`jackbox.simulate`'s loop."""
    return api.run_prepared(member_run(spec, i, record_every))


def member_run(spec: EnsembleSpec, i: int, record_every: int = 1) -> api.Run:
    """The single run of member i: its start, its parameters, and the study's box speed bound if a sweep moves
    the box (:func:`_study_box_speed`), so that it takes the member's steps to the bit."""
    q0, qd0, p = (a[0] for a in member_inputs(spec, i, i + 1))
    return dataclasses.replace(_base_run(spec), p=p, q=q0, qd=qd0, record_every=int(record_every),
                               box_speed=_study_box_speed(spec))


# ---------------------------------------------------------------------------


def _execute(fn, spec, chunk, threads, scheduler, dask_local, progress, log, steps_per_member=None):
    """Run fn over every member in chunks, here or on Dask; concatenate the parts in order."""
    import numba

    api.check_progress_log(progress, log)
    if threads is not None:     # (before anything is compiled: a typo must not cost a first compile)
        whole = not isinstance(threads, bool) and isinstance(threads, (int, np.integer)) and threads >= 1
        if scheduler or dask_local:
            if not whole:
                raise SimulationError(f"threads must be a whole number of threads per Dask worker (1 or more), "
                                      f"got {threads!r}")
        elif not (whole and threads <= numba.config.NUMBA_NUM_THREADS):
            raise SimulationError(f"threads must be a whole number from 1 to {numba.config.NUMBA_NUM_THREADS}, "
                                  f"got {threads!r}")
    n = spec.n
    steps_per_member = spec.n_steps if steps_per_member is None else steps_per_member
    t_load = time.perf_counter()
    kind = "chaos" if spec.renorm_steps else "ensemble"
    gpu = spec.device == "cuda"
    kernel = _kernel(spec, "setup" if gpu else kind)
    if log and not numba.config.DISABLE_JIT and not loader.is_cached(kernel, "setup" if gpu else kind):
        log(f"compiling the engine's {'member setup' if gpu else kind + ' loop'} (once per machine, for every "
            f"scene) ...")
    compiled = loader.compile_kernel(kernel, "setup" if gpu else kind)
    if gpu:
        from .engine import gpu as gpu_engine
        if log and not gpu_engine.is_cached(kernel.gpu(), kind):
            log(f"compiling the GPU {kind} kernel of {spec.scene.name} (once per machine and model, about a "
                f"minute) ...")
        compiled["gpu"] = gpu_engine.prepare(kernel.gpu(), kind)
    load_seconds = time.perf_counter() - t_load
    if chunk is None:
        chunk = (GPU_CHUNK if gpu else CHUNK_MEMBERS) if (progress or scheduler or dask_local) else n
        if scheduler or dask_local:
            chunk = max(64, min(chunk, -(-n // 32)))
    if isinstance(chunk, bool) or not isinstance(chunk, (int, np.integer)) or chunk < 1:
        raise SimulationError(f"chunk must be a positive integer, got {chunk!r}")
    bounds = [(a, min(a + chunk, n)) for a in range(0, n, chunk)]
    t0 = time.perf_counter()
    if scheduler or dask_local:
        from .distributed import run_on_dask

        parts = run_on_dask(fn, spec, bounds, address=scheduler, n_workers=dask_local,
                            threads_per_worker=threads or 1, progress=progress, log=log)
        used = f"dask {scheduler or f'local, {dask_local} workers'}"
        n_threads = None
    else:
        old = numba.get_num_threads()
        if threads is not None:
            numba.set_num_threads(threads)
        n_threads = numba.get_num_threads()
        bar = progress_bar(n, progress, "member", kind)
        parts = []
        try:
            for a, b in bounds:
                parts.append(fn(spec, a, b))
                bar.update(b - a)
        finally:
            numba.set_num_threads(old)
            bar.close()
        used = f"GPU ({gpu_engine.device_name()})" if gpu else "this process"
    seconds = time.perf_counter() - t0
    # (one part run here, the whole study: its arrays as they are, a copy of 1e6 members' took 0.07 s; a part
    # from Dask is copied, which leaves no array read-only)
    local = len(parts) == 1 and not (scheduler or dask_local)
    merged = parts[0] if local else {key: np.concatenate([p[key] for p in parts]) for key in parts[0]}
    meta = {"jackbox": __version__, "scene": spec.scene.name, "n": n, "seed": spec.seed, "dt": spec.dt,
            "t_end": spec.t_end, "n_steps": spec.n_steps, "chunk": chunk, "where": used, "threads": n_threads,
            "run_seconds": seconds, "load_seconds": load_seconds, "kernel_cache": compiled["cache"],
            "member_steps_per_second": n * steps_per_member / seconds if seconds > 0 else None,
            "device": spec.device, "perturb": dict(spec.perturb), "grid": spec.grid, "params": dict(spec.params),
            "sweep": {k: [lo, hi] for k, lo, hi in spec.sweep},
            "model_hash": loader.model_hash(spec.scene.structure()), "scene_tables": spec.scene.raw}
    if spec.renorm_steps:
        meta |= {"d0": spec.d0, "renorm_steps": spec.renorm_steps}
    return merged, meta


def _device(device, scheduler, dask_local, lanes=None) -> str:
    """The device a study asked for, checked: one clear line where it cannot be had (and lanes: None or a bool)."""
    if lanes is not None and not isinstance(lanes, (bool, np.bool_)):
        raise SimulationError(f"lanes must be True, False or None (where it pays), got {lanes!r}")
    if dask_local is not None and (isinstance(dask_local, bool) or not isinstance(dask_local, (int, np.integer))
                                   or dask_local < 1):
        raise SimulationError(f"dask_local must be a number of worker processes (1 or more), got {dask_local!r}")
    if scheduler is not None and not (isinstance(scheduler, str) and scheduler):
        raise SimulationError(f"scheduler must be a Dask scheduler's address (tcp://HOST:PORT), got {scheduler!r}")
    if not isinstance(device, str) or device not in ("cpu", "cuda"):
        raise SimulationError(f"device must be 'cpu' or 'cuda', got {device!r}")
    if device == "cuda":
        if scheduler or dask_local:
            raise SimulationError("device 'cuda' runs here, on this machine's GPU: not with a Dask scheduler "
                                  "or cluster")
        if lanes:
            raise SimulationError("lanes are the CPU's (SIMD blocks of members): not with device 'cuda'")
        from .engine.gpu import unavailable
        why = unavailable()
        if why:
            raise SimulationError(why)
    return device


def _where(meta: dict) -> str:
    return meta["where"] if meta.get("device") == "cuda" or not meta["threads"] else f"{meta['threads']} thread(s)"


def _kernel(spec: EnsembleSpec, method: str | None = None):
    return loader.kernel_for(spec.scene, method=method)


def _base_run(spec: EnsembleSpec) -> api.Run:
    return api.prepare(spec.scene, spec.t_end, spec.dt, params=dict(spec.params))


def _setup(spec: EnsembleSpec, kernel, first: int) -> K.Setup:
    """What each member's setup reads (:class:`jackbox.engine.Setup`): a few small arrays, not a row per member."""
    scene, run = spec.scene, _base_run(spec)
    dofs = scene.dof_names
    n = len(dofs)
    perturb_at = [n + dofs.index(name[:-4]) if name.endswith("_dot") else dofs.index(name) for name, _ in spec.perturb]
    sweep_at, sweep_axis = [], []
    for axis, (name, _, _) in enumerate(spec.sweep):
        for slot in _param_slots(scene, name):
            sweep_at.append(slot)
            sweep_axis.append(axis)
    # one parameter: spread over the members; two: a square grid (the second the faster)
    sweep_side = 0 if not spec.sweep else spec.n if len(spec.sweep) == 1 else _side(spec.n, 2)
    grid = _side(spec.n, len(spec.perturb)) if spec.grid and spec.perturb else 0
    swept = {scene.param_names[slot] for slot in sweep_at}
    jack_factor, n_points = api.jack_radius_rule(scene)
    twins = spec.renorm_steps > 0
    return K.Setup(
        q=_f8(run.q), qd=_f8(run.qd), p=_f8(run.p),
        tol=api.tolerances(dataclasses.replace(run, box_speed=_study_box_speed(spec)), kernel),
        perturb_at=_i8(perturb_at), perturb_by=_f8([size for _, size in spec.perturb]), grid=int(grid),
        sweep_at=_i8(sweep_at), sweep_axis=_i8(sweep_axis), sweep_lo=_f8([lo for _, lo, _ in spec.sweep]),
        sweep_hi=_f8([hi for _, _, hi in spec.sweep]), sweep_side=int(sweep_side),
        jack_factor=float(jack_factor), n_points=int(n_points), dt=float(run.dt),
        seed=int(spec.seed), first=int(first), d0=float(spec.d0) if twins else 0.0,
        scale=_chaos_scale(spec) if twins else _f8([]), derive=_derive(spec, swept))


def _derive(spec: EnsembleSpec, swept: set[str]) -> np.ndarray:
    """``Setup.derive``: the inertias the swept parameters move (the scene derives them), as slots."""
    scene, given = spec.scene, {name for name, _ in spec.params}
    moved = {derived_inertia_inputs(scene, name) for name in swept} - {None} - given
    if not moved:
        return _i8([])
    at = scene.param_names.index
    box = [at("J_box"), at("m_box"), at("L"), at("w_box")] if "J_box" in moved else [-1] * 4
    jack = ([at("J_jack"), at("m_jack"), at("a_jack"), DERIVE_CROSS if scene.shape == "cross" else DERIVE_SQUARE]
            if "J_jack" in moved else [-1] * 4)
    return _i8(box + jack)


def _set_up(spec: EnsembleSpec, kernel, start: int, stop: int) -> dict[str, np.ndarray]:
    """Members start..stop-1 set up by the engine, in parallel: one row each of q0, qd0, params, tol,
    offset (a chaos twin's, else no columns) and gap (the start's smallest)."""
    m, n, n_p = stop - start, len(spec.scene.dof_names), len(spec.scene.param_names)
    rows = {"q0": np.empty((m, n)), "qd0": np.empty((m, n)), "params": np.empty((m, n_p)),
            "tol": np.empty((m, K.T_SPEED + n)), "offset": np.empty((m, 2 * n if spec.renorm_steps else 0)),
            "gap": np.empty(m)}
    kernel.set_up_members(_setup(spec, kernel, start), rows["q0"], rows["qd0"], rows["params"], rows["tol"],
                          rows["offset"], rows["gap"])
    return rows


def _study_box_speed(spec: EnsembleSpec) -> float | None:
    """The speed bound of a prescribed box that a sweep moves, one for every member (None: the base run's).

    Over the swept ranges (:func:`jackbox.api.box_speed_bound`): valid for each
    member, some 5 ms for the whole study, where each member's own took 0.1 ms
    (12 s for 1e5 members). ``ens.trajectory(i)`` runs with it too.
    """
    scene = spec.scene
    if not scene.prescribed:
        return None
    ranges = {scene.param_names[slot]: (min(lo, hi), max(lo, hi))
              for name, lo, hi in spec.sweep for slot in _param_slots(scene, name)}
    if not set(ranges) & (_motion_names(scene) | {"L", "w_box"}):
        return None
    run = _base_run(spec)
    if _derive(spec, set(ranges)).size and _motion_names(scene) & {"J_box", "J_jack"}:
        return math.inf          # an inertia the sweep moves through the scene's formula: no range known
    return float(api.box_speed_bound(scene, run.p, run.n_steps * run.dt, ranges)[0])


def _check_starts(spec: EnsembleSpec, rows: dict[str, np.ndarray], start: int) -> None:
    """Refuse members whose start (perturbed, or with swept sizes) is inside a wall, before any runs."""
    gaps = rows["gap"]
    L = rows["params"][:, spec.scene.param_names.index("L")]
    bad = np.flatnonzero(gaps < -START_TOL * L)
    if len(bad):
        i = bad[0]
        remedy = " or ".join((["use smaller perturbations"] if spec.perturb else [])
                             + (["narrow the sweep"] if spec.sweep else []))
        raise SimulationError(
            f"{spec.scene.name}: member {start + i}'s {'perturbed ' if spec.perturb else ''}start reaches "
            f"{-gaps[i]:.3g} into a wall or the ground ({len(bad)} such members in members "
            f"{start}..{start + len(gaps) - 1}); {remedy}")


def _motion_names(scene: Scene) -> set[str]:
    """The parameters a prescribed box's motion formulas name (none for a free box)."""
    if not scene.prescribed:
        return set()
    constants = set(BASE_SYMBOLS) | set(scene.user_params) | {"t"}
    names = set()
    for formula in scene.motion:
        names |= parse_formula(formula, constants).names
    return names - {"t"}


def _f8(values) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.float64).reshape(-1)


def _i8(values) -> np.ndarray:
    return np.ascontiguousarray(values, dtype=np.int64).reshape(-1)


def _chaos_scale(spec: EnsembleSpec) -> np.ndarray:
    P = spec.scene.params() | dict(spec.params)
    L, g = P["L"], abs(P["g"])
    v = math.sqrt(g * L) if g > 0 else L / spec.t_end
    dofs = spec.scene.dof_names
    lengths = [1.0 if name.startswith("theta") else L for name in dofs]
    rates = [v / L if name.startswith("theta") else v for name in dofs]
    return np.array(lengths + rates)


def _check_swept(scene: Scene, name: str, slots: list[int], swept: dict[str, str], params: dict) -> None:
    """Refuse a sweep that sets a slot twice (``e`` and ``restitution``, or a sweep and ``params``), or
    a polygon's vertex whose jack's inertia the scene derives. (A swept mass or size moves the box's or
    a cross's or square's inertia with it in each member: ``Setup.derive``.)"""
    for slot in slots:
        slot_name = scene.param_names[slot]
        if slot_name in swept:
            raise SimulationError(f"sweep: {swept[slot_name]!r} and {name!r} both set {slot_name}: sweep it once")
        if slot_name in params:
            raise SimulationError(f"{slot_name} is given both in params and in the sweep over {name!r}: give it once")
        if (scene.shape == "polygon" and derived_inertia_inputs(scene, slot_name) == "J_jack"
                and "J_jack" not in params):
            # (each member's inertia would be the polygon's own, which the members' setup does not compute)
            raise SimulationError(f"sweep: {name} moves the jack's inertia, which the scene derives from the "
                                  "polygon: give jack.inertia in the scene (--set jack.inertia=...) or J_jack in "
                                  "params to sweep it with that inertia fixed")
        swept[slot_name] = name


def _param_slots(scene: Scene, name: str) -> list[int]:
    return [scene.param_names.index(slot) for slot in api.param_slots(scene, name, "sweep")]


def _fallback_lines(fallback: np.ndarray, warnings: np.ndarray) -> list[str]:
    """Where members were first order (the fallback) or a solver did not converge; nothing if nowhere."""
    lines = []
    used = fallback > 0
    if used.any():
        lines.append(f"  fallback (Moreau-Jean, first order): {used.sum()} members, {fallback.sum():.4g} s in all, "
                     f"at most {fallback.max():.4g} s in one (.fallback)")
    if np.any(warnings > 0):
        lines.append(f"  solver warnings: {np.sum(warnings > 0)} members, {warnings.sum()} in all (.warnings); "
                     f"re-run one with .trajectory(i) to see where")
    return lines


def _lost(status: np.ndarray) -> str:
    """How many members did not complete, by status: '3 of 400 members (2 stalled, 1 non-finite)'."""
    bad = status != K.DONE
    kinds = ", ".join(f"{np.sum(status == s)} {STATUS_NAMES.get(int(s), s)}" for s in np.unique(status[bad]))
    return f"{bad.sum()} of {len(status)} members ({kinds})"


def _outcome(status: np.ndarray) -> str:
    done = int(np.sum(status == K.DONE))
    return f"all {done} completed" if done == len(status) else f"{done} completed, NOT COMPLETED: {_lost(status)}"


def _side(n: int, k: int) -> int | None:
    side = round(n ** (1.0 / k))
    for s in (side - 1, side, side + 1):
        if s >= 1 and s ** k == n:
            return s
    return None


def _sample_steps(samples, run: api.Run) -> tuple[int, ...]:
    if samples is None:
        return ()
    try:
        flat = np.ndim(samples) <= 1
        values = list(np.ravel(samples)) if isinstance(samples, (list, tuple, np.ndarray)) else [samples]
    except ValueError:            # (a ragged list)
        flat, values = False, []
    if not flat or not values or not all(is_number(v) for v in values):
        raise SimulationError(f"samples must be a time or a list of times (s), got {samples!r}")
    times = np.array(values, float)
    if not np.all(np.isfinite(times)) or times.min(initial=0.0) < 0 or times.max(initial=0.0) > run.n_steps * run.dt * (1 + 1e-12):
        raise SimulationError(f"samples must be times between 0 and t_end = {run.n_steps * run.dt:g} s")
    steps = [int(round(t / run.dt)) for t in times]
    for k in range(1, len(steps)):
        # samples_q[:, k] is the state at samples[k]: times out of order, or two on one step, would leave
        # the columns at other times than asked for, or fewer of them
        if steps[k] <= steps[k - 1]:
            same = steps[k] == steps[k - 1]
            raise SimulationError(
                f"samples must be increasing times at least one step (dt = {run.dt:g} s) apart: "
                f"{times[k - 1]:g} and {times[k]:g} " + (f"fall on the same step (t = {steps[k] * run.dt:g} s)"
                                                          if same else "are out of order"))
    return tuple(steps)


def _save(path, arrays: dict, spec: EnsembleSpec, meta: dict) -> Path:
    import io

    path = Path(path)
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays, scene=np.array(spec.scene.text),
                        meta=np.array(json.dumps(meta, default=_json_default)))
    write_atomic(path, buf.getvalue())
    return path


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"not JSON serialisable: {type(value).__name__}")
