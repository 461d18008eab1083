"""What a call costs besides its steps: a run or a study of two steps, everything compiled and cached.

    python benchmarks/overhead.py [--repeat 5] [--rounds 3] [--against CHECKOUT] [--quick] [--out DIR]

A parameter scan by ``jackbox.simulate`` in a loop, or many small studies,
pays this on every call: finding the scene's model, the look-up of its
compiled code in the cache, the checks of the arguments, setting up the
members and the result. Each figure is the median of ``--repeat`` calls in a
new process (after one call that loads what it needs); ``--rounds`` such
processes, and with ``--against`` a checkout (a git worktree of another
commit) timed the same way, the processes alternating so both see the same
machine. The medians over rounds go to ``overhead.md`` and ``overhead.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from jackbox.fileio import write_atomic  # noqa: E402

#: the calls timed: (name, what it is)
CALLS = (("simulate", "`jackbox.simulate(\"shaken\", t_end=0.002)`: a run of two steps"),
         ("study_32", "`ensemble(\"shaken\", 32, t_end=0.002, lanes=True)`: a study of one block, two steps"),
         ("study_2000", "`ensemble(\"shaken\", 2000, t_end=0.002, lanes=True)`: 2000 members, two steps"))

#: a child process: each call's median time in ms, as JSON on its last line
CHILD = r"""
import json, statistics, sys, time
import jackbox
from jackbox.ensemble import ensemble
repeat = int(sys.argv[1])
scene = jackbox.load_scene("shaken")
kw = dict(perturb={"theta_jack": 1e-6}, t_end=0.002, seed=0, lanes=True)
calls = {"simulate": lambda: jackbox.simulate(scene, t_end=0.002),
         "study_32": lambda: ensemble(scene, 32, **kw), "study_2000": lambda: ensemble(scene, 2000, **kw)}
out = {}
for name, call in calls.items():
    call()                      # loads (or compiles) what it needs
    seconds = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        call()
        seconds.append(time.perf_counter() - t0)
    out[name] = 1e3 * statistics.median(seconds)
print(json.dumps({"jackbox": jackbox.__file__, "ms": out}))
"""


def timed(root: Path, repeat: int) -> dict:
    """One process with ``root``'s code: each call's median in ms."""
    env = os.environ | {"PYTHONPATH": str(root), "JACKBOX_PROGRESS": "0"}
    proc = subprocess.run([sys.executable, "-c", CHILD, str(repeat)], env=env, cwd=root, capture_output=True,
                          text=True)
    if proc.returncode != 0:
        last = (proc.stderr.strip().splitlines() or ["(no message)"])[-1]
        raise SystemExit(f"overhead.py: the calls with {root}'s code failed: {last}")
    got = json.loads(proc.stdout.strip().splitlines()[-1])
    if not Path(got["jackbox"]).resolve().is_relative_to(root.resolve()):
        raise SystemExit(f"overhead.py: the calls meant for {root} imported jackbox from {got['jackbox']}")
    return got["ms"]


def commit_of(root: Path) -> str | None:
    """The checkout's commit (short), if it is a git work tree."""
    done = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True, text=True)
    return (done.stdout.strip() or None) if done.returncode == 0 else None


def markdown(res: dict) -> str:
    other = res.get("against")
    head = "| call | this checkout, ms |" + (" other checkout, ms | this / other |" if other else "")
    lines = ["# What a call costs besides its steps", "",
             f"Measured by `{res['command']}` on {res['machine']}: each figure the median over {res['rounds']} new "
             f"processes of the median of {res['repeat']} calls in each (after one call that loads what it needs)"
             + (f" (this checkout at {res['commit']})" if res.get("commit") else "")
             + (f"; against `{other['checkout']}`" + (f" at {other['commit']}" if other.get("commit") else "")
                + ", its processes alternating with these" if other else "") + ".", "",
             head, "|---|---|" + ("---|---|" if other else "")]
    for name, what in CALLS:
        mine = res["this"][name]
        row = f"| {what} | {mine:.2f} |"
        if other:
            row += f" {other['ms'][name]:.2f} | {mine / other['ms'][name]:.2f} |"
        lines.append(row)
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeat", type=int, default=15, help="calls timed in each process, median (default 15)")
    ap.add_argument("--rounds", type=int, default=3, help="processes for each checkout, median (default 3)")
    ap.add_argument("--against", type=Path, metavar="CHECKOUT", help="another checkout's code, side by side")
    ap.add_argument("--quick", action="store_true", help="one round of three calls: a smoke test")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results", help="folder for the results")
    args = ap.parse_args(argv)
    if args.against is not None and not (args.against / "jackbox" / "__init__.py").is_file():
        ap.error(f"--against {args.against}: not a jackbox checkout (no jackbox/__init__.py there)")
    repeat, rounds = (3, 1) if args.quick else (args.repeat, args.rounds)
    if repeat < 1 or rounds < 1:
        ap.error("--repeat and --rounds must be 1 or more")
    runs: dict = {"this": [], "other": []}
    for _ in range(rounds):
        runs["this"].append(timed(ROOT, repeat))
        if args.against is not None:
            runs["other"].append(timed(args.against, repeat))

    def medians(rows):
        return {name: statistics.median(r[name] for r in rows) for name, _ in CALLS}

    res = {"machine": f"{platform.machine()}, {os.cpu_count()} cores", "repeat": repeat, "rounds": rounds,
           "command": " ".join(["python", "benchmarks/overhead.py", *(argv if argv is not None else sys.argv[1:])]),
           "commit": commit_of(ROOT), "this": medians(runs["this"]), "samples": runs}
    if args.against is not None:
        res["against"] = {"checkout": str(args.against), "commit": commit_of(args.against),
                          "ms": medians(runs["other"])}
    args.out.mkdir(parents=True, exist_ok=True)
    write_atomic(args.out / "overhead.json", json.dumps(res, indent=1))
    text = markdown(res)
    write_atomic(args.out / "overhead.md", text)
    print(text, end="")
    print(f"wrote {args.out / 'overhead.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
