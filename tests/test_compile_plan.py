"""What is compiled, where it is cached, and when: the engine's stages on first need, a helper
process for half of the work, and no engine code in Numba's own ``__pycache__``.

Compile time is user time (benchmarks/results/compile.md): a run compiles only the stages it
reaches, and what it does compile is shared between two processes. These tests hold the
machinery to its promises without timing anything: a run that needs a stage it did not compile
first gives the numbers of a run that had it all along; the parts are shared out by cost; every
engine function is cached under the engine's digest, never beside its source.
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from numba.core.dispatcher import Dispatcher

import jackbox
from jackbox import api, engine, loader
from jackbox.ensemble import chaos, ensemble

from .test_stress import SLIDING_HEAVY_JACK

#: the engine's modules with compiled functions
MODULES = ("records", "integrator", "gaps", "broad", "impact", "events", "modes", "fallback", "loop", "tolerances",
           "draws", "members")


def test_every_engine_function_is_cached_under_the_engine_digest():
    # Numba fixes a function's cache folder when it is decorated; one decorated before jackbox knew
    # its cache folder went to jackbox/engine/__pycache__, stamped by its own file only, and was served
    # stale after an edit of a callee in another module.
    checked = 0
    for name in MODULES:
        module = importlib.import_module(f"jackbox.engine.{name}")
        for fn in vars(module).values():
            if isinstance(fn, Dispatcher) and fn.py_func.__module__ == module.__name__:
                path = Path(fn._cache._cache_path)
                assert path.name == engine.cache.DIGEST and path.parent.name == "engine", (fn, path)
                checked += 1
    assert checked > 40


def _without_lazy_stages(monkeypatch):
    """This process as if the stages compiled on first need were neither compiled nor cached."""
    loops = {name: fn for name, fn in engine._loops.items() if name not in engine.LAZY}
    monkeypatch.setattr(engine, "_loops", loops)
    cached = engine.cached
    monkeypatch.setattr(engine, "cached", lambda name, names=None: name not in engine.LAZY and cached(name, names))
    statuses = []
    entry = engine.entry
    run_exact = entry("run_exact")

    def counted(*args):
        out = run_exact(*args)
        statuses.append(out[3])
        return out

    monkeypatch.setattr(engine, "entry", lambda name: counted if name == "run_exact" else entry(name))
    return statuses


@pytest.fixture
def fresh_kernels(monkeypatch):
    """kernel_for gives a new Kernel (no table made yet) for each call, and so does a kernel's with_lanes."""
    kernel_for, load_kernel = loader.kernel_for, loader.load_kernel
    monkeypatch.setattr(loader, "kernel_for", lambda scene, log=None, method=None:
                        loader.Kernel(kernel_for(scene, log, method).module))
    monkeypatch.setattr(loader, "load_kernel", lambda *args, **kw: loader.Kernel(load_kernel(*args, **kw).module))


def test_a_held_contact_compiles_the_release_stage_mid_run_and_changes_nothing(monkeypatch, fresh_kernels):
    scene = jackbox.load_scene("drop", {"restitution": 0.0, "ground_restitution": 0.0})
    whole = jackbox.simulate(scene, t_end=1.5)
    assert len(whole.held) > 0 or (whole.contact_event == 1).any()      # contacts were held: the release stage ran
    statuses = _without_lazy_stages(monkeypatch)
    # two processes: a helper takes a share of the stages while this one compiles (here: loads) the ride
    monkeypatch.setenv("JACKBOX_COMPILE_JOBS", "2")
    monkeypatch.setattr(engine, "_helpers", {})
    started, spawn = [], engine._spawn
    monkeypatch.setattr(engine, "_spawn", lambda args, **kw: started.append(args) or spawn(args, **kw))
    said = []
    lazy = jackbox.simulate(scene, t_end=1.5, log=said.append)
    assert statuses.count(engine.MISSING) == 1 and statuses[-1] == engine.DONE
    # the held loop and the release search, not the fallback: this run never hands a step over
    assert len(whole.fallback_t) == 0 and {"release", "hold"} <= set(engine._loops)
    assert "fallback" not in engine._loops
    (share,) = started
    assert share and set(share) < set(engine.LAZY) and not engine._helpers
    # the pause is explained, once
    (line,) = [line for line in said if "stages" in line]
    assert "for held contacts at t = " in line and "first use only" in line
    assert "release and hold stages" in line and "fallback" not in line
    assert "release" in engine._loops
    for key in ("t", "q", "qd", "energy", "impact_t", "contact_t", "contact_event"):
        np.testing.assert_array_equal(getattr(lazy, key), getattr(whole, key), err_msg=key)


def test_a_run_that_needs_the_fallback_compiles_it_mid_run_and_changes_nothing(monkeypatch, fresh_kernels):
    dt, over = SLIDING_HEAVY_JACK                    # (a heavy jack the exact method hands to the fallback)
    scene = jackbox.load_scene("drop", over)
    whole = jackbox.simulate(scene, t_end=1.0, dt=dt)
    assert len(whole.fallback_t)
    statuses = _without_lazy_stages(monkeypatch)
    lazy = jackbox.simulate(scene, t_end=1.0, dt=dt)
    # plastic: the held loop first (a contact comes to rest), then the fallback where a step is handed over
    assert statuses.count(engine.MISSING) == 2 and statuses[-1] == engine.DONE
    assert set(engine.LAZY) <= set(engine._loops)
    for key in ("t", "q", "qd", "fallback_t", "contact_t", "contact_event"):
        np.testing.assert_array_equal(getattr(lazy, key), getattr(whole, key), err_msg=key)


@pytest.mark.parametrize("scene, params, first", [
    ("drop", {"e": 0.0, "e_ground": 0.0}, ("release", "hold")),
    ("drop", {"e": 1.0, "e_ground": 0.5}, ("release", "hold")),     # (the ground can hold the box)
    ("drop", {"e": 0.9, "e_ground": 1.0}, ("release", "hold")),
    ("drop", {"e": 1.0, "e_ground": 1.0}, ("fallback",)),
    ("spring", {"e": 1.0, "e_ground": 0.0}, ("fallback",)),         # (no ground: its restitution is unused)
])
def test_a_single_run_compiles_the_stage_it_most_likely_stopped_for_first(monkeypatch, scene, params, first):
    # the stop does not say which stage it needs: the held loop where an impact can be plastic, the fallback
    # where every impact is elastic; with those in memory already (a guess that missed), every stage
    run = api.prepare(scene, t_end=0.01, params=params)
    kernel = loader.kernel_for(run.scene)
    p = run.p
    monkeypatch.setattr(engine, "_loops", {name: fn for name, fn in engine._loops.items() if name not in engine.LAZY})
    assert kernel._stages_needed(p) == first
    monkeypatch.setattr(engine, "_loops", {**engine._loops, **{name: None for name in first}})
    assert kernel._stages_needed(p) == tuple(engine.LAZY)


@pytest.mark.parametrize("study", ["ensemble", "ensemble alone", "chaos", "chaos alone"])
def test_a_study_compiles_a_stage_when_a_member_first_needs_it_and_changes_nothing(monkeypatch, fresh_kernels, study):
    # members that reach a held contact stop (MISSING), the stage is compiled, and they run again from their start
    # (an ensemble's members in blocks of lanes, or each alone)
    scene = jackbox.load_scene("drop", {"restitution": 0.0, "ground_restitution": 0.0})
    kwargs = {"perturb": {"theta_jack": 0.3}, "t_end": 1.5}
    in_lanes = study in ("ensemble", "chaos")
    run = ((lambda: ensemble(scene, 6, lanes=in_lanes, **kwargs)) if study.startswith("ensemble")
           else (lambda: chaos(scene, 6, lanes=in_lanes, **kwargs)))
    whole = run()
    _without_lazy_stages(monkeypatch)
    entry, calls = engine.entry, []
    name = {"ensemble": "run_member_blocks", "ensemble alone": "run_members", "chaos": "run_twin_member_blocks",
            "chaos alone": "run_twin_members"}[study]
    monkeypatch.setattr(engine, "entry", lambda n: (lambda *a: calls.append(len(a[1])) or entry(n)(*a))
                        if n == name else entry(n))
    lazy = run()
    # all, then those that stopped, with the held loop and the release search; the fallback only if one needs it
    fell_back = bool((whole.fallback > 0).any())
    assert calls[0] == 6 and 0 < calls[1] <= 6 and len(calls) == 2 + fell_back, calls
    assert {"release", "hold"} <= set(engine._loops) and ("fallback" in engine._loops) == fell_back
    assert (lazy.status == engine.DONE).all()
    keys = ("q", "qd", "energy", "impacts", "steps", "fallback", "samples_q") if study.startswith("ensemble") else \
        ("stretch", "impacts", "steps", "fallback")
    for key in keys:
        np.testing.assert_array_equal(getattr(lazy, key), getattr(whole, key), err_msg=key)


def test_study_members_that_need_the_fallback_stop_again_and_run_again_with_it(monkeypatch, fresh_kernels):
    # a heavy plastic jack: held contacts first (the likely stages), then a step handed over (the fallback);
    # the members stop twice, and every number is the one of a study with every stage compiled
    dt, over = SLIDING_HEAVY_JACK
    scene = jackbox.load_scene("drop", over)
    kwargs = {"perturb": {"theta_jack": 1e-9}, "t_end": 1.0, "dt": dt, "lanes": False}
    whole = ensemble(scene, 3, **kwargs)
    assert (whole.fallback > 0).all()
    _without_lazy_stages(monkeypatch)
    entry, calls = engine.entry, []
    monkeypatch.setattr(engine, "entry", lambda n: (lambda *a: calls.append(len(a[1])) or entry(n)(*a))
                        if n == "run_members" else entry(n))
    lazy = ensemble(scene, 3, **kwargs)
    assert calls == [3, 3, 3], calls
    assert set(engine.LAZY) <= set(engine._loops) and (lazy.status == engine.DONE).all()
    for key in ("q", "qd", "energy", "impacts", "steps", "fallback"):
        np.testing.assert_array_equal(getattr(lazy, key), getattr(whole, key), err_msg=key)


def test_an_elastic_run_needs_no_lazy_stage(monkeypatch, fresh_kernels):
    statuses = _without_lazy_stages(monkeypatch)
    traj = jackbox.simulate("shaken", t_end=2.0)
    assert len(traj.impact_t) > 0 and statuses == [engine.DONE]
    assert not set(engine.LAZY) & set(engine._loops)


def test_a_single_run_loads_the_cached_lazy_stages_only_when_a_step_needs_them(monkeypatch, fresh_kernels):
    # a warm start of an elastic run leaves the stages for held contacts on disk (a load is ~8 ms); a
    # run that reaches a held contact loads them at that step and resumes there, with the same numbers
    held = jackbox.load_scene("drop", {"restitution": 0.0, "ground_restitution": 0.0})
    whole = jackbox.simulate(held, t_end=1.5)
    assert engine.cached("release") and engine.cached("hold")      # (the stages a held contact needs)
    monkeypatch.setattr(engine, "_loops", {name: fn for name, fn in engine._loops.items() if name not in engine.LAZY})
    statuses = []
    run_exact, entry = engine.entry("run_exact"), engine.entry

    def counted(*args):
        out = run_exact(*args)
        statuses.append(out[3])
        return out

    monkeypatch.setattr(engine, "entry", lambda name: counted if name == "run_exact" else entry(name))
    traj = jackbox.simulate("shaken", t_end=2.0)
    assert len(traj.impact_t) > 0 and statuses[-1] == engine.DONE
    assert not set(engine.LAZY) & set(engine._loops)
    statuses.clear()
    lazy = jackbox.simulate(held, t_end=1.5)
    assert engine.MISSING in statuses and statuses[-1] == engine.DONE and "hold" in engine._loops
    for key in ("t", "q", "qd", "energy", "impact_t", "contact_t", "contact_event"):
        np.testing.assert_array_equal(getattr(lazy, key), getattr(whole, key), err_msg=key)


def test_the_parts_are_shared_out_by_cost(monkeypatch):
    started = []

    class Process:
        def __init__(self, argv, **kw):
            started.append((argv, kw["env"]))

    monkeypatch.setattr(engine.subprocess, "Popen", Process)
    monkeypatch.setattr(engine, "_loops", {})
    monkeypatch.setattr(engine, "_helpers", {})
    monkeypatch.setattr(engine, "cached", lambda name, names=None: False)
    monkeypatch.setenv("JACKBOX_COMPILE_JOBS", "2")
    names, loops = ("run_members", "set_up_members", "fill_tolerances"), ("exact",)
    every = engine.parts(names, loops)
    assert set(engine.LAZY) <= set(every) and "exact" in every and "update" in every
    theirs = engine.start(names, loops, busy=6.0)
    (argv, env), = started
    assert argv[:3] == [sys.executable, "-m", "jackbox.engine.helper"] and argv[3:] == theirs
    assert env["JACKBOX_COMPILE_JOBS"] == "1" and env["JACKBOX_CACHE_DIR"] == str(engine.cache.cache_dir())
    mine = [name for name in every if name not in theirs]
    assert mine and theirs and set(theirs) == set(engine._helpers)
    load = 6.0 + sum(engine.COST[n] for n in mine)
    helper = 0.5 + sum(engine.COST[n] for n in theirs)
    assert abs(load - helper) <= max(engine.COST.values())
    # lazily: the stages compiled on first need are nobody's part
    monkeypatch.setattr(engine, "_helpers", {})
    started.clear()
    assert not set(engine.LAZY) & set(engine.start(("run_exact",), loops, lazy=True, busy=6.0))
    # one process only: nothing started
    monkeypatch.setattr(engine, "_helpers", {})
    monkeypatch.setenv("JACKBOX_COMPILE_JOBS", "1")
    started.clear()
    assert engine.start(names, loops) == [] and started == []


def test_the_helper_compiles_what_it_is_given_into_the_cache_it_is_given(tmp_path):
    env = os.environ | {"JACKBOX_CACHE_DIR": str(tmp_path)}
    env.pop("NUMBA_DISABLE_JIT", None)
    done = subprocess.run([sys.executable, "-m", "jackbox.engine.helper", "fill_tolerances"], env=env,
                          capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    folder = tmp_path / "engine" / engine.cache.DIGEST
    assert any(folder.glob("tolerances.fill_tolerances-*.nbi"))
    # that part and its callees only
    assert {p.name.split(".")[0] for p in folder.glob("*.nbi")} == {"tolerances"}
    done = subprocess.run([sys.executable, "-m", "jackbox.engine.helper", "fly_away"], env=env,
                          capture_output=True, text=True)
    assert done.returncode == 1 and "not a part of the engine: fly_away" in done.stderr


def test_a_prepared_run_reports_compiling_through_the_api(monkeypatch):
    # api.run_prepared names its method to kernel_for, so a helper can start before the model compiles
    seen = []
    kernel_for = loader.kernel_for
    monkeypatch.setattr(loader, "kernel_for", lambda scene, log=None, method=None:
                        seen.append(method) or kernel_for(scene, log, method))
    api.run_prepared(api.prepare("drop", t_end=0.01, method="naive"))
    assert seen == ["naive"]


def test_a_new_model_compiles_half_of_its_functions_in_a_helper(tmp_path, monkeypatch):
    from .conftest import with_engine, write_scene
    from .test_cache import drop_of_its_own

    # (the engine as the suite built it, for the helper's process: a new model on a machine that has one)
    monkeypatch.setenv("JACKBOX_CACHE_DIR", str(with_engine(tmp_path / "cache")))
    monkeypatch.setenv("JACKBOX_COMPILE_JOBS", "2")
    monkeypatch.setattr(loader, "_loaded", {})
    monkeypatch.setattr(loader, "_stamped", {})
    monkeypatch.setattr(loader, "_parts", {})
    monkeypatch.setattr(engine, "_helpers", {})
    scene = jackbox.load_scene(write_scene(tmp_path, drop_of_its_own()))
    started, shares = [], []
    spawn = engine._spawn
    monkeypatch.setattr(engine, "_spawn", lambda args, **kw: started.append(args) or spawn(args, **kw))
    start_binding = engine.start_binding
    monkeypatch.setattr(engine, "start_binding",
                        lambda todo, *costs: shares.append(start_binding(todo, *costs)) or shares[-1])
    kernel = loader.kernel_for(scene)
    compiled = kernel.module.COMPILED
    assert list(compiled) == list(engine.SIGNATURES)
    # a new structure: the helper started before its model was generated, then got the paths of its share
    assert started == [["--parts", "-"]] and engine._warm is None
    [share] = shares
    parts = loader.part_entries()
    assert 0 < len(share) < len(parts)
    # shared by cost: neither side has more than half of the work and the heaviest part more
    cost = {name: engine.PART_COST[name] for name in parts}
    theirs = sum(cost[name] for name in share)
    assert abs(2 * theirs - sum(cost.values())) <= max(cost.values()) + engine.FIRST_COMPILE
    # the helper's share was loaded from the cache it wrote; the rest was compiled here
    helpers = {entry for name in share for entry in parts[name]}
    assert all(compiled[name].cache_hits for name in helpers)
    assert not any(compiled[name].cache_hits for name in engine.SIGNATURES if name not in helpers)
    assert not engine._binders
    # the same numbers as the committed drop (push = 0): the functions work, whoever compiled them
    run = jackbox.simulate(scene, t_end=0.3)
    np.testing.assert_array_equal(run.q, jackbox.simulate("drop", t_end=0.3).q)


def test_a_warm_helper_with_no_work_ends_when_let_go(tmp_path, monkeypatch):
    monkeypatch.setenv("JACKBOX_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("JACKBOX_COMPILE_JOBS", "2")
    monkeypatch.setattr(engine, "_helpers", {})
    monkeypatch.setattr(engine, "_warm", None)
    assert engine.warm_binder() and engine.warm_binder()      # one helper, however often asked
    process = engine._warm
    engine.cool_binder()
    assert engine._warm is None and process.wait(timeout=60) == 0
    assert not any(tmp_path.rglob("*.nb[ic]")), "it compiled nothing into the cache"
    # and one process only: none is started
    monkeypatch.setenv("JACKBOX_COMPILE_JOBS", "1")
    assert not engine.warm_binder() and engine._warm is None


def test_is_cached_finds_the_loop_and_the_entry_point_in_the_cache(monkeypatch):
    kernel = loader.kernel_for(jackbox.load_scene("drop"))
    loader.compile_kernel(kernel, "exact")
    assert loader.is_cached(kernel, "exact")
    monkeypatch.setattr(engine, "_loops", {})            # not in this process: the cache's files decide
    assert loader.is_cached(kernel, "exact")
    monkeypatch.setattr(engine, "cached", lambda name: name != "exact")
    assert not loader.is_cached(kernel, "exact")


def test_the_parts_are_shared_out_so_that_the_later_process_finishes_first():
    # two of 3 s against three of 2 s: 6 s each; one by one, the heaviest first, ends at 7 s
    cost = {"a": 3.0, "b": 3.0, "c": 2.0, "d": 2.0, "e": 2.0}
    theirs = engine.share_out(cost, 0.0, 0.0)
    assert set(theirs) in ({"a", "b"}, {"c", "d", "e"})
    assert engine.share_out(cost, 0.0, 0.0) == theirs            # the same parts, the same split
    # what this process does first counts: with 4 s of its own, the helper takes 8 of the 12
    assert sum(cost[n] for n in engine.share_out(cost, 4.0, 0.0)) == 8.0
    # a helper that would finish later than this process alone gets nothing
    assert engine.share_out({"a": 1.0}, 0.0, 5.0) == []
    # no part moved from the later process to the other one would end them sooner
    rng = np.random.default_rng(3)
    for _ in range(20):
        cost = {f"p{i}": float(c) for i, c in enumerate(rng.uniform(0.1, 10.0, rng.integers(1, 9)))}
        mine, start = rng.uniform(0, 5, 2)
        theirs = set(engine.share_out(cost, mine, start))

        def finish(helper):
            load = mine + sum(c for n, c in cost.items() if n not in helper)
            return max(load, start + sum(cost[n] for n in helper)) if helper else load

        best = finish(theirs)
        assert all(finish(theirs ^ {n}) >= best for n in cost)
    # more parts than EXHAUSTIVE: one by one, the heaviest first, each to the process that is free sooner
    cost = {f"p{i:02d}": float(i % 7 + 1) for i in range(engine.EXHAUSTIVE + 3)}
    theirs = engine.share_out(cost, 2.0, 1.0)
    assert theirs == sorted(theirs, key=lambda n: (-cost[n], n))
    load = 2.0 + sum(c for n, c in cost.items() if n not in theirs)
    helper = 1.0 + sum(cost[n] for n in theirs)
    assert max(load, helper) < 2.0 + sum(cost.values()) and abs(load - helper) <= max(cost.values())


def test_the_cache_index_test_matches_numbas_file_names(tmp_path):
    """engine.cache.has_index (a listing, not pathlib's glob: a millisecond of every run) finds an index of the
    function asked for and of no other: ``<module>.<function>-<line>.<python>.nbi``."""
    has = engine.cache.has_index
    (tmp_path / "members.run_member_blocks-712.py311.nbi").touch()
    (tmp_path / "members.run_members-90.py311.nbc").touch()      # machine code without its index
    assert not has(tmp_path, "run_members") and has(tmp_path, "run_member_blocks")
    assert not has(tmp_path, "run_member")
    (tmp_path / "members.run_members-90.py311.nbi").touch()
    assert has(tmp_path, "run_members") and has(tmp_path, "run_members", "members")
    assert not has(tmp_path, "run_members", "loop") and not has(tmp_path / "none", "run_members")
    (tmp_path / "lanes_ab12.calm.lanes-3.py311.nbi").touch()     # (no function's own index)
    assert not has(tmp_path, "lanes", "lanes_ab12")
    assert has(tmp_path, "run_members", names=["x.run_members-1.py311.nbi"])
    assert not has(tmp_path, "run_members", names=[])


def test_a_models_part_paths_follow_its_file_and_the_cache_folder(tmp_path, monkeypatch):
    """The binding parts' paths a model file had are kept (hashing their texts took half a millisecond of every
    run and study), and made again where the file or the cache folder changed."""
    model = tmp_path / "drop.py"
    model.write_text((loader.GENERATED_DIR / "drop.py").read_text())

    def fresh():
        return [(name, loader.part_path(name, text)) for name, text in loader.binding_parts(model.read_text()).items()]

    first = loader._part_paths(model)
    assert first == fresh() and loader._part_paths(model) is first
    monkeypatch.setenv("JACKBOX_CACHE_DIR", str(tmp_path / "elsewhere"))
    moved = loader._part_paths(model)
    assert moved == fresh() and all(str(path).startswith(str(tmp_path / "elsewhere")) for _, path in moved)
    model.write_text(model.read_text().replace("entries of an array as a tuple", "entries of an array, a tuple"))
    edited = loader._part_paths(model)
    assert edited == fresh() and {path for _, path in edited} != {path for _, path in moved}


def test_a_parts_cache_files_are_found_by_one_listing_of_their_folder(tmp_path, monkeypatch):
    """loader._numba_files and _cached read one listing of the parts' ``__pycache__`` (a glob per part matched
    every file name there, thousands, three times a part: 0.8 s of a warm start), with the glob's answers."""
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    part = tmp_path / "lanes_ab12.py"
    for name in ("lanes_ab12.lanes-40.py311.nbi", "lanes_ab12.lanes-40.py311.1.nbc", "lanes_ab12.calm-9.py311.nbi",
                 "lanes_ab12.sums.json", "lanes_ab1.lanes-40.py311.nbi", "fly_cd34.fly-3.py311.nbi"):
        (cache / name).touch()
    assert loader._numba_files(part) == sorted(tmp_path.glob("__pycache__/lanes_ab12.*.nb[ic]"))
    index = loader._pycache_index(cache)
    assert loader._numba_files(part, index) == loader._numba_files(part)
    assert not loader._cached("lanes", part, index)         # (time_table's index is missing)
    (cache / "lanes_ab12.time_table-7.py311.nbi").touch()
    assert loader._cached("lanes", part) and not loader._cached("lanes", part, index)   # (an index is a snapshot)
    listed = []
    listing = engine.cache.listing
    monkeypatch.setattr(engine.cache, "listing", lambda folder: listed.append(folder) or listing(folder))
    monkeypatch.setattr(loader, "_parts", {})      # (as in a new process: no part loaded yet, each one asked)
    loader._unbound(loader.GENERATED_DIR / "drop.py")
    assert len(listed) == 1, listed                 # every part of the model, one listing of their folder


@pytest.mark.parametrize("collecting", [True, False])
def test_numba_compiles_with_the_collector_paused_and_leaves_it_as_it_was(monkeypatch, collecting):
    """A compile makes millions of objects that live until it ends: the cyclic collector's passes over them
    were a sixth of compiling a model's held steps (4.8 s of 28.6 s, drop, timed by gc.callbacks). Both ways
    of compiling (a model's binding part, an engine part) run with it off, and leave it as they found it."""
    import gc
    from types import SimpleNamespace

    seen = []

    def cfunc(*args, **kwargs):
        def compiled(fn):
            seen.append(gc.isenabled())
            return SimpleNamespace(fn=fn, cache_hits=[])
        return compiled

    monkeypatch.setattr(engine.numba, "cfunc", cfunc)
    monkeypatch.setattr(engine, "_loops", dict(engine._loops))
    monkeypatch.setattr(engine.numba.config, "DISABLE_JIT", False)
    was = gc.isenabled()
    (gc.enable if collecting else gc.disable)()
    try:
        assert engine.bind_part("phi", lambda *args: None).fn is not None
        assert engine.compile_part("hold")
        assert seen == [False, False]
        assert gc.isenabled() == collecting
        # and when the compile fails
        monkeypatch.setattr(engine.numba, "cfunc", lambda *a, **k: (_ for _ in ()).throw(RuntimeError("typing")))
        with pytest.raises(RuntimeError, match="typing"):
            engine.bind_part("phi", lambda *args: None)
        assert gc.isenabled() == collecting
    finally:
        (gc.enable if was else gc.disable)()
