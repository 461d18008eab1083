"""The throughput ceiling: a small hand-written C loop doing the kernel's free-flight step.

    python benchmarks/ceiling.py [--steps 1000000] [--repeat 5] [--build-dir DIR]

``ceiling/shaken_step.c`` integrates the ``shaken`` scene with the kernel's RK4
tableau and evaluates all 16 gaps after every step, as the naive method does,
but resolves no impact. It is written by hand and kept small; it is the
yardstick the kernel's ns per step is compared with, not a second simulator.

Flags: ``-O3 -march=native -ffp-contract=off``. Contraction into fused
multiply-adds is off so that the loop rounds like the Python and Numba code
(Numba does not contract either), which lets the test check it to round-off;
``-ffast-math`` is never used, for the same reason.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shutil
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

SOURCE = Path(__file__).resolve().parent / "ceiling" / "shaken_step.c"
FLAGS = ("-O3", "-march=native", "-ffp-contract=off")


class NoCompilerError(RuntimeError):
    """No C compiler (``cc`` or ``gcc``) is on the PATH."""


def find_compiler() -> str:
    """Path of ``cc``, else ``gcc``; raises NoCompilerError when neither exists."""
    for name in ("cc", "gcc"):
        path = shutil.which(name)
        if path:
            return path
    raise NoCompilerError("no C compiler found: install cc or gcc to build benchmarks/ceiling/shaken_step.c")


def compiler_info() -> dict:
    """The compiler, the first line of its ``--version`` and the flags used."""
    cc = find_compiler()
    out = subprocess.run([cc, "--version"], capture_output=True, text=True, check=True).stdout
    return {"compiler": cc, "version": out.splitlines()[0] if out else "", "flags": list(FLAGS)}


def compile_c(build_dir) -> Path:
    """Build ``shaken_step`` into ``build_dir`` and return the executable's path."""
    exe = Path(build_dir) / "shaken_step"
    exe.parent.mkdir(parents=True, exist_ok=True)
    cmd = [find_compiler(), *FLAGS, "-std=c99", "-o", str(exe), str(SOURCE), "-lm"]
    done = subprocess.run(cmd, capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{done.stderr}")
    return exe


def run_c(exe, steps: int, dt: float, p, q, qd) -> dict:
    """One run of the C loop -> its JSON line as a dict (final q, qd, min_gap, timing)."""
    args = [str(exe), str(int(steps)), repr(float(dt))]
    args += [repr(float(x)) for x in (*p, *q, *qd)]   # repr: shortest round-trip text
    out = subprocess.run(args, capture_output=True, text=True, check=True).stdout
    return json.loads(out)


def shaken_start():
    """(p, q, qd, dt) of the shaken scene, as jackbox resolves them."""
    from jackbox import api

    run = api.prepare("shaken")
    return run.p, run.q, run.qd, run.dt


def measure(steps: int = 1_000_000, repeat: int = 5, build_dir=None) -> dict:
    """Median ns per step of the C loop over ``repeat`` runs of ``steps`` steps.

    The shaken scene is run from its start state with its dt; past the jack's
    first contact it flies through the walls (no impacts), which changes no
    operation count, so the timing holds; ``min_gap`` then is negative.
    """
    p, q, qd, dt = shaken_start()
    info = compiler_info()
    if build_dir is None:
        where = tempfile.TemporaryDirectory(prefix="jackbox-ceiling-")
    else:
        where = contextlib.nullcontext(build_dir)
    with where as folder:
        exe = compile_c(folder)
        runs = [run_c(exe, steps, dt, p, q, qd) for _ in range(repeat)]
    ns = [r["ns_per_step"] for r in runs]
    return {"scene": "shaken", "steps": steps, "repeat": repeat, "dt": dt,
            "ns_per_step": statistics.median(ns), "ns_per_step_runs": ns, **info}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=1_000_000)
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--build-dir", type=Path, default=None, help="keep the executable here")
    args = parser.parse_args(argv)
    try:
        r = measure(args.steps, args.repeat, args.build_dir)
    except NoCompilerError as exc:
        print(f"ceiling: {exc}", file=sys.stderr)
        return 1
    print(f"ceiling (hand-written C, shaken): {r['ns_per_step']:.1f} ns/step, median of {r['repeat']} x "
          f"{r['steps']} steps; {r['version']} {' '.join(r['flags'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
