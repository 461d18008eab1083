"""Find (or build) the generated model of a scene and assemble its compiled kernel.

Two content-addressed steps keep compiled code from ever going stale:

1. The *model module*: a committed ``generated/<name>.py`` whose recorded
   model hash is the scene's (a built-in, or any scene of the same structure:
   a copy or a renamed scene compiles nothing), otherwise
   ``<cache>/models/<hash>.py``, generated on first use and shared by every
   scene of that structure. The hash covers the scene's structure (not its
   name) and the compiler's source.
2. The *kernel module*: ``<cache>/kernels/<stem>_<key>.py``, the text of the
   model module, a binding section and the text of :mod:`jackbox.kernel`, where
   ``key`` hashes all of that text and Numba's version. Numba caches its machine
   code beside that file (``cache=True``); a changed model or kernel gives a new
   file, so old machine code is never served for new source.

The cache folder is ``$JACKBOX_CACHE_DIR``, else ``$XDG_CACHE_HOME/jackbox``,
else ``~/.cache/jackbox``. Only building a model needs sympy.
"""

from __future__ import annotations

import ast
import hashlib
import importlib.util
import json
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path
from types import ModuleType

import numba
import numpy as np

from codegen.version import is_sealed, model_hash

from .errors import CacheWarning
from .fileio import write_atomic
from .scene import Scene

KERNEL_SOURCE = Path(__file__).with_name("kernel.py")
GENERATED_DIR = Path(__file__).resolve().parent.parent / "generated"
#: functions a model may lack; the kernel only calls them when the model has them
OPTIONAL = {
    "phi_t": "def phi_t(t, q, p, out):\n    pass\n",
    "box_motion": "def box_motion(t, p, out):\n    pass\n",
}
_loaded: dict[str, ModuleType] = {}
#: (path, inode, mtime, size) -> whether the generated module there is sealed (see intact())
_intact: dict[tuple, bool] = {}
#: kernel modules whose Numba cache files were checked against their manifest in this process
_verified: set[str] = set()
#: configured cache folder -> the folder used: itself, or a temporary one where it cannot be written
_folders: dict[str, Path] = {}
#: (cache folder, model file, its and the kernel's inode, mtime and size) -> module
_stamped: dict[tuple, ModuleType] = {}


def configured_cache_dir() -> Path:
    """The cache folder the environment names (it may not exist, or not be writable)."""
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
            _warn(f"the cache folder {folder} cannot be written: compiling into {_folders[key]} "
                  f"for this process only (set JACKBOX_CACHE_DIR to a writable folder to keep it)")
    return _folders[key]


def _can_write(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tempfile.TemporaryFile(dir=folder).close()
        return True
    except OSError:
        return False



def recorded_hash(path: Path) -> str | None:
    """The model hash written in a generated module's constants, if any."""
    try:
        with open(path, encoding="utf-8") as fh:
            for _, line in zip(range(40), fh):
                if line.startswith("MODEL_HASH = "):
                    return line.split('"')[1]
    except OSError:
        return None
    return None


def committed_model(digest: str) -> Path | None:
    """The committed module in ``generated/`` with this model hash, if there is one."""
    for path in sorted(GENERATED_DIR.glob("*.py")):
        if recorded_hash(path) == digest:
            return path
    return None


def cached_model_path(scene: Scene) -> Path:
    """Where a scene's module goes in the cache: named by its model hash, not by the scene."""
    return cache_dir() / "models" / f"{model_hash(scene.structure())}.py"


def model_path(scene: Scene) -> Path:
    """Where the current generated module of `scene` is, or will be written.

    The structure decides, not the name: a scene with a built-in's structure
    (a copy of ``drop.toml`` under another name, say) uses the committed module,
    unless that module is damaged (then the cache's copy serves).
    """
    digest = model_hash(scene.structure())
    if scene.builtin and recorded_hash(GENERATED_DIR / f"{scene.name}.py") == digest:
        committed = GENERATED_DIR / f"{scene.name}.py"
    else:
        committed = committed_model(digest)
    if committed is not None and intact(committed):
        return committed
    if committed is not None:
        _warn(f"{committed} is damaged or was edited by hand (its seal does not match): "
              f"using a copy generated into the cache instead (jackbox build restores it)")
    return cached_model_path(scene)


def ensure_model(scene: Scene, log=None) -> Path:
    """The generated module of `scene`, generating it first if it is missing, stale or damaged."""
    path = model_path(scene)
    current = recorded_hash(path) == model_hash(scene.structure())
    if not current or not intact(path):
        from codegen.driver import build   # sympy is only needed here

        if current:
            _warn(f"{path} was damaged (its seal does not match its text): generating it again")
        result = build(scene, path)
        _intact.clear()
        if log:
            log(f"generated {path} ({sum(result.seconds.values()):.2f} s)")
    return path


def intact(path: Path) -> bool:
    """Whether a generated module is whole and unchanged: its last line seals the text above.

    Read and hashed once per process for each version of the file (by stat).
    """
    try:
        stamp = (str(path), *_stat(path))
    except OSError:
        return False
    if stamp not in _intact:
        try:
            _intact[stamp] = is_sealed(path.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError):
            _intact[stamp] = False
    return _intact[stamp]


def kernel_source(model_text: str, kernel_text: str | None = None) -> str:
    """Text of the kernel module: the model, a binding section, then the kernel."""
    kernel_text = KERNEL_SOURCE.read_text() if kernel_text is None else kernel_text
    present = _functions_of(model_text)
    absent = [name for name in OPTIONAL if name not in present]
    stubs = "".join("\n\n" + OPTIONAL[name] for name in absent)
    binding = (
        "\n\n# " + "-" * 77 + "\n"
        "# Binding (jackbox.loader): the model's functions compiled by Numba, in this file,\n"
        "# so the kernel below calls them as globals and caches with them.\n"
        "# " + "-" * 77 + "\n"
        "from numba import njit as _njit\n"
        + stubs
        + "\n\n"
        + "".join(f"{name} = _njit(cache=True)({name})\n" for name in (*present, *absent))
        + "\n# " + "-" * 77 + "\n# Kernel (jackbox/kernel.py)\n# " + "-" * 77 + "\n"
    )
    return model_text + binding + kernel_text


def load_kernel(model_file: Path, kernel_text: str | None = None) -> ModuleType:
    """Import (assembling on first use) the kernel module for a generated model."""
    # a second call with unchanged files costs two stat()s, not reading and hashing them
    stamp = None
    if kernel_text is None:
        stamp = (str(cache_dir()), str(model_file), *_stat(model_file), *_stat(KERNEL_SOURCE))
        if stamp in _stamped:
            return _stamped[stamp]
    text = kernel_source(model_file.read_text(), kernel_text)
    key = hashlib.sha256((numba.__version__ + "\0" + text).encode()).hexdigest()[:16]
    if key in _loaded:
        if stamp is not None:
            _stamped[stamp] = _loaded[key]
        return _loaded[key]
    # committed models are <name>.py, cached ones <model hash>.py
    stem = model_file.stem
    path = cache_dir() / "kernels" / f"{_ident(stem)}_{key}.py"
    if not path.exists() or path.read_text() != text:
        write_atomic(path, text)
    name = f"jackbox_kernel_{_ident(stem)}_{key}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    _loaded[key] = module
    if stamp is not None:
        _stamped[stamp] = module
    return module


def _stat(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_ino, st.st_mtime_ns, st.st_size


def kernel_for(scene: Scene, log=None) -> ModuleType:
    """The kernel module of `scene` (model generated if needed)."""
    return load_kernel(ensure_model(scene, log))


def compile_kernel(module: ModuleType, method: str | None = None, n_rec: int = 2) -> dict:
    """Make sure the kernel's machine code for `method` is ready: compiled now or loaded from cache.

    method: ``"exact"``, ``"naive"``, ``"ensemble"`` or ``"chaos"`` (the
    parallel member loops) or None for the two methods. Each is compiled on
    first use only.
    Returns ``{"seconds": ..., "cache": "hit" | "miss" | "memory" | "disabled"}``:
    loaded from Numba's cache, compiled now, compiled earlier in this process,
    or not compiled at all (``NUMBA_DISABLE_JIT=1``).
    """
    t0 = time.perf_counter()
    if numba.config.DISABLE_JIT:
        return {"seconds": 0.0, "cache": "disabled"}
    if module.__file__ not in _verified:
        _verified.add(module.__file__)
        _check_manifest(module)
    cached = bool(_numba_files(module))
    try:
        result = _compile(module, method, n_rec, t0)
    except Exception as exc:       # a damaged cache entry that slipped past the manifest
        if not cached:             # nothing was loaded: a failure of its own
            raise
        _warn(f"loading the compiled {method or 'exact and naive'} loop of {Path(module.__file__).name} "
              f"from the cache failed ({type(exc).__name__}: {str(exc)[:120]}): compiling it again")
        _clear_numba_files(module)      # the dispatchers find no entry now, and compile
        result = _compile(module, method, n_rec, t0)
    if result["cache"] == "miss":
        _write_manifest(module)
    return result


def _compile(module: ModuleType, method: str | None, n_rec: int, t0: float) -> dict:
    wanted = {"exact": ("integrate_exact",), "naive": ("integrate",),
              "ensemble": ("run_members", "start_gaps"), "chaos": ("run_twin_members", "start_gaps"),
              None: ("integrate", "integrate_exact")}[method]
    loops = [getattr(module, name) for name in wanted]
    if all(f.signatures for f in loops):
        return {"seconds": 0.0, "cache": "memory"}
    n, C = module.N_DOF, module.N_CONTACT
    p = np.zeros(module.N_PARAM)
    rec = (np.zeros(n_rec), np.zeros((n_rec, 6)), np.zeros((n_rec, 6)), np.zeros(n_rec), 0)
    log = (np.zeros(C + 1), np.zeros(C + 1, np.int64))
    # zero steps from step 1: compiles without evaluating the model at p = 0
    if "integrate" in wanted:
        module.integrate(np.zeros(n), np.zeros(n), p, 0.0, 1.0, 1, 1, 1, 1, *rec, *log, 0)
    if "integrate_exact" in wanted:
        module.integrate_exact(np.zeros(n), np.zeros(n), np.zeros(C, np.int64), p,
                               np.zeros(module.T_SPEED + n), 0.0, 1.0, 1, 1, 1, 1, *rec,
                               *log, np.zeros(C + 1, np.int64), 0)
        if module.PRESCRIBED:
            module.box_motion(0.0, p, np.zeros(6))
    if "run_members" in wanted:
        # zero members: compiles the parallel loops without running the model
        Q, P = np.zeros((0, n)), np.zeros((0, module.N_PARAM))
        T = np.zeros((0, module.T_SPEED + n))
        module.run_members(Q, Q, P, T, 1.0, 1, np.zeros(0, np.int64), np.zeros((0, 0, 6)),
                           np.zeros((0, 0, 6)), np.zeros((0, 6)), np.zeros((0, 6)), np.zeros((0, 5)))
    if "run_twin_members" in wanted:
        Q, P = np.zeros((0, n)), np.zeros((0, module.N_PARAM))
        module.run_twin_members(Q, Q, Q, Q, P, np.zeros((0, module.T_SPEED + n)), 1.0, 1, 1, np.ones(2 * n),
                                np.zeros((0, 1)), np.zeros((0, 3)))
    if "start_gaps" in wanted:
        module.start_gaps(np.zeros((0, n)), np.zeros((0, module.N_PARAM)))
    hits = sum(sum(f.stats.cache_hits.values()) for f in loops)
    return {"seconds": time.perf_counter() - t0, "cache": "hit" if hits else "miss"}


#: what compile_kernel compiles for each method (the first is the one to look for in the cache)
ENTRY = {"exact": "integrate_exact", "naive": "integrate", "ensemble": "run_members", "chaos": "run_twin_members"}


def is_cached(module: ModuleType, method: str) -> bool:
    """Whether Numba's cache beside the kernel module holds `method`'s loop (so no compile is due)."""
    path = Path(module.__file__)
    return any(path.parent.glob(f"__pycache__/{path.stem}.{ENTRY[method]}-*.nbi"))


def _numba_files(module: ModuleType) -> list[Path]:
    """Numba's cache files (index and machine code) beside a kernel module."""
    path = Path(module.__file__)
    return sorted(path.parent.glob(f"__pycache__/{path.stem}.*.nb[ic]"))


def _manifest(module: ModuleType) -> Path:
    path = Path(module.__file__)
    return path.parent / "__pycache__" / f"{path.stem}.sums.json"


def _write_manifest(module: ModuleType) -> None:
    """Record the checksums of the kernel's cache files (after a compile wrote some)."""
    sums = {f.name: [f.stat().st_ino, _sha256(f)] for f in _numba_files(module)}
    try:
        write_atomic(_manifest(module), json.dumps(sums, indent=0, sort_keys=True))
    except OSError:
        pass     # a read-only cache: its files are what they are


def _check_manifest(module: ModuleType) -> None:
    """Remove the kernel's cache files when one no longer matches its recorded checksum.

    Numba reads its index and machine code without checking them: a truncated
    or altered file fails on every later load (or worse). Numba replaces a file
    by renaming a new one over it (a new inode), so a file another process has
    written since, like one the manifest does not list, is left to Numba; the
    same inode with other bytes is damage.
    """
    path = _manifest(module)
    if not path.exists():
        return
    try:
        sums = json.loads(path.read_text())
        bad = []
        for name, (inode, digest) in sums.items():
            f = path.parent / name
            if f.exists() and f.stat().st_ino == inode and _sha256(f) != digest:
                bad.append(name)
    except (OSError, ValueError, TypeError, AttributeError):
        bad = [path.name]
    if bad:
        _warn(f"the compiled code of {Path(module.__file__).name} in the cache is damaged ({bad[0]}"
              f"{f' and {len(bad) - 1} more' if len(bad) > 1 else ''}): compiling it again")
        _clear_numba_files(module)


def _clear_numba_files(module: ModuleType) -> None:
    for f in [*_numba_files(module), _manifest(module)]:
        try:
            f.unlink(missing_ok=True)
        except OSError:
            pass


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _warn(message: str) -> None:
    warnings.warn(message, CacheWarning, stacklevel=3)


def _functions_of(model_text: str) -> tuple[str, ...]:
    for line in model_text.splitlines():
        if line.startswith("FUNCTIONS = "):
            return tuple(ast.literal_eval(line.split("=", 1)[1].strip()))
    raise ValueError("not a generated model module: no FUNCTIONS line")


def _ident(name: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in name)
