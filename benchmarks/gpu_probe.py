"""Why a GPU ensemble runs at the rate it does: block size, rounds and their turn lengths, divergence.

    python benchmarks/gpu_probe.py [--out DIR]    (on a machine with an NVIDIA GPU and numba-cuda)

Prints, one line a study as it is measured (and writes ``gpu_probe.json`` to
DIR): shaken (1e6 members x 10 s) and drop e = 0.6 (1e5 x 3 s) in one go
and in rounds (:func:`jackbox.engine.gpu.run_rounds`); in rounds with other
turn lengths (``gpu.CHUNK``, the steps of a round's flight and of a held
member's turn; ``gpu.ALONE``, a free member's turn in the exact loop near
contact), which are kernel arguments: nothing is compiled again; and at a
block size of 128 (32-256 changed shaken's rate by under 1% on an H200,
benchmarks/results/gpu_probe.json). About two minutes on an H200. Figures are member-steps per second of the whole study, one
sample each: a probe, not the benchmark (``jackbox bench --device cuda`` is
that). Run it after the benchmark: it expects the kernels in the cache.
"""

import argparse
import json
import time
import warnings
from pathlib import Path

from jackbox import ensemble as E
from jackbox.engine import gpu
from jackbox.scene import load_scene

SHAKEN = ("shaken", {}, 1_000_000, 10.0)
DROP = ("drop", {"restitution": "0.6"}, 100_000, 3.0)


def rate(study, rounds, block=64, chunk=256, alone=16) -> dict:
    name, over, n, t = study
    gpu.ROUNDS, gpu.BLOCK, gpu.CHUNK, gpu.ALONE = rounds, block, chunk, alone
    t0 = time.perf_counter()
    e = E.ensemble(load_scene(name, over), n, t_end=t, perturb={"theta_jack": 1e-6}, device="cuda")
    row = {"scene": name, "n": n, "t_end": t, "rounds": rounds, "block": block, "chunk": chunk, "alone": alone,
           "member_steps_per_second": e.meta["member_steps_per_second"], "seconds": time.perf_counter() - t0,
           "impulses_per_member": float(e.impacts.mean()), "completed": int(e.completed.sum())}
    print(json.dumps(row), flush=True)
    return row


def main() -> None:
    warnings.simplefilter("ignore")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("."))
    out = parser.parse_args().out
    for name, over, _, _ in (SHAKEN, DROP):
        for rounds in (False, True):            # compiled or loaded, not timed
            gpu.ROUNDS = rounds
            E.ensemble(load_scene(name, over), 64, t_end=0.01, perturb={"theta_jack": 1e-6}, device="cuda")
    rows = []
    for study in (SHAKEN, DROP):
        rows += [rate(study, False), rate(study, True)]
        for chunk, alone in ((64, 16), (128, 16), (1024, 16), (256, 4), (256, 64)):
            rows.append(rate(study, True, 64, chunk, alone))
        rows.append(rate(study, True, 128))
        out.mkdir(parents=True, exist_ok=True)
        (out / "gpu_probe.json").write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
