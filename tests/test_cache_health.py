"""A cache that heals itself: a damaged generated model or a damaged Numba cache file
is found, removed and rebuilt with one warning; an unwritable cache folder is
avoided; ``jackbox cache`` shows the folder and ``jackbox cache clear`` empties it.

Every test runs the naive loop (the cheapest) of ``drop`` with a fresh cache:
the model's functions (its binding module) are compiled into it. The engine's
own files get the same manifest check (loader.compile_kernel).
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import warnings
from pathlib import Path

import numpy as np
import pytest
from numba.core.caching import IndexDataCacheFile

import jackbox
from jackbox import engine, loader
from jackbox.errors import CacheWarning

from .conftest import run_cli, write_scene
from .test_cache import METHOD, drop_of_its_own


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("JACKBOX_CACHE_DIR", str(tmp_path / "cache"))
    _forget(monkeypatch)
    return tmp_path / "cache"


def _forget(monkeypatch):
    """A new process, as far as the loader knows: nothing imported, checked or stamped."""
    for table in ("_loaded", "_stamped", "_intact", "_parts"):
        monkeypatch.setattr(loader, table, {})
    monkeypatch.setattr(engine.cache, "_folders", {})
    monkeypatch.setattr(loader, "_verified", set())
    loader._kept_parts.cache_clear()


def run(scene="drop"):
    return jackbox.simulate(scene, t_end=0.3, method=METHOD)


def cache_warnings(record) -> list[str]:
    return [str(w.message) for w in record if issubclass(w.category, CacheWarning)]


def test_a_truncated_generated_model_is_rebuilt_with_one_warning(fresh_cache, tmp_path):
    scene = jackbox.load_scene(write_scene(tmp_path, drop_of_its_own()))
    before = run(scene)
    path = loader.ensure_model(scene)
    text = path.read_text()
    path.write_text(text[: len(text) // 2])      # the header (and its model hash) survives
    loader._intact.clear()
    with pytest.warns(CacheWarning, match="damaged") as record:
        after = run(scene)
    assert len(cache_warnings(record)) == 1
    assert path.read_text() == text
    np.testing.assert_array_equal(after.q, before.q)


def test_a_damaged_committed_module_is_not_used(fresh_cache, tmp_path, monkeypatch):
    generated = tmp_path / "generated"
    shutil.copytree(loader.GENERATED_DIR, generated)
    monkeypatch.setattr(loader, "GENERATED_DIR", generated)
    text = (generated / "drop.py").read_text()
    (generated / "drop.py").write_text(text.replace("p_g = p[6]", "p_g = -p[6]", 1))   # gravity up
    with pytest.warns(CacheWarning, match="seal does not match") as record:
        path = loader.model_path(jackbox.load_scene("drop"))
    assert path.parent == fresh_cache / "models"
    assert len(cache_warnings(record)) == 1


@pytest.mark.parametrize("kind, damage, manifest", [
    ("nbi", "truncate", True),     # the index, cut short: the manifest sees it
    ("nbc", "flip", True),         # machine code with 16 bytes flipped: the manifest sees it
    ("nbi", "truncate", False),    # no manifest (an older jackbox's cache): Numba's load fails
])
def test_a_damaged_numba_cache_file_is_compiled_again(fresh_cache, monkeypatch, kind, damage, manifest):
    before = run()
    assert before.meta["kernel"]["cache"] == "miss"
    files = sorted((fresh_cache / "kernels" / "__pycache__").glob(f"*.phi-*.{kind}"))
    assert files, "the model's phi cache files"
    data = bytearray(files[0].read_bytes())
    if damage == "truncate":
        data = data[: len(data) // 3]
    else:
        for i in range(len(data) // 2, len(data) // 2 + 16):
            data[i] ^= 0xFF
    files[0].write_bytes(bytes(data))
    if not manifest:     # the damage is then only seen when Numba fails to load it
        for f in (fresh_cache / "kernels" / "__pycache__").glob("*.sums.json"):
            f.unlink()
    _forget(monkeypatch)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        after = run()
    said = cache_warnings(record)
    if manifest or damage == "truncate":
        assert len(said) == 1 and "again" in said[0], said
        assert after.meta["kernel"]["cache"] == "miss"
    np.testing.assert_array_equal(after.q, before.q)
    # and the next process loads the mended cache without a word
    _forget(monkeypatch)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        again = run()
    assert cache_warnings(record) == [] and again.meta["kernel"]["cache"] == "hit"


@pytest.mark.parametrize("damage", ["garbage", "parts missing"])
def test_a_damaged_file_of_binding_parts_is_made_again_without_a_word(fresh_cache, monkeypatch, damage):
    before = loader.binding_parts(Path(loader.ensure_model(jackbox.load_scene("drop"))).read_text())
    (kept,) = (fresh_cache / "kernels").glob("parts_*.json")
    kept.write_text("{not json" if damage == "garbage" else '{"phi": "def phi(): pass"}')
    _forget(monkeypatch)          # (a new process)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        after = loader.binding_parts(Path(loader.ensure_model(jackbox.load_scene("drop"))).read_text())
    assert after == before and after["phi"].count("def phi(") == 1
    assert json.loads(kept.read_text()) == before             # written again, whole


def test_an_unwritable_cache_folder_is_avoided_with_one_warning(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("JACKBOX_CACHE_DIR", str(blocker / "cache"))
    _forget(monkeypatch)
    with pytest.warns(CacheWarning, match="cannot be written") as record:
        traj = run()
        run()
    assert len(cache_warnings(record)) == 1
    assert traj.t[-1] == 0.3 and np.all(np.isfinite(traj.q))
    assert not (blocker / "cache").exists()


def _files_of(folder):
    """Every file under `folder` with its inode, size and modification time."""
    return {str(f): (f.stat().st_ino, f.stat().st_size, f.stat().st_mtime_ns)
            for f in sorted(folder.rglob("*")) if f.is_file()}


@pytest.fixture
def read_only_warm_cache(fresh_cache, monkeypatch):
    """A warm cache made read-only: by its permissions, and, for root (whom they do not
    stop), by the one check jackbox makes of whether it may write there."""
    run()
    (fresh_cache / "kernels" / "__pycache__" / "scratch.tmp").write_text("")   # a stray file: not linked
    before = _files_of(fresh_cache)
    for f in [fresh_cache, *fresh_cache.rglob("*")]:
        f.chmod(f.stat().st_mode & ~0o222)
    can_write = engine.cache._can_write
    monkeypatch.setattr(engine.cache, "_can_write", lambda folder: folder != fresh_cache and can_write(folder))
    _forget(monkeypatch)
    yield fresh_cache, before
    for f in [fresh_cache, *fresh_cache.rglob("*")]:
        f.chmod(f.stat().st_mode | 0o200)


def test_a_read_only_warm_cache_is_read_in_place_without_a_word(read_only_warm_cache):
    folder, before = read_only_warm_cache
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        traj = run()
    assert cache_warnings(record) == []
    assert traj.meta["kernel"]["cache"] == "hit", "nothing compiled: the cached code was read where it is"
    assert _files_of(folder) == before, "the read-only folder is untouched"
    used = engine.cache.cache_dir()
    assert used != folder and not (used / "engine" / "scratch.tmp").exists()


def test_code_compiled_beside_a_read_only_cache_is_kept_aside_with_one_warning(read_only_warm_cache, tmp_path):
    folder, before = read_only_warm_cache
    scene = jackbox.load_scene(write_scene(tmp_path, drop_of_its_own()))
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        traj = run(scene)
        run(scene)
    said = cache_warnings(record)
    assert len(said) == 1 and "read-only" in said[0] and str(folder) in said[0], said
    assert traj.meta["kernel"]["cache"] == "miss" and np.all(np.isfinite(traj.q))
    assert _files_of(folder) == before


def test_a_full_disk_keeps_the_compiled_code_for_the_process_with_one_warning(fresh_cache, tmp_path, monkeypatch):
    """Nothing more fits on the cache's disk: the binding module goes to a folder of this
    process, Numba's failed saves keep the machine code in memory, the run succeeds."""
    monkeypatch.setenv("JACKBOX_COMPILE_JOBS", "1")
    monkeypatch.setattr(engine.cache, "_said", set())
    scene = jackbox.load_scene(write_scene(tmp_path, drop_of_its_own()))
    fresh_cache.mkdir()

    def no_space(write, everywhere):
        def full(self_or_path, *args):
            path = Path(args[0] if everywhere else self_or_path)
            if everywhere or path.resolve().is_relative_to(fresh_cache.resolve()):
                raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
            return write(self_or_path, *args)
        return full

    monkeypatch.setattr(loader, "write_atomic", no_space(loader.write_atomic, everywhere=False))
    monkeypatch.setattr(IndexDataCacheFile, "_open_for_write", no_space(IndexDataCacheFile._open_for_write, True))
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        traj = run(scene)
        run(scene)
    said = cache_warnings(record)
    assert len(said) == 1 and "No space left on device" in said[0], said
    assert traj.meta["kernel"]["cache"] == "miss"
    assert list(fresh_cache.rglob("*.*")) == []
    monkeypatch.undo()
    np.testing.assert_allclose(traj.q, run().q, rtol=0, atol=1e-12)


def test_cache_command_shows_and_clears_the_folder(fresh_cache, capsys):
    run()
    status, out, _ = run_cli(capsys, "cache")
    assert status == 0 and str(fresh_cache) in out and f"{len(loader.part_entries())} binding parts" in out
    status, out, _ = run_cli(capsys, "cache", "clear")
    assert status == 0 and "cleared" in out
    assert not any((fresh_cache / part).exists() for part in ("kernels", "models", "engine"))
    status, out, _ = run_cli(capsys, "cache")
    assert "0 generated models, 0 binding parts" in out


def test_cache_prune_removes_only_what_was_made_for_other_engine_builds(fresh_cache, capsys):
    run()
    this = fresh_cache / "engine" / engine.cache.DIGEST
    this.mkdir(parents=True, exist_ok=True)
    (this / "kept.nbi").write_bytes(b"x")
    older = fresh_cache / "engine" / "0123456789abcdef"
    older.mkdir()
    (older / "old.nbc").write_bytes(b"y" * 2**20)
    # a binding part made for that build (its text names it), its Numba cache files and a kept cut of a
    # model into parts that names it; and one that names no build (a model's own functions): kept
    kernels = fresh_cache / "kernels"
    ours = [p for p in kernels.glob("*.py") if f"# engine: {engine.cache.DIGEST}\n" in p.read_text()]
    assert ours                                    # (this run's parts that reach the engine's code)
    header = "# " + "-" * 77 + "\n# Binding part (jackbox.loader): the model's accel as the engine's function value\n"
    stale = [kernels / "accel_00000000000000aa.py", kernels / "__pycache__" / "accel_00000000000000aa.accel-8.py311.nbi",
             kernels / "__pycache__" / "accel_00000000000000aa.accel-8.py311.1.nbc",
             kernels / "parts_00000000000000bb.json"]
    stale[0].write_text(header + "# engine: 0123456789abcdef\n")
    stale[1].write_bytes(b"z" * 2**19)
    stale[2].write_bytes(b"z" * 2**19)
    stale[3].write_text(json.dumps({"accel": header + "# engine: 0123456789abcdef\n"}))
    plain = kernels / "phi_00000000000000cc.py"
    plain.write_text(header)
    before = sorted(p for p in fresh_cache.rglob("*") if "engine" not in p.parts)
    status, out, _ = run_cli(capsys, "cache", "prune")
    assert status == 0 and ("pruned     1 engine build(s) of other versions (1.0 MiB) and 4 file(s) of binding "
                            "parts made for them (1.0 MiB)") in out, out
    assert not older.exists() and (this / "kept.nbi").exists()
    # models and kernels: all but the stale ones, this build's parts and the plain one among them
    assert sorted(p for p in fresh_cache.rglob("*") if "engine" not in p.parts) == [p for p in before
                                                                                    if p not in stale]
    assert plain.exists() and all(p.exists() for p in ours)
    status, out, _ = run_cli(capsys, "cache", "prune")
    assert "pruned     0 engine build(s)" in out and "and 0 file(s)" in out
