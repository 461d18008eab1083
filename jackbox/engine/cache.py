"""Where the engine's machine code is cached: one folder per engine version, never stale.

Numba caches a function beside its source file and checks only that file: it
does not notice when a callee in another module changes, so a cached loop
could outlive the events or impact code it was compiled with. The engine's
functions therefore get their own cache locator: their machine code goes to
``<jackbox cache>/engine/<digest>/``, where the digest covers the text of every
engine module and Numba's version, and every entry is stamped with it. Any
edit of any stage gives a new folder, so old code is never loaded for new
source, and an unchanged engine is compiled once per machine.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import Callable

import numba
from numba.core.caching import CacheImpl, _CacheLocator

HERE = Path(__file__).resolve().parent

#: the jackbox cache folder, set by jackbox.loader (None: Numba's own locators decide)
folder: Callable[[], Path] | None = None


def digest_of(folder: Path = HERE) -> str:
    """16 hex digits of the text of every module in `folder` (the engine) and Numba's version."""
    h = hashlib.sha256(numba.__version__.encode())
    for path in sorted(folder.glob("*.py")):
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:16]


#: a digest of the engine's source (every module of this package) and of Numba's version
DIGEST = digest_of()


def engine_cache_path() -> Path | None:
    """The folder of the engine's machine code (None when no jackbox cache folder is set)."""
    return None if folder is None else folder() / "engine" / DIGEST


class EngineLocator(_CacheLocator):
    """Numba's cache locator for the functions of jackbox.engine (see the module's docstring)."""

    def __init__(self, py_func, py_file, path: Path):
        self._py_file = py_file        # (Numba names it in its warnings)
        self._lineno = py_func.__code__.co_firstlineno
        self._path = path

    def get_cache_path(self):
        return str(self._path)

    def get_source_stamp(self):
        return DIGEST

    def get_disambiguator(self):
        return str(self._lineno)

    @classmethod
    def from_function(cls, py_func, py_file):
        if Path(os.path.abspath(py_file)).parent != HERE:
            return None
        path = engine_cache_path()
        if path is None:
            return None
        self = cls(py_func, py_file, path)
        try:
            self.ensure_cache_path()
        except OSError:
            return None
        return self


def install() -> None:
    """Put the engine's locator first in Numba's list (once)."""
    if EngineLocator not in CacheImpl._locator_classes:
        CacheImpl._locator_classes.insert(0, EngineLocator)


def files() -> list[Path]:
    """The engine's cache files (index and machine code) in its folder."""
    path = engine_cache_path()
    return sorted(path.glob("*.nb[ic]")) if path is not None and path.is_dir() else []
