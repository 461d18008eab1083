"""The benchmark scripts run end to end (their --quick modes) and their figures are sane.

Timings are never asserted (STYLE.md): only that the files are written and that
the measured convergence orders are those of the methods.
"""

from __future__ import annotations

import json
import math
import platform
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent


def test_workprecision_quick_mode(tmp_path):
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "workprecision.py"), "--quick", "--out", str(tmp_path)],
                   check=True, cwd=ROOT, capture_output=True, text=True, timeout=300)
    for ext in ("csv", "json", "md", "png"):
        assert (tmp_path / f"workprecision.{ext}").stat().st_size > 0, ext
    assert (tmp_path / "workprecision.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    result = json.loads((tmp_path / "workprecision.json").read_text())
    (scene,) = result["scenes"]
    # the exact method is RK4 with located impacts: order 4; the naive one is first order at impacts
    # (its errors scatter with where the impacts fall in a step, hence the wide band)
    exact, naive = scene["orders"]["exact"], scene["orders"]["naive"]
    assert len(exact["dt"]) >= 3 and 3.0 < exact["order"] < 5.0, exact
    assert len(naive["dt"]) >= 3 and 0.5 < naive["order"] < 1.6, naive
    # the reference agrees with scipy's event-located solution far below the errors fitted
    assert scene["same_scipy"] and scene["diff_scipy"] < 1e-9
    assert scene["floor"] * 30 <= min(exact["error"])
    md = (tmp_path / "workprecision.md").read_text()
    assert "## Observed order" in md and "## Speed-up of the exact kernel at equal error" in md


def _positive(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) and x > 0


def test_throughput_quick_mode(tmp_path):
    # one scene, tiny sizes, no new processes; the first run on a machine compiles the
    # every-gap-every-step kernel variant (cached afterwards), hence the generous timeout
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "throughput.py"), "--quick", "--no-cold",
                           "--scenes", "shaken", "--repeat", "1", "--out", str(tmp_path)],
                          cwd=ROOT, capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr
    for ext in ("md", "json"):
        assert (tmp_path / f"throughput.{ext}").stat().st_size > 0, ext
    result = json.loads((tmp_path / "throughput.json").read_text())
    assert result["quick"] and result["invariants_hold"] and "throughput.py" in result["command"]
    (row,) = result["scenes"]
    assert row["scene"] == "shaken" and row["cold_start_s"] is None and row["warm_start_s"] is None
    for key in ("codegen_s", "exact_ns_per_step", "no_broad_phase_ns_per_step", "broad_phase_gain",
                "record_every_step_ns_per_step", "recording_gain", "naive_ns_per_step",
                "reference_ns_per_step", "speedup_exact_vs_reference", "speedup_naive_vs_reference"):
        assert _positive(row[key]), (key, row[key])
    # a real invariant, not a timing: skipping gap rows far from contact, or recording less,
    # changes no operation on the state, so the runs end in bit-identical states
    assert row["same_final_state_broad_phase"] is True
    assert row["same_final_state_recording"] is True
    ceiling = result["ceiling"]
    if ceiling["available"]:
        for key in ("c_ns_per_step", "kernel_over_c", "no_broad_phase_over_c"):
            assert _positive(ceiling[key]), (key, ceiling[key])
    else:
        assert ceiling["reason"]        # no C compiler here: said why, did not crash
    ens = result["ensemble"]
    if ens["available"]:
        for threads in ("1", "2"):
            assert _positive(ens["threads"][threads]["member_steps_per_second"]), threads
        assert _positive(ens["efficiency"]) and ens["same_results"] is True
        assert [(st["kind"], st["scene"]) for st in ens["studies"]] == [("ensemble", "shaken"), ("ensemble", "drop"),
                                                                         ("chaos", "shaken")]
        for st in ens["studies"]:     # in lanes and alone: the same members, bit for bit
            assert st["same_results"] is True and all(
                _positive(st["rows"][way][t]["member_steps_per_second"]) for way in ("lanes", "alone") for t in "12")
    else:
        assert ens["reason"]
    md = (tmp_path / "throughput.md").read_text()
    for title in ("## Step time and start-up", "## Against the lambdified reference", "## Broad phase",
                  "## Recording", "## The C ceiling", "## Ensemble scaling"):
        assert title in md, title


def test_contact_quick_mode(tmp_path):
    """benchmarks/contact.py --quick: the files, and the one figure that is not a timing: nothing lost."""
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "contact.py"), "--quick", "--out", str(tmp_path)],
                   check=True, cwd=ROOT, capture_output=True, text=True, timeout=600)
    result = json.loads((tmp_path / "contact.json").read_text())
    assert [r["lost"] for r in result["studies"]] == [0] * 5
    assert result["sweep"]["lost"] == 0
    assert {r["e"] for r in result["restitution"]} == {0.0, 0.025, 0.1, 0.2, 0.5, 1.0}
    assert all(_positive(r["run_s"]) for r in result["restitution"])
    assert _positive(result["resting"]["resting_ns_per_step"]) and result["resting"]["held_contacts"] == 4
    assert "| study |" in (tmp_path / "contact.md").read_text()


def test_contact_side_by_side_with_another_checkout(tmp_path):
    """--against runs the restitution rows with another checkout's code too (here this one's: no second tree
    needed), in processes of their own; a folder that is not a checkout is refused in one line."""
    script = str(ROOT / "benchmarks" / "contact.py")
    subprocess.run([sys.executable, script, "--quick", "--out", str(tmp_path), "--against", str(ROOT)],
                   check=True, cwd=ROOT, capture_output=True, text=True, timeout=600)
    result = json.loads((tmp_path / "contact.json").read_text())
    keys = {f"{r['scene']} {r['e']!r}" for r in result["restitution"]}
    assert set(result["against"]["this"]) == set(result["against"]["other"]) == keys
    assert all(_positive(v) for v in result["against"]["other"].values())
    assert "| this checkout | other | this / other |" in (tmp_path / "contact.md").read_text()
    bad = subprocess.run([sys.executable, script, "--quick", "--out", str(tmp_path), "--against", str(tmp_path)],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "not a jackbox checkout" in bad.stderr and "Traceback" not in bad.stderr


def test_overhead_quick_mode_side_by_side(tmp_path):
    """benchmarks/overhead.py --quick --against (this checkout again): each call's figure for both, in the files;
    a folder that is not a checkout is refused in one line."""
    script = str(ROOT / "benchmarks" / "overhead.py")
    subprocess.run([sys.executable, script, "--quick", "--out", str(tmp_path), "--against", str(ROOT)],
                   check=True, cwd=ROOT, capture_output=True, text=True, timeout=600)
    result = json.loads((tmp_path / "overhead.json").read_text())
    assert set(result["this"]) == set(result["against"]["ms"]) == {"simulate", "study_32", "study_2000"}
    assert all(_positive(v) for v in [*result["this"].values(), *result["against"]["ms"].values()])
    assert "| this checkout, ms | other checkout, ms | this / other |" in (tmp_path / "overhead.md").read_text()
    bad = subprocess.run([sys.executable, script, "--quick", "--out", str(tmp_path), "--against", str(tmp_path)],
                         cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and "not a jackbox checkout" in bad.stderr and "Traceback" not in bad.stderr


def test_throughput_resting_row():
    # jackbox bench's rows for a step with held contacts against a free one: the settled
    # plastic drop, and the jack riding the shaken box's floor. Every figure measured, and
    # the runs really hold (the drop the same four contacts at its end, no impulse; the
    # stretch of shaken two tips and no event): a timing of the wrong thing would be worse than none
    from jackbox.bench import SIZES, bench_resting, markdown

    r = bench_resting(1, SIZES["quick"])
    assert r["available"] and r["still_at_rest"]
    assert r["held"] == ["bottom:0", "bottom:1", "ground:2", "ground:3"] and r["held_contacts"] == 4
    for key in ("resting_ns_per_step", "free_ns_per_step", "ratio"):
        assert _positive(r[key]), (key, r[key])
    ride = r["riding"]
    assert ride["held"] == ["bottom:1", "bottom:2"] and ride["events"] == 0
    for key in ("held_ns_per_step", "elastic_ns_per_step", "ratio"):
        assert _positive(ride[key]), (key, ride[key])
    # and wedged in a corner: four contacts persistent, three rows held and one following them
    corner = r["corner"]
    assert corner["held"] == ["right:2", "right:3", "bottom:1", "bottom:2"] and corner["events"] == 0
    assert _positive(corner["held_ns_per_step"]) and _positive(corner["ratio"])
    text = markdown({"command": "x", "machine": {"description": "m"}, "repeat": 1, "wall_seconds": 1.0,
                     "quick": True, "sizes": SIZES["quick"], "load_average": {"start": None, "end": None},
                     "scenes": [], "ceiling": {"reason": "-"}, "ensemble": {"reason": "-"}, "resting": r,
                     "targets": []})
    assert "## Held contacts" in text and "bottom:0, bottom:1, ground:2, ground:3" in text
    assert "riding a shaken floor, shaken e = 0: 2 (bottom:1, bottom:2)" in text
    assert "held in a corner, shaken e = 0: 4 (right:2, right:3, bottom:1, bottom:2)" in text


def test_campaign_quick_mode(tmp_path):
    # benchmarks/campaign.py: the property tests' draws and checks at the issue's ranges; two
    # scenes of one family here, only that it runs, counts and writes (its figures are the README's)
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "campaign.py"), "--examples", "2",
                           "--families", "prescribed box", "--out", str(tmp_path)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    result = json.loads((tmp_path / "campaign.json").read_text())
    (family,) = result["families"]
    assert family["family"] == "prescribed box" and family["examples"] == 2
    assert family["passed"] + len(family["failures"]) == 2
    assert result["ranges"]["MASS_RATIO"] == [1e-4, 1e4]
    assert "| prescribed box" in (tmp_path / "campaign.md").read_text()


def test_campaign_names_each_failed_check():
    # the failures the property tests' checks raise, as benchmarks/campaign.py tables them
    import importlib.util
    spec = importlib.util.spec_from_file_location("campaign", ROOT / "benchmarks" / "campaign.py")
    campaign = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(campaign)
    assert campaign.classify(AssertionError(("linear momentum", 3.6e-12, 3.3e-12))) == "linear momentum drift"
    assert campaign.classify(AssertionError((0.62, 1e-12, 0, 0.007))) == "angular momentum drift"
    assert campaign.classify(AssertionError("energy rose by 2e-8 of its scale")) == "energy gained"
    assert campaign.classify(AssertionError()) == "AssertionError"


def test_campaign_recheck_runs_listed_draws_again(tmp_path):
    # --recheck: the draws a file lists, run again with their family's checks (here a weightless cross
    # that the held steps' passes fixed, tests/test_stress.py's COARSE_TURNS: it must pass), and a
    # file that is neither kind of list refused with one line
    from tests.test_stress import COARSE_TURNS

    dt, over = COARSE_TURNS["omega dt 2.0"]
    draws = tmp_path / "draws.json"
    draws.write_text(json.dumps({"draws": [{"family": "weightless cross", "check": "angular momentum drift",
                                            "dt": dt, "overrides": {"gravity": 0.0, **over}}]}))
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "campaign.py"), "--recheck", str(draws),
                           "--out", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    result = json.loads((tmp_path / "recheck.json").read_text())
    assert result["passed"] == 1 and [d["now"] for d in result["draws"]] == ["pass"]
    assert "| weightless cross | angular momentum drift | pass |" in (tmp_path / "recheck.md").read_text()
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"something": 1}))
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "campaign.py"), "--recheck", str(bad)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 2 and "is not a campaign.json nor a list of draws" in done.stderr
    assert "Traceback" not in done.stderr


def _profile_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("jackbox_profile_bench", ROOT / "benchmarks" / "profile.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_profile_names_the_machine_code_numba_compiled(tmp_path):
    # perf's map of JIT code: each function Numba compiled in this process, at the address it runs from
    import ctypes

    import numba

    profile = _profile_module()

    @numba.cfunc("float64(float64)")
    def tripled(x):
        return 3.0 * x

    functions = profile.jit_functions()
    count = profile.write_perf_map(tmp_path / "perf.map", functions)
    rows = [line.split(" ", 2) for line in (tmp_path / "perf.map").read_text().splitlines()]
    assert count == len(rows) > 0
    starts = [int(start, 16) for start, _, _ in rows]
    assert starts == sorted(starts) and all(int(size, 16) > 0 for _, size, _ in rows)
    mine = [(int(start, 16), int(size, 16)) for start, size, name in rows if "tripled" in name]
    assert mine, "the cfunc compiled here is not in the map"
    # its native entry point (the cfunc's address) lies inside one of the ranges named after it
    address = ctypes.cast(tripled.ctypes, ctypes.c_void_p).value
    assert any(start <= address < start + size for start, size in mine)
    assert profile.demangled("_ZN7jackbox6engine6events10cubic_rootB3v80B38c8tJTIeFIjxB2IKSgIdddddd") == \
        "jackbox.engine.events.cubic_root"
    assert profile.demangled("__sin_fma") == "__sin_fma"
    # --annotate's pieces: the cfunc's bytes disassembled hold its multiply, and the hot lines come with the
    # instructions before them
    objdump = shutil.which("objdump")
    if objdump is None:
        pytest.skip("objdump is not installed")
    multiply = {"i386:x86-64": "mulsd", "aarch64": "fmul"}.get(profile.OBJDUMP_MACHINE.get(platform.machine()))
    if multiply is None:
        pytest.skip(f"no disassembly here for {platform.machine()}")
    # the multiply is in the Python function's own code, which the cfunc's wrapper calls: it is looked for there,
    # before that function's first return (a range runs to the next function, which may lie a megabyte on: the
    # test that looked anywhere in the wrapper's range passed or failed by what lay after it)
    inner = [(start, size, name) for start, size, name in rows
             if profile.demangled(name).endswith(".tripled") and not name.startswith("_ZN08NumbaEnv")]
    assert len(inner) == 1, inner
    start, size = int(inner[0][0], 16), int(inner[0][1], 16)
    # (to the next function where it is near, else to the end of the page the function starts in, mapped, and a
    # page more while no return is found: the function goes on into it, so it is mapped too)
    end = size if size <= 4096 else 4096 - start % 4096
    while True:
        lines = profile.disassembly(start, end, objdump)
        returns = [i for i, (_, insn) in enumerate(lines) if insn.split()[:1] in (["ret"], ["retq"])]
        if returns or end >= size:
            break
        end += 4096
    assert returns, lines
    body = lines[:returns[0] + 1]
    assert any(multiply in insn for _, insn in body), lines
    offsets = [offset for offset, _ in lines]
    hot = profile.hot_lines(lines, {offsets[4]: 3, offsets[0]: 1}, min_share=0.5)
    assert len(hot) == 4 and hot[-1].startswith(" 75.00%") and hot[0].startswith("  0.00%")
    assert profile.hot_lines(lines, {offsets[4]: 1}, 0.5, before=0)[0].split()[1] == f"{offsets[4]:x}"


def test_trip_quick_mode(tmp_path):
    # the harness is compiled in the subprocess (no cache): a minute on a cold machine
    done = subprocess.run([sys.executable, str(ROOT / "benchmarks" / "trip.py"), "--quick", "--out", str(tmp_path)],
                          cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    result = json.loads((tmp_path / "trip.json").read_text())
    assert result["quick"] and "trip.py" in result["command"] and result["rows"]
    # an invariant, not a timing: the step through run_segment and through the loop's body in a
    # reused, zeroed scratch end in the same bits
    assert result["same_bits"] is True
    for row in result["rows"]:
        assert row["impulses"] >= 3 and row["impact_step"] >= 30, row     # the third impact was found
        for key in ("impact_call_ns", "free_call_ns", "impact_body_ns", "free_body_ns", "run_ns_per_step"):
            assert _positive(row[key]), (key, row)
    assert "| impact step |" in (tmp_path / "trip.md").read_text()
