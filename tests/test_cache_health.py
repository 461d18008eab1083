"""A cache that heals itself: a damaged generated model or a damaged Numba cache file
is found, removed and rebuilt with one warning; an unwritable cache folder is
avoided; ``jackbox cache`` shows the folder and ``jackbox cache clear`` empties it.

Every test runs the naive loop (the cheapest) of ``drop`` with a fresh cache:
the model's functions (its binding module) are compiled into it. The engine's
own files get the same manifest check (loader.compile_kernel).
"""

from __future__ import annotations

import shutil
import warnings

import numpy as np
import pytest

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
    for table in ("_loaded", "_stamped", "_intact"):
        monkeypatch.setattr(loader, table, {})
    monkeypatch.setattr(engine.cache, "_folders", {})
    monkeypatch.setattr(loader, "_verified", set())


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


def test_cache_command_shows_and_clears_the_folder(fresh_cache, capsys):
    run()
    status, out, _ = run_cli(capsys, "cache")
    assert status == 0 and str(fresh_cache) in out and "1 kernel modules" in out
    status, out, _ = run_cli(capsys, "cache", "clear")
    assert status == 0 and "cleared" in out
    assert not any((fresh_cache / part).exists() for part in ("kernels", "models", "engine"))
    status, out, _ = run_cli(capsys, "cache")
    assert "0 generated models, 0 kernel modules" in out
