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

import atexit
import hashlib
import os
import shutil
import tempfile
import warnings
from pathlib import Path

import numba
from numba.core.caching import Cache, CacheImpl, _CacheLocator
from numba.core.runtime import nrt

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
    """The cache folder: the configured one where it can be written, else a folder for this process.

    A read-only folder that exists (a shared install, a read-only mount) is
    read as it is: the process works in a temporary folder that links every
    file of the read-only one that this engine can use (:func:`_overlay`), so
    cached code loads from there and what is compiled now goes to the
    temporary folder (one warning when that happens, :func:`kept_for_now`).
    Where the folder cannot even be made, the temporary folder starts empty
    (one warning now). Either is removed when the process ends.
    """
    folder = configured_cache_dir()
    key = str(folder)
    if key not in _folders:
        _folders[key] = folder
        if not _can_write(folder):
            scratch = _scratch("jackbox-cache-")
            _folders[key] = scratch
            if folder.is_dir():
                _overlay(folder, scratch)
                _read_only[str(scratch)] = folder
            else:
                warnings.warn(f"the cache folder {folder} cannot be written: compiling into {scratch} "
                              f"for this process only (set JACKBOX_CACHE_DIR to a writable folder to keep it)",
                              CacheWarning, stacklevel=3)
    return _folders[key]


def _scratch(prefix: str) -> Path:
    """A new temporary folder of this process, removed when it ends."""
    folder = Path(tempfile.mkdtemp(prefix=prefix))
    atexit.register(shutil.rmtree, folder, ignore_errors=True)
    return folder


#: temporary folder -> the read-only cache folder it links (see cache_dir)
_read_only: dict[str, Path] = {}


def _overlay(source: Path, target: Path) -> None:
    """Link into `target` the files of `source` that this engine and its models can use.

    Only the folders jackbox reads are linked (generated models, binding
    modules and their machine code, this engine version's machine code), file
    by file, so that a file written later (Numba writes a new file and renames
    it over the old) replaces the link in `target` and never touches `source`.
    """
    for sub in ("models", "kernels", "kernels/__pycache__", f"engine/{DIGEST}"):
        there = source / sub
        if not there.is_dir():
            continue
        here = target / sub
        here.mkdir(parents=True, exist_ok=True)
        for f in there.iterdir():
            if f.is_file():
                (here / f.name).symlink_to(f)


def kept_for_now(what: str) -> None:
    """Say (once per process) that code compiled now is not kept, when the cache is read-only."""
    folder = cache_dir()
    source = _read_only.pop(str(folder), None)
    if source is not None:
        warnings.warn(f"the cache folder {source} is read-only: {what}, made now, is kept in {folder} "
                      f"for this process only (set JACKBOX_CACHE_DIR to a writable folder to keep it)",
                      CacheWarning, stacklevel=3)


def set_aside(exc: OSError) -> Path:
    """Go on in a temporary folder after writing into the cache failed (a full disk, say); one warning.

    The temporary folder links what the cache holds (as for a read-only
    folder), so what was cached stays in use; it is removed when the process
    ends. Returns the new cache folder.
    """
    folder = configured_cache_dir()
    current = cache_dir()
    scratch = _scratch("jackbox-cache-")
    _overlay(current, scratch)
    _folders[str(folder)] = scratch
    _read_only.pop(str(current), None)
    _unsaved(exc, current)
    return scratch


_said: set[str] = set()


def _unsaved(exc: OSError, where) -> None:
    """The one warning of a process whose compiled code cannot be written into the cache."""
    if "unsaved" not in _said:
        _said.add("unsaved")
        warnings.warn(f"cannot write into the cache folder {where} ({exc.strerror or exc}): compiled code "
                      f"is kept for this process only", CacheWarning, stacklevel=4)


def _ours(path) -> bool:
    """Whether `path` is in a jackbox cache folder (configured, temporary or the engine's own)."""
    path = Path(path).resolve()
    folders = {Path(key) for key in _folders} | set(_folders.values())
    return (path.name.startswith("jackbox-engine-")
            or any(path.is_relative_to(folder.resolve()) for folder in folders))


def _save_or_keep(save):
    """Numba's save_overload for jackbox's cache: a failed write (a full disk) keeps the code in memory."""
    def save_overload(self, sig, data):
        try:
            save(self, sig, data)
        except OSError as exc:
            if not _ours(self._cache_path):
                raise
            _unsaved(exc, self._cache_path)
    save_overload.jackbox = True
    return save_overload


def _load_as_is(load):
    """Numba's load_overload for jackbox's cache: machine code loaded without refreshing the registries.

    Numba refreshes its target context before every cache load: the first
    refresh imports every registry of lowering code it has (its NumPy and
    linear-algebra support, SciPy's BLAS where SciPy is installed), about
    0.4 s, more than a warm start's own work. Loading machine code needs none
    of it, only the runtime's symbols (:meth:`rtsys.initialize`); a compile
    refreshes the context itself first (``CompilerBase``), so anything
    compiled later in the process sees every registry as before.
    """
    def load_overload(self, sig, target_context):
        if not _ours(self._cache_path):
            return load(self, sig, target_context)
        nrt.rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)
    load_overload.jackbox = True
    return load_overload


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
            self._path = _scratch("jackbox-engine-")
        return self


def install() -> None:
    """Put the engine's locator first in Numba's list; guard saving into jackbox's cache, load from it as is (once)."""
    if EngineLocator not in CacheImpl._locator_classes:
        CacheImpl._locator_classes.insert(0, EngineLocator)
    if not getattr(Cache.save_overload, "jackbox", False):
        Cache.save_overload = _save_or_keep(Cache.save_overload)
    if not getattr(Cache.load_overload, "jackbox", False):
        Cache.load_overload = _load_as_is(Cache.load_overload)


def files() -> list[Path]:
    """The engine's cache files (index and machine code) in its folder."""
    path = engine_cache_path()
    return sorted(path.glob("*.nb[ic]")) if path.is_dir() else []


def listing(folder: Path) -> list[str]:
    """The names in a folder (none if it cannot be read)."""
    try:
        return os.listdir(folder)
    except OSError:
        return []


def has_index(folder: Path, fn: str, module: str | None = None, names: list[str] | None = None) -> bool:
    """Whether Numba's cache folder holds an index of the function fn: a file ``<module>.<fn>-*.nbi`` (of any
    module where None).

    names: the folder's :func:`listing`, where the caller asks of several
    functions. (pathlib's glob of the same pattern matched a regular
    expression against each of some 200 names, each time: the ten asked
    before each study or run took a millisecond.)
    """
    names = listing(folder) if names is None else names
    if module is not None:
        first = f"{module}.{fn}-"
        return any(n.endswith(".nbi") and n.startswith(first) for n in names)
    mid = f".{fn}-"
    return any(n.endswith(".nbi") and mid in n for n in names)


def has_files() -> bool:
    """Whether the engine's folder holds any cache file (:func:`files` sorts some 200 paths: a millisecond)."""
    return any(n.endswith((".nbi", ".nbc")) for n in listing(engine_cache_path()))
