"""Why a GPU ensemble runs at the rate it does: registers, local memory, block size, divergence.

    python benchmarks/gpu_probe.py            (on a machine with an NVIDIA GPU and numba-cuda)

Prints, for the kernel of shaken's members: registers and local memory per
thread; the rate of 1e5 members x 10 s at block sizes 32..256; the same
members all identical (no divergence in a warp); shaken with walls far away
(free flight only); and, with rounds (jackbox.engine.gpu.run_rounds), the
perturbed members again. Figures are member-steps per second of the whole
study, one sample each (a probe, not the benchmark: ``jackbox bench --device
cuda`` is that).
"""

import warnings

from jackbox import ensemble as E
from jackbox.engine import gpu
from jackbox.scene import load_scene


def rate(scene, n, t, perturb, block=64, rounds=False):
    gpu.BLOCK, gpu.ROUNDS = block, rounds
    e = E.ensemble(scene, n, t_end=t, perturb=perturb, device="cuda")
    return f"{e.meta['member_steps_per_second']:.3g} member-steps/s, {e.impacts.mean():.3g} impulses a member"


def main() -> None:
    warnings.simplefilter("ignore")
    shaken = load_scene("shaken")
    rate(shaken, 64, 0.01, {"theta_jack": 1e-6})             # compiled or loaded, not timed
    members = E._kernel(E.plan(shaken, 4, None, None, None, 0.01, None, 0, False, None), "setup").gpu().members
    print("registers per thread", members.get_regs_per_thread(), flush=True)
    print("local memory per thread (bytes)", members.get_local_mem_per_thread(), flush=True)
    for block in (32, 64, 128, 256):
        print(f"block {block}: shaken 1e5 x 10 s", rate(shaken, 100_000, 10.0, {"theta_jack": 1e-6}, block),
              flush=True)
    print("identical members: shaken 1e5 x 10 s", rate(shaken, 100_000, 10.0, {}), flush=True)
    far = load_scene("shaken", {"inner_half_width": "50"})
    print("walls far away (free flight only): 1e5 x 1 s", rate(far, 100_000, 1.0, {"theta_jack": 1e-6}), flush=True)
    print("in rounds: shaken 1e5 x 10 s", rate(shaken, 100_000, 10.0, {"theta_jack": 1e-6}, rounds=True), flush=True)


if __name__ == "__main__":
    main()
