"""Persistent multi-contact: the studies that used to stall, low restitution, resting steps.

    python benchmarks/contact.py [--members 2000] [--repeat 3] [--quick] [--out benchmarks/results]
                                 [--against CHECKOUT]

Measures, for the issue "Contact that never gives up":

* **studies**: the ensembles that used to lose members (a drop thrown spinning
  at 15 rad/s with e = 0.5 and e = 0; a weightless box spinning at 10 rad/s
  with a square and a cross jack pressed into its wall; the drop with e = 0),
  ``--members`` each, 2 s: members lost, members that used the fallback
  (Moreau-Jean time-stepping, first order) and for how long, solver warnings,
  wall time;
* **restitution**: shaken and spring for 10 s at e in {0, 0.025, 0.1, 0.2,
  0.5, 1}: contact events (impulses and mode changes), time in the fallback,
  and wall time against the elastic run (median of ``--repeat``, one process,
  interleaved); with ``--against CHECKOUT`` also the run times of this
  checkout's code and the other's side by side, each repeat a new process of
  each, alternating (``PYTHONPATH``), so both see the same machine;
* **resting steps**: ns per step of the plastic drop once everything rests
  (four persistent contacts) against the same scene in free fall (gravity,
  no contact), both by the kernel's own clock (``meta["kernel"]["run_seconds"]``);
* **sweep**: ``ensemble("shaken", N, sweep={"restitution": (0, 1)})`` in
  lanes (a restitution sweep goes in them) and each member alone, against the
  elastic study of the same size each member alone and in lanes, wall time
  (compile excluded: warm-up studies run first).

Writes ``contact.json`` and ``contact.md`` to ``--out``; the README quotes the
table. ``--quick`` runs small sizes (tests/test_benchmarks_smoke.py).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

import jackbox
from jackbox import engine
from jackbox.ensemble import ensemble
from jackbox.fileio import write_atomic

SPIN = {"initial.qd": [0, 0, 15, 0.8, 0, 6]}
#: a weightless box spinning at 10 rad/s, a light jack co-rotating at half radius (tests/test_stress.py)
WEIGHTLESS = {"box.inner_half_width": 1.0, "box.wall_thickness": 0.1, "box.mass": 1000.0, "jack.mass": 0.01,
              "jack.half_size": 0.1, "restitution": 0.5, "gravity": 0.0, "world.ground": False,
              "initial.q": [0, 0, 0, -0.5, 0, 0.3], "initial.qd": [0, 0, 10, 0, -5, 10]}
STUDIES = {
    "spinning drop, e = 0.5": ("drop", {"restitution": 0.5, "ground_restitution": 0.5} | SPIN,
                               {"theta_jack": 0.5, "x_jack_dot": 0.5}),
    "spinning drop, e = 0": ("drop", {"restitution": 0.0, "ground_restitution": 0.0} | SPIN,
                             {"theta_jack": 0.5, "x_jack_dot": 0.5}),
    "weightless spinning box, square jack": ("drop", WEIGHTLESS | {"jack.shape": "square"}, {"theta_jack": 0.5}),
    "weightless spinning box, cross jack": ("drop", WEIGHTLESS | {"jack.shape": "cross"}, {"theta_jack": 0.5}),
    "drop, e = 0": ("drop", {"restitution": 0.0, "ground_restitution": 0.0}, {"theta_jack": 1e-3, "x_jack_dot": 1e-3}),
}
RESTITUTIONS = (0.0, 0.025, 0.1, 0.2, 0.5, 1.0)


def studies(members: int, t_end: float) -> list[dict]:
    rows = []
    for name, (base, over, perturb) in STUDIES.items():
        scene = jackbox.load_scene(base, over)
        ensemble(scene, 2, perturb=perturb, t_end=0.01)        # compile outside the clock,
        engine.prepare((), ("exact",))         # the stages first needed later (held contacts, fallback) too
        t0 = time.perf_counter()
        ens = ensemble(scene, members, perturb=perturb, t_end=t_end)
        wall = time.perf_counter() - t0
        used = ens.fallback > 0
        rows.append({"study": name, "members": members, "t_end": t_end, "lost": int((~ens.completed).sum()),
                     "fallback_members": int(used.sum()), "fallback_seconds": float(ens.fallback.sum()),
                     "fallback_max": float(ens.fallback.max()), "warnings": int(ens.warnings.sum()),
                     "impulses_median": float(np.median(ens.impacts)), "wall_s": wall})
        print(f"{name}: {rows[-1]['lost']} of {members} lost, fallback in {rows[-1]['fallback_members']} "
              f"({rows[-1]['fallback_seconds']:.3g} s in all), {wall:.1f} s", flush=True)
    return rows


def restitution(repeat: int, t_end: float) -> list[dict]:
    rows = []
    for name in ("shaken", "spring"):
        runs = {e: [] for e in RESTITUTIONS}
        out = {}
        for _ in range(repeat):
            for e in RESTITUTIONS:            # interleaved, so a busy spell hits every e alike
                traj = jackbox.simulate(name, t_end=t_end, params={"e": e, "e_ground": e})
                runs[e].append(traj.meta["kernel"]["run_seconds"])
                out[e] = traj
        elastic = statistics.median(runs[1.0])
        for e in RESTITUTIONS:
            traj = out[e]
            rows.append({"scene": name, "e": e, "t_end": t_end, "impulses": len(traj.impact_t),
                         "mode_changes": len(traj.contact_t), "events": len(traj.impact_t) + len(traj.contact_t),
                         "fallback_seconds": traj.fallback_seconds, "run_s": statistics.median(runs[e]),
                         "vs_elastic": statistics.median(runs[e]) / elastic})
            r = rows[-1]
            print(f"{name} e = {e:g}: {r['events']} events, fallback {r['fallback_seconds']:.3g} s, "
                  f"{r['vs_elastic']:.2f}x the elastic run", flush=True)
    return rows


#: a child process of --against: the kernel's run time of each restitution row (the median of three runs
#: in the process), as JSON on its last line
CHILD = r"""
import json, sys
import jackbox
t_end, values = float(sys.argv[1]), json.loads(sys.argv[2])
for name in ("shaken", "spring"):                      # (warm: loads or compiles what the runs need)
    jackbox.simulate(name, t_end=t_end, params={"e": 0.0, "e_ground": 0.0})
out = {}
for name in ("shaken", "spring"):
    for e in values:
        # three runs a process, their median: a process's first runs are often slower as a whole
        seconds = sorted(jackbox.simulate(name, t_end=t_end, params={"e": e, "e_ground": e}).meta["kernel"]["run_seconds"]
                         for _ in range(3))
        out[f"{name} {e!r}"] = seconds[1]
print(json.dumps({"jackbox": jackbox.__file__, "runs": out}))
"""


def side_by_side(checkout: Path, repeat: int, t_end: float) -> dict:
    """Each restitution row's run time with this checkout's code and with ``checkout``'s, medians of new processes."""
    import subprocess
    here = Path(__file__).resolve().parent.parent
    runs: dict = {"this": {}, "other": {}}
    for _ in range(repeat):
        for who, root in (("this", here), ("other", checkout.resolve())):
            env = os.environ | {"PYTHONPATH": str(root), "JACKBOX_PROGRESS": "0"}
            # (run from that checkout: `python -c` puts the working folder first on the path)
            proc = subprocess.run([sys.executable, "-c", CHILD, str(t_end), json.dumps(RESTITUTIONS)], env=env,
                                  cwd=root, capture_output=True, text=True)
            if proc.returncode != 0:
                last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
                raise SystemExit(f"contact.py: the runs with {root}'s code failed: {last}")
            got = json.loads(proc.stdout.strip().splitlines()[-1])
            if not Path(got["jackbox"]).resolve().is_relative_to(root):
                raise SystemExit(f"contact.py: the runs meant for {root} imported jackbox from {got['jackbox']}")
            for key, value in got["runs"].items():
                runs[who].setdefault(key, []).append(value)
    return {who: {key: statistics.median(v) for key, v in rows.items()} for who, rows in runs.items()}


def resting(repeat: int) -> dict:
    """ns per step at rest (the plastic drop, settled) and in free fall (no contact)."""
    settled = jackbox.simulate("drop", t_end=8.0, params={"e": 0.0, "e_ground": 0.0})
    q, qd = settled.q[-1].tolist(), settled.qd[-1].tolist()
    at_rest = jackbox.load_scene("drop", {"restitution": 0.0, "ground_restitution": 0.0,
                                          "initial.q": q, "initial.qd": qd})
    falling = jackbox.load_scene("drop", {"initial.q": [0, 1000.0, 0, 0, 1000.0, 0], "initial.qd": [0] * 6})
    ns = {"resting": [], "free": []}
    for _ in range(repeat):
        for key, scene in (("resting", at_rest), ("free", falling)):
            traj = jackbox.simulate(scene, t_end=5.0, record_every=5000)
            ns[key].append(traj.meta["kernel"]["run_seconds"] / traj.meta["n_steps"] * 1e9)
    held = len({k for k in settled.contact_constraint if np.sum(settled.contact_constraint == k) % 2 == 1})
    out = {"held_contacts": held, "resting_ns_per_step": statistics.median(ns["resting"]),
           "free_ns_per_step": statistics.median(ns["free"])}
    out["ratio"] = out["resting_ns_per_step"] / out["free_ns_per_step"]
    print(f"resting step ({held} held): {out['resting_ns_per_step']:.0f} ns, free {out['free_ns_per_step']:.0f} ns, "
          f"{out['ratio']:.1f}x", flush=True)
    return out


def sweep(members: int, t_end: float) -> dict:
    ensemble("shaken", 2, sweep={"restitution": (0.0, 1.0)}, t_end=0.01)
    engine.prepare((), ("exact",))
    # the elastic study and the sweep each member alone and in lanes (where it pays:
    # jackbox.ensemble.use_lanes), as a user's study goes once its lanes are compiled (they are compiled
    # here first, so the figure does not depend on the cache)
    ensemble("shaken", 64, t_end=0.01, lanes=True)
    t0 = time.perf_counter()
    ens = ensemble("shaken", members, t_end=t_end, params={"e": 1.0, "e_ground": 1.0}, lanes=False)
    elastic = time.perf_counter() - t0
    t0 = time.perf_counter()
    in_lanes = ensemble("shaken", members, t_end=t_end, params={"e": 1.0, "e_ground": 1.0}, lanes=True)
    elastic_lanes = time.perf_counter() - t0
    t0 = time.perf_counter()
    swept = ensemble("shaken", members, sweep={"restitution": (0.0, 1.0)}, t_end=t_end)
    wall = time.perf_counter() - t0
    t0 = time.perf_counter()
    swept_alone = ensemble("shaken", members, sweep={"restitution": (0.0, 1.0)}, t_end=t_end, lanes=False)
    wall_alone = time.perf_counter() - t0
    out = {"members": members, "t_end": t_end, "elastic_s": elastic, "elastic_lanes_s": elastic_lanes,
           "sweep_s": wall, "sweep_alone_s": wall_alone, "ratio": wall / elastic,
           "ratio_lanes": wall / elastic_lanes,
           "lost": sum(int((~s.completed).sum()) for s in (swept, swept_alone, ens, in_lanes)),
           "fallback_members": int((swept.fallback > 0).sum())}
    print(f"shaken restitution sweep, {members} members: {wall:.1f} s ({wall_alone:.1f} s each member alone) "
          f"against {elastic:.2f} s elastic, each member alone ({out['ratio']:.2f}x), {elastic_lanes:.2f} s in "
          f"lanes ({out['ratio_lanes']:.1f}x), {out['lost']} lost", flush=True)
    return out


def markdown(res: dict) -> str:
    lines = ["# Persistent multi-contact (benchmarks/contact.py)", "",
             f"Machine: {res['machine']}. Command: `{res['command']}`.", "",
             "| study | members | lost | in the fallback | fallback time (all members) | warnings | wall |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in res["studies"]:
        lines.append(f"| {r['study']} | {r['members']} | {r['lost']} | {r['fallback_members']} | "
                     f"{r['fallback_seconds']:.3g} s | {r['warnings']} | {r['wall_s']:.1f} s |")
    horizon = f"{res['restitution'][0]['t_end']:g} s" if res["restitution"] else "10 s"
    lines += ["", f"| scene, {horizon} | e | impulses | mode changes | fallback | run time | vs e = 1 |",
              "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in res["restitution"]:
        lines.append(f"| {r['scene']} | {r['e']:g} | {r['impulses']} | {r['mode_changes']} | "
                     f"{r['fallback_seconds']:.3g} s | {1e3 * r['run_s']:.2f} ms | {r['vs_elastic']:.2f}x |")
    lines += ["", "Run time: the kernel's, every step recorded (`simulate`'s default), median of the repeats."]
    if res.get("against"):
        other = res["against"]
        lines += ["", f"Side by side with `{other['checkout']}` (new processes of each, alternating, medians of "
                  f"{other['repeat']} processes of the median of 3 runs each), ms:", "", f"| scene, {horizon} | e | this checkout | other | this / other |",
                  "| --- | --- | --- | --- | --- |"]
        for r in res["restitution"]:
            key = f"{r['scene']} {r['e']!r}"
            a, b = other["this"][key], other["other"][key]
            lines.append(f"| {r['scene']} | {r['e']:g} | {1e3 * a:.2f} | {1e3 * b:.2f} | {a / b:.2f} |")
    rs = res["resting"]
    lines += ["", f"Resting step (plastic drop, settled, {rs['held_contacts']} persistent contacts): "
              f"{rs['resting_ns_per_step']:.0f} ns against {rs['free_ns_per_step']:.0f} ns in free fall "
              f"({rs['ratio']:.1f}x)."]
    sw = res["sweep"]
    lines += ["", f"Restitution sweep (0..1) of shaken, {sw['members']} members, {sw['t_end']:g} s: "
              f"{sw['sweep_s']:.1f} s in lanes ({sw['sweep_alone_s']:.1f} s with each member alone) against "
              f"{sw['elastic_s']:.2f} s for the elastic study with each member alone ({sw['ratio']:.2f}x) and "
              f"{sw['elastic_lanes_s']:.2f} s for it in lanes ({sw['ratio_lanes']:.1f}x); "
              f"{sw['lost']} members lost, {sw['fallback_members']} used the fallback.", ""]
    return "\n".join(lines)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--members", type=int, default=2000, help="members per study (default 2000)")
    ap.add_argument("--repeat", type=int, default=3, help="runs per timing, median (default 3)")
    ap.add_argument("--quick", action="store_true", help="small sizes: a smoke test")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results", help="folder for the results")
    ap.add_argument("--against", type=Path, metavar="CHECKOUT",
                    help="also time the restitution rows with another checkout's code (a git worktree), side by side")
    args = ap.parse_args(argv)
    if args.against is not None and not (args.against / "jackbox" / "__init__.py").is_file():
        ap.error(f"--against {args.against}: not a jackbox checkout (no jackbox/__init__.py there)")
    members, t_end, horizon, repeat = ((20, 0.5, 1.0, 1) if args.quick
                                       else (args.members, 2.0, 10.0, args.repeat))
    res = {"machine": f"{platform.machine()}, {os.cpu_count()} cores",
           "command": " ".join(["python", "benchmarks/contact.py", *(argv if argv is not None else sys.argv[1:])]),
           "studies": studies(members, t_end), "restitution": restitution(repeat, horizon),
           "resting": resting(repeat), "sweep": sweep(members, horizon)}
    if args.against is not None:
        res["against"] = {"checkout": str(args.against), "repeat": repeat,
                          **side_by_side(args.against, repeat, horizon)}
    args.out.mkdir(parents=True, exist_ok=True)
    write_atomic(args.out / "contact.json", json.dumps(res, indent=1))
    write_atomic(args.out / "contact.md", markdown(res))
    print(f"wrote {args.out / 'contact.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
