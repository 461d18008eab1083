"""Random scenes at the full ranges: every run completes, nothing penetrates, no energy is gained.

    python benchmarks/campaign.py [--examples 300] [--seed 0] [--out DIR]
    python benchmarks/campaign.py --recheck FILE [--out DIR]

The property tests of ``tests/test_stress.py`` draw random scenes (box size,
wall, masses, jack size, start state, speeds, restitution, dt) and check each
run against what does not depend on the code under test: gaps recomputed in
numpy, energy recomputed and never rising, momentum where it is an invariant.
In CI they draw 25 examples each from narrower ranges (jack-to-box mass ratio
1e-3..1e3, speeds up to 10 sqrt(g L), square jacks that turn freely). This
script runs the same tests, with the same checks, at the ranges of the issue
"Contact that never gives up": mass ratios 1e-4..1e4, speeds up to
30 sqrt(g L), square jacks up to 0.99 L (wedged), e in [0, 1] with both ends,
``--examples`` draws each, not derandomized (``--seed`` picks them).

Each failing draw is classified by the check that failed, and written out
(scene overrides and dt) so that it can be run again. Writes
``campaign.md`` and ``campaign.json``.

Hypothesis's draws follow the runs' outcomes, so a change to the engine makes
the same seed draw other scenes after the first that runs differently: to
compare two versions of the code on the same scenes, ``--recheck FILE`` runs
again every draw that a ``campaign.json`` lists as failed (or every draw of
``results/campaign_known_failures.json``), with the same checks, and writes
``recheck.md`` and ``recheck.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import random
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import jackbox  # noqa: E402
from jackbox.fileio import write_atomic  # noqa: E402

FAMILIES = {
    "drops": ("test_random_drops_never_penetrate_nor_gain_energy", {},
              "box and square jack, gravity and the ground"),
    "weightless square": ("test_random_weightless_scenes_keep_momentum", {"shape": "square", "structure": "float"},
                          "no gravity, no ground, square jack"),
    "weightless cross": ("test_random_weightless_scenes_keep_momentum", {"shape": "cross", "structure": "cross"},
                         "no gravity, no ground, cross jack"),
    "prescribed box": ("test_random_prescribed_box_never_penetrates", {}, "a box moved by a hand, gravity"),
}
#: each family's checks on one run (tests/test_stress.py's functions) and its base scene (its ``base``):
#: the weightless families' is their test's structure
CHECKS = {"drops": ("check_drop_run", "drop"), "weightless square": ("check_weightless_run", None),
          "weightless cross": ("check_weightless_run", None), "prescribed box": ("check_prescribed_run", "hand")}
#: the issue's ranges: jack-to-box mass ratio, speeds in sqrt(g L), the square jack's half-size in L
RANGES = {"MASS_RATIO": (1e-4, 1e4), "SPEED": (0.1, 30.0), "SQUARE_SIZE": 0.99}


def classify(exc: BaseException) -> str:
    text = str(exc)
    if type(exc).__name__ == "OverBudget":
        return "over the event budget"
    if "energy rose" in text or "energy" in text.lower():
        return "energy gained"
    if "has gap" in text:
        return "gap below the test's floor"
    if isinstance(exc, AssertionError) and text.startswith("('linear momentum'"):
        return "linear momentum drift"
    if isinstance(exc, AssertionError) and text.startswith("(") and len(text.split(",")) == 4:
        return "angular momentum drift"
    return type(exc).__name__


def run_family(T, name: str, examples: int, seed: int) -> dict:
    from hypothesis import HealthCheck, Phase, given, seed as hseed, settings
    from hypothesis import strategies as st
    from hypothesis.errors import UnsatisfiedAssumption

    test_name, kwargs, what = FAMILIES[name]
    inner = getattr(T, test_name).hypothesis.inner_test
    last: dict = {}
    load = jackbox.load_scene

    def recording_load(base, overrides=None, *a, **k):
        last["overrides"] = overrides
        return load(base, overrides, *a, **k)

    simulate = T.simulate

    def recording_simulate(scene, budget=T.EVENT_BUDGET, **kw):
        last["dt"] = kw.get("dt")
        return simulate(scene, budget, **kw)

    out = {"family": name, "what": what, "examples": 0, "failures": [], "by_check": {}}

    @hseed(seed)
    @settings(max_examples=examples, deadline=None, derandomize=False, phases=[Phase.generate], database=None,
              suppress_health_check=list(HealthCheck))
    @given(data=st.data())
    def one(data):
        last.clear()
        try:
            inner(data=data, **kwargs)
        except UnsatisfiedAssumption:
            raise
        except Exception as exc:          # a failed check: classified and kept, the campaign goes on
            kind = classify(exc)
            out["by_check"][kind] = out["by_check"].get(kind, 0) + 1
            out["failures"].append({"check": kind, "message": str(exc)[:400], "dt": last.get("dt"),
                                    "overrides": last.get("overrides")})
        out["examples"] += 1

    jackbox.load_scene, T.jackbox.load_scene, T.simulate = recording_load, recording_load, recording_simulate
    t0 = time.perf_counter()
    try:
        one()
    finally:
        jackbox.load_scene, T.jackbox.load_scene, T.simulate = load, load, simulate
    out["seconds"] = time.perf_counter() - t0
    out["passed"] = out["examples"] - len(out["failures"])
    print(f"{name}: {out['passed']} of {out['examples']} pass"
          + "".join(f"; {n} {kind}" for kind, n in sorted(out["by_check"].items())) + f" ({out['seconds']:.0f} s)",
          flush=True)
    return out


def markdown(res: dict) -> str:
    lines = ["# Random scenes at the full ranges (benchmarks/campaign.py)", "",
             f"Machine: {res['machine']}. Command: `{res['command']}`. Ranges: jack-to-box mass ratio "
             f"{RANGES['MASS_RATIO'][0]:g}..{RANGES['MASS_RATIO'][1]:g}, speeds up to "
             f"{RANGES['SPEED'][1]:g} sqrt(g L), square jacks up to {RANGES['SQUARE_SIZE']:g} L, e in [0, 1]; "
             "the checks of tests/test_stress.py.", "",
             "| family | scenes | pass | failed checks |", "| --- | --- | --- | --- |"]
    for r in res["families"]:
        failed = ", ".join(f"{n} {kind}" for kind, n in sorted(r["by_check"].items())) or "-"
        lines.append(f"| {r['family']} ({r['what']}) | {r['examples']} | {r['passed']} | {failed} |")
    lines += ["", "Every failing draw (scene overrides and dt) is in campaign.json.", ""]
    return "\n".join(lines)


def draws_in(path: Path) -> list[dict]:
    """The draws a file lists: a campaign.json's failures, or a list under "draws" (each with its family)."""
    data = json.loads(path.read_text())
    if "draws" in data:
        return list(data["draws"])
    return [{"family": fam["family"], **f} for fam in data["families"] for f in fam["failures"]]


def recheck(T, path: Path) -> dict:
    """Every draw in ``path`` run again with its family's checks: which pass now, and how the others fail."""
    out = []
    for d in draws_in(path):
        check, base = CHECKS[d["family"]]
        base = base or FAMILIES[d["family"]][1]["structure"]
        t0 = time.perf_counter()
        try:
            getattr(T, check)(jackbox.load_scene(T.base(base), d["overrides"]), d["dt"])
            kind, message = "pass", ""
        except Exception as exc:          # a failed check: classified, the recheck goes on
            kind, message = classify(exc), str(exc)[:400]
        out.append({"family": d["family"], "was": d.get("check", ""), "now": kind, "message": message,
                    "seconds": time.perf_counter() - t0, "dt": d["dt"], "overrides": d["overrides"]})
        print(f"{d['family']}: {d.get('check', '?')} -> {kind}", flush=True)
    return {"draws": out, "passed": sum(r["now"] == "pass" for r in out)}


def recheck_markdown(res: dict) -> str:
    lines = ["# Failing random scenes run again (benchmarks/campaign.py --recheck)", "",
             f"Machine: {res['machine']}. Command: `{res['command']}`. "
             f"{res['passed']} of {len(res['draws'])} pass now.", "",
             "| family | failed then | now |", "| --- | --- | --- |"]
    lines += [f"| {r['family']} | {r['was']} | {r['now']} |" for r in res["draws"]]
    return "\n".join(lines + [""])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--examples", type=int, default=300, help="random scenes per family (default 300)")
    ap.add_argument("--seed", type=int, default=0, help="which random scenes (default 0)")
    ap.add_argument("--families", nargs="+", choices=list(FAMILIES), default=list(FAMILIES),
                    help="which families of scenes (default: all)")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results", help="folder for the results")
    ap.add_argument("--recheck", type=Path, metavar="FILE",
                    help="instead: run again the failed draws a campaign.json (or campaign_known_failures.json) lists")
    args = ap.parse_args(argv)
    if args.examples < 1:
        ap.error(f"--examples must be at least 1, got {args.examples}")
    if args.recheck is not None:
        if not args.recheck.is_file():
            ap.error(f"--recheck: no file {args.recheck}")
        try:
            draws_in(args.recheck)
        except (ValueError, KeyError, TypeError) as exc:
            ap.error(f"--recheck: {args.recheck} is not a campaign.json nor a list of draws ({exc})")
    import tests.test_stress as T

    command = " ".join(["python", "benchmarks/campaign.py", *(argv if argv is not None else sys.argv[1:])])
    if args.recheck is not None:
        res = {"machine": f"{platform.machine()}, {os.cpu_count()} cores", "command": command,
               **recheck(T, args.recheck)}
        args.out.mkdir(parents=True, exist_ok=True)
        write_atomic(args.out / "recheck.json", json.dumps(res, indent=1, default=str))
        write_atomic(args.out / "recheck.md", recheck_markdown(res))
        print(f"{res['passed']} of {len(res['draws'])} pass now; wrote {args.out / 'recheck.md'}")
        return 0

    for key, value in RANGES.items():
        setattr(T, key, value)
    random.seed(args.seed)
    res = {"machine": f"{platform.machine()}, {os.cpu_count()} cores", "command": command,
           "ranges": RANGES, "families": [run_family(T, name, args.examples, args.seed) for name in args.families]}
    args.out.mkdir(parents=True, exist_ok=True)
    write_atomic(args.out / "campaign.json", json.dumps(res, indent=1, default=str))
    write_atomic(args.out / "campaign.md", markdown(res))
    print(f"wrote {args.out / 'campaign.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
