"""What one step of an ensemble block's lanes costs, and what share of the machine's float64 peak it reaches.

    python benchmarks/lane_step.py [--scene shaken] [--repeat 5] [--out benchmarks/results]

The lanes of the scene's model (``jackbox/engine/lanes.py`` bound to the
generated functions, the text :func:`jackbox.loader.binding_parts` writes) are
compiled here without the cache and stepped on one block of LANES members of
the scene's ensemble (``theta_jack`` perturbed by 1e-6) in free flight, at
dt = 1e-6 so that no lane comes near a wall (every step is the vector loop,
the gap bound lowered each step and recomputed for the block when it runs
low). Reports ns per lane-step (median of ``--repeat``), the floating-point
operations per lane-step (counted in the vectorised step loop's LLVM IR: each
vector add, subtract, multiply or divide is one operation per lane), and the
share of the peak: cores x clock x 16 float64 operations per cycle (AVX-512 on
two 256-bit add and two 256-bit multiply pipes, no fused multiply-add, which
jackbox does not use: a contraction would change the bits). Writes
``lane_step.json`` and ``lane_step.md``.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import time
from pathlib import Path

import numba
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from jackbox import engine, loader  # noqa: E402
from jackbox.ensemble import _kernel, _set_up, plan  # noqa: E402

#: float64 operations per cycle and core that the peak counts (see the module's docstring)
OPS_PER_CYCLE = 16


def compiled_lanes(scene: str):
    """The model's lanes part, compiled here (no cache), as Numba functions callable from Python (the lanes and
    the table of terms of time they read); and the lanes' IR."""
    text = loader.binding_parts((loader.GENERATED_DIR / f"{scene}.py").read_text(), lanes=True)["lanes"]
    text = text.replace("cache=True", "cache=False").split("COMPILED = ")[0]
    space: dict = {}
    exec(compile(text, f"lanes part of {scene}", "exec"), space)
    ir = numba.cfunc(engine.SIGNATURES["lanes"])(space["lanes"]).inspect_llvm()
    return numba.njit(space["lanes"]), numba.njit(space["time_table"]), ir


def step_loop_ops(ir: str) -> float:
    """Floating-point operations per lane in the vectorised step loop (the vector body with the speed bound's abs)."""
    best = 0.0
    for block in re.split(r"\n(?=[\w.]+:)", ir):
        if not block.startswith("vector.body") or not re.search(r"@llvm\.fabs\.v\d+f64", block):
            continue
        ops = re.findall(r"= (?:fadd|fsub|fmul|fdiv|fneg) (?:fast )?<(\d+) x double>", block)
        lanes = max((int(w) for w in ops), default=1)
        best = max(best, sum(int(w) for w in ops) / lanes)
    return best


def clock_ghz() -> float | None:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("cpu MHz"):
                return float(line.split(":")[1]) / 1000.0
    except OSError:
        pass
    return None


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default="shaken")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--steps", type=int, default=100_000)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent / "results")
    args = parser.parse_args(argv)

    W = engine.LANES
    spec = plan(args.scene, W, perturb={"theta_jack": 1e-6})
    rows = _set_up(spec, _kernel(spec), 0, W)
    lanes, time_table, ir = compiled_lanes(args.scene)
    p, tol = rows["params"][0].copy(), rows["tol"][0].copy()

    def fresh():
        S = np.zeros(engine.records.BLOCK_ROWS * W)
        for d in range(6):
            S[d * W:(d + 1) * W] = rows["q0"][:, d]
            S[(6 + d) * W:(7 + d) * W] = rows["qd0"][:, d]
        S[engine.records.BOUND_ROW * W:(engine.records.BOUND_ROW + 1) * W] = np.nan
        return S

    live, quiet = np.ones(W, np.int64), np.zeros(W, np.int64)
    dt = 1e-6
    never = numba.njit(lambda t, t_next, dt, S, lane, at, to, p, tol: -1)   # (free flight: no event to take)
    tab = np.empty(2 * args.steps * time_table(0.0, dt, 0, p, np.empty(0)))    # (a study's table of its steps)
    time_table(0.0, dt, args.steps, p, tab)
    lanes(0.0, dt, 0, 10, fresh(), p, tol, live, quiet, tab, never)
    times = []
    for _ in range(args.repeat):
        S = fresh()
        t0 = time.perf_counter()
        reached = lanes(0.0, dt, 0, args.steps, S, p, tol, live, quiet, tab, never)
        times.append(time.perf_counter() - t0)
        if reached != args.steps:
            raise SystemExit(f"the block stopped at step {reached}: not free flight")
    ns = statistics.median(times) / (args.steps * W) * 1e9
    ops = step_loop_ops(ir)
    ghz = clock_ghz()
    share = ops / ns / (ghz * OPS_PER_CYCLE) if ghz and ops else None
    result = {"scene": args.scene, "lanes": W, "dt": dt, "steps": args.steps, "repeat": args.repeat,
              "ns_per_lane_step": ns, "samples_s": times, "flops_per_lane_step": ops,
              "gflops_per_core": ops / ns if ops else None, "clock_ghz": ghz, "ops_per_cycle": OPS_PER_CYCLE,
              "share_of_peak": share, "numba": numba.__version__}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "lane_step.json").write_text(json.dumps(result, indent=2) + "\n")
    md = ["# The lanes' step", "",
          f"Measured by `python benchmarks/lane_step.py --scene {args.scene} --repeat {args.repeat}`: one block of "
          f"{W} members in free flight (dt = {dt:g}), the model's lanes compiled without the cache; median of "
          f"{args.repeat}.", "",
          "| scene | ns per lane-step | float64 operations per lane-step | Gflop/s, one core | share of the peak |",
          "|---|---|---|---|---|",
          f"| {args.scene} | {ns:.2f} | {ops:.0f} | {ops / ns:.1f} | "
          + (f"{100 * share:.0f}% of {ghz:.2f} GHz x {OPS_PER_CYCLE} |" if share else "- |"), ""]
    (args.out / "lane_step.md").write_text("\n".join(md))
    print("\n".join(md))
    return 0


if __name__ == "__main__":
    sys.exit(main())
