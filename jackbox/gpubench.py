"""The GPU's figures: member-steps per second against every CPU core, agreement, compile time.

    jackbox bench --device cuda [--repeat 3] [--quick] [--one-go] [--out DIR]

In one run, on one machine (an NVIDIA GPU and the CPU cores beside it), each
GPU study in rounds (:func:`jackbox.engine.gpu.run_rounds`, the default: members
near contact packed into warps of their own) and, with ``--one-go``, also each
member from start to end in one thread (kernel ``members``):

* compile: each kernel the run needs (``alone``, ``flying`` and ``calming`` of every
  built-in scene, ``members`` with ``--one-go``, ``twins`` of shaken) compiled in a new process
  (cold: NVVM and the PTX assembler; the CPU's parts are timed apart; side by
  side, one process a kernel, while the CPU's engine compiles in this one;
  a kernel already cached is compiled in a fresh cache), then loaded in
  another (cached, one after the other); with each kernel's registers and
  local memory per thread;
* agreement: every built-in scene, 1000 members (perturbed starts) for 1 s on
  the GPU and on the CPU: the largest difference of the final coordinates and
  rates, and whether every member has the same impulse count; the FTLEs of a
  chaos study of shaken (1000 twin pairs, 1 s);
* throughput: ``shaken`` (free flight most of the time) at n = 1e4, 1e5, 1e6
  members x 10 s and ``drop`` with restitution 0.6 (contact heavy) at 1e5
  members x 3 s, on the GPU, against the CPU on all its cores (the CPU's best
  way: lanes where they apply) over fewer members (its rate does not depend on
  n); member-steps per second of the whole study (setup, copies, run); with
  ``--one-go``, shaken at the largest n and drop e = 0.6 again in one go;
* divergence: drop e = 0.6 with every member the same (all threads of a warp
  take the same branches) against perturbed members (they settle at
  different times), the same n (one sample each: the slowest study of the
  run), with ``--one-go`` the perturbed ones in one go too.

Writes ``gpu.md`` and ``gpu.json`` beside ``throughput.md`` (``gpu.json`` after
each part too, so that a run cut short keeps what it measured).
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import time

import numpy as np

import jackbox

from .fileio import write_atomic

#: the issue's targets (reported, never asserted)
TARGET_SHAKEN_RATE, TARGET_DROP_RATE, TARGET_OVER_CPU = 1e10, 1e9, 100.0
TARGET_COLD, TARGET_CACHED = 60.0, 2.0
SIZES = {
    "full": {"shaken_n": (10_000, 100_000, 1_000_000), "shaken_t": 10.0, "drop_n": 100_000, "drop_t": 3.0,
             "cpu_shaken_n": 100_000, "cpu_drop_n": 4_000, "agree_n": 1000, "agree_t": 1.0},
    "quick": {"shaken_n": (256,), "shaken_t": 0.1, "drop_n": 256, "drop_t": 0.1,
              "cpu_shaken_n": 64, "cpu_drop_n": 32, "agree_n": 16, "agree_t": 0.05},
}
DROP_OVER = {"restitution": 0.6}
PERTURB = {"theta_jack": 1e-6}
#: kernels compiled cold, side by side: (scene, kernel); ``members`` with --one-go only
KERNELS = tuple((scene, name) for scene in ("shaken", "drop", "spring")
                for name in ("members", "alone", "flying", "calming")) + (("shaken", "smallest_gaps"), ("shaken", "twins"))


def kernels_for(one_go: bool) -> tuple:
    return tuple(k for k in KERNELS if one_go or k[1] != "members")

_COMPILE = """
import json, sys, time, warnings
warnings.simplefilter("ignore")
t0 = time.perf_counter()
from jackbox import loader
from jackbox.engine import gpu
from jackbox.scene import load_scene
kernel = loader.kernel_for(load_scene(sys.argv[1]))
kernels = kernel.gpu()
t1 = time.perf_counter()
cached = gpu.is_cached(kernels, sys.argv[2])
result = gpu.prepare(kernels, sys.argv[2])
seconds = time.perf_counter() - t1
kernel, real = getattr(kernels, sys.argv[2]), not gpu._simulated()
one = lambda per: next(iter(per.values())) if isinstance(per, dict) else per     # (one signature compiled)
print(json.dumps({"seconds": seconds, "before": t1 - t0, "cached_before": cached, "cache": result,
                  "registers": one(kernel.get_regs_per_thread()) if real else None,
                  "local_bytes": one(kernel.get_local_mem_per_thread()) if real else None}))
"""


def run(args) -> int:
    """Measure, print the tables, write gpu.md and gpu.json; 1 when the GPU and the CPU disagree."""
    from . import bench
    from .engine import gpu
    from .errors import JackboxError

    why = gpu.unavailable()
    if why:
        raise JackboxError(why)
    size = SIZES["quick" if args.quick else "full"]
    out = args.out if args.out is not None else bench.default_out(args.quick)
    repeat = max(1, args.repeat)
    one_go = bool(getattr(args, "one_go", False))
    t_start = time.perf_counter()
    result = {"jackbox": jackbox.__version__, "command": bench.command_line(), "machine": machine(),
              "out_of_line": list(gpu.MORE_OUT_OF_LINE),
              "repeat": repeat, "quick": bool(args.quick), "one_go": one_go, "sizes": size}
    out.mkdir(parents=True, exist_ok=True)

    def part(key, value):
        result[key] = value
        write_atomic(out / "gpu.json", json.dumps(result, indent=2, default=float) + "\n")

    part("compile", compile_times(lambda: warm_cpu(size), kernels_for(one_go)))
    part("agreement", agreement(size, one_go))
    part("throughput", throughput(size, repeat, one_go))
    part("divergence", divergence(size, one_go))
    result["wall_seconds"] = time.perf_counter() - t_start
    result["targets"] = targets(result)
    agree = result["agreement"]
    result["agrees"] = all(a["same_impulses"] and a["max_state_difference"] <= 1e-10 for a in agree["scenes"]) \
        and agree["chaos"]["max_ftle_difference"] <= 1e-6
    text = markdown(result)
    print(text)
    write_atomic(out / "gpu.md", text)
    write_atomic(out / "gpu.json", json.dumps(result, indent=2, default=float) + "\n")
    bench._say(f"wrote {out / 'gpu.md'} and {out / 'gpu.json'} ({result['wall_seconds']:.0f} s)")
    if not result["agrees"]:
        print("jackbox bench: error: the GPU's members differ from the CPU's by more than 1e-10 (or their impulse "
              "counts, or the FTLEs by more than 1e-6): see gpu.json", file=sys.stderr)
        return 1
    return 0


def _study(scene: str, n: int, t_end: float, device: str, over=None, perturb=PERTURB, chaos=False):
    from . import ensemble
    from .scene import load_scene

    scene = load_scene(scene, {k: str(v) for k, v in (over or {}).items()})
    if chaos:
        return ensemble.chaos(scene, n, t_end=t_end, renorm=min(0.1, t_end), perturb=perturb, device=device)
    return ensemble.ensemble(scene, n, t_end=t_end, perturb=perturb, device=device)


def warm_cpu(size: dict) -> None:
    """Every CPU part the run needs compiled or loaded (lanes and the lazy stages included), not timed."""
    from . import bench

    bench._say("the CPU's engine and lanes (compiled once, or loaded)")
    for scene, over in (("shaken", None), ("drop", DROP_OVER), ("spring", None)):
        _study(scene, 32, size["agree_t"], "cpu", over)
    from . import ensemble
    ensemble.ensemble("shaken", 32, t_end=0.01, perturb=PERTURB, lanes=True)
    _study("shaken", 32, 0.01, "cpu", chaos=True)


def _compile(scene: str, name: str, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-c", _COMPILE, scene, name], stdout=subprocess.PIPE, text=True, env=env)


def _printed(proc: subprocess.Popen) -> dict:
    return json.loads(proc.communicate()[0].strip().splitlines()[-1])


def _cached_here(scene: str, name: str) -> bool:
    from . import loader
    from .engine import gpu
    from .scene import load_scene

    return gpu.is_cached(loader.kernel_for(load_scene(scene)).gpu(), name)


def compile_times(meanwhile=None, kernels=KERNELS) -> dict:
    """Each kernel compiled in a new process (side by side), then loaded from the cache in another (one after
    the other); ``meanwhile`` runs here while the cold ones compile.

    A kernel already in the cache is compiled cold all the same, into a fresh cache of its own (jackbox's,
    ``JACKBOX_CACHE_DIR``, where the kernel file goes, and Numba's, where numba-cuda looks first; the CPU's
    parts then compile there too, timed apart): a second run of the benchmark on one machine measures what
    the first did. (With a fresh ``NUMBA_CACHE_DIR`` alone the compile was cold, but ``gpu.is_cached`` looked
    beside the kernel file only and called it a hit: the H100 run of 5eecd97 showed two cold compiles,
    57.85 s and 56.69 s, as "found cached". It now asks numba-cuda's cache where it looks.)
    """
    import tempfile

    from . import bench

    bench._say(f"compiling {len(kernels)} GPU kernels cold, one process each, side by side")
    base = dict(os.environ, PYTHONWARNINGS="ignore")
    with tempfile.TemporaryDirectory(prefix="jackbox-cold-") as fresh:
        envs = [dict(base, JACKBOX_CACHE_DIR=fresh, NUMBA_CACHE_DIR=fresh) if _cached_here(scene, name) else base
                for scene, name in kernels]
        procs = [_compile(scene, name, env) for (scene, name), env in zip(kernels, envs)]
        if meanwhile is not None:       # (each prints one line when it ends: nothing waits on a full pipe)
            meanwhile()
        cold = [_printed(proc) for proc in procs]
    bench._say("loading them from the cache, one process after another")
    warm = [_printed(_compile(scene, name, base)) for scene, name in kernels]
    rows = [{"scene": scene, "kernel": name, "cold_seconds": c["seconds"], "cold_cache": c["cache"],
             "cold_in_fresh_cache": e is not base, "cold_process_before": c["before"],
             "cached_seconds": w["seconds"], "cached_cache": w["cache"],
             "cached_process_seconds": w["seconds"] + w["before"], "registers": w["registers"],
             "local_bytes": w["local_bytes"]}
            for (scene, name), c, w, e in zip(kernels, cold, warm, envs)]
    return {"kernels": rows}


def _was_cold(row: dict) -> bool:
    """Whether a kernel's first compile was cold: a miss, or compiled in a fresh cache (which runs before
    gpu.is_cached asked numba-cuda where its cache is could call a hit)."""
    return row["cold_cache"] == "miss" or bool(row.get("cold_in_fresh_cache"))


def agreement(size: dict, one_go: bool = False) -> dict:
    """Every built-in scene on the GPU and the CPU: final states, impulse counts; shaken's FTLEs."""
    from . import bench
    from .engine import gpu
    from .scene import builtin_scenes

    n, t = size["agree_n"], size["agree_t"]
    scenes = []
    for scene in builtin_scenes():
        bench._say(f"agreement: {scene}, {n} members x {t:g} s, GPU and CPU")
        over = DROP_OVER if scene == "drop" else None
        a = _study(scene, n, t, "cpu", over, perturb={"theta_jack": 0.3})
        for rounds in (False, True) if one_go else (True,):
            gpu.ROUNDS, saved = rounds, gpu.ROUNDS
            try:
                b = _study(scene, n, t, "cuda", over, perturb={"theta_jack": 0.3})
            finally:
                gpu.ROUNDS = saved
            scenes.append({"scene": scene, "rounds": rounds, "n": n, "t_end": t, "over": over or {},
                           "max_state_difference": float(max(np.nanmax(np.abs(a.q - b.q)),
                                                             np.nanmax(np.abs(a.qd - b.qd)))),
                           "same_impulses": bool(np.array_equal(a.impacts, b.impacts)),
                           "same_status": bool(np.array_equal(a.status, b.status)),
                           "impulses_per_member": float(a.impacts.mean())})
    bench._say(f"agreement: shaken chaos, {n} twin pairs x {t:g} s")
    a = _study("shaken", n, t, "cpu", chaos=True, perturb={"theta_jack": 0.3})
    b = _study("shaken", n, t, "cuda", chaos=True, perturb={"theta_jack": 0.3})
    chaos = {"n": n, "t_end": t, "max_ftle_difference": float(np.nanmax(np.abs(a.ftle - b.ftle))),
             "ftle_mean": float(np.nanmean(a.ftle))}
    return {"scenes": scenes, "chaos": chaos}


def _rates(scene: str, n: int, t: float, device: str, repeat: int, over=None, perturb=PERTURB,
           rounds: bool = True) -> dict:
    from .engine import gpu

    gpu.ROUNDS, saved = rounds, gpu.ROUNDS
    try:
        return _rates_now(scene, n, t, device, repeat, over, perturb) | {"rounds": rounds}
    finally:
        gpu.ROUNDS = saved


def _rates_now(scene, n, t, device, repeat, over, perturb) -> dict:
    _study(scene, min(n, 64), min(t, 0.01), device, over, perturb)         # loaded, not timed
    rates, seconds = [], []
    for _ in range(repeat):
        e = _study(scene, n, t, device, over, perturb)
        rates.append(e.meta["member_steps_per_second"])
        seconds.append(e.meta["run_seconds"])
    return {"scene": scene, "over": over or {}, "n": n, "t_end": t, "device": device,
            "member_steps_per_second": statistics.median(rates), "run_seconds": statistics.median(seconds),
            "samples": rates, "impulses_per_member": float(e.impacts.mean()),
            "completed": int(e.completed.sum())}


def throughput(size: dict, repeat: int, one_go: bool = False) -> dict:
    """GPU rows at each n (in rounds), CPU rows (all cores) over fewer members, the same studies; with one_go,
    the largest GPU studies again in one go."""
    from . import bench

    rows = []
    for n in size["shaken_n"]:
        bench._say(f"throughput: shaken, {n} members x {size['shaken_t']:g} s on the GPU x {repeat}")
        rows.append(_rates("shaken", n, size["shaken_t"], "cuda", repeat))
    bench._say(f"throughput: shaken, {size['cpu_shaken_n']} members on the CPU x {repeat}")
    rows.append(_rates("shaken", size["cpu_shaken_n"], size["shaken_t"], "cpu", repeat))
    bench._say(f"throughput: drop e = 0.6, {size['drop_n']} members on the GPU x {repeat}")
    rows.append(_rates("drop", size["drop_n"], size["drop_t"], "cuda", repeat, DROP_OVER))
    bench._say(f"throughput: drop e = 0.6, {size['cpu_drop_n']} members on the CPU x {repeat}")
    rows.append(_rates("drop", size["cpu_drop_n"], size["drop_t"], "cpu", repeat, DROP_OVER))
    if one_go:
        bench._say("throughput: the same GPU studies in one go (kernel members)")
        rows.append(_rates("shaken", size["shaken_n"][-1], size["shaken_t"], "cuda", repeat, rounds=False))
        rows.append(_rates("drop", size["drop_n"], size["drop_t"], "cuda", repeat, DROP_OVER, rounds=False))

    def best(scene, device):
        return max((r for r in rows if r["scene"] == scene and r["device"] == device),
                   key=lambda r: r["member_steps_per_second"])["member_steps_per_second"]

    return {"rows": rows, "cpu_threads": _threads(),
            "gpu_over_cpu": {scene: best(scene, "cuda") / best(scene, "cpu") for scene in ("shaken", "drop")}}


def divergence(size: dict, one_go: bool = False) -> dict:
    """drop e = 0.6 with identical members (no divergence in a warp) against perturbed ones, the same n, in
    rounds; with one_go, the perturbed ones in one go too. One sample each."""
    from . import bench

    n, t = size["drop_n"], size["drop_t"]
    spread = {"theta_jack": 0.3, "x_jack": 0.2}
    bench._say(f"divergence: drop e = 0.6, {n} members on the GPU, identical, then perturbed")
    same = _rates("drop", n, t, "cuda", 1, DROP_OVER, perturb={})
    rounds = _rates("drop", n, t, "cuda", 1, DROP_OVER, perturb=spread)
    out = {"identical": same, "perturbed_rounds": rounds,
           "cost_rounds": same["member_steps_per_second"] / rounds["member_steps_per_second"]}
    if one_go:
        perturbed = _rates("drop", n, t, "cuda", 1, DROP_OVER, perturb=spread, rounds=False)
        out |= {"perturbed": perturbed, "cost": same["member_steps_per_second"] / perturbed["member_steps_per_second"]}
    return out


def targets(result: dict) -> list[dict]:
    rows = result["throughput"]["rows"]

    def rate(scene, n):
        return max((r["member_steps_per_second"] for r in rows if r["scene"] == scene and r["device"] == "cuda"
                    and r["n"] == n), default=float("nan"))

    size = result["sizes"]
    comp = result["compile"]["kernels"]
    cold = max((r["cold_seconds"] for r in comp if _was_cold(r)), default=float("nan"))
    return [
        {"what": f"shaken, {size['shaken_n'][-1]:.0e} members x {size['shaken_t']:g} s, member-steps/s",
         "target": f">= {TARGET_SHAKEN_RATE:.0e}", "value": rate("shaken", size["shaken_n"][-1]),
         "met": rate("shaken", size["shaken_n"][-1]) >= TARGET_SHAKEN_RATE},
        {"what": f"drop e = 0.6, {size['drop_n']:.0e} members, member-steps/s", "target": f">= {TARGET_DROP_RATE:.0e}",
         "value": rate("drop", size["drop_n"]), "met": rate("drop", size["drop_n"]) >= TARGET_DROP_RATE},
        {"what": "shaken, GPU over all CPU cores", "target": f">= {TARGET_OVER_CPU:g}x",
         "value": result["throughput"]["gpu_over_cpu"]["shaken"],
         "met": result["throughput"]["gpu_over_cpu"]["shaken"] >= TARGET_OVER_CPU},
        {"what": "GPU kernel compile, cold (slowest), s", "target": f"<= {TARGET_COLD:g}",
         "value": cold, "met": cold <= TARGET_COLD},
        {"what": "GPU kernel load, cached (slowest), s", "target": f"<= {TARGET_CACHED:g}",
         "value": max(r["cached_seconds"] for r in comp),
         "met": max(r["cached_seconds"] for r in comp) <= TARGET_CACHED},
    ]


def markdown(result: dict) -> str:
    m = result["machine"]
    lines = ["# jackbox on a GPU", "",
             f"`{result['command']}` on {m['gpu']} (driver {m['driver']}) and {m['cpu']} ({m['cores']} cores, "
             f"{result['throughput']['cpu_threads']} Numba threads); numba-cuda {m['numba_cuda']}, Numba "
             f"{m['numba']}, float64, the exact method. Medians of {result['repeat']}; {result['wall_seconds']:.0f} s "
             "in all.", ""]
    if "out_of_line" in result:
        lines += [f"Kept out of line besides the stages: {', '.join(result['out_of_line']) or 'nothing'}.", ""]
    if result.get("note"):
        lines += [f"Note: {result['note']}.", ""]
    if result["quick"]:
        lines += ["Quick sizes: these runs are too short for the figures to mean anything.", ""]
    lines += ["## Throughput (member-steps per second, the whole study: setup, copies, run)", "",
              "| study | device | members | s simulated | member-steps/s | impulses per member |",
              "|---|---|---|---|---|---|"]
    for r in result["throughput"]["rows"]:
        what = r["scene"] + (" e = 0.6" if r["over"] else "")
        device = r["device"] + (", one go" if r["device"] == "cuda" and not r.get("rounds") else "")
        lines.append(f"| {what} | {device} | {r['n']:,} | {r['t_end']:g} | {r['member_steps_per_second']:.3g} "
                     f"| {r['impulses_per_member']:.3g} |")
    ratio = result["throughput"]["gpu_over_cpu"]
    lines += ["", f"GPU over all CPU cores: shaken {ratio['shaken']:.0f}x, drop e = 0.6 {ratio['drop']:.0f}x.", ""]
    d = result["divergence"]
    spread = (f"{d['perturbed']['member_steps_per_second']:.3g} in one go, " if "perturbed" in d else "") \
        + f"{d['perturbed_rounds']['member_steps_per_second']:.3g} in rounds"
    costs = (f"{d['cost']:.2f}x in one go, " if "cost" in d else "") + f"{d['cost_rounds']:.2f}x in rounds"
    lines += ["## Divergence (drop e = 0.6, the same n)", "",
              f"Identical members {d['identical']['member_steps_per_second']:.3g} member-steps/s, perturbed members "
              f"(theta_jack +-0.3, x_jack +-0.2) {spread}: divergence costs {costs}.", ""]
    lines += ["## Agreement with the CPU", "",
              "| scene | members | s | largest state difference | same impulse counts | same status |",
              "|---|---|---|---|---|---|"]
    for a in result["agreement"]["scenes"]:
        lines.append(f"| {a['scene']}{' (rounds)' if a.get('rounds') else ''} | {a['n']} | {a['t_end']:g} | {a['max_state_difference']:.2g} | "
                     f"{'yes' if a['same_impulses'] else '**NO**'} | {'yes' if a['same_status'] else '**NO**'} |")
    c = result["agreement"]["chaos"]
    lines += ["", f"Chaos study of shaken ({c['n']} twin pairs, {c['t_end']:g} s): FTLEs differ by at most "
                  f"{c['max_ftle_difference']:.2g} (mean FTLE {c['ftle_mean']:.3g}).", ""]
    lines += ["## Compile (cold: one new process a kernel, side by side; cached: one after another; the CPU's "
              "parts timed apart)", "",
              "| kernel | cold | cached | registers | local memory |", "|---|---|---|---|---|"]
    for r in result["compile"]["kernels"]:
        cold = f"{r['cold_seconds']:.1f} s" if _was_cold(r) else "(found cached: not measured)"
        lines.append(f"| {r['scene']} {r['kernel']} | {cold} | {r['cached_seconds']:.2f} s "
                     f"| {r['registers']} | {(r['local_bytes'] or 0) / 1024:.1f} KiB |")
    lines += ["", "## Targets", "", "| what | target | measured | met |", "|---|---|---|---|"]
    for t in result["targets"]:
        value, met = (f"{t['value']:.3g}", "yes" if t["met"] else "**NO**") if t["value"] == t["value"] \
            else ("not measured", "?")
        lines.append(f"| {t['what']} | {t['target']} | {value} | {met} |")
    return "\n".join(lines) + "\n"


def machine() -> dict:
    import numba
    from importlib.metadata import version

    from . import bench
    from .engine import gpu

    info = bench.machine()
    info["gpu"] = gpu.device_name()
    info["numba_cuda"] = version("numba-cuda")
    try:
        info["driver"] = subprocess.run(["nvidia-smi", "--query-gpu=driver_version", "--format=csv,noheader"],
                                        capture_output=True, text=True, timeout=30).stdout.strip() or "unknown"
    except (OSError, subprocess.SubprocessError):
        info["driver"] = "unknown"
    info["numba"] = numba.__version__
    return info


def _threads() -> int:
    import numba
    return numba.get_num_threads()

