"""Find (or build) the generated model of a scene and bind it to the compiled engine.

Three content-addressed pieces keep compiled code from ever going stale:

1. The *model module*: a committed ``generated/<name>.py`` whose recorded
   model hash is the scene's (a built-in, or any scene of the same structure:
   a copy or a renamed scene compiles nothing), otherwise
   ``<cache>/models/<hash>.py``, generated on first use and shared by every
   scene of that structure. The hash covers the scene's structure (not its
   name) and the compiler's source.
2. The *binding parts*: ``<cache>/kernels/<function>_<key>.py``, one for each
   function the engine calls, holding that function and what it reaches by
   name (for the free-flight hot path, :mod:`jackbox.engine.flight` and the
   model's tuple functions), compiled as a ``cfunc`` value; ``key`` hashes
   that text (with the engine's digest where it reaches engine code) and
   Numba's version. Numba caches the machine code beside that file, so an
   edit recompiles only the functions whose text it changed.
3. The *engine* (:mod:`jackbox.engine`): compiled once per machine and engine
   version for every model, cached in ``<cache>/engine/<digest>/``.

The runtime reaches the compiler through the top level of :mod:`codegen` only:
:func:`build_model` (used by :func:`ensure_model` and ``jackbox build``) hands
:func:`codegen.generate` the scene's :class:`codegen.ModelSpec` and writes the
text it returns (sympy is imported only then), and :func:`codegen.model_hash`
tells a current module from a stale one. The cache folder is
``$JACKBOX_CACHE_DIR``, else ``$XDG_CACHE_HOME/jackbox``, else
``~/.cache/jackbox``.
"""

from __future__ import annotations

import ast
import functools
import hashlib
import importlib.util
import json
import re
import sys
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import numba
import numpy as np

from numba.core.errors import NumbaExperimentalFeatureWarning

from codegen import generate, is_sealed, model_hash

from . import engine
from .engine.flight import INLINED
from .engine.lanes import INLINED as LANES_INLINED
from .errors import CacheWarning
from .fileio import write_atomic
from .scene import Scene

FLIGHT_SOURCE = Path(__file__).with_name("engine") / "flight.py"
LANES_SOURCE = Path(__file__).with_name("engine") / "lanes.py"
#: the lanes of a model that has none compiled (yet): every lane "not quiet", so a block would step
#: each member alone through the exact loop (a kernel binds the real ones before a study uses them)
LANES_STUB = ("def time_table(t0, dt, n, p, out):\n    return 0\n\n\n"
              "def lanes(t0, dt, i, i_stop, S, p, tol, live, quiet, tab, lane_event):\n"
              "    for l in range(quiet.shape[0]):\n        quiet[l] = 0\n    return i\n\n\n"
              "def lane_event(t, t_next, dt, S, lane, at, to, p, tol):\n    return -1\n")
#: what a model's ride costs to compile (shaken, 2 cores): only to share the work of a first held contact
#: out between two processes (Kernel._compile_stages)
RIDE_COST = 6.8
#: the held steps on floats of a model that has none compiled (yet): no step taken, the held loop takes them
#: on its arrays (the same numbers); a kernel binds the real ones when the held loop is first in a table
RIDE_STUB = ("def ride(t0, dt, i, i_stop, q, qd, p, tol, rest, m, k1, k2, winv, io_f, rec_t, rec_q, rec_qd, io_k,\n"
             "         record_every, n_total, qb, qdb, ga, gb, ls, A):\n    io_k[1] = 0\n    return i\n")
GENERATED_DIR = Path(__file__).resolve().parent.parent / "generated"
#: functions a model may lack; the kernel only calls them when the model has them
OPTIONAL = {
    "box_motion": "def box_motion(t, p, out):\n    pass\n",
}
_loaded: dict[str, ModuleType] = {}
#: (path, inode, mtime, size) -> whether the generated module there is sealed (see intact())
_intact: dict[tuple, bool] = {}
#: binding modules and engine folders whose Numba cache files were checked against their manifest
_verified: set = set()
#: (cache folder, model file, its and the hot path's inode, mtime and size) -> kernel
_stamped: dict[tuple, "Kernel"] = {}


configured_cache_dir = engine.cache.configured_cache_dir
cache_dir = engine.cache.cache_dir


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
        if current:
            _warn(f"{path} was damaged (its seal does not match its text): generating it again")
        try:
            result = build_model(scene, path)
        except OSError as exc:         # a full disk: go on in a folder of this process
            if not path.is_relative_to(cache_dir()):
                raise
            engine.cache.set_aside(exc)
            path = model_path(scene)
            result = build_model(scene, path)
        _intact.clear()
        if log:
            log(f"generated {path} ({sum(result.seconds.values()):.2f} s)")
    return path


@dataclass
class BuildResult:
    path: Path
    text: str
    changed: bool
    seconds: dict[str, float]   #: the compiler's stages: derive, cse_emit


def build_model(scene: Scene, path: Path) -> BuildResult:
    """Generate the module of `scene` into `path` (atomic; untouched if the text is unchanged)."""
    text, seconds = generate(scene.model_spec())      # imports sympy (once per process)
    changed = not path.exists() or path.read_bytes() != text.encode("utf-8")
    if changed:
        write_atomic(path, text)
        engine.cache.kept_for_now(f"the model {path.name}")
    return BuildResult(path, text, changed, seconds)


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


def binding_parts(model_text: str, flight_text: str | None = None, lanes: bool = False,
                  ride: bool = False) -> dict[str, str]:
    """The text of each *binding part*: one small module per function the engine calls.

    A part holds one function of :data:`jackbox.engine.SIGNATURES` (or the
    functions of a group of :data:`GROUPS`) with what it reaches by name and
    nothing else: a gap function its generated body and ``import math``; the
    free-flight hot path (:mod:`jackbox.engine.flight`) the model's tuple
    functions and constants it calls, inlined. Each is compiled as a
    ``cfunc`` and cached beside its file, which is named by a hash of its
    text; so a model edit compiles only the functions whose text it changed
    (a new potential term: the accelerations, the energy and the flight loop,
    not the gaps), and a part two models share is compiled once. A part that reaches the
    engine's code (the hot path's imports) names the engine's digest, so an
    edit of the engine is never served stale machine code.

    lanes: the ``lanes`` part is an ensemble block's (:mod:`jackbox.engine.lanes`),
    for a model that has lanes (``clearance_v``: a free box); else it is
    :data:`LANES_STUB`, the same for every model, so a model compiles its
    lanes only when a study first needs them. ride: the ``ride`` part is the
    model's held steps on floats (:func:`jackbox.engine.flight.ride`), else
    :data:`RIDE_STUB`: compiled when a run first holds a contact
    (:meth:`Kernel.table`).
    """
    flight_text = FLIGHT_SOURCE.read_text() if flight_text is None else flight_text
    lanes_text = LANES_SOURCE.read_text() if lanes and has_lanes(model_text) else LANES_STUB
    return dict(_kept_parts(model_text, flight_text, lanes_text, "" if ride else RIDE_STUB, engine.cache.DIGEST))


#: the line of a binding part that reaches the engine's code, naming the engine build it was made for
_ENGINE_LINE = re.compile(r"^# engine: ([0-9a-f]+)$", re.MULTILINE)


def parts_of_other_engines(kernels, digest: str) -> list:
    """The files under a cache's ``kernels`` folder made for another engine build than ``digest``, for
    ``jackbox cache prune``: binding parts whose text names another (:func:`_binding_parts` names the
    engine's digest in every part that reaches its code: such a part is never read by this version),
    Numba's cache files of those parts (named after them), and the kept cuts of a model into parts
    (``parts_*.json``) whose texts name another."""
    old = []
    for part in sorted(kernels.glob("*.py")):
        try:
            head = part.read_text(encoding="utf-8", errors="replace")[:4096]
        except OSError:
            continue
        named = _ENGINE_LINE.search(head)
        if named and named.group(1) != digest:
            old.append(part)
            old.extend(sorted((kernels / "__pycache__").glob(part.stem + ".*")))
    for kept in sorted(kernels.glob("parts_*.json")):
        try:
            texts = json.loads(kept.read_text(encoding="utf-8"))
            names = {name for text in texts.values() for name in _ENGINE_LINE.findall(text)}
        except (OSError, ValueError, AttributeError, TypeError):
            continue                     # (not one of ours as we write them: left)
        if names and digest not in names:
            old.append(kept)
    return old


#: a digest of this module's own text: how parts are cut (see _kept_parts)
_SELF = hashlib.sha256(Path(__file__).read_bytes()).hexdigest()[:16]


@functools.lru_cache(maxsize=16)
def _kept_parts(model_text: str, flight_text: str, lanes_text: str, stub_text: str, digest: str) -> dict[str, str]:
    """:func:`_binding_parts`, kept in the cache folder: a warm start reads it instead of parsing the model.

    Cutting a model into parts parses its text and walks every statement
    (about 40 ms, a tenth of a warm start). The file is named by a hash of
    everything the parts depend on (the texts, the engine's digest, this
    module's text), so it never goes stale; one that cannot be read or
    written is simply made again.
    """
    key = hashlib.sha256("\0".join([model_text, flight_text, lanes_text, stub_text, digest, _SELF]).encode()).hexdigest()[:16]
    path = cache_dir() / "kernels" / f"parts_{key}.json"
    try:
        kept = json.loads(path.read_text(encoding="utf-8"))
        if isinstance(kept, dict) and set(kept) == set(part_entries()):
            return kept
    except (OSError, ValueError):
        pass
    parts = _binding_parts(model_text, flight_text, lanes_text, stub_text, digest)
    try:
        write_atomic(path, json.dumps(parts))
    except OSError:
        pass                       # (a read-only or full cache: made again next time)
    return parts


def has_lanes(model_text: str) -> bool:
    """Whether a generated model has the functions an ensemble block's lanes need."""
    return "clearance_v" in _functions_of(model_text)


def _binding_parts(model_text: str, flight_text: str, lanes_text: str, stub_text: str, digest: str) -> dict[str, str]:
    """(binding_parts, kept for the texts a process sees again; stub_text: defines ``ride`` over the hot path's)"""
    model_blocks = _blocks(_with_stubs(model_text))
    flight_blocks = _blocks(flight_text) + _blocks(lanes_text) + (_blocks(stub_text) if stub_text else [])
    defined = {name: i for i, (names, _, _) in enumerate(model_blocks + flight_blocks) for name in names}
    blocks = model_blocks + flight_blocks
    parts = {}
    for part, entries in part_entries().items():
        wanted, todo = set(), list(entries)
        while todo:
            i = defined.get(todo.pop())
            if i is not None and i not in wanted:
                wanted.add(i)
                todo.extend(blocks[i][2])
        chosen = sorted(wanted)
        names = {name for i in chosen for name in blocks[i][0]}
        engine_code = any(i >= len(model_blocks) for i in chosen)
        rule = "# " + "-" * 77 + "\n"
        parts[part] = (
            rule + f"# Binding part (jackbox.loader): the model's {', '.join(entries)} as the engine's function "
            + ("values" if len(entries) > 1 else "value") + "\n"
            + "".join(f"# signature of {entry}: {engine.SIGNATURES[entry]}\n" for entry in entries)
            + f"# compiled without reference counting, error model {engine.ERROR_MODEL!r} (jackbox.engine.bind_part)\n"
            + (f"# engine: {digest}\n" if engine_code else "")
            + rule + "\n"
            + "\n\n\n".join(blocks[i][1] for i in chosen) + "\n\n\n"
            + ("from numba import njit as _njit\n" if names & set(_JITTED) else "")
            + "from jackbox.engine import bind_part as _bind_part\n\n"
            + "".join(f"{name} = _njit(cache=True, error_model={engine.ERROR_MODEL!r}{_JITTED[name]})({name})\n"
                      for name in _JITTED if name in names and name not in entries)
            + "COMPILED = {" + ", ".join(f"{entry!r}: _bind_part({entry!r}, {entry})" for entry in entries) + "}\n"
        )
    return parts


#: functions compiled together, as one binding part: the two RK4 loops of the hot path share every
#: helper (the model's accelerations on tuples, the tableau), which each part would compile again; the
#: lanes and the table of terms of time they read share the model's accel_time_s
GROUPS = {"flight": ("free_step", "fly"), "lanes": ("time_table", "lanes")}


def part_entries() -> dict[str, tuple[str, ...]]:
    """The binding parts of a model: part name -> the functions of SIGNATURES it holds, in their order."""
    out = {}
    for name in engine.SIGNATURES:
        group = next((g for g, members in GROUPS.items() if name in members), None)
        if group is None:
            out[name] = (name,)
        elif group not in out:
            out[group] = tuple(n for n in engine.SIGNATURES if n in GROUPS[group])
    return out


#: the helpers of the hot path a part compiles as njit functions (callees inlined by LLVM, or
#: by Numba where marked), with their options
_JITTED = {**{name: "" for name in ("tuple_of", "accel_s", "accel_time_s", "time_of", "box_motion_s", "axpy_s",
                                    "wsum_s", "wdot_s", "row_dot_s", "respond_s", "respond2_s", "respond4_s")},
           **{name: ', inline="always"' for name in INLINED + LANES_INLINED},
           # a lane near a wall (lanes.calm): phi_s and gap_rate_s inlined, so that LLVM computes the sine
           # and cosine of each angle once for both; no references counted (calm allocates nothing)
           **{name: ', inline="always"' for name in ("phi_s", "gap_rate_s")}, "calm": ", _nrt=False",
           # a lane's event step (lanes.event_lane): each a function of its own, called only where a lane has
           # an event (their re-step's RK4 compiled once, in restep)
           **{name: ", _nrt=False" for name in ("event_lane", "crossing_lane", "locate_lane", "impact_lane",
                                                 "restep", "probe", "gaps_rates_at", "row_at",
                                                 "inverse_mass")},
           # the held steps' helpers (flight.ride): inlined by Numba where a call would pass the rows through
           # memory (factor4 too: called, a corner's step took 1.2 times as long, and the stage could not skip
           # a dependent fourth row's work, known only once it is factored); a pose's terms (after two sines
           # and cosines, a call costs little) and the solves (solve4 at three sites: inlined, it added two
           # seconds of compiling and no speed) left to LLVM
           **{name: "" for name in ("factor2", "solve2", "solve4", "contact_pose_s")},
           **{name: ', inline="always"' for name in ("contact_row_s", "held_rows", "factor_held", "factor4",
                                                      "held_push", "held_stage", "settle")},
           "trade": ", _nrt=False"}


def _blocks(text: str) -> list[tuple[set, str, set]]:
    """The top-level statements of a module's text: (names each defines, its source, names it reads).

    The module's docstring is left out; imports define the names they bind.
    """
    lines = text.splitlines()
    out = []
    for node in ast.parse(text).body:
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant):
            continue
        if isinstance(node, ast.FunctionDef):
            names = {node.name}
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names = {(alias.asname or alias.name).split(".")[0] for alias in node.names}
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names = {n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name)}
        else:
            raise ValueError(f"a binding cannot take a top-level {type(node).__name__} (line {node.lineno})")
        first = min([node.lineno] + [d.lineno for d in getattr(node, "decorator_list", [])])
        source = "\n".join(lines[first - 1:node.end_lineno])
        reads = {n.id for n in ast.walk(node) if isinstance(n, ast.Name)} - names
        out.append((names, source, reads))
    return out


def model_module(model_file: Path, model_text: str) -> ModuleType:
    """The generated model as a plain module (its constants and Python functions), with stubs for what it lacks."""
    module = ModuleType(f"jackbox_model_{_ident(model_file.stem)}")
    module.__file__ = str(model_file)
    exec(compile(_with_stubs(model_text), str(model_file), "exec"), module.__dict__)
    return module


def _with_stubs(model_text: str) -> str:
    """A generated model's text with a stub for each function of OPTIONAL it lacks."""
    present = _functions_of(model_text)
    return model_text + "".join("\n\n" + OPTIONAL[name] for name in OPTIONAL if name not in present)


def part_path(name: str, text: str) -> Path:
    """Where the binding part of this text lives: named by the function and a hash of the text and Numba's version."""
    key = hashlib.sha256((numba.__version__ + "\0" + text).encode()).hexdigest()[:16]
    return cache_dir() / "kernels" / f"{name}_{key}.py"


def load_binding(model_file: Path, flight_text: str | None = None, lanes: bool = False) -> ModuleType:
    """The model as a module, with its functions bound to the engine in ``COMPILED`` (compiled or loaded).

    Writes the binding parts (:func:`binding_parts`) that are not in the cache
    yet; those whose machine code is not cached are compiled, about half in a
    helper process (:func:`jackbox.engine.start_binding`) where there are two
    cores. ``CACHE`` says whether any was compiled now ("miss").
    """
    model_text = model_file.read_text()
    texts = binding_parts(model_text, flight_text, lanes)
    paths = {name: part_path(name, text) for name, text in texts.items()}
    # (the hot path's text too: its ride, bound later from it, is in no part yet)
    key = hashlib.sha256("\0".join([model_text, str(flight_text), *map(str, paths.values())]).encode()).hexdigest()[:16]
    if key in _loaded:
        return _loaded[key]
    for name, text in texts.items():
        paths[name] = _write_part(paths[name], text)
    module = model_module(model_file, model_text)
    indexes: dict = {}           # (each folder of parts listed once for all of them: see _pycache_index)
    todo = {name: path for name, path in paths.items()
            if str(path) not in _parts and not _cached(name, path, _index_of(path, indexes))}
    real_lanes = lanes and has_lanes(model_text)
    theirs = engine.start_binding(todo, engine.LANES_COST if real_lanes else None) if todo else []
    parts = {}
    for name in sorted(paths, key=lambda name: name in theirs):      # the helper's last
        if name in theirs:
            engine.wait_binding(paths[name])
        parts[name] = _import_part(paths[name], None if name in theirs else _index_of(paths[name], indexes))
    compiled = {entry: fn for part in parts.values() for entry, fn in part.COMPILED.items()}
    module.COMPILED = {name: compiled[name] for name in engine.SIGNATURES}
    module.PARTS = paths
    module.LANES = real_lanes
    module.FLIGHT_TEXT = flight_text
    module.PART_CACHE = {name: part.CACHE for name, part in parts.items()}
    module.CACHE = ("disabled" if numba.config.DISABLE_JIT else
                    "miss" if any(part.CACHE == "miss" for part in parts.values()) else "hit")
    if module.CACHE == "miss":
        engine.cache.kept_for_now(f"the functions of the model {model_file.name}")
    _loaded[key] = module
    return module


def _write_part(path: Path, text: str) -> Path:
    """Write a binding part unless it is there (whole); a full disk moves the cache aside. Returns its path."""
    try:
        if path.exists() and path.read_text() == text:
            return path
        write_atomic(path, text)
    except OSError as exc:         # a full disk: go on in a folder of this process
        path = engine.cache.set_aside(exc) / "kernels" / path.name
        write_atomic(path, text)
    return path


#: binding parts imported in this process: path -> module (a part two models share is loaded once)
_parts: dict[str, ModuleType] = {}


def _import_part(path: Path, index: dict | None = None) -> ModuleType:
    """Import a binding part (compiling its function, or loading its machine code from the cache).

    index: its folder's :func:`_pycache_index`, taken since nothing but this
    process's imports wrote there (None: listed here)."""
    if str(path) in _parts:
        return _parts[str(path)]
    if str(path) not in _verified:
        _verified.add(str(path))
        if _check_manifest(_numba_files(path, index), _manifest(path), path.name):
            index = None        # (files removed: listed again)
    name = engine.binding_name(path)
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    cached = bool(_numba_files(path, index))
    try:
        _import(spec, module)
    except Exception as exc:       # a damaged cache entry that slipped past the manifest
        if not cached:             # nothing was loaded: a failure of its own
            raise
        _warn(f"loading the compiled function of {path.name} from the cache failed "
              f"({type(exc).__name__}: {str(exc)[:120]}): compiling it again")
        _clear(_numba_files(path), _manifest(path))
        _import(spec, module)
    module.CACHE = "disabled"
    if not numba.config.DISABLE_JIT:
        module.CACHE = "hit" if all(fn.cache_hits for fn in module.COMPILED.values()) else "miss"
        if module.CACHE == "miss" or not _manifest(path).exists():     # (a helper's: written by it)
            _write_manifest(_numba_files(path), _manifest(path))
    _parts[str(path)] = module
    return module


def _import(spec, module: ModuleType) -> None:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
        spec.loader.exec_module(module)


class Kernel:
    """A model bound to the engine: its functions as one record, and the engine's entry points.

    The entry points keep the positional arrays of the loops' callers (see
    :mod:`jackbox.engine.loop` and :mod:`jackbox.engine.members`) and pass the
    model and the loops first, as one table (:meth:`table`). The model's
    constants (``N_DOF``, ``N_CONTACT`` ...) and plain functions (``phi``,
    ``accel`` ... for Python callers) are attributes, and so are the engine's
    (``DONE``, ``T_GAP`` ...); :meth:`jit` gives a Numba-compiled model function.
    """

    def __init__(self, module: ModuleType):
        self.module = module
        self.__file__ = module.__file__
        fns = module.COMPILED
        self.record = engine.Model(
            module.N_DOF, module.N_CONTACT, module.N_WALL_CONTACT, module.E_SLOT, module.E_GROUND_SLOT,
            int(module.PRESCRIBED), int(module.HAS_GROUND), *(fns[name] for name in engine.SIGNATURES))
        self._jitted: dict = {}
        self._tables: dict = {}
        self._ride = None             # the model's ride, once a table holds the held loop
        self._cache = module.CACHE     # reported by the first compile_kernel, "memory" after it

    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        if hasattr(self.module, name):
            return getattr(self.module, name)
        return getattr(engine, name)        # status codes, event kinds, tolerance slots

    def jit(self, name: str):
        """The model function `name` compiled by Numba (for Python callers: tests, benchmarks)."""
        if name not in self._jitted:
            fn = getattr(self.module, name)
            self._jitted[name] = fn if numba.config.DISABLE_JIT else numba.njit(fn)
        return self._jitted[name]

    @property
    def cache_hit(self) -> bool:
        """Whether every model function was loaded from Numba's cache (none compiled in this process)."""
        return all(cache == "hit" for cache in self.module.PART_CACHE.values())

    def table(self, loops=("exact",), lazy: bool | str = True):
        """The model and the engine's loops as the one array the entry points take (made once per kernel).

        lazy: the stages compiled on first need (engine.LAZY) may be left out
        (the exact loop hands back a step that needs one: see
        :meth:`integrate_exact` and :meth:`run_members`); ``engine.RESUME``:
        left out until one is needed, even if cached (see :func:`engine.table`).
        """
        key = (loops, lazy)
        if key not in self._tables:
            table = engine.table(self.record, loops, lazy)
            hold, ride = engine.TABLE.index("hold"), engine.TABLE.index("ride")
            if numba.config.DISABLE_JIT:
                if table[hold] != 0:
                    table = (*table[:ride], self.ride(), *table[ride + 1:])
            elif table[0, hold] != 0:      # the held loop's steps on floats: the model's own ride
                fn = self.ride()
                table[0, ride], table[1, ride] = fn.address, engine.native_address(fn)
            self._tables[key] = table
        return self._tables[key]

    def ride(self):
        """The model's held steps on floats (:func:`jackbox.engine.flight.ride`), compiled (or loaded) on first need.

        The binding has a stub in its place (:data:`RIDE_STUB`): a model that
        never holds a contact (an elastic run) never compiles it (6.8 s here, since it takes three and four
        rows too; 4.3 s before).
        """
        if self._ride is None:
            path = _write_part(self._ride_path(), self._ride_text())
            part = _import_part(path)
            if part.CACHE == "miss":
                engine.cache.kept_for_now(f"the held steps of the model {Path(self.__file__).name}")
            self._ride = part.COMPILED["ride"]
        return self._ride

    def _compile_stages(self, stages: tuple[str, ...] = tuple(engine.LAZY)) -> None:
        """Compile (or load) engine stages compiled on first need (engine.LAZY; the model's ride with ``hold``).

        In two processes where there are two cores: a helper takes a share of
        the engine's stages (:func:`engine.start`, by LAZY_COST) while this
        process compiles the ride, then the rest. One after the other, a cold
        shaken run at e = 0 spent 20 s on them at its first held contact.
        """
        ride = "hold" in stages
        engine.start((), stages, busy=RIDE_COST if ride and not self.ride_ready() else 0.0, costs=engine.LAZY_COST,
                     first=False)
        if ride:
            self.ride()
        if engine.prepare((), stages) == "miss":
            engine.cache.kept_for_now("a stage of the engine")

    def ride_ready(self) -> bool:
        """Whether the model's ride is loaded or cached (nothing to compile)."""
        path = self._ride_path()
        return self._ride is not None or str(path) in _parts or _cached("ride", path)

    def _ride_text(self) -> str:
        return binding_parts(Path(self.__file__).read_text(), self.module.FLIGHT_TEXT, ride=True)["ride"]

    def _ride_path(self) -> Path:
        return part_path("ride", self._ride_text())

    def integrate_exact(self, q, qd, rest, p, tol, t0, dt, i_begin, i_end, n_total, record_every,
                        rec_t, rec_q, rec_qd, rec_energy, n_rec, ev_t, ev_k, ev_kind, n_ev, log=None):
        while True:
            i, n_rec, n_ev, status = engine.entry("run_exact")(
                self.table(lazy=engine.RESUME), q, qd, rest, p, tol, float(t0), float(dt), i_begin, i_end, n_total, record_every,
                rec_t, rec_q, rec_qd, rec_energy, n_rec, ev_t, ev_k, ev_kind, n_ev)
            if status != engine.MISSING:
                return i, n_rec, n_ev, status
            # a step needs a stage compiled on first need: compile it, then go on from that step
            stages = self._stages_needed(p)
            if log and not (all(engine.ready(name) for name in stages) and ("hold" not in stages or self.ride_ready())):
                log(f"compiling the engine's {' and '.join(stages)} stage{'s' if len(stages) > 1 else ''}"
                    + (" and the model's held steps for held contacts" if "hold" in stages else "")
                    + f" at t = {t0 + i * dt:g} s (first use only) ...")
            self._compile_stages(stages)
            self._tables.pop((("exact",), engine.RESUME), None)
            self._tables.pop((("exact",), True), None)
            i_begin = i

    def _stages_needed(self, p) -> tuple[str, ...]:
        """The stages a run that stopped for one (MISSING) compiles, with parameters p (a study: a row each).

        The stop does not say which stage the step needs (the step is undone,
        its contact modes with it), so the likely one first: where an impact
        can be inelastic, the held loop and the release search (a contact
        coming to rest); where every impact is elastic, the fallback (a step
        handed over). A guess that misses stops the run again at the same
        step, and what is in memory then leaves every stage to compile. So the
        fallback (6.3 s of LAZY_COST) waits for a step handed over: a run that
        holds contacts but never falls back (shaken or drop at e = 0) never
        compiles it, and an elastic run that falls back never compiles the
        held loop and its ride.
        """
        module, p = self.module, np.asarray(p)
        elastic = bool(np.all(p[..., module.E_SLOT] == 1.0)
                       and (not module.HAS_GROUND or np.all(p[..., module.E_GROUND_SLOT] == 1.0)))
        stages = ("fallback",) if elastic else ("release", "hold")
        if all(name in engine._loops for name in stages):
            stages = tuple(engine.LAZY)
        return stages

    def integrate(self, q, qd, p, t0, dt, i_begin, i_end, n_total, record_every,
                  rec_t, rec_q, rec_qd, rec_energy, n_rec, ev_t, ev_k, n_imp):
        kind = np.zeros(ev_t.shape[0], np.int64)
        return engine.entry("run_naive")(
            self.table(("naive",)), q, qd, p, float(t0), float(dt), i_begin, i_end, n_total, record_every,
            rec_t, rec_q, rec_qd, rec_energy, n_rec, ev_t, ev_k, kind, n_imp)

    def gpu(self):
        """This model's GPU kernels (:mod:`jackbox.engine.gpu`; the file written, the kernels compiled on first use)."""
        from .engine import gpu
        return gpu.load_kernels(_with_stubs(Path(self.__file__).read_text()), FLIGHT_SOURCE.read_text(), self.module)

    def run_members(self, Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin,
                    lanes: bool = False, device: str = "cpu"):
        """Every member, in parallel (see :func:`jackbox.engine.members.run_members`); rows of the outputs filled.

        The stages compiled on first need (engine.LAZY) are left out while
        they are not compiled: a member whose step needs one stops (status
        MISSING); the likely stages are then compiled (:meth:`_stages_table`)
        and those members run again from their start, which gives the numbers
        a run with every stage gives (a member's result depends on its inputs
        only); one that stops again, for another stage, runs again with every
        stage.

        lanes: in blocks of ``engine.LANES`` members stepped together
        (:func:`jackbox.engine.members.run_member_blocks`; the same numbers),
        where the model has lanes and every member has the parameters (but
        for the restitution) and tolerances of the first (:meth:`lanes_apply`).
        device: ``"cuda"``, one GPU thread a member (:mod:`jackbox.engine.gpu`;
        lanes are the CPU's). Returns each member's
        smallest gap at its final state where the GPU computed them, else None.
        """
        if device == "cuda":
            from .engine import gpu
            return gpu.run_members(self.gpu(), Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q,
                                   fin_qd, fin)
        entry, kernel = "run_members", self
        if lanes and self.lanes_apply(P, TOL):
            entry, kernel = "run_member_blocks", self.with_lanes()

        def run(table, rows, *outputs):
            engine.entry(entry)(table, *(a[rows] for a in (Q0, QD0, P, TOL)), dt, n_steps, sample_steps, *outputs)

        engine.entry(entry)(kernel.table(), Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd,
                            fin_q, fin_qd, fin)
        again = np.flatnonzero(fin[:, 3] == engine.MISSING)
        for _ in range(len(engine.LAZY) + 1):      # (at most: the likely stages, then every one)
            if not again.size:
                break
            outputs = (np.full_like(samp_q[again], np.nan), np.full_like(samp_qd[again], np.nan),
                       np.zeros_like(fin_q[again]), np.zeros_like(fin_qd[again]), np.zeros_like(fin[again]))
            run(kernel._stages_table(P[again]), again, *outputs)
            for whole, part in zip((samp_q, samp_qd, fin_q, fin_qd, fin), outputs):
                whole[again] = part
            again = again[outputs[4][:, 3] == engine.MISSING]
        return None

    def run_twin_members(self, Q0, QD0, DQ, DQD, P, TOL, dt, n_steps, renorm_steps, scale, stretch, fin,
                         lanes: bool = False, device: str = "cpu"):
        """Twins of every member, in parallel; members stopped for a stage not compiled run again (see run_members).

        lanes: in blocks of ``engine.LANES // 2`` pairs, the references and
        their twins in the lanes of one block
        (:func:`jackbox.engine.members.run_twin_member_blocks`; the same numbers).
        """
        if device == "cuda":
            from .engine import gpu
            return gpu.run_twin_members(self.gpu(), Q0, QD0, DQ, DQD, P, TOL, dt, n_steps, renorm_steps, scale,
                                        stretch, fin)
        entry, kernel = "run_twin_members", self
        if lanes and self.lanes_apply(P, TOL):
            entry, kernel = "run_twin_member_blocks", self.with_lanes()
        engine.entry(entry)(kernel.table(), Q0, QD0, DQ, DQD, P, TOL, dt, n_steps, renorm_steps, scale, stretch, fin)
        again = np.flatnonzero(fin[:, 1] == engine.MISSING)
        for _ in range(len(engine.LAZY) + 1):      # (at most: the likely stages, then every one)
            if not again.size:
                break
            outputs = (np.zeros_like(stretch[again]), np.zeros_like(fin[again]))
            engine.entry(entry)(kernel._stages_table(P[again]), *(a[again] for a in (Q0, QD0, DQ, DQD, P, TOL)),
                                dt, n_steps, renorm_steps, scale, *outputs)
            stretch[again], fin[again] = outputs
            again = again[outputs[1][:, 1] == engine.MISSING]

    @property
    def has_lanes(self) -> bool:
        """Whether the model has the functions an ensemble block's lanes need (a free box)."""
        return "clearance_v" in self.module.FUNCTIONS

    def lanes_apply(self, P, TOL) -> bool:
        """Whether members with these parameter and tolerance rows can go through lanes (see run_members): the
        same tolerances and the same parameters but for the restitution (e, e_ground), which only an impact
        reads (each lane has its own: a restitution sweep goes in lanes)."""
        if not self.has_lanes or P.shape[0] == 0:
            return False
        shared = np.ones(P.shape[1], bool)
        shared[[self.module.E_SLOT, self.module.E_GROUND_SLOT]] = False
        return bool((P[:, shared] == P[0, shared]).all()) and bool((TOL == TOL[0]).all())

    def lanes_ready(self, entry: str = "run_member_blocks") -> bool:
        """Whether this model's lanes and the engine's block loop ``entry`` are compiled or cached (nothing to compile)."""
        if not self.has_lanes:
            return False
        text = binding_parts(Path(self.__file__).read_text(), lanes=True)["lanes"]
        path = part_path("lanes", text)
        return ((self.module.LANES or str(path) in _parts or _cached("lanes", path))
                and (bool(engine._dispatcher(entry).signatures) or engine.cached(entry)))

    def with_lanes(self) -> "Kernel":
        """This model with its own lanes bound (compiled on first use), for ensemble blocks."""
        return self if self.module.LANES else load_kernel(Path(self.__file__), lanes=True)

    def _stages_table(self, P):
        """The exact loop's table for members (parameter rows P) that stopped for a stage: the likely
        stages compiled first (:meth:`_stages_needed`), those not compiled still left out, so a member
        that needs one of them stops again (and runs again from its start, with every stage then)."""
        self._compile_stages(self._stages_needed(P))
        self._tables.pop((("exact",), True), None)
        return self.table(lazy=True)

    def set_up_members(self, setup, Q0, QD0, P, TOL, OFFSET, GAP):
        return engine.entry("set_up_members")(self.table(()), setup, Q0, QD0, P, TOL, OFFSET, GAP)

    def tolerances(self, p, jack_factor, n_points, dt, box_speed):
        out = np.empty(engine.T_SPEED + self.N_DOF)
        engine.entry("fill_tolerances")(self.table(()), p, float(jack_factor), int(n_points), float(dt),
                                        float(box_speed), out)
        return out


def load_kernel(model_file: Path, flight_text: str | None = None, lanes: bool = False) -> Kernel:
    """The :class:`Kernel` of a generated model (its binding imported, compiling on first use).

    lanes: with the model's own lanes for ensemble blocks (see :func:`binding_parts`).
    """
    stamp = None
    if flight_text is None:
        # a second call with unchanged files costs two stat()s, not reading and hashing them
        stamp = (str(cache_dir()), str(model_file), *_stat(model_file), *_stat(FLIGHT_SOURCE), lanes,
                 *(_stat(LANES_SOURCE) if lanes else ()))
        if stamp in _stamped:
            return _stamped[stamp]
    module = load_binding(model_file, flight_text, lanes)
    kernel = module.__dict__.get("KERNEL")
    if kernel is None:
        kernel = module.KERNEL = Kernel(module)
    if stamp is not None:
        _stamped[stamp] = kernel
    return kernel


def _stat(path: Path) -> tuple[int, int, int]:
    st = path.stat()
    return st.st_ino, st.st_mtime_ns, st.st_size


def kernel_for(scene: Scene, log=None, method: str | None = None) -> Kernel:
    """The :class:`Kernel` of `scene` (model generated and its functions compiled if needed).

    method: the method :func:`compile_kernel` will be asked for next, if
    known: the engine's parts it needs that are not cached start compiling in
    a helper process now, while the model's functions compile here.
    """
    if not model_path(scene).exists():
        engine.warm_binder()          # a new structure: the helper starts while its model is generated
    path = ensure_model(scene, log)
    unbound = [] if numba.config.DISABLE_JIT else _unbound(path)
    bound = not unbound
    if bound:
        engine.cool_binder()
    if method is not None:
        engine.start(ENTRY[method], _loops_of(method), lazy=LAZY_METHODS.get(method, False),
                     busy=sum(engine.PART_COST.get(name, 0.5) for name in unbound))
    if log and not bound:
        log(f"compiling the model functions of {scene.name} (first use of this structure) ...")
    return load_kernel(path)


def _unbound(model_file: Path) -> list[str]:
    """The model's binding parts neither loaded in this process nor cached (those a load would compile)."""
    indexes: dict = {}
    return [name for name, path in _part_paths(model_file)
            if str(path) not in _parts and not _cached(name, path, _index_of(path, indexes))]


#: each model file's binding parts and their paths (by file and cache folder), with the file's identity when
#: they were made
_paths_of: dict[str, tuple[tuple[int, int, int], list[tuple[str, Path]]]] = {}


def _part_paths(model_file: Path) -> list[tuple[str, Path]]:
    """(name, path) of each binding part of a generated model; made again only where its file changed (the
    parts' texts hashed for their paths took half a millisecond of every study and run)."""
    key, stat = f"{model_file}\0{cache_dir()}", _stat(model_file)      # (a part's path is in the cache folder)
    kept = _paths_of.get(key)
    if kept is None or kept[0] != stat:
        kept = (stat, [(name, part_path(name, text)) for name, text in binding_parts(model_file.read_text()).items()])
        _paths_of[key] = kept
    return kept[1]


def _cached(part: str, path: Path, index: dict | None = None) -> bool:
    """Whether Numba's cache beside a binding part holds an index for each of its functions (index: see
    :func:`_numba_files`)."""
    names = _part_files(path, index)
    return all(engine.cache.has_index(path.parent / "__pycache__", entry, path.stem, names)
               for entry in part_entries()[part])


#: the engine's entry points each method needs (the first is the one to look for in the cache)
ENTRY = {"exact": ("run_exact", "fill_tolerances"), "naive": ("run_naive",),
         "ensemble": ("run_members", "set_up_members", "fill_tolerances"),
         "chaos": ("run_twin_members", "set_up_members", "fill_tolerances"),
         "setup": ("set_up_members", "fill_tolerances")}
#: the loop each method runs (compiled once as a function value; "setup", a study's members set up here
#: and run on a GPU, runs none)
LOOP = {"exact": "exact", "naive": "naive", "ensemble": "exact", "chaos": "exact", "setup": None}
#: the methods whose runs leave the stages of engine.LAZY out until one needs them (see Kernel.integrate_exact
#: and Kernel.run_members): an elastic run or study never compiles them; a single run ("exact", which resumes
#: at the step that needs one) never even loads them from the cache
LAZY_METHODS = {"exact": engine.RESUME, "ensemble": True, "chaos": True}


def compile_kernel(kernel: Kernel, method: str | None = None) -> dict:
    """Make sure the engine's machine code for `method` is ready: compiled now or loaded from the cache.

    method: ``"exact"``, ``"naive"``, ``"ensemble"`` or ``"chaos"`` (the
    parallel member loops) or None for the two methods. The engine is compiled
    once per machine, for every model; the model's own functions were
    compiled (or loaded) when its kernel was. Returns ``{"seconds": ...,
    "cache": "hit" | "miss" | "memory" | "disabled", "model": ..., "engine":
    ...}``: loaded from Numba's cache, compiled now, ready earlier in this
    process, or not compiled at all (``NUMBA_DISABLE_JIT=1``); "cache" sums up
    the model's part (reported by the first call for a kernel only) and the
    engine's.
    """
    t0 = time.perf_counter()
    if numba.config.DISABLE_JIT:
        return {"seconds": 0.0, "cache": "disabled"}
    model, kernel._cache = kernel._cache, "memory"
    names = ENTRY[method] if method else ENTRY["exact"] + ENTRY["naive"]
    loops = _loops_of(method) if method else ("exact", "naive")
    folder = engine.cache.engine_cache_path()
    if folder is not None and str(folder) not in _verified:
        _verified.add(str(folder))
        _check_manifest(engine.cache.files(), folder / "sums.json", "the engine")
    cached = engine.cache.has_files()
    try:
        result = engine.prepare(names, loops, lazy=LAZY_METHODS.get(method, False))
    except Exception as exc:       # a damaged cache entry that slipped past the manifest
        if not cached:
            raise
        _warn(f"loading the compiled engine ({', '.join(names)}) from the cache failed "
              f"({type(exc).__name__}: {str(exc)[:120]}): compiling it again")
        _clear(engine.cache.files(), folder / "sums.json")
        _reset_engine(names, loops)
        result = engine.prepare(names, loops, lazy=LAZY_METHODS.get(method, False))
    if result == "miss" and folder is not None:
        _write_manifest(engine.cache.files(), folder / "sums.json")
        engine.cache.kept_for_now(f"the engine ({', '.join(names)})")
    # compiled now if either part was; loaded if either was loaded; else ready in memory
    both = {model, result}
    cache = "miss" if "miss" in both else "hit" if "hit" in both else "memory"
    return {"seconds": time.perf_counter() - t0, "cache": cache, "model": model, "engine": result}


def _reset_engine(names, loops) -> None:
    """Forget what a failed load left in the engine, so it compiles afresh."""
    for name in loops:
        engine._loops.pop(name, None)
    for name in names:
        fn = engine._dispatcher(name)
        fn._can_compile = True
        fn.overloads.clear()


def is_cached(kernel: Kernel, method: str) -> bool:
    """Whether the engine's machine code for `method` is ready (in this process or in the cache)."""
    fn = engine._dispatcher(ENTRY[method][0])
    if getattr(fn, "signatures", None) and all(loop in engine._loops for loop in _loops_of(method)):
        return True
    return engine.cached(ENTRY[method][0]) and all(engine.cached(loop) for loop in _loops_of(method))


def _loops_of(method: str) -> tuple[str, ...]:
    return () if LOOP[method] is None else (LOOP[method],)


def _numba_files(path: Path, index: dict | None = None) -> list[Path]:
    """Numba's cache files (index and machine code) beside a binding module; index: its folder's
    :func:`_pycache_index`, where the caller has one (else the folder is listed now)."""
    return sorted(path.parent / "__pycache__" / name for name in _part_files(path, index))


def _part_files(path: Path, index: dict | None = None) -> list[str]:
    """The names of :func:`_numba_files`."""
    index = _pycache_index(path.parent / "__pycache__") if index is None else index
    return index.get(path.stem, [])


def _pycache_index(folder: Path) -> dict[str, list[str]]:
    """Numba's cache files in the ``__pycache__`` of binding parts, by the part's file name: one listing.

    Every part of every model has its files there: thousands on a machine
    where models are edited (11,854 on this project's), and a glob of one
    part's matched a regular expression against all of them, three times for
    each of a model's dozen parts: 0.8 s of a warm start.
    """
    index: dict[str, list[str]] = {}
    for name in engine.cache.listing(folder):
        if name.endswith((".nbi", ".nbc")):
            index.setdefault(name.split(".", 1)[0], []).append(name)
    return index


def _index_of(path: Path, indexes: dict) -> dict:
    """The :func:`_pycache_index` of a part's folder, listed once into ``indexes`` (folder -> index)."""
    folder = path.parent / "__pycache__"
    if folder not in indexes:
        indexes[folder] = _pycache_index(folder)
    return indexes[folder]


def _manifest(path: Path) -> Path:
    return path.parent / "__pycache__" / f"{path.stem}.sums.json"


def _write_manifest(files: list[Path], manifest: Path) -> None:
    """Record the checksums of cache files (after a compile wrote some)."""
    sums = {f.name: [f.stat().st_ino, _sha256(f)] for f in files}
    try:
        write_atomic(manifest, json.dumps(sums, indent=0, sort_keys=True))
    except OSError:
        pass     # a read-only cache: its files are what they are


def _check_manifest(files: list[Path], manifest: Path, what: str) -> bool:
    """Remove cache files when one no longer matches its recorded checksum; returns whether it did.

    Numba reads its index and machine code without checking them: a truncated
    or altered file fails on every later load (or worse). Numba replaces a file
    by renaming a new one over it (a new inode), so a file another process has
    written since, like one the manifest does not list, is left to Numba; the
    same inode with other bytes is damage.
    """
    if not manifest.exists():
        return False
    try:
        sums = json.loads(manifest.read_text())
        bad = []
        for name, (inode, digest) in sums.items():
            f = manifest.parent / name
            if f.exists() and f.stat().st_ino == inode and _sha256(f) != digest:
                bad.append(name)
    except (OSError, ValueError, TypeError, AttributeError):
        bad = [manifest.name]
    if bad:
        _warn(f"the compiled code of {what} in the cache is damaged ({bad[0]}"
              f"{f' and {len(bad) - 1} more' if len(bad) > 1 else ''}): compiling it again")
        _clear(files, manifest)
    return bool(bad)


def _clear(files: list[Path], manifest: Path) -> None:
    for f in [*files, manifest]:
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
