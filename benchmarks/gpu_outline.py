"""What keeping more functions out of line does to the GPU's kernels: compile time, registers, speed, agreement.

    python benchmarks/gpu_outline.py [--out DIR]    (on a machine with an NVIDIA GPU and numba-cuda)

NVVM inlines every device function that is not marked ``noinline``
(:data:`jackbox.engine.gpu.OUT_OF_LINE`, :data:`~jackbox.engine.gpu.HELPERS_OUT_OF_LINE`):
inlined, the model's generated functions and the engine's small solvers are
copied into each of their callers, which was most of the ``alone`` kernel's
PTX (shaken: 110k instructions inlined, 41k with them out of line; NVVM 26 s
against 11 on 2 cores). This measures both ways on one machine, in one run:

* compile: ``alone``, ``flying`` and ``calming`` of shaken and drop,
  each way, every kernel cold in a process of its own, all side by side (the
  CPU's engine compiles meanwhile in this process); registers and local memory;
* speed: one process each way (``JACKBOX_GPU_OUT_OF_LINE``, which names the
  functions and so the kernel file): shaken 1e6 members x 10 s and drop
  e = 0.6 1e5 x 3 s, twice each and once traced (``gpu.TRACE``);
* agreement: each way, shaken and drop e = 0.6, 1000 members x 1 s against the
  CPU (the largest state difference, the same impulse counts).

One line of JSON per result as it is measured; all of them in
``gpu_outline.json`` in DIR.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

from jackbox.engine.gpu import HELPERS_OUT_OF_LINE

#: the two ways: the helpers inlined (as before 2026-11-27), or out of line (jackbox's default)
WAYS = {"inline": "", "out_of_line": ",".join(HELPERS_OUT_OF_LINE)}
KERNELS = [(scene, name) for scene in ("shaken", "drop") for name in ("alone", "flying", "calming")]

RUN = r"""
import json, sys, time, warnings
import numpy as np
warnings.simplefilter("ignore")
from jackbox import ensemble as E
from jackbox.engine import gpu
from jackbox.scene import load_scene
way, quick = sys.argv[1], sys.argv[2] == "quick"
for name, over in (("shaken", {}), ("drop", {"restitution": "0.6"})):        # loaded, not timed
    E.ensemble(load_scene(name, over), 64, t_end=0.01, perturb={"theta_jack": 1e-6}, device="cuda")
for name, over, n, t in (("shaken", {}, 1_000_000, 10.0), ("drop", {"restitution": "0.6"}, 100_000, 3.0)):
    n, t = (8, 0.05) if quick else (n, t)
    for traced in (False, False, True):
        gpu.TRACE = [] if traced else None
        t0 = time.perf_counter()
        e = E.ensemble(load_scene(name, over), n, t_end=t, perturb={"theta_jack": 1e-6}, device="cuda")
        row = {"way": way, "scene": name, "n": n, "t_end": t, "traced": traced,
               "member_steps_per_second": e.meta["member_steps_per_second"], "run_seconds": e.meta["run_seconds"],
               "impulses_per_member": float(e.impacts.mean())}
        if traced:
            trace, gpu.TRACE = gpu.TRACE, None
            row["rounds"] = len(trace)
            row |= {key: sum(r.get(key, 0.0) for r in trace)
                    for key in ("fly", "calming", "alone_event", "alone_free", "alone_held")}
            row |= {key: trace[-1].get(key) for key in ("calm_tests", "calm_steps", "calm_flown")}
        print(json.dumps(row), flush=True)
for name, over in (("shaken", {}), ("drop", {"restitution": "0.6"})):
    kw = dict(t_end=0.05 if quick else 1.0, perturb={"theta_jack": 0.3})
    n = 8 if quick else 1000
    a = E.ensemble(load_scene(name, over), n, **kw)
    b = E.ensemble(load_scene(name, over), n, device="cuda", **kw)
    print(json.dumps({"way": way, "agree": name, "max_state_difference": float(max(np.nanmax(abs(a.q - b.q)),
                                                                                   np.nanmax(abs(a.qd - b.qd)))),
                      "same_impulses": bool((a.impacts == b.impacts).all()),
                      "same_status": bool((a.status == b.status).all())}), flush=True)
"""


def main() -> None:
    warnings.simplefilter("ignore")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("."))
    parser.add_argument("--quick", action="store_true", help="tiny studies (a check of the script, on the simulator)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    rows = []

    def keep(row):
        rows.append(row)
        print(json.dumps(row), flush=True)
        (args.out / "gpu_outline.json").write_text(json.dumps(rows, indent=1) + "\n")

    # every kernel cold: a fresh jackbox cache for this run (the kernel files go there, and numba-cuda caches
    # beside them unless NUMBA_CACHE_DIR says otherwise), removed at the end; the model's CPU parts compile
    # there too, in this process while the kernels compile
    with tempfile.TemporaryDirectory(prefix="jackbox-outline-") as fresh:
        os.environ["JACKBOX_CACHE_DIR"] = fresh
        measure(args, keep)


def measure(args, keep) -> None:
    """Compile both ways side by side, then run each way in a process of its own (see the module's docstring)."""
    from jackbox import gpubench

    base = {k: v for k, v in os.environ.items() if k != "JACKBOX_GPU_OUT_OF_LINE"} | {"PYTHONWARNINGS": "ignore"}
    envs = {way: base | {"JACKBOX_GPU_OUT_OF_LINE": more} for way, more in WAYS.items()}
    t0 = time.perf_counter()
    procs = [(way, scene, name, gpubench._compile(scene, name, envs[way])) for way in WAYS for scene, name in KERNELS]
    from jackbox import ensemble as E
    from jackbox.scene import load_scene
    for scene, over in (("shaken", {}), ("drop", {"restitution": "0.6"})):      # the CPU's parts
        E.ensemble(load_scene(scene, over), 32, t_end=1.0, perturb={"theta_jack": 0.3})
    for way, scene, name, proc in procs:
        keep({"way": way, "scene": scene, "kernel": name, **gpubench._printed(proc)})
    keep({"compiled_side_by_side_seconds": time.perf_counter() - t0})
    for way in WAYS:
        with open(args.out / f"outline_{way}.log", "w") as err:
            proc = subprocess.Popen([sys.executable, "-c", RUN, way, "quick" if args.quick else "full"], env=envs[way],
                                    stdout=subprocess.PIPE, stderr=err, text=True)
            for line in proc.stdout:
                if line.startswith("{"):
                    keep(json.loads(line))
            if proc.wait() != 0:
                keep({"way": way, "error": f"exit {proc.returncode}: see outline_{way}.log"})


if __name__ == "__main__":
    main()
