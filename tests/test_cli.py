"""The ``jackbox`` command line: help, scenes, run (output file, summary, --set), the
one-line refusals of user mistakes, build (--check, a stale module, a scene file's model
in the cache) and the energy figures that compare prints. (ensemble and chaos: in
test_ensemble.py; --dask local: in test_dask.py.)

Most tests call ``jackbox.cli.main`` in-process; a few go through a real
``python -m jackbox.cli`` to see exactly what a user sees. Runs are 0.2 s of the
built-in 'drop' scene, whose kernel is reused from the user's cache.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import jackbox
from jackbox.cli import main
from jackbox.scene import builtin_scenes

from .conftest import FREE_FLOAT, run_cli, write_scene

# SCENES.md, "Output: trajectory file (.npz)"
NPZ_KEYS = {"t", "q", "qd", "energy", "impact_t", "impact_constraint", "constraint_names",
            "scene", "meta"}
DROP_TEXT = builtin_scenes()["drop"].read_text(encoding="utf-8")
T_END = "0.2"
N_SAMPLES = 201      # 0.2 s at the scene's dt = 1e-3, both ends included


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    # a run without --out writes runs/<name> in the working folder: never in the repo
    monkeypatch.chdir(tmp_path)




def assert_one_line_error(status, out, err):
    assert status == 2, (status, out, err)
    assert "Traceback" not in err
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("jackbox: error: "), err
    assert out == ""


def files_under(folder: Path) -> set[str]:
    return {str(p.relative_to(folder)) for p in folder.rglob("*")}


# --- help ---------------------------------------------------------------------------------

def test_help_subprocess():
    proc = subprocess.run([sys.executable, "-m", "jackbox.cli", "--help"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    for word in ("run", "build", "scenes", "--version"):
        assert word in proc.stdout
    assert proc.stderr == ""


# the program as the `jackbox` command runs it: cli.console(), which ends the process with os._exit
CONSOLE = """
import atexit, sys, threading, time
import jackbox.cli as cli
atexit.register(lambda: print("an exit handler ran"))
if sys.argv[1] == "thread":
    del sys.argv[1]
    threading.Thread(target=lambda: (time.sleep(0.3), print("the thread finished", file=sys.stderr))).start()
cli.console()
"""


@pytest.mark.parametrize("thread", [False, True])
@pytest.mark.parametrize("argv", [["scenes"], ["run", "no-such-scene.toml"]])
def test_the_program_ends_with_mains_status_and_output_and_runs_the_exit_handlers(capsys, thread, argv):
    # stdout is a pipe (block-buffered): every line main and the exit handler printed must still
    # come out; a thread still running is waited for, as Python's own exit does
    status, out, err = run_cli(capsys, *argv)
    env = {name: value for name, value in os.environ.items() if name != "PYTHONUNBUFFERED"}
    proc = subprocess.run([sys.executable, "-c", CONSOLE, *(["thread"] if thread else []), *argv],
                          capture_output=True, text=True, timeout=120, env=env)
    assert (proc.returncode, proc.stdout) == (status, out + "an exit handler ran\n")
    # (the thread's line may come before main's: main's takes longer where Numba loads slowly)
    assert sorted(proc.stderr.splitlines()) == sorted((err + "the thread finished\n" * thread).splitlines())


@pytest.mark.parametrize("argv", [[], ["--help"], ["-h"]])
def test_help(capsys, argv):
    status, out, _ = run_cli(capsys, *argv)
    assert status == 0
    assert "usage: jackbox" in out
    for command in ("run", "build", "scenes"):
        assert command in out


def test_version(capsys):
    status, out, _ = run_cli(capsys, "--version")
    assert status == 0
    assert jackbox.__version__ in out


@pytest.mark.parametrize("command, options", [
    ("run", ["--t-end", "--dt", "--set", "--record-every", "--out", "--quiet", "-q", "scene"]),
    ("build", ["--check", "SCENE"]),
    ("scenes", ["built-in"]),
])
def test_subcommand_help(capsys, command, options):
    status, out, _ = run_cli(capsys, command, "--help")
    assert status == 0
    assert f"usage: jackbox {command}" in out
    for option in options:
        assert option in out, option


# --- scenes -------------------------------------------------------------------------------

def test_scenes_lists_builtins(capsys):
    status, out, err = run_cli(capsys, "scenes")
    assert status == 0
    listed = [line.split()[0] for line in out.splitlines() if line.strip()]
    assert {"drop", "shaken", "spring"} <= set(listed)
    # each with its description
    assert jackbox.load_scene("drop").description in out


# --- run ----------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def drop_run(tmp_path_factory):
    """One quiet 0.2 s run of drop, shared by the tests that only read its output."""
    out_dir = tmp_path_factory.mktemp("drop_run") / "out"
    status = main(["run", "drop", "--t-end", T_END, "--out", str(out_dir), "-q", "--no-plots"])
    return status, out_dir


def test_run_no_plots_writes_only_the_trajectory(drop_run):
    # the pictures that run writes by default are tested in test_plots.py
    status, out_dir = drop_run
    assert status == 0
    assert files_under(out_dir) == {"trajectory.npz"}


def test_run_npz_keys_and_shapes(drop_run):
    _, out_dir = drop_run
    with np.load(out_dir / "trajectory.npz", allow_pickle=False) as data:
        # SCENES.md's keys, plus the contact mode changes and the fallback's stretches of the exact method
        assert set(data.files) == NPZ_KEYS | {"contact_t", "contact_constraint", "contact_event", "fallback_t"}
        arrays = {k: data[k] for k in data.files}
        assert arrays["fallback_t"].shape == (0, 2)     # the drop needs none
    n, k = N_SAMPLES, len(arrays["impact_t"])
    assert arrays["t"].shape == (n,)
    assert arrays["q"].shape == (n, 6)
    assert arrays["qd"].shape == (n, 6)
    assert arrays["energy"].shape == (n,)
    assert arrays["impact_t"].shape == (k,)
    assert arrays["impact_constraint"].shape == (k,)
    # drop: a square jack (4 corners x 4 walls) and the ground (4 box corners)
    names = [str(s) for s in arrays["constraint_names"]]
    assert len(names) == 20
    assert names[:4] == ["right:0", "right:1", "right:2", "right:3"]
    assert names[-4:] == ["ground:0", "ground:1", "ground:2", "ground:3"]
    assert arrays["scene"].shape == () and arrays["meta"].shape == ()
    assert arrays["t"][0] == 0.0
    assert arrays["t"][-1] == pytest.approx(0.2)
    np.testing.assert_allclose(arrays["q"][0], [0.0, 2.0, 0.3, 0.0, 2.0, 0.0])
    assert str(arrays["scene"]) == DROP_TEXT
    meta = json.loads(str(arrays["meta"]))
    assert {"jackbox", "method", "dt", "params", "model_hash"} <= set(meta)
    assert meta["jackbox"] == jackbox.__version__
    assert meta["dt"] == 1e-3
    assert meta["params"]["e"] == 1.0


def test_run_npz_round_trips_through_trajectory(drop_run, tmp_path):
    _, out_dir = drop_run
    path = out_dir / "trajectory.npz"
    traj = jackbox.Trajectory.load(path)
    with np.load(path, allow_pickle=False) as data:
        for key in ("t", "q", "qd", "energy", "impact_t", "impact_constraint"):
            np.testing.assert_array_equal(getattr(traj, key), data[key])
        assert traj.constraint_names == tuple(str(s) for s in data["constraint_names"])
        assert traj.meta == json.loads(str(data["meta"]))
    assert traj.scene == DROP_TEXT
    assert len(traj) == N_SAMPLES
    again = jackbox.Trajectory.load(traj.save(tmp_path / "again.npz"))
    for key in ("t", "q", "qd", "energy", "impact_t", "impact_constraint"):
        np.testing.assert_array_equal(getattr(again, key), getattr(traj, key))
    assert (again.constraint_names, again.scene, again.meta) == (traj.constraint_names, traj.scene, traj.meta)


def test_run_prints_summary(capsys, tmp_path):
    out_dir = tmp_path / "out"
    status, out, _ = run_cli(capsys, "run", "drop", "--t-end", T_END, "--out", str(out_dir))
    assert status == 0
    for word in ("steps", "impacts", "energy", "steps/s"):
        assert word in out, out
    assert "200 of dt" in out          # 0.2 s / 1e-3
    assert str(out_dir / "trajectory.npz") in out
    assert (out_dir / "trajectory.npz").is_file()


def test_run_set_restitution_reaches_meta(capsys, tmp_path):
    out_dir = tmp_path / "out"
    status, _, err = run_cli(capsys, "run", "drop", "--t-end", T_END, "--out", str(out_dir), "-q",
                             "--set", "restitution=0.6")
    assert status == 0, err
    params = jackbox.Trajectory.load(out_dir / "trajectory.npz").meta["params"]
    assert params["e"] == 0.6
    assert params["e_ground"] == 0.6    # ground_restitution follows restitution


def test_run_scene_file(capsys, tmp_path):
    from jackbox import loader

    path = tmp_path / "mine.toml"
    path.write_text(DROP_TEXT.replace('name = "drop"', 'name = "mine"'), encoding="utf-8")
    # same structure as drop: the same compiled kernel serves it, nothing is generated
    # or compiled for it (the cache is keyed by structure, not by name)
    mine = jackbox.load_scene(path)
    assert loader.model_path(mine) == loader.GENERATED_DIR / "drop.py"
    assert loader.kernel_for(mine) is loader.kernel_for(jackbox.load_scene("drop"))
    jackbox.simulate("drop", t_end=0.01)          # drop's exact loop compiled (or loaded)
    status, _, err = run_cli(capsys, "run", str(path), "--t-end", T_END, "--out", "res", "-q")
    assert status == 0, err
    traj = jackbox.Trajectory.load(tmp_path / "res" / "trajectory.npz")
    assert traj.meta["scene"] == "mine"
    assert traj.meta["kernel"]["cache"] == "memory"     # drop's loop, not a compile of its own
    assert 'name = "mine"' in traj.scene


def test_run_record_every(capsys, tmp_path):
    status, _, err = run_cli(capsys, "run", "drop", "--t-end", T_END, "--record-every", "10",
                             "--out", "out", "-q")
    assert status == 0, err
    traj = jackbox.Trajectory.load(tmp_path / "out" / "trajectory.npz")
    assert len(traj) == 21
    assert traj.t[-1] == pytest.approx(0.2)


# --- user mistakes: status 2, one line, nothing written -----------------------------------

def _malformed_toml(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text(DROP_TEXT.replace("[jack]", "[jack"), encoding="utf-8")
    return str(path), "TOML"


def _invalid_value(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text(DROP_TEXT.replace("restitution = 1.0", "restitution = 1.5"), encoding="utf-8")
    return str(path), "impact.restitution"


def _missing_file(tmp_path):
    return str(tmp_path / "nowhere.toml"), "no such"


def _missing_builtin(tmp_path):
    return "no_such_scene", "no such"


@pytest.mark.parametrize("make", [_missing_file, _missing_builtin, _malformed_toml, _invalid_value])
def test_bad_scene(capsys, tmp_path, make):
    scene, word = make(tmp_path)
    out_dir = tmp_path / "out"
    before = files_under(tmp_path)
    result = run_cli(capsys, "run", scene, "--t-end", T_END, "--out", str(out_dir))
    assert_one_line_error(*result)
    assert word in result[2]
    if scene.endswith(".toml"):
        assert scene in result[2]       # the message names the file
    assert files_under(tmp_path) == before


@pytest.mark.parametrize("setting, word", [
    ("restitution", "NAME=VALUE"),         # no '='
    ("=0.6", "NAME=VALUE"),                # no name
    ("nosuch=1", "--set nosuch"),          # unknown name
    ("mass=2", "--set mass"),              # in [box] and [jack]: ambiguous
    ("restitution=2", "impact.restitution"),
])
def test_bad_set(capsys, tmp_path, setting, word):
    before = files_under(tmp_path)
    result = run_cli(capsys, "run", "drop", "--t-end", T_END, "--out", str(tmp_path / "out"),
                     "--set", setting)
    assert_one_line_error(*result)
    assert word in result[2]
    assert files_under(tmp_path) == before


def test_out_is_a_regular_file(capsys, tmp_path):
    target = tmp_path / "taken"
    target.write_bytes(b"not a folder")
    result = run_cli(capsys, "run", "drop", "--t-end", T_END, "--out", str(target))
    assert_one_line_error(*result)
    assert str(target) in result[2]
    assert target.read_bytes() == b"not a folder"
    assert files_under(tmp_path) == {"taken"}


def test_failed_run_leaves_existing_trajectory_intact(capsys, tmp_path):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    old = out_dir / "trajectory.npz"
    old.write_bytes(b"an earlier run")
    scene, _ = _invalid_value(tmp_path)
    result = run_cli(capsys, "run", scene, "--t-end", T_END, "--out", str(out_dir))
    assert_one_line_error(*result)
    assert old.read_bytes() == b"an earlier run"
    assert files_under(out_dir) == {"trajectory.npz"}


def test_bad_scene_subprocess_shows_no_traceback(tmp_path):
    scene, _ = _malformed_toml(tmp_path)
    proc = subprocess.run([sys.executable, "-m", "jackbox.cli", "run", scene, "--out", "out"],
                          capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith("jackbox: error: "), proc.stderr
    assert scene in lines[0] and "TOML" in lines[0]
    assert not (tmp_path / "out").exists()


def test_force_that_cannot_be_evaluated_is_one_line(capsys, tmp_path):
    path = tmp_path / "div.toml"
    path.write_text(DROP_TEXT + '\n[forces]\nx_box = "1/0"\n', encoding="utf-8")
    result = run_cli(capsys, "run", str(path), "--t-end", T_END, "--out", str(tmp_path / "out"))
    assert_one_line_error(*result)


# --- build --------------------------------------------------------------------------------

def test_build_check_builtins_current(capsys):
    status, out, err = run_cli(capsys, "build", "--check")
    assert status == 0, out + err
    lines = out.splitlines()
    assert len(lines) == len(builtin_scenes())
    for name in ("drop", "shaken", "spring"):
        assert any(line.startswith("current") and line.endswith(f"{name}.py") for line in lines), out


def test_build_check_names_a_stale_builtin_and_build_rewrites_it(capsys, tmp_path, monkeypatch):
    # a copy of generated/ whose drop.py records another model hash: --check says so and
    # exits 1, writing nothing; build regenerates it, byte-identical to the committed module
    from jackbox import loader

    folder = tmp_path / "generated"
    folder.mkdir()
    committed = (loader.GENERATED_DIR / "drop.py").read_text(encoding="utf-8")
    recorded = loader.recorded_hash(loader.GENERATED_DIR / "drop.py")
    stale = committed.replace(f'MODEL_HASH = "{recorded}"', 'MODEL_HASH = "0000000000000000"')
    assert stale != committed
    (folder / "drop.py").write_text(stale, encoding="utf-8")
    monkeypatch.setattr(loader, "GENERATED_DIR", folder)

    status, out, err = run_cli(capsys, "build", "--check", "drop")
    assert status == 1, out + err
    assert out.splitlines() == [f"STALE    {folder / 'drop.py'}"]
    assert (folder / "drop.py").read_text(encoding="utf-8") == stale

    status, out, err = run_cli(capsys, "build", "drop")
    assert status == 0, out + err
    assert out.startswith(f"wrote      {folder / 'drop.py'}"), out
    assert (folder / "drop.py").read_text(encoding="utf-8") == committed

    status, out, err = run_cli(capsys, "build", "--check", "drop")
    assert status == 0 and out.splitlines() == [f"current  {folder / 'drop.py'}"], out + err


def test_build_scene_file_writes_its_model_into_the_cache(capsys, tmp_path, monkeypatch):
    # README: a scene that is not built in has its module generated into the cache folder
    # ($JACKBOX_CACHE_DIR), never into generated/; a second build leaves it byte-identical
    from codegen import model_hash

    from jackbox import loader

    cache = tmp_path / "cache"
    monkeypatch.setenv("JACKBOX_CACHE_DIR", str(cache))
    path = write_scene(tmp_path, FREE_FLOAT, "float.toml")       # no gravity: not a built-in's structure
    scene = jackbox.load_scene(path)
    digest = model_hash(scene.structure())
    assert loader.committed_model(digest) is None

    status, out, err = run_cli(capsys, "build", str(path))
    assert status == 0, out + err
    lines = out.splitlines()
    assert len(lines) == 1 and lines[0].startswith("wrote"), out
    written = Path(lines[0].split()[1])
    assert written.is_relative_to(cache) and written.is_file()
    assert written == loader.model_path(scene)                   # where a run looks for it
    text = written.read_text(encoding="utf-8")
    assert loader.recorded_hash(written) == digest
    assert "Do NOT modify by hand" in text
    before = written.stat().st_mtime_ns
    assert loader.ensure_model(scene) == written and written.stat().st_mtime_ns == before   # used as is

    status, out, err = run_cli(capsys, "build", str(path))
    assert status == 0 and out.startswith(f"unchanged  {written}"), out + err
    assert written.read_text(encoding="utf-8") == text
    assert [p.name for p in cache.rglob("*.py")] == [written.name]


# --- compare ------------------------------------------------------------------------------

def settled_at(t: np.ndarray, energy: np.ndarray) -> float | None:
    """README: a run has settled once its energy stays within 1% of the energy it lost of its
    final value, for at least the last 10% of the run (an elastic run, losing nothing, has not)."""
    lost = energy[0] - energy[-1]
    if not lost > 1e-9 * abs(energy[0]):
        return None
    outside = np.flatnonzero(np.abs(energy - energy[-1]) > 0.01 * lost)
    i = outside[-1] + 1 if len(outside) else 0
    return float(t[i]) if i < len(t) and t[-1] - t[i] >= 0.1 * (t[-1] - t[0]) else None


def test_compare_prints_the_energy_of_each_run(capsys, tmp_path):
    status, out, err = run_cli(capsys, "compare", "drop", "--restitution", "1.0", "0.6", "--out", "cmp")
    assert status == 0, err
    rows = {}
    for line in out.splitlines():
        cells = re.split(r"\s{2,}", line.strip())
        if cells[0] in ("1", "0.6"):
            rows[float(cells[0])] = cells
    assert sorted(rows) == [0.6, 1.0], out
    # drop's start, by hand: both bodies at y = 2 (masses 10 and 1), the jack moving at 0.8 m/s
    # and spinning at 6 rad/s (J = 2 m a^2 / 3, a = 0.25)
    e0 = 9.81 * (10.0 + 1.0) * 2.0 + 0.5 * 0.8 ** 2 + 0.5 * (2 * 0.25 ** 2 / 3) * 6.0 ** 2
    trajs = {}
    for e, cells in rows.items():
        traj = jackbox.simulate("drop", params={"e": e, "e_ground": e})     # the scene's 5 s
        trajs[e] = traj
        start, end, lost, impulses, settles = cells[1:]
        # printed with 6 significant digits (the loss with 4, its share with 1 decimal)
        assert traj.energy[0] == pytest.approx(e0, rel=1e-14)
        assert float(start.removesuffix(" J")) == pytest.approx(traj.energy[0], rel=5e-6), cells
        assert float(end.removesuffix(" J")) == pytest.approx(traj.energy[-1], rel=5e-6), cells
        m = re.fullmatch(r"(\S+) J \((\S+)%\)", lost)
        assert m, cells
        loss = traj.energy[0] - traj.energy[-1]
        if e == 1.0:       # elastic: the energy is kept to round-off, and the loss printed as 0
            assert abs(loss) < 1e-12 * e0 and float(m[1]) == 0.0 and float(m[2]) == 0.0, cells
        else:
            assert loss > 0.1 * e0
            assert float(m[1]) == pytest.approx(loss, rel=5e-4), cells
            assert float(m[2]) == pytest.approx(100 * loss / traj.energy[0], abs=0.05), cells
        assert int(impulses) == len(traj.impact_t), cells
        t_s = settled_at(traj.t, traj.energy)
        if t_s is None:
            assert settles == "did not settle", cells
        else:
            m = re.fullmatch(r"at t = (\S+) s", settles)
            assert m and float(m[1]) == pytest.approx(t_s, rel=5e-3), cells
    # README: the elastic box keeps bouncing and the inelastic one settles
    assert rows[1.0][5] == "did not settle" and rows[0.6][5].startswith("at t = ")
    assert np.array_equal(trajs[1.0].t, trajs[0.6].t)
    assert (tmp_path / "cmp" / "comparison.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
