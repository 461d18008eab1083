"""Where the engine's machine code is cached: one folder per engine version, never stale.

Numba caches a function beside its source file and checks only that file: it
does not notice when a callee in another module changes, so a cached loop
could outlive the events or impact code it was compiled with. The engine's
functions therefore get their own cache locator: their machine code goes to
``<jackbox cache>/engine/<digest>/``, where the digest covers the text of every
engine module and Numba's version, and every entry is stamped with it. Any
edit of any stage gives a new folder, so old code is never loaded for new
source, and an unchanged engine is compiled once per machine.

The jackbox cache folder itself is found here too (:func:`cache_dir`), from
the environment alone, so that it is known when the engine's modules are
imported: Numba fixes a function's cache folder when it is decorated, and a
function decorated before the folder was known would fall back to Numba's
own ``__pycache__`` beside the source, keyed by that one file's time stamp
(stale as soon as a callee in another module changes).
"""

from __future__ import annotations

import hashlib
import os
import tempfile
import warnings
from pathlib import Path

import numba
from numba.core.caching import CacheImpl, _CacheLocator

from ..errors import CacheWarning

HERE = Path(__file__).resolve().parent

#: configured cache folder -> the folder used: itself, or a temporary one where it cannot be written
_folders: dict[str, Path] = {}


def configured_cache_dir() -> Path:
    """The cache folder the environment names (it may not exist, or not be writable).

    ``$JACKBOX_CACHE_DIR``, else ``$XDG_CACHE_HOME/jackbox``, else ``~/.cache/jackbox``.
    """
    if os.environ.get("JACKBOX_CACHE_DIR"):
        return Path(os.environ["JACKBOX_CACHE_DIR"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "jackbox"


def cache_dir() -> Path:
    """The cache folder: the configured one, or, where nothing can be written there, a
    temporary folder for this process (compiled code is then not kept; one warning)."""
    folder = configured_cache_dir()
    key = str(folder)
    if key not in _folders:
        _folders[key] = folder
        if not _can_write(folder):
            _folders[key] = Path(tempfile.mkdtemp(prefix="jackbox-cache-"))
            warnings.warn(f"the cache folder {folder} cannot be written: compiling into {_folders[key]} "
                          f"for this process only (set JACKBOX_CACHE_DIR to a writable folder to keep it)",
                          CacheWarning, stacklevel=3)
    return _folders[key]


def _can_write(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
        return True
    except OSError:
        return False


def digest_of(folder: Path = HERE) -> str:
    """16 hex digits of the text of every module in `folder` (the engine) and Numba's version."""
    h = hashlib.sha256(numba.__version__.encode())
    for path in sorted(folder.glob("*.py")):
        h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()[:16]


#: a digest of the engine's source (every module of this package) and of Numba's version
DIGEST = digest_of()


def engine_cache_path() -> Path:
    """The folder of the engine's machine code."""
    return cache_dir() / "engine" / DIGEST


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
        # never None for the engine: Numba's next locator would put it beside the source, stamped by one file
        self = cls(py_func, py_file, engine_cache_path())
        try:
            self.ensure_cache_path()
        except OSError:          # (the folder was writable a moment ago): this process only
            self._path = Path(tempfile.mkdtemp(prefix="jackbox-engine-"))
        return self


def install() -> None:
    """Put the engine's locator first in Numba's list (once)."""
    if EngineLocator not in CacheImpl._locator_classes:
        CacheImpl._locator_classes.insert(0, EngineLocator)


def files() -> list[Path]:
    """The engine's cache files (index and machine code) in its folder."""
    path = engine_cache_path()
    return sorted(path.glob("*.nb[ic]")) if path.is_dir() else []
