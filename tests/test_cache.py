"""Compiled once, never stale: Numba's cache is reused by a second process and can
never serve machine code for source that has changed since it was compiled.

Caching does not depend on the loop, so most of these tests run the cheapest one,
the naive method's; the hot-path test needs the exact loop (it is the one that flies).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import jackbox
from codegen import SEAL, seal
from jackbox import engine, loader

from .conftest import with_engine, write_scene

#: the cheapest loop: what is cached and when is the same for every loop
METHOD = "naive"
RUN = ("import jackbox, json; t = jackbox.simulate('drop', t_end=0.05, method='naive'); "
       "print(json.dumps(t.meta['kernel']))")


def test_second_process_loads_the_kernel_from_cache(tmp_path):
    env = os.environ | {"JACKBOX_CACHE_DIR": str(tmp_path)}
    env.pop("NUMBA_DISABLE_JIT", None)
    runs = [json.loads(subprocess.run([sys.executable, "-c", RUN], env=env, capture_output=True,
                                      text=True, check=True).stdout) for _ in range(2)]
    assert [r["cache"] for r in runs] == ["miss", "hit"]
    # loading is much cheaper than compiling (seconds vs a fraction of one)
    assert runs[1]["load_seconds"] < runs[0]["load_seconds"] / 3


def test_a_warm_process_loads_machine_code_without_numbas_lowering_registries(tmp_path):
    # Numba refreshes its target context before every cache load, importing all of its lowering
    # code (0.4 s, most of a warm start); jackbox's cache loads as is, and a compile later in the
    # process still sees every registry (Numba's compiler refreshes the context itself). (The engine as
    # the suite built it: the first process compiles drop's functions, the second loads everything.)
    env = os.environ | {"JACKBOX_CACHE_DIR": str(with_engine(tmp_path))}
    env.pop("NUMBA_DISABLE_JIT", None)
    probe = ("import sys, json, jackbox, numba; t = jackbox.simulate('drop', t_end=0.3); "
             "loaded = 'numba.np.linalg' in sys.modules; "
             "f = numba.njit(lambda a: a.sum() + a.dot(a))(__import__('numpy').arange(3.0)); "
             "print(json.dumps([t.meta['kernel']['cache'], loaded, t.q[-1].tolist(), float(f)]))")
    runs = [json.loads(subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, text=True,
                                      check=True).stdout) for _ in range(2)]
    assert [r[0] for r in runs] == ["miss", "hit"]
    assert runs[0][1] and not runs[1][1]       # compiled: the registries; loaded: none of them
    assert runs[1][2] == runs[0][2]            # the same machine code, the same numbers
    assert runs[1][3] == runs[0][3] == 8.0     # a compile after a registry-free load still works


def drop_of_its_own() -> str:
    """drop's text with a force that is a parameter set to 0: the same motion, a structure of its own."""
    text = jackbox.builtin_scenes()["drop"].read_text()
    return (text.replace("[box]", "[params]\npush = 0.0\n\n[box]", 1)
            .replace("[impact]", '[forces]\nx_jack = "push"\n\n[impact]'))


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("JACKBOX_CACHE_DIR", str(tmp_path / "cache"))
    # kernels imported earlier in this process would be reused from memory
    monkeypatch.setattr(loader, "_loaded", {})
    monkeypatch.setattr(loader, "_stamped", {})
    monkeypatch.setattr(loader, "_parts", {})
    return tmp_path / "cache"


def test_changed_hot_path_is_recompiled(fresh_cache, tmp_path, monkeypatch):
    before = jackbox.simulate("drop", t_end=0.3)       # the exact method: the one that flies
    # An edit of the free-flight hot path: the RK4 weights become wrong (1/5 instead of 1/6).
    edited = tmp_path / "flight.py"
    source = loader.FLIGHT_SOURCE.read_text()
    assert "h = dt / _SCALE" in source        # (the edit below must change something)
    edited.write_text(source.replace("h = dt / _SCALE", "h = dt / 5.0"))
    monkeypatch.setattr(loader, "FLIGHT_SOURCE", edited)
    after = jackbox.simulate("drop", t_end=0.3)
    assert not loader.load_kernel(loader.ensure_model(jackbox.load_scene("drop"))).cache_hit
    assert np.abs(after.q[-1] - before.q[-1]).max() > 1e-3   # the edit shows: not the old code
    # the hot path's functions were compiled again; the gaps, which do not reach it, were not
    assert [len(list((fresh_cache / "kernels").glob(f"{name}_*.py"))) for name in ("flight", "contact_rows")] == [2, 1]


def test_changed_engine_source_gets_a_cache_folder_of_its_own(tmp_path):
    # Numba checks only a function's own file; the engine's machine code is
    # kept per digest of all of its modules, so an edit of any stage is never
    # served code compiled from the old text.
    copy = tmp_path / "engine"
    shutil.copytree(Path(engine.__file__).parent, copy, ignore=shutil.ignore_patterns("__pycache__"))
    assert engine.cache.digest_of(copy) == engine.cache.DIGEST
    events = copy / "events.py"
    text = events.read_text()
    assert "4.0 * 2.220446049250313e-16" in text       # (locate's tolerance: an edit that changes the numbers)
    events.write_text(text.replace("4.0 * 2.220446049250313e-16", "8.0 * 2.220446049250313e-16"))
    assert engine.cache.digest_of(copy) != engine.cache.DIGEST
    assert engine.cache.engine_cache_path().name == engine.cache.DIGEST


def test_edited_model_module_is_recompiled(fresh_cache, tmp_path):
    # drop's text alone would use the committed generated/drop.py
    scene = jackbox.load_scene(write_scene(tmp_path, drop_of_its_own()))
    before = jackbox.simulate(scene, t_end=0.3, method=METHOD)
    path = loader.ensure_model(scene)
    assert path.parent == fresh_cache / "models"
    # an edit that keeps the header (and so the hash) and is sealed again, as a
    # compiler change that forgot its version would write it: gravity pushes up, in
    # accel_time_s() (the terms of time that accel() and the free-flight loop both
    # read). (An edit without a new seal is damage: tests/test_cache_health.py.)
    text = path.read_text()
    body = text[: text.rindex(SEAL)].removesuffix("\n")
    assert body.count("    _x0 = -p_g\n") == 1
    path.write_text(seal(body.replace("    _x0 = -p_g\n", "    _x0 = p_g\n")))
    after = jackbox.simulate(scene, t_end=0.3, method=METHOD)
    assert after.meta["kernel"]["cache"] == "miss"
    assert after.q[-1, 4] > before.q[-1, 4] + 0.5      # the jack rose instead of falling


def test_changed_scene_structure_regenerates_the_model(fresh_cache, tmp_path):
    base = jackbox.builtin_scenes()["drop"].read_text()
    one = jackbox.load_scene(write_scene(tmp_path, base.replace("[impact]", '[forces]\nx_jack = "2.0"\n\n[impact]'), "a.toml"))
    two = jackbox.load_scene(write_scene(tmp_path, base.replace("[impact]", '[forces]\nx_jack = "-2.0"\n\n[impact]'), "b.toml"))
    a, b = jackbox.simulate(one, t_end=0.2, method=METHOD), jackbox.simulate(two, t_end=0.2, method=METHOD)
    assert a.meta["model_hash"] != b.meta["model_hash"]
    # each run used its own force: x differs by (2 - -2) t^2 / 2 / m_jack after t = 0.2 s
    assert a.q[-1, 3] - b.q[-1, 3] == pytest.approx(0.08, rel=1e-9)
    assert len(list((fresh_cache / "models").glob("*.py"))) == 2


def test_a_model_edit_compiles_only_the_functions_it_changed(fresh_cache, tmp_path):
    # each function is compiled (and cached) on its own, named by its text: a new potential term
    # changes the accelerations, the energy and the hot path that calls them, never the gaps
    text = drop_of_its_own()
    one = jackbox.simulate(jackbox.load_scene(write_scene(tmp_path, text, "one.toml")), t_end=0.05, method=METHOD)
    before = set(loader._parts)
    files = set((fresh_cache / "kernels").glob("*.py"))
    edited = jackbox.load_scene(write_scene(
        tmp_path, text + '\n[potential]\ntether = "0.5*0.01*(x_jack - x_box)**2"\n', "two.toml"))
    kernel = loader.kernel_for(edited)
    new = {name for name, path in kernel.module.PARTS.items() if str(path) not in before}
    # (flight: fly and free_step, the hot path; the held steps on floats are compiled when a run first holds
    # a contact: Kernel.ride)
    assert new == {"accel", "energy", "flight"}
    assert {path.name.rsplit("_", 1)[0] for path in set((fresh_cache / "kernels").glob("*.py")) - files} == new
    # and the tether pulls (the edit is not served the old functions): the jack moves 0.8 m/s
    # sideways from x_box, so the tether's k (x_jack - x_box) / m_jack lags it by k 0.8 t^3 / 6
    two = jackbox.simulate(edited, t_end=0.05, method=METHOD)
    assert two.q[-1, 3] - one.q[-1, 3] == pytest.approx(-0.01 * 0.8 * 0.05 ** 3 / 6, rel=1e-3)


def test_builtin_scene_uses_the_committed_module():
    scene = jackbox.load_scene("shaken")
    assert loader.model_path(scene) == loader.GENERATED_DIR / "shaken.py"
    # a structural change (a ground) moves it to the cache instead of touching generated/
    grounded = scene.with_overrides({"ground": "true", "initial.q": "[0, 6, 0, 1, 7.5, 0.3]"})
    assert loader.model_path(grounded).parent.name == "models"


def test_renamed_copy_of_a_scene_compiles_nothing(fresh_cache, tmp_path):
    # the cache is keyed by structure, not by name: a copy of a user's scene under
    # another name (or a copy of a built-in) reuses the generated module and the kernel
    text = drop_of_its_own()
    one = jackbox.load_scene(write_scene(tmp_path, text, "one.toml"))
    two = jackbox.load_scene(write_scene(tmp_path, text.replace('name = "drop"', 'name = "two"'), "two.toml"))
    assert one.name != two.name
    a = jackbox.simulate(one, t_end=0.2, method=METHOD)
    b = jackbox.simulate(two, t_end=0.2, method=METHOD)
    assert a.meta["kernel"]["cache"] == "miss" and b.meta["kernel"]["cache"] == "memory"
    assert len(list((fresh_cache / "models").glob("*.py"))) == 1
    assert len(list((fresh_cache / "kernels").glob("*.py"))) == len(loader.part_entries())
    np.testing.assert_array_equal(a.q, b.q)
    copy = jackbox.load_scene(write_scene(tmp_path, jackbox.builtin_scenes()["drop"].read_text(), "copy.toml"))
    assert loader.model_path(copy) == loader.GENERATED_DIR / "drop.py"



#: compiles the ensembles' prange loop alone, into the cache (as another process that got there first would)
PRANGE_LOOP = """
from jackbox import engine
from jackbox.engine import members
from jackbox.engine.records import F8, I1, I8, V2, ExactType, ModelType, StagesType
V3 = engine.V3
members.all_members.compile((ModelType, ExactType, StagesType, V2, V2, V2, V2, F8, I8, I1, V3, V3, V2, V2, V2))
"""
ENSEMBLE = ("from jackbox.ensemble import ensemble; e = ensemble('shaken', 4, perturb={'theta_jack': 1e-6}, t_end=0.01, seed=0); "
            "print(int(e.completed.sum()))")


def test_an_entry_compiled_over_a_cached_prange_loop_loads_in_a_new_process(tmp_path):
    """A cached function that calls a prange loop is saved with a hook that starts Numba's
    threads when it is loaded, except when the loop itself came from the cache as it was
    compiled (two processes compiling the engine at once, as the test suite's workers do).
    Running it in a later process then ended that process with "LLVM ERROR: Symbol not
    found: allocate_sched" (seen in the suite: the benchmark smoke test's ensemble). The
    engine starts the threads before it loads an entry point that runs one.

    The engine's other machine code comes from this session's cache (copied), so only the
    members' functions are compiled here, in the order that leaves the hook out.
    """
    cache = tmp_path / "cache"
    ours = engine.cache.engine_cache_path()
    shutil.copytree(ours, cache / "engine" / ours.name, ignore=shutil.ignore_patterns("members.*"))
    for folder in ("kernels", "models"):
        if (ours.parent.parent / folder).is_dir():
            shutil.copytree(ours.parent.parent / folder, cache / folder)
    env = os.environ | {"JACKBOX_CACHE_DIR": str(cache)}
    env.pop("NUMBA_DISABLE_JIT", None)

    def run(code):
        return subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=600)

    assert run(PRANGE_LOOP).returncode == 0
    first = run(ENSEMBLE)               # compiles run_members over the cached loop
    assert first.returncode == 0, first.stderr
    (saved,) = (cache / "engine").glob("*/members.run_members-*.nbc")
    if b"_reload_parfors" in saved.read_bytes():
        pytest.skip("this Numba saves the threads' hook with the caller too: nothing left to check")
    again = run(ENSEMBLE)               # loads it
    assert again.returncode == 0, again.stderr
    assert again.stdout.split() == first.stdout.split() == ["4"]
