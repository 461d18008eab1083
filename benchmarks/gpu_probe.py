"""Why a GPU ensemble runs at the rate it does: where the rounds' time goes, turn lengths, block size.

    python benchmarks/gpu_probe.py [--out DIR] [--sweep] [--calm]    (on a machine with an NVIDIA GPU and numba-cuda)

Compiles the kernels it needs (``alone``, ``flying`` and ``calming`` of each built-in scene,
one process each, side by side; found cached, loaded), then, one line a study
as it is measured (and ``gpu_probe.json`` in DIR):

* the rounds traced (:data:`jackbox.engine.gpu.TRACE`): shaken (1e6 members x
  10 s) and drop e = 0.6 (1e5 x 3 s) in rounds, each launch synchronised and
  timed: the rounds, the seconds in ``flying``, in ``alone`` for members near
  contact and for held ones, and between launches, with the members each
  listed; and shaken with identical members (1e5 x 10 s: free flight alone);
* with ``--sweep``, the rounds' turn lengths traced (``gpu.EVENT_TURN``,
  ``gpu.ALONE``, ``gpu.HELD_TURN``, ``gpu.CHUNK``: kernel arguments, nothing
  is compiled again), a block size of 128 (32-256 changed shaken's rate by
  under 1% on an H200), and the shortest turns' agreement with the CPU
  (1000 members x 1 s of each scene: the largest state difference, whether
  every impulse count is the same).

* with ``--calm``, only where the rounds take their calm steps (``gpu.CALM``:
  in a launch of their own for the members the lean flight stopped near
  contact, flying on there or handed back to the lean flight when quiet
  again, or in every member's flight), shaken and drop e = 0.6, each traced
  and not; a traced study also counts the calm tests, the calm steps they
  found and the steps flown with the calm test (``calming``'s share); and
  the hand-backs' chunk lengths and passes a round for shaken.

Figures are member-steps per second of the whole study, one sample each (a
traced study is slower by its synchronisations): a probe, not the benchmark
(``jackbox bench --device cuda`` is that).
"""

import argparse
import json
import time
import warnings
from pathlib import Path

from jackbox import ensemble as E
from jackbox import gpubench
from jackbox.engine import gpu
from jackbox.scene import load_scene

SHAKEN = ("shaken", {}, 1_000_000, 10.0)
DROP = ("drop", {"restitution": "0.6"}, 100_000, 3.0)
ALIKE = ("shaken", {}, 100_000, 10.0)


def rate(study, rounds=True, block=gpu.BLOCK, chunk=gpu.CHUNK, alone=gpu.ALONE, traced=False, perturb=True,
         event=gpu.EVENT_TURN, held=gpu.HELD_TURN, calm=gpu.CALM, passes=gpu.PASSES) -> dict:
    """One study's rate with these settings (each call sets all of them; the defaults are jackbox's)."""
    name, over, n, t = study
    gpu.ROUNDS, gpu.BLOCK, gpu.CHUNK, gpu.ALONE, gpu.EVENT_TURN, gpu.HELD_TURN = rounds, block, chunk, alone, event, held
    gpu.CALM, gpu.PASSES = calm, passes
    gpu.TRACE = [] if traced else None
    t0 = time.perf_counter()
    e = E.ensemble(load_scene(name, over), n, t_end=t, perturb={"theta_jack": 1e-6} if perturb else None,
                   device="cuda")
    row = {"scene": name, "n": n, "t_end": t, "perturbed": perturb, "rounds": rounds, "block": block, "chunk": chunk,
           "alone": alone, "event_turn": event, "held_turn": held, "calm": gpu.CALM, "passes": passes,
           "member_steps_per_second": e.meta["member_steps_per_second"],
           "seconds": time.perf_counter() - t0, "impulses_per_member": float(e.impacts.mean()),
           "completed": int(e.completed.sum())}
    if traced:
        trace, gpu.TRACE = gpu.TRACE, None
        row["traced"] = {"rounds": len(trace),
                         **{key: sum(r.get(key, 0.0) for r in trace)
                            for key in ("start", "fly", "calming", "alone_event", "alone_free", "alone_held")},
                         **{"listed_" + key: sum(r.get(key, 0) for r in trace)
                            for key in ("event", "free", "held", "calm", "passes")},
                         **{key: trace[-1].get(key) for key in ("calm_tests", "calm_steps", "calm_flown")}}
        print(json.dumps(row), flush=True)
        row["trace"] = trace
        return row
    print(json.dumps(row), flush=True)
    return row


def main() -> None:
    warnings.simplefilter("ignore")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("."))
    parser.add_argument("--sweep", action="store_true", help="the turn lengths traced, and a block size of 128")
    parser.add_argument("--calm", action="store_true", help="only where the rounds take their calm steps")
    args = parser.parse_args()
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    procs = [gpubench._compile(scene, name, None) for scene in ("shaken", "drop", "spring")
             for name in ("alone", "flying", "calming")]
    compiled = [gpubench._printed(p) for p in procs]
    print(json.dumps({"compiled_side_by_side_seconds": time.perf_counter() - t0, "kernels": compiled}), flush=True)
    for name, over, _, _ in (SHAKEN, DROP):            # loaded, not timed
        E.ensemble(load_scene(name, over), 64, t_end=0.01, perturb={"theta_jack": 1e-6}, device="cuda")
    rows = [{"compiled": compiled}]

    def keep(row):
        rows.append(row)
        (out / "gpu_probe.json").write_text(json.dumps(rows, indent=1) + "\n")

    if args.calm:
        for study in (SHAKEN, DROP):
            for calm in (gpu.APART, gpu.SHORT, gpu.IN_FLIGHT, gpu.APART, gpu.SHORT):
                keep(rate(study, calm=calm))
            for calm in (gpu.APART, gpu.SHORT):
                keep(rate(study, calm=calm, traced=True))
        for chunk, passes in ((512, gpu.PASSES), (1024, gpu.PASSES), (256, 2), (256, 32)):     # SHORT's hand-backs
            keep(rate(SHAKEN, calm=gpu.SHORT, chunk=chunk, passes=passes))
        return
    for study in (SHAKEN, DROP):
        keep(rate(study, traced=True))
        keep(rate(study))
    keep(rate(ALIKE, traced=True, perturb=False))
    if args.sweep:      # (event turn, near-contact turn, held turn, flight), traced
        for study, turns in ((SHAKEN, ((16, 16, 256, 256), (1, 16, 256, 256), (1, 4, 256, 256), (1, 1, 256, 256),
                                       (2, 2, 256, 256), (4, 4, 256, 256), (1, 1, 256, 1024))),
                             (DROP, ((16, 16, 256, 256), (1, 1, 256, 256), (1, 1, 64, 256), (1, 1, 16, 256),
                                     (1, 4, 32, 256)))):
            for event, alone, held, chunk in turns:
                keep(rate(study, traced=True, event=event, alone=alone, held=held, chunk=chunk))
        keep(rate(SHAKEN, block=128))
        for name, over in (("shaken", {}), ("drop", {"restitution": "0.6"}), ("spring", {})):
            keep(agree(name, over))


def agree(name, over, n=1000, t=1.0) -> dict:
    """The shortest turns against the CPU (as ``jackbox bench --device cuda`` compares the defaults)."""
    gpu.EVENT_TURN, gpu.ALONE, gpu.HELD_TURN = 1, 1, 16
    kw = dict(t_end=t, perturb={"theta_jack": 1e-6})
    a, b = E.ensemble(load_scene(name, over), n, **kw), E.ensemble(load_scene(name, over), n, device="cuda", **kw)
    row = {"agree": name, "n": n, "t_end": t, "event_turn": 1, "alone": 1, "held_turn": 16, "calm": gpu.CALM,
           "max_state_difference": float(max(abs(a.q - b.q).max(), abs(a.qd - b.qd).max())),
           "same_impulses": bool((a.impacts == b.impacts).all()), "same_status": bool((a.status == b.status).all())}
    print(json.dumps(row), flush=True)
    return row


if __name__ == "__main__":
    main()
