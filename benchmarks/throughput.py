"""Step throughput, code generation time, and cold/warm start, for every built-in scene.

    python benchmarks/throughput.py [--repeat 5] [--out benchmarks/results]

Prints a table and writes ``throughput.md`` and ``throughput.json``. Times are
medians of ``--repeat`` runs made in this one invocation (the machines are
shared and noisy: compare ratios, not absolute times). Compile time is reported
apart from run time, never mixed in.

* codegen: derive (sympy) + one cse + emit, in process;
* cold start: a new process with an empty kernel cache runs 1 step (import,
  model load, Numba compile);
* warm start: the same with the cache filled (import, load from cache);
* kernel: ns per RK4 step over the scene's whole run, recording every step,
  for the exact method (the default: located impacts, resting contact) and
  the naive one (impulses at step ends);
* reference: ns per step of the lambdified plain-Python twin (0.3 s of the
  scene), which runs the naive method: the speed-up compares like with like.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numba

import jackbox
from codegen.driver import generate


def median_time(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def process_seconds(name: str, cache: str) -> float:
    code = f"import jackbox; jackbox.simulate({name!r}, t_end=1e-3)"
    env = os.environ | {"JACKBOX_CACHE_DIR": cache}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-c", code], env=env, check=True)
    return time.perf_counter() - t0


def bench_scene(name: str, repeat: int) -> dict:
    scene = jackbox.load_scene(name)
    codegen = median_time(lambda: generate(scene), max(1, repeat // 2))
    colds, warms = [], []
    for _ in range(max(1, repeat // 2)):
        with tempfile.TemporaryDirectory() as cache:
            colds.append(process_seconds(name, cache))
            warms.append(process_seconds(name, cache))
    jackbox.simulate(scene, t_end=scene.dt)          # compiled or loaded: not timed below
    jackbox.simulate(scene, t_end=scene.dt, method="naive")
    runs, naive_runs = [], []
    for _ in range(repeat):    # interleaved, so both see the same machine load
        runs.append(jackbox.simulate(scene).meta["kernel"]["run_seconds"])
        naive_runs.append(jackbox.simulate(scene, method="naive").meta["kernel"]["run_seconds"])
    n_steps = round(scene.t_end / scene.dt)
    ref_t = 0.3
    ref_runs = [jackbox.reference.simulate(scene, t_end=ref_t).meta["reference"]["run_seconds"]
                for _ in range(max(1, repeat // 2))]
    kernel_ns = statistics.median(runs) / n_steps * 1e9
    naive_ns = statistics.median(naive_runs) / n_steps * 1e9
    reference_ns = statistics.median(ref_runs) / round(ref_t / scene.dt) * 1e9
    return {
        "scene": name, "steps": n_steps,
        "codegen_s": codegen, "cold_start_s": statistics.median(colds),
        "warm_start_s": statistics.median(warms),
        "kernel_ns_per_step": kernel_ns, "kernel_steps_per_s": 1e9 / kernel_ns,
        "naive_ns_per_step": naive_ns, "exact_over_naive": kernel_ns / naive_ns,
        "reference_ns_per_step": reference_ns, "reference_steps_per_s": 1e9 / reference_ns,
        "speedup": reference_ns / naive_ns,
    }


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5, help="runs per figure (median)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    parser.add_argument("--scenes", nargs="*", default=list(jackbox.builtin_scenes()))
    args = parser.parse_args(argv)
    rows = []
    for name in args.scenes:
        print(f"benchmarking {name} ...", file=sys.stderr)
        rows.append(bench_scene(name, args.repeat))
    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, Numba {numba.__version__}"
    lines = [
        ("| scene | codegen | cold start | warm start | exact ns/step | exact steps/s | naive ns/step "
         "| exact / naive | reference ns/step (naive) | speed-up (naive) |"),
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['codegen_s']:.2f} s | {r['cold_start_s']:.2f} s | {r['warm_start_s']:.2f} s "
                     f"| {r['kernel_ns_per_step']:.0f} | {r['kernel_steps_per_s']:.3g} "
                     f"| {r['naive_ns_per_step']:.0f} | {r['exact_over_naive']:.2f} "
                     f"| {r['reference_ns_per_step']:.0f} | {r['speedup']:.0f}x |")
    table = "\n".join(lines)
    print(table)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "throughput.md").write_text(
        f"Measured by `python benchmarks/throughput.py --repeat {args.repeat}` on {machine}; "
        f"medians of one run of the script.\n\n{table}\n")
    (args.out / "throughput.json").write_text(json.dumps({"machine": machine, "rows": rows}, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
