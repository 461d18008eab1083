"""Stage 4: run the compiler for a scene and put the module where the runtime finds it.

* built-in scenes: ``generated/<name>.py`` (committed; ``jackbox build`` rewrites it);
* any other structure (a user's file, or a built-in changed with ``--set`` in a
  way that changes its structure): ``<cache>/models/<hash>.py``; a scene with a
  built-in's structure uses the committed module
  (:func:`jackbox.loader.model_path` decides which).

Writes are atomic (temporary file, then rename) and skipped when the text is
unchanged, so an unchanged model leaves its file byte-identical.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

from jackbox.fileio import write_atomic
from jackbox.scene import Scene

from .emitter import emit_module
from .model import derive


@dataclass
class BuildResult:
    path: Path
    text: str
    changed: bool
    seconds: dict[str, float]   #: derive, emit (cse + print) times


def build_command(scene: Scene) -> str:
    """The command that regenerates this scene's module."""
    return f"jackbox build {scene.name if scene.builtin else scene.source}"


def generate(scene: Scene) -> tuple[str, dict[str, float]]:
    """Module text for `scene`, with the time each stage took."""
    t0 = time.perf_counter()
    model = derive(scene)
    t1 = time.perf_counter()
    text = emit_module(model, build_command(scene))
    t2 = time.perf_counter()
    return text, {"derive": t1 - t0, "cse_emit": t2 - t1}


def build(scene: Scene, path: Path) -> BuildResult:
    """Generate the module of `scene` into `path` (atomic; untouched if unchanged)."""
    text, seconds = generate(scene)
    old = path.read_text() if path.exists() else None
    if old != text:
        write_atomic(path, text)
    return BuildResult(path, text, old != text, seconds)
