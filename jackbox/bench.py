"""Step throughput, what each skip gains, the C ceiling and ensemble scaling, in one run.

    jackbox bench [--scenes NAME ...] [--repeat 5] [--out DIR] [--quick] [--no-cold]
    jackbox bench --device cuda [--repeat 3] [--one-go]     (the GPU's figures: jackbox.gpubench)
    python benchmarks/throughput.py ...            (the same, from a checkout)

For every built-in scene (or those named), in one process and one run:

* codegen: derive (sympy) + one cse + emit, in process;
* cold start: a new process with an empty kernel cache runs 1 step (import,
  model load, Numba compile); warm start: the same with the cache filled;
* ns per RK4 step over the scene's whole run (its t_end and dt, impacts
  included), calling the compiled loops directly: the exact method (the
  default kernel), the same kernel built with ``BROAD_PHASE = False`` (every
  gap row every step; it must end in the bit-identical state), the exact
  method recording energy and a sample at every step (same state again), and
  the naive method. Unless said otherwise a run records only its first and
  last state, as the reference below does;
* the lambdified plain-Python reference (method naive), ns per step;
* for ``shaken``: the hand-written C loop of ``benchmarks/ceiling.py`` (RK4
  and all 16 gaps every step), and the kernel's ns per step over it;
* for ``shaken``: an ensemble at 1 and 2 threads, member-steps per second,
  and the 1 -> 2 core efficiency ``rate(2) / (2 rate(1))``;
* for ``drop``: a step with held contacts (the plastic drop once box and jack
  rest, four persistent contacts) against a free one (the same pair falling
  far from every wall), ns per step.

Figures are medians of ``--repeat`` samples, the variants interleaved so that
they see the same machine load: compare ratios, not absolute times, across
machines. Compile time is reported apart from run time, never mixed in.
Writes ``throughput.md`` (one table per concern) and ``throughput.json``.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import math
import os
import platform
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import jackbox

from . import api, loader
from .errors import JackboxError
from .fileio import check_writable, write_atomic
from .scene import builtin_scenes, load_scene

ROOT = Path(jackbox.__file__).resolve().parent.parent
CEILING = ROOT / "benchmarks" / "ceiling.py"
#: the scene of the C ceiling and of the ensemble figures (free flight most of the time)
SHAKEN = "shaken"
TOGGLE = "BROAD_PHASE = True"
#: the figures' sizes: seconds per timed kernel sample, reference length (s of the
#: scene), C loop steps, ensemble members and length (s), length of the resting run (s)
SIZES = {
    "full": {"sample_seconds": 0.2, "reference_t": 0.3, "c_steps": 1_000_000, "ensemble_n": 2000,
             "ensemble_t": 10.0, "rest_t": 10.0},
    "quick": {"sample_seconds": 0.01, "reference_t": 0.02, "c_steps": 20_000, "ensemble_n": 64,
              "ensemble_t": 0.1, "rest_t": 0.05},
}
#: the issue's targets (reported, never asserted)
TARGET_SPEEDUP, TARGET_C_RATIO, TARGET_RATE, TARGET_EFFICIENCY = 500.0, 1.3, 2.5e7, 0.85
#: ensembles in SIMD lanes (issue "Ensembles at the hardware limit"): shaken's rate, and drop e = 0.6's
#: gain over its members stepped alone
TARGET_LANES_RATE, TARGET_LANES_GAIN = 2e8, 5.0
#: a step with held contacts against a free one (issue "Contact that never gives up")
TARGET_REST_RATIO = 10.0
#: the scene of the resting-step figure: the plastic drop, once everything rests
DROP = "drop"


def default_out(quick: bool = False) -> Path:
    """``benchmarks/results`` of the checkout jackbox runs from, else ``./jackbox-bench``.

    A quick run (whose figures mean little) never replaces the committed results:
    it goes to ``./jackbox-bench-quick`` unless ``--out`` says otherwise.
    """
    if quick:
        return Path("jackbox-bench-quick")
    if (ROOT / "pyproject.toml").is_file() and (ROOT / "benchmarks").is_dir():
        return ROOT / "benchmarks" / "results"
    return Path("jackbox-bench")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--scenes", nargs="+", metavar="NAME", default=None,
                        help="built-in scenes to measure (default: all of them)")
    parser.add_argument("--repeat", type=int, default=5, metavar="N",
                        help="samples per figure; the figures are their medians (default: 5)")
    parser.add_argument("--out", type=Path, metavar="DIR", default=None,
                        help="where throughput.md and throughput.json go (default: benchmarks/results "
                             "in a checkout, else ./jackbox-bench; with --quick, ./jackbox-bench-quick)")
    parser.add_argument("--quick", action="store_true",
                        help="tiny sizes, to check that the benchmark runs (its figures mean little)")
    parser.add_argument("--no-cold", action="store_true",
                        help="skip the cold and warm start-up (new processes, a fresh kernel cache each)")
    parser.add_argument("--compile", action="store_true",
                        help="instead: the compile-time table (first run, model edit, every feature, warm "
                             "start; new processes from empty caches), written to compile.md/.json; "
                             "--repeat defaults to 1 here")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu",
                        help="cuda: instead, the GPU's figures (member-steps/s at 1e4-1e6 members against every "
                             "CPU core, agreement with the CPU, kernel compile time), written to gpu.md/.json")
    parser.add_argument("--one-go", action="store_true",
                        help="with --device cuda: also each member in one go (kernel members), against rounds")
    parser.add_argument("--against", type=Path, metavar="CHECKOUT", default=None,
                        help="with --compile: measure another checkout's code side by side")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


def run(args) -> int:
    """Measure everything, print the tables, write the files; 1 when an invariant failed."""
    compiling = getattr(args, "compile", False)
    out = args.out if args.out is not None else default_out(args.quick and not compiling)
    check_writable(out)         # (refused before minutes of measuring, not when the figures are written)
    if compiling:
        from . import compilebench

        argv = ["--repeat", str(args.repeat if "--repeat" in sys.argv else 1)]
        argv += ["--against", str(args.against)] if args.against else []
        argv += ["--out", str(out)]
        return compilebench.main(argv)
    if args.against is not None:
        raise JackboxError("--against goes with --compile")
    if getattr(args, "device", "cpu") == "cuda":
        from . import gpubench

        return gpubench.run(args)
    scenes = list(args.scenes) if args.scenes else list(builtin_scenes())
    unknown = [s for s in scenes if s not in builtin_scenes()]
    if unknown:
        raise JackboxError(f"not a built-in scene: {', '.join(unknown)} "
                           f"(built-in: {', '.join(builtin_scenes())})")
    if args.repeat < 1:
        raise JackboxError(f"--repeat must be at least 1, got {args.repeat}")
    size = SIZES["quick" if args.quick else "full"]
    t_start = time.perf_counter()
    load_start = _load_average()
    rows = [bench_scene(name, args.repeat, size, cold=not args.no_cold) for name in scenes]
    if SHAKEN in scenes:
        shaken = next(r for r in rows if r["scene"] == SHAKEN)
        ceiling = bench_ceiling(shaken, args.repeat, size)
        ens = bench_ensemble(args.repeat, size)
    else:
        ceiling = {"available": False, "reason": f"{SHAKEN} is not among the scenes measured"}
        ens = {"available": False, "reason": f"{SHAKEN} is not among the scenes measured"}
    if DROP in scenes:
        resting = bench_resting(args.repeat, size)
    else:
        resting = {"available": False, "reason": f"{DROP} is not among the scenes measured"}
    result = {
        "jackbox": jackbox.__version__, "command": getattr(args, "command_line", None) or command_line(),
        "machine": machine(), "repeat": args.repeat, "quick": bool(args.quick), "sizes": size,
        "wall_seconds": time.perf_counter() - t_start,
        # other work on the machine skews every figure, the 2-thread ensemble most
        "load_average": {"start": load_start, "end": _load_average()},
        "scenes": rows, "ceiling": ceiling, "ensemble": ens, "resting": resting,
    }
    result["targets"] = targets(result)
    result["invariants_hold"] = all(
        [r["same_final_state_broad_phase"] and r["same_final_state_recording"] for r in rows]
        + ([ens["same_results"]] if ens.get("available") else [])
        + ([resting["still_at_rest"], *(resting[key]["events"] == 0 for key in STRETCHES)]
           if resting.get("available") else []))
    text = markdown(result)
    print(text)
    write_atomic(out / "throughput.md", text)
    write_atomic(out / "throughput.json", json.dumps(result, indent=2) + "\n")
    _say(f"wrote {out / 'throughput.md'} and {out / 'throughput.json'} ({result['wall_seconds']:.0f} s)")
    if not result["invariants_hold"]:
        print("jackbox bench: error: an invariant failed (see same_final_state_* / same_results in "
              "throughput.json): the variants must end in bit-identical states", file=sys.stderr)
        return 1
    return 0


# ---------------------------------------------------------------------------
# one scene


def bench_scene(name: str, repeat: int, size: dict, cold: bool = True) -> dict:
    scene = load_scene(name)
    few = max(1, repeat // 2)
    _say(f"{name}: codegen")
    from codegen import generate       # sympy: imported on its first run, only for this figure

    spec = scene.model_spec()
    # the stages' own times, as generate measures them: not the import of sympy on the first run
    codegen = statistics.median(sum(generate(spec)[1].values()) for _ in range(few))
    colds, warms = [], []
    if cold:
        _say(f"{name}: cold and warm start ({few} x 2 new processes, each cold one compiles)")
        for _ in range(few):
            with tempfile.TemporaryDirectory(prefix="jackbox-bench-") as cache:
                colds.append(start_seconds(name, cache))
                warms.append(start_seconds(name, cache))

    _say(f"{name}: loading the kernels (default, and with BROAD_PHASE = False)")
    model_file = loader.ensure_model(scene)
    text = loader.FLIGHT_SOURCE.read_text()      # read once: both variants from the same source
    if text.count(TOGGLE) != 1:
        raise RuntimeError(f"{loader.FLIGHT_SOURCE} must set {TOGGLE!r} exactly once for the benchmark "
                           f"to build its every-gap-every-step variant")
    kernel = loader.load_kernel(model_file, text)
    loader.compile_kernel(kernel)
    every_gap = loader.load_kernel(model_file, text.replace(TOGGLE, "BROAD_PHASE = False"))
    every_gap_compile = loader.compile_kernel(every_gap, "exact")

    run = api.prepare(scene)
    n = run.n_steps
    variants = {
        "exact": Loop(kernel, run, "exact", lean=True),
        "no_broad_phase": Loop(every_gap, run, "exact", lean=True),
        "record_every_step": Loop(kernel, run, "exact", lean=False),
        "naive": Loop(kernel, run, "naive", lean=True),
    }
    _say(f"{name}: kernel, {n} steps a run, {repeat} samples of each of {', '.join(variants)}")
    finals = {key: v.once() for key, v in variants.items()}        # warm, and the end states
    ns, med = interleaved(variants, repeat, size["sample_seconds"])

    _say(f"{name}: lambdified reference, {size['reference_t']:g} s of the scene x {repeat}")
    from . import reference                   # sympy
    ref_steps = api.prepare(scene, t_end=size["reference_t"]).n_steps
    ref_ns = [reference.simulate(scene, t_end=size["reference_t"], record_every=ref_steps + 1)
              .meta["reference"]["run_seconds"] / ref_steps * 1e9 for _ in range(repeat)]
    reference_ns = statistics.median(ref_ns)

    return {
        "scene": name, "steps": n, "dt": run.dt,
        "codegen_s": codegen,
        "cold_start_s": statistics.median(colds) if colds else None,
        "warm_start_s": statistics.median(warms) if warms else None,
        "exact_ns_per_step": med["exact"], "exact_steps_per_s": 1e9 / med["exact"],
        "no_broad_phase_ns_per_step": med["no_broad_phase"],
        "broad_phase_gain": med["no_broad_phase"] / med["exact"],
        "same_final_state_broad_phase": finals["exact"] == finals["no_broad_phase"],
        "record_every_step_ns_per_step": med["record_every_step"],
        "recording_gain": med["record_every_step"] / med["exact"],
        "same_final_state_recording": finals["exact"] == finals["record_every_step"],
        "naive_ns_per_step": med["naive"], "exact_over_naive": med["exact"] / med["naive"],
        "reference_ns_per_step": reference_ns, "reference_steps": ref_steps,
        "speedup_exact_vs_reference": reference_ns / med["exact"],
        "speedup_naive_vs_reference": reference_ns / med["naive"],
        "no_broad_phase_kernel_cache": every_gap_compile["cache"],
        "runs_per_sample": {key: v.inner for key, v in variants.items()},
        "samples_ns_per_step": ns | {"reference": ref_ns},
    }


def interleaved(loops: dict, repeat: int, seconds: float) -> tuple[dict, dict]:
    """ns per step of each :class:`Loop`, ``repeat`` samples of about ``seconds`` each, the loops
    interleaved so that a busy spell hits them alike; returns the samples and their medians."""
    for v in loops.values():
        v.calibrate(seconds)
    ns = {key: [] for key in loops}
    for _ in range(repeat):
        for key, v in loops.items():
            ns[key].append(v.sample())
    return ns, {key: statistics.median(x) for key, x in ns.items()}


class Loop:
    """One compiled loop on one prepared run, called directly as :func:`jackbox.api.run_prepared` does.

    lean: record only the first and last state (``record_every`` past the end),
    else energy and a sample at every step.
    """

    def __init__(self, kernel, run: api.Run, method: str, lean: bool):
        self.kernel, self.run, self.method = kernel, run, method
        self.record_every = run.n_steps + 1 if lean else 1
        n_rec = run.n_steps // self.record_every + 1 + (run.n_steps % self.record_every != 0)
        self.rec = (np.empty(n_rec), np.empty((n_rec, 6)), np.empty((n_rec, 6)), np.empty(n_rec))
        size = max(1 << 16, 8 * kernel.N_CONTACT)        # never full on the built-in scenes
        self.ev = (np.empty(size), np.empty(size, np.int64), np.zeros(size, np.int64))
        self.tol = api.tolerances(run, kernel) if method == "exact" else None
        self.inner = 1
        self.steps = run.n_steps         # the steps a call of once() takes

    def once(self) -> bytes:
        """Run the scene once; returns the end state (q, qd, contacts at rest, event log) as bytes."""
        k, r = self.kernel, self.run
        q, qd = r.q.copy(), r.qd.copy()
        rec_t, rec_q, rec_qd, rec_e = self.rec
        ev_t, ev_k, ev_kind = self.ev
        if self.method == "exact":
            rest = np.zeros(k.N_CONTACT + api.K.MODE_SLOTS, np.int64)
            i, n_rec, n_ev, status = k.integrate_exact(
                q, qd, rest, r.p, self.tol, 0.0, r.dt, 0, r.n_steps, r.n_steps, self.record_every,
                rec_t, rec_q, rec_qd, rec_e, 0, ev_t, ev_k, ev_kind, 0)
            log = (rest, ev_t[:n_ev], ev_k[:n_ev], ev_kind[:n_ev])
        else:
            i, n_rec, n_ev, status = k.integrate(
                q, qd, r.p, 0.0, r.dt, 0, r.n_steps, r.n_steps, self.record_every,
                rec_t, rec_q, rec_qd, rec_e, 0, ev_t, ev_k, 0)
            log = (ev_t[:n_ev], ev_k[:n_ev])
        if status != k.DONE or i != r.n_steps:
            raise RuntimeError(f"{r.scene.name} ({self.method}): the run stopped at step {i} of "
                               f"{r.n_steps} with status {status}")
        return b"".join(a.tobytes() for a in (q, qd, *log, rec_q[n_rec - 1], rec_qd[n_rec - 1]))

    def calibrate(self, seconds: float) -> None:
        """Runs per sample so that a sample takes about `seconds`."""
        once = _seconds(self.once)
        self.inner = max(1, round(seconds / max(once, 1e-9)))

    def sample(self) -> float:
        """ns per step over `inner` runs of the scene."""
        t0 = time.perf_counter()
        for _ in range(self.inner):
            self.once()
        return (time.perf_counter() - t0) / (self.inner * self.steps) * 1e9


def bench_resting(repeat: int, size: dict) -> dict:
    """ns per step with held contacts against free ones: at rest (the plastic drop, settled, against the
    same pair in free fall, no contact near), and riding a moving floor (shaken at e = 0, against its
    elastic run)."""
    _say(f"{DROP}: a step with held contacts against a free one, {size['rest_t']:g} s of each x {repeat}")
    settled = api.simulate(DROP, t_end=8.0, params={"e": 0.0, "e_ground": 0.0})
    held = settled.held
    at_rest = load_scene(DROP, {"restitution": 0.0, "ground_restitution": 0.0,
                                "initial.q": settled.q[-1].tolist(), "initial.qd": settled.qd[-1].tolist()})
    falling = load_scene(DROP, {"initial.q": [0.0, 1000.0, 0.0, 0.0, 1000.0, 0.0], "initial.qd": [0.0] * 6})
    kernel = loader.kernel_for(at_rest)
    loader.compile_kernel(kernel, "exact")
    riding = load_scene(SHAKEN, {"restitution": 0.0})
    shaken = loader.kernel_for(riding)
    loader.compile_kernel(shaken, "exact")
    loops = {"resting": Loop(kernel, api.prepare(at_rest, t_end=size["rest_t"]), "exact", lean=True),
             "free": Loop(kernel, api.prepare(falling, t_end=size["rest_t"]), "exact", lean=True),
             "riding": Stretch(shaken, api.prepare(riding), RIDE[0], RIDE[1] if size["rest_t"] >= 1 else RIDE[0] + 0.05),
             "corner": Stretch(shaken, api.prepare(riding), CORNER[0],
                               CORNER[1] if size["rest_t"] >= 1 else CORNER[0] + 0.05),
             "elastic": Loop(shaken, api.prepare(load_scene(SHAKEN)), "exact", lean=True)}
    for v in loops.values():
        v.once()                                  # warm
    ns, med = interleaved(loops, repeat, size["sample_seconds"])
    # the run stays at rest: the same contacts held at its end, no event logged
    rest_run = api.simulate(at_rest, t_end=size["rest_t"], record_every=10**6)
    stretches = {key: {"scene": SHAKEN, "from": loops[key].t_from, "to": loops[key].t_to, "held": loops[key].held,
                       "held_ns_per_step": med[key], "elastic_ns_per_step": med["elastic"],
                       "ratio": med[key] / med["elastic"], "events": loops[key].events} for key in STRETCHES}
    return {"available": True, "scene": DROP, "t_end": size["rest_t"], "held_contacts": len(held),
            "held": list(held), "resting_ns_per_step": med["resting"], "free_ns_per_step": med["free"],
            "ratio": med["resting"] / med["free"],
            "still_at_rest": rest_run.held == held and len(rest_run.impact_t) == 0,
            **stretches, "samples_ns_per_step": ns}


#: the stretch (s) of shaken at e = 0 whose steps ride the box's floor: the jack's two tips held on it, no
#: event from 3.246 s to 6.10 s
RIDE = (3.3, 5.8)
#: the stretch (s) of the same run whose jack is held in a corner of the tilted box: four contacts persistent
#: (two tips on the floor, two on the right wall, one tip in the corner), a redundant set (three rows held,
#: the fourth follows them: jackbox.engine.modes.hold_independent), no event from
#: 8.5425 s to 9.4803 s. (The run is chaotic: a change to the engine's round-off moves these stretches, and
#: tests/test_benchmarks_smoke.py says so.)
CORNER = (8.55, 9.47)
#: the held stretches of shaken at e = 0 that bench_resting times, and how the tables name them
STRETCHES = {"riding": "riding a shaken floor", "corner": "held in a corner"}


class Stretch(Loop):
    """Steps ``t_from .. t_to`` of a prepared run (exact method), from the state and contact modes the run
    reaches at t_from (integrated once, here): the held stretch of a run alone."""

    def __init__(self, kernel, run: api.Run, t_from: float, t_to: float):
        super().__init__(kernel, run, "exact", lean=True)
        self.i0, self.i1 = round(t_from / run.dt), round(t_to / run.dt)
        self.t_from, self.t_to = self.i0 * run.dt, self.i1 * run.dt
        self.q, self.qd = run.q.copy(), run.qd.copy()
        self.rest = np.zeros(kernel.N_CONTACT + api.K.MODE_SLOTS, np.int64)
        self._run(self.q, self.qd, self.rest, 0, self.i0)
        self.held = [name for k, name in enumerate(run.scene.constraint_names) if self.rest[k]]
        self.events = 0
        self.steps = self.i1 - self.i0

    def _run(self, q, qd, rest, i0, i1) -> int:
        r, (rec_t, rec_q, rec_qd, rec_e), (ev_t, ev_k, ev_kind) = self.run, self.rec, self.ev
        i, n_rec, n_ev, status = self.kernel.integrate_exact(
            q, qd, rest, r.p, self.tol, 0.0, r.dt, i0, i1, r.n_steps, r.n_steps + 1,
            rec_t, rec_q, rec_qd, rec_e, 0, ev_t, ev_k, ev_kind, 0)
        if status != self.kernel.DONE or i != i1:
            raise RuntimeError(f"{r.scene.name}: the stretch stopped at step {i} of {i1} with status {status}")
        return n_ev

    def once(self) -> bytes:
        q, qd, rest = self.q.copy(), self.qd.copy(), self.rest.copy()
        self.events = self._run(q, qd, rest, self.i0, self.i1)
        return b"".join(a.tobytes() for a in (q, qd, rest))


def start_seconds(name: str, cache: str) -> float:
    """Wall time of a new process that runs one step of `name` with kernel cache `cache`."""
    code = f"import jackbox; jackbox.simulate({name!r}, t_end=1e-3)"
    env = os.environ | {"JACKBOX_CACHE_DIR": cache}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], env=env, check=True)
    return time.perf_counter() - t0


# ---------------------------------------------------------------------------
# the C ceiling and the ensemble (shaken)


def load_ceiling():
    """benchmarks/ceiling.py of the checkout, or None when jackbox is not run from one."""
    if not CEILING.is_file():
        return None
    spec = importlib.util.spec_from_file_location("jackbox_bench_ceiling", CEILING)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def bench_ceiling(shaken: dict, repeat: int, size: dict) -> dict:
    """The hand-written C loop's ns per step, and the kernel's over it (lower is faster)."""
    ceiling = load_ceiling()
    if ceiling is None:
        return {"available": False, "reason": f"{CEILING} not found (jackbox is not run from a checkout)"}
    _say(f"{SHAKEN}: C ceiling, {repeat} x {size['c_steps']} steps")
    try:
        r = ceiling.measure(size["c_steps"], repeat)
    except ceiling.NoCompilerError as exc:
        return {"available": False, "reason": str(exc)}
    except (RuntimeError, OSError, subprocess.CalledProcessError) as exc:
        return {"available": False, "reason": f"the C loop failed: {exc}"}
    c_ns = r["ns_per_step"]
    return {"available": True, "reason": None, "scene": SHAKEN, "c_ns_per_step": c_ns,
            "c_steps": r["steps"], "c_samples_ns_per_step": r["ns_per_step_runs"],
            "compiler": r["version"], "flags": r["flags"],
            "kernel_ns_per_step": shaken["exact_ns_per_step"],
            "kernel_over_c": shaken["exact_ns_per_step"] / c_ns,
            "no_broad_phase_ns_per_step": shaken["no_broad_phase_ns_per_step"],
            "no_broad_phase_over_c": shaken["no_broad_phase_ns_per_step"] / c_ns}


#: the ensembles measured: shaken (free flight most of the time) and drop at e = 0.6 (contact
#: heavy: hundreds of impulses a member, then resting contact), each in lanes and alone
ENSEMBLES = ((SHAKEN, {}, 1.0, 1.0, "ensemble"), (DROP, {"restitution": 0.6}, 0.25, 0.3, "ensemble"),
             (SHAKEN, {}, 0.5, 1.0, "chaos"))
#: the issue's target for a chaos study (twins) of shaken in lanes, 2 threads
TARGET_CHAOS_RATE = 1.5e8


def bench_ensemble(repeat: int, size: dict) -> dict:
    """Member-steps per second of ensembles at 1 and 2 threads, in lanes and alone, interleaved.

    The figures of shaken in lanes (the default) keep their old keys (``threads``,
    ``efficiency``); every study is in ``studies``.
    """
    import numba

    from . import ensemble
    from .scene import load_scene

    if numba.config.NUMBA_NUM_THREADS < 2:
        return {"available": False, "reason": f"Numba has {numba.config.NUMBA_NUM_THREADS} thread(s)"}
    studies = []
    for scene_name, over, n_share, t_share, kind in ENSEMBLES:
        scene = load_scene(scene_name, {k: str(v) for k, v in over.items()})
        n = max(16, int(size["ensemble_n"] * n_share))
        t_end = size["ensemble_t"] * t_share
        study = ensemble.chaos if kind == "chaos" else ensemble.ensemble

        def go(threads, lanes, members=n):
            return study(scene, members, perturb={"theta_jack": 1e-6}, t_end=t_end, seed=0, threads=threads,
                         lanes=lanes)

        _say(f"{scene_name}: {kind}, {n} members x {t_end:g} s, in lanes and alone, 1 and 2 threads x {repeat}")
        go(2, True, 4), go(2, False, 4)              # compiled or loaded from the cache: not timed
        rates = {(lanes, t): [] for lanes in (True, False) for t in (1, 2)}
        seconds = {key: [] for key in rates}
        same, first = True, None
        for _ in range(repeat):
            for lanes, threads in rates:
                e = go(threads, lanes)
                rates[lanes, threads].append(e.meta["member_steps_per_second"])
                seconds[lanes, threads].append(e.meta["run_seconds"])
                first = e if first is None else first
                same = same and np.array_equal(e.stretch if kind == "chaos" else e.q,
                                               first.stretch if kind == "chaos" else first.q, equal_nan=True) \
                    and np.array_equal(e.impacts, first.impacts)
        rate = {key: statistics.median(x) for key, x in rates.items()}
        rows = {("lanes" if lanes else "alone"): {
            str(t): {"member_steps_per_second": rate[lanes, t], "run_seconds": statistics.median(seconds[lanes, t]),
                     "samples_member_steps_per_second": rates[lanes, t]} for t in (1, 2)} for lanes in (True, False)}
        studies.append({"scene": scene_name, "kind": kind, "over": over, "n": n, "t_end": t_end,
                        "member_steps": n * first.spec.n_steps, "impulses_per_member": float(first.impacts.mean()),
                        "rows": rows, "lanes_over_alone": {str(t): rate[True, t] / rate[False, t] for t in (1, 2)},
                        "efficiency": rate[True, 2] / (2 * rate[True, 1]), "same_results": bool(same)})
    shaken = studies[0]
    return {"available": True, "reason": None, "scene": SHAKEN, "n": shaken["n"], "t_end": shaken["t_end"],
            "member_steps": shaken["member_steps"], "perturb": {"theta_jack": 1e-6},
            "threads": shaken["rows"]["lanes"], "efficiency": shaken["efficiency"],
            "same_results": all(st["same_results"] for st in studies), "studies": studies}


# ---------------------------------------------------------------------------
# the report


def targets(result: dict) -> list[dict]:
    """The issue's targets against this run's figures: reported, never asserted."""
    rows = {r["scene"]: r for r in result["scenes"]}
    out = []
    if SHAKEN in rows:
        out.append({"what": f"exact kernel vs lambdified reference, {SHAKEN}", "target": f">= {TARGET_SPEEDUP:g}x",
                    "value": rows[SHAKEN]["speedup_exact_vs_reference"],
                    "met": rows[SHAKEN]["speedup_exact_vs_reference"] >= TARGET_SPEEDUP})
    c = result["ceiling"]
    if c.get("available"):
        # (the C loop checks every gap every step; the kernel's skips are what should beat it)
        out.append({"what": "kernel / C loop", "target": f"<= {TARGET_C_RATIO:g}",
                    "value": c["kernel_over_c"], "met": c["kernel_over_c"] <= TARGET_C_RATIO})
        out.append({"what": "kernel / C loop, with the skips", "target": "< 1 (beats it)",
                    "value": c["kernel_over_c"], "met": c["kernel_over_c"] < 1.0})
    e = result["ensemble"]
    if e.get("available"):
        r2 = e["threads"]["2"]["member_steps_per_second"]
        out.append({"what": f"ensemble member-steps/s, 2 threads, {SHAKEN}", "target": f">= {TARGET_RATE:.2g}",
                    "value": r2, "met": r2 >= TARGET_RATE})
        out.append({"what": "1 -> 2 thread efficiency", "target": f">= {TARGET_EFFICIENCY:.0%}",
                    "value": e["efficiency"], "met": e["efficiency"] >= TARGET_EFFICIENCY})
        out.append({"what": f"ensemble in lanes, 2 threads, {SHAKEN} (issue: members across SIMD lanes)",
                    "target": f">= {TARGET_LANES_RATE:.2g}", "value": r2, "met": r2 >= TARGET_LANES_RATE})
        for st in e["studies"][1:]:
            if st.get("kind") == "chaos":
                rc = st["rows"]["lanes"]["2"]["member_steps_per_second"]
                out.append({"what": f"chaos study (twins) in lanes, 2 threads, {st['scene']}",
                            "target": f">= {TARGET_CHAOS_RATE:.2g}", "value": rc, "met": rc >= TARGET_CHAOS_RATE})
                continue
            gain = st["lanes_over_alone"]["2"]
            out.append({"what": f"ensemble in lanes / alone, 2 threads, {st['scene']} e = {st['over']['restitution']}",
                        "target": f">= {TARGET_LANES_GAIN:g}x", "value": gain, "met": gain >= TARGET_LANES_GAIN})
    r = result.get("resting", {})
    if r.get("available"):
        out.append({"what": f"a step with held contacts / a free step, at rest ({DROP})",
                    "target": f"<= {TARGET_REST_RATIO:g}x", "value": r["ratio"], "met": r["ratio"] <= TARGET_REST_RATIO})
        for key, where in STRETCHES.items():
            ride = r.get(key)
            if ride:
                out.append({"what": f"a step with held contacts / a free step, {where} ({ride['scene']})",
                            "target": f"<= {TARGET_REST_RATIO:g}x", "value": ride["ratio"],
                            "met": ride["ratio"] <= TARGET_REST_RATIO})
    return out


def markdown(result: dict) -> str:
    rows, c, e = result["scenes"], result["ceiling"], result["ensemble"]
    s = result["sizes"]
    lines = [
        "# Throughput",
        "",
        f"Measured by `{result['command']}` on {result['machine']['description']}; medians of one run "
        f"({result['repeat']} sample(s) of each figure, the variants interleaved; "
        f"{result['wall_seconds']:.0f} s in all{', quick sizes' if result['quick'] else ''}; "
        f"1-minute load average {_load(result['load_average'])}).",
        "",
        "Kernel figures are ns per RK4 step over each scene's whole run (its t_end and dt, impacts "
        "included), the compiled loops called directly, recording only the first and last state "
        "unless said otherwise. Compare ratios, not absolute times, across machines.",
        "",
        "## Step time and start-up",
        "",
        "| scene | steps | codegen | cold start | warm start | exact ns/step | exact steps/s "
        "| naive ns/step | exact / naive |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['steps']} | {r['codegen_s']:.2f} s | {_s(r['cold_start_s'])} "
                     f"| {_s(r['warm_start_s'])} | {r['exact_ns_per_step']:.1f} | {r['exact_steps_per_s']:.3g} "
                     f"| {r['naive_ns_per_step']:.1f} | {r['exact_over_naive']:.2f} |")
    lines += [
        "",
        "Cold start: a new process with an empty kernel cache runs one step (import, model, Numba "
        "compile); warm start: the same, kernel loaded from the cache.",
        "",
        "## Against the lambdified reference",
        "",
        "| scene | reference ns/step (naive method, plain Python) | speed-up of the exact kernel "
        "| speed-up of the naive kernel (same method) |",
        "|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['reference_ns_per_step']:.0f} | {r['speedup_exact_vs_reference']:.0f}x "
                     f"| {r['speedup_naive_vs_reference']:.0f}x |")
    lines += [
        "",
        f"The reference runs {s['reference_t']:g} s of each scene (sympy.lambdify, numpy), recording "
        "its first and last state.",
        "",
        "## Broad phase: no gap rows far from contact",
        "",
        "| scene | exact ns/step | without broad phase (every gap every step) | gain | same final state |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['exact_ns_per_step']:.1f} | {r['no_broad_phase_ns_per_step']:.1f} "
                     f"| {r['broad_phase_gain']:.2f}x | {_yes(r['same_final_state_broad_phase'])} |")
    lines += [
        "",
        "Without: the same kernel compiled with `BROAD_PHASE = False`. Both must end in the "
        "bit-identical state.",
        "",
        "## Recording: energy and samples only when recorded",
        "",
        "| scene | first and last state | every step | gain | same final state |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['exact_ns_per_step']:.1f} | {r['record_every_step_ns_per_step']:.1f} "
                     f"| {r['recording_gain']:.2f}x | {_yes(r['same_final_state_recording'])} |")
    lines += ["", "ns per step of the exact kernel; gain: every step / first and last.", "",
              f"## The C ceiling ({SHAKEN})", ""]
    if c.get("available"):
        lines += [
            "| C loop ns/step | kernel ns/step | kernel / C | without broad phase ns/step | without / C |",
            "|---|---|---|---|---|",
            f"| {c['c_ns_per_step']:.1f} | {c['kernel_ns_per_step']:.1f} | {c['kernel_over_c']:.2f} "
            f"| {c['no_broad_phase_ns_per_step']:.1f} | {c['no_broad_phase_over_c']:.2f} |",
            "",
            f"`benchmarks/ceiling/shaken_step.c`: RK4 and all 16 gaps every step, no impact resolved, "
            f"{c['c_steps']} steps from the scene's start; {c['compiler']}, `{' '.join(c['flags'])}`. "
            "Below 1: the kernel is faster.",
        ]
    else:
        lines.append(f"Unavailable: {c['reason']}.")
    lines += ["", "## Ensemble scaling: members in lanes and alone", ""]
    if e.get("available"):
        lines += ["| study | members | threads | in lanes, member-steps/s | alone | lanes / alone | run time in lanes "
                  "| same results |", "|---|---|---|---|---|---|---|---|"]
        for st in e["studies"]:
            what = (("chaos twins, " if st.get("kind") == "chaos" else "") + st["scene"]
                    + "".join(f", {k} = {v:g}" for k, v in st["over"].items()))
            for t in ("1", "2"):
                lanes, alone = st["rows"]["lanes"][t], st["rows"]["alone"][t]
                lines.append(f"| {what} | {st['n']} x {st['t_end']:g} s | {t} | {lanes['member_steps_per_second']:.3g} "
                             f"| {alone['member_steps_per_second']:.3g} | {st['lanes_over_alone'][t]:.2f} "
                             f"| {lanes['run_seconds']:.3g} s | {_yes(st['same_results'])} |")
        lines += [
            "",
            "`jackbox.ensemble.ensemble(scene, n, perturb={'theta_jack': 1e-6}, t_end=..., seed=0, threads=1 or 2, "
            "lanes=True or False)`, and `chaos(...)` with the same arguments (a pair of twins a member: two "
            "member-steps a step). In lanes: blocks of `engine.LANES` members in vector instructions while no "
            "member's step has an event (near a wall, the exact loop's own test), each step with an event or a held "
            f"contact alone (the same bits). Efficiency 1 -> 2 threads in lanes, {SHAKEN}: "
            f"{e['efficiency']:.0%}.",
        ]
    else:
        lines.append(f"Unavailable: {e['reason']}.")
    r = result.get("resting", {})
    lines += ["", "## Held contacts", ""]
    if r.get("available"):
        lines += [
            "| held contacts | held ns/step | free ns/step | held / free | stays held |",
            "|---|---|---|---|---|",
            f"| at rest, {DROP}: {r['held_contacts']} ({', '.join(r['held'])}) | {r['resting_ns_per_step']:.0f} "
            f"| {r['free_ns_per_step']:.1f} | {r['ratio']:.1f}x | {_yes(r['still_at_rest'])} |",
        ]
        for key, where in STRETCHES.items():
            ride = r.get(key)
            if ride:
                lines.append(
                    f"| {where}, {ride['scene']} e = 0: {len(ride['held'])} ({', '.join(ride['held'])}) "
                    f"| {ride['held_ns_per_step']:.0f} | {ride['elastic_ns_per_step']:.1f} | {ride['ratio']:.1f}x "
                    f"| {_yes(ride['events'] == 0)} |")
        ride = r.get("riding")
        lines += [
            "",
            f"At rest: the plastic drop (e = 0) run for 8 s, then {r['t_end']:g} s from its end state, the "
            "box on the ground and the jack on its floor. Its held accelerations vanish, so its steps coast "
            "(every coordinate moves on at its rate), in stretches of up to `loop.CHUNK` steps whose held rows "
            "are read and solved at the stretch's end. Free: the same pair falling far from every wall (the "
            "broad phase skips every gap row).",
        ]
        if ride:
            lines += [
                "",
                f"Riding: {ride['scene']} at e = 0 from {ride['from']:g} s to {ride['to']:g} s, the jack's tips "
                "held on the floor of the shaken box and no event, against the elastic run's steps (free "
                "flight but for 15 impulses): every step integrates the held dynamics (RK4 with the contact "
                "forces at each stage: the rows, their matrix and its factorization four times a step) and "
                "projects onto the held rows.",
            ]
        corner = r.get("corner")
        if corner:
            lines += [
                "",
                f"In a corner: the same run from {corner['from']:g} s to {corner['to']:g} s, the jack wedged in a "
                "corner of the tilted box (one tip in the corner, touching both walls, one on each wall): four "
                "contacts persistent with three degrees of freedom between them, so the contact update holds "
                "three rows and marks the one that depends on them as following (`modes.hold_independent`: "
                "its gap follows theirs by the geometry). Taken on floats too (`flight.ride`, `flight.factor4`).",
            ]
    else:
        lines.append(f"Unavailable: {r.get('reason', 'not measured')}.")
    if result["targets"]:
        lines += ["", "## Targets", ""]
        if result["quick"]:
            lines += ["Quick sizes: these runs are too short for the figures to mean anything.", ""]
        lines += ["| what | target | measured | met |", "|---|---|---|---|"]
        for t in result["targets"]:
            value = f"{t['value']:.0%}" if "efficiency" in t["what"] else f"{t['value']:.3g}"
            lines.append(f"| {t['what']} | {t['target']} | {value} | {_yes(t['met'])} |")
    return "\n".join(lines) + "\n"


def machine() -> dict:
    import numba

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as fh:
            cpu = next((line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")), cpu)
    except OSError:
        pass
    info = {"cpu": cpu, "cores": os.cpu_count(), "numba_threads": numba.config.NUMBA_NUM_THREADS,
            "os": f"{platform.system()} {platform.machine()}", "python": platform.python_version(),
            "numpy": np.__version__, "numba": numba.__version__, "svml": svml()}
    info["description"] = (f"{cpu}, {info['cores']} cores, {info['os']}, Python {info['python']}, "
                           f"NumPy {info['numpy']}, Numba {info['numba']} (SVML {info['svml']})")
    return info


def svml() -> str:
    """Whether Numba vectorises sin and cos with Intel's SVML here: ``on``, or ``off`` and why.

    It needs an llvmlite built with SVML (conda's; the wheels on the package
    index are not) and the library (the ``intel-cmplr-lib-rt`` package).
    jackbox's lanes do not call the library's sine in a vectorised loop (their
    own polynomial, :func:`jackbox.engine.lanes.sincos`), so their figures do
    not depend on it; the line says what the machine had.
    """
    import numba
    from llvmlite import binding

    if numba.config.USING_SVML:
        return "on"
    try:
        patched = binding.targets.has_svml()
    except AttributeError:
        patched = False
    if not patched:
        return "off: this llvmlite is built without it"
    if numba.config.DISABLE_INTEL_SVML:
        return "off: NUMBA_DISABLE_INTEL_SVML"
    return "off: no libsvml (the intel-cmplr-lib-rt package)"


def command_line() -> str:
    """This process's command line as typed: ``python benchmarks/throughput.py ...`` or ``jackbox bench ...``."""
    argv0 = sys.argv[0]
    head = ["python", argv0] if argv0.endswith(".py") else [Path(argv0).name]
    return " ".join(shlex.quote(a) for a in head + sys.argv[1:])


def _seconds(fn) -> float:
    t0 = time.perf_counter()
    fn()
    return time.perf_counter() - t0


def _load_average() -> float | None:
    try:
        return os.getloadavg()[0]
    except (AttributeError, OSError):
        return None


def _load(load: dict) -> str:
    if load["start"] is None:
        return "unknown"
    return f"{load['start']:.2f} at the start, {load['end']:.2f} at the end"


def _s(x) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{x:.2f} s"


def _yes(flag: bool) -> str:
    return "yes" if flag else "**NO**"


_T0 = time.perf_counter()


def _say(message: str) -> None:
    print(f"bench [{time.perf_counter() - _T0:5.0f} s]: {message}", file=sys.stderr, flush=True)


if __name__ == "__main__":
    sys.exit(main())
