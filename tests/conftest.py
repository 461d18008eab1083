"""Shared scenes for the tests: the built-ins plus a few that reach other code paths."""

from __future__ import annotations

import os
import shutil
import tempfile
import textwrap
from pathlib import Path

import pytest

import jackbox

BUILTINS = ("shaken", "spring", "drop")

_saved_env: list[dict[str, str | None]] = []


def pytest_configure(config):
    """Compile into a cache of the test suite's own, never the user's ``~/.cache/jackbox``.

    ``$JACKBOX_TEST_CACHE_DIR`` if set, else pytest's cache folder
    (``.pytest_cache/d/jackbox``: kept between runs, so a second run is warm;
    ``pytest --cache-clear`` starts from an empty one), else a temporary folder.
    Subprocesses (the CLI, Dask workers) inherit it through the environment.
    Under pytest-xdist the workers fill the cores already: compiling stays in
    one process per worker (``JACKBOX_COMPILE_JOBS=1``) unless the environment
    says otherwise.
    """
    folder = os.environ.get("JACKBOX_TEST_CACHE_DIR")
    if not folder:
        cache = getattr(config, "cache", None)
        folder = str(cache.mkdir("jackbox")) if cache is not None else tempfile.mkdtemp(prefix="jackbox-tests-")
    wanted = {"JACKBOX_CACHE_DIR": folder}
    if os.environ.get("PYTEST_XDIST_WORKER") and "JACKBOX_COMPILE_JOBS" not in os.environ:
        wanted["JACKBOX_COMPILE_JOBS"] = "1"
    _saved_env.append({name: os.environ.get(name) for name in wanted})
    os.environ.update(wanted)


def pytest_unconfigure(config):
    if _saved_env:
        for name, saved in _saved_env.pop().items():
            if saved is None:
                os.environ.pop(name, None)
            else:
                os.environ[name] = saved

#: A box shaken up and down by a hand (prescribed motion), a polygon jack inside.
PRESCRIBED = """
name = "hand"
description = "prescribed box, hexagon jack"
[params]
amp = 0.3
freq = 1.5
[box]
inner_half_width = 1.0
wall_thickness = 0.1
mass = 4.0
motion = "prescribed"
x = "0.1*sin(2*pi*t)"
y = "amp*sin(2*pi*freq*t)"
theta = "0.2*sin(pi*t)"
[jack]
shape = "polygon"
mass = 0.7
# point-symmetric, so its centroid is exactly the origin
vertices = [[0.3, 0.0], [0.15, 0.2], [-0.15, 0.25], [-0.3, 0.0], [-0.15, -0.2], [0.15, -0.25]]
[world]
gravity = 9.81
[potential]
tether = "0.5*3.0*(x_jack - x_box)**2"
[forces]
theta_jack = "-0.05*theta_jack_dot"
[impact]
restitution = 0.8
[initial]
q = [0, 0, 0, 0.2, 0.1, 0.4]
qd = [0, 0, 0, 1.0, 2.0, -3.0]
[run]
t_end = 2.0
dt = 1e-3
"""

#: No gravity, no forces: total momentum is kept by every impact.
FREE_FLOAT = """
name = "float"
[box]
inner_half_width = 1.0
wall_thickness = 0.2
mass = 3.0
[jack]
shape = "square"
half_size = 0.3
mass = 1.0
[world]
gravity = 0.0
[initial]
q = [0, 0, 0.1, 0.2, -0.1, 0.5]
qd = [0.3, -0.2, 0.4, 2.0, 1.5, 4.0]
[run]
t_end = 3.0
dt = 1e-3
"""


def with_engine(folder: Path) -> Path:
    """``folder`` (a new cache folder) holding the suite's build of the engine, as far as it is compiled yet:
    its machine code, not its manifest of checksums (the copies are new files). For tests of what a process
    compiles or loads for a model, whose engine its user compiled long before: each such test compiled
    the whole engine again in its processes (40-80 s of the suite's time). Returns ``folder``."""
    from jackbox.engine import cache

    kept = folder / "engine" / cache.DIGEST
    kept.mkdir(parents=True, exist_ok=True)
    for f in cache.files():
        shutil.copy2(f, kept / f.name)
    return folder


def run_cli(capsys, *argv):
    """``jackbox`` with argv -> (status, stdout, stderr); argparse exits become statuses too."""
    from jackbox.cli import main

    try:
        status = main(list(argv))
    except SystemExit as exc:
        status = exc.code
    out, err = capsys.readouterr()
    return status, out, err


def write_scene(folder: Path, text: str, name: str = "scene.toml") -> Path:
    path = folder / name
    path.write_text(textwrap.dedent(text))
    return path


@pytest.fixture(scope="session")
def scene_dir(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("scenes")


@pytest.fixture(scope="session")
def prescribed_scene(scene_dir):
    return jackbox.load_scene(write_scene(scene_dir, PRESCRIBED, "hand.toml"))


@pytest.fixture(scope="session")
def float_scene(scene_dir):
    return jackbox.load_scene(write_scene(scene_dir, FREE_FLOAT, "float.toml"))


@pytest.fixture(scope="session")
def all_scenes(prescribed_scene, float_scene):
    """Every built-in scene plus the ones above, by name."""
    scenes = {name: jackbox.load_scene(name) for name in BUILTINS}
    return scenes | {"hand": prescribed_scene, "float": float_scene}
