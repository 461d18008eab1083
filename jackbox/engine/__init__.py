"""The engine: the model-independent half of jackbox, compiled once per machine.

One module per stage, in the order of the algorithm:

* :mod:`.records`     the vocabulary: status codes, event kinds, tolerance
  slots, the :class:`Model` record a model reaches the engine as, scratch;
* :mod:`.integrator`  one RK4 step on arrays (persistent contacts held);
* :mod:`.gaps`        gaps in time: speed bounds, the cubic through a step;
* :mod:`.broad`       the broad phase: bounding circles, no gap row;
* :mod:`.impact`      the contact matrix, a dense solver, the impulses' LCP;
* :mod:`.events`      event location inside a step (Illinois iteration);
* :mod:`.modes`       contact modes: persistent contacts, forces, release;
* :mod:`.fallback`    Moreau-Jean time-stepping, for what the exact method cannot resolve;
* :mod:`.loop`        the loops: integrate, look, locate, resolve, record;
* :mod:`.tolerances`  the tolerance row of one set of parameters (lengths, speeds, radii);
* :mod:`.draws`       random numbers as a hash of (seed, member, stream, draw);
* :mod:`.members`     ensembles and twins: each member's setup, then its run, one per ``prange`` iteration;
* :mod:`.flight`      the free-flight hot path, compiled with each model;
* :mod:`.cache`       where the machine code lives (one folder per engine version).

A model reaches the engine only as a :class:`~.records.Model` record of
integers and first-class function values (``cfunc``), the same Numba type
for every model: each entry point below is compiled once, for an explicit
signature, then compiling is switched off, so no model can make Numba build
(and cache) a second engine.
"""

from __future__ import annotations

import contextlib
import gc
import importlib
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numba
import numpy as np
from numba.core import types
from numba.core.errors import NumbaExperimentalFeatureWarning
from numba.np.ufunc.parallel import _launch_threads

from . import cache

cache.install()          # before any engine module is imported: each fixes its cache folder when decorated

from .records import (TABLE, CROSSING, EXACT, FALLBACK_STEP, HOLD, NAIVE, RELEASE_AT, STEP, UPDATE, DONE, LANES,  # noqa: E402
                      FALLBACK, HANDOFF_DENSE, HANDOFF_EVENTS, HANDOFF_MODES, HANDOFF_STUCK, HANDOFF_ZENO, IMPACT_LOG_FULL, INSIDE,
                      MISSING, NEED_FALLBACK, NEED_HOLD, NEED_RELEASE, IMPULSE, MAX_EVENTS,
                      MODE_SLOTS, NONFINITE, RELEASE, REST, STALLED, T_AREST, T_BOXV, T_EVENT,
                      T_GAP, T_RBOX, T_RJACK, T_SPEED, T_VREST, T_WALL, THROUGH, TWIN_FIN, WARN_LCP, WARN_LOCATE, WARNING, Events, F8, I1,
                      I2, I8, Model, Samples, Setup, SetupType, SIGNATURES, SIZES, V1, V2)

V3 = types.Array(F8, 3, "C")
#: module and argument types of every njit entry point (each takes the loop it runs first)
ENTRIES = {
    "run_exact": ("loop", (I2, V1, V1, I1, V1, V1, F8, F8, I8, I8, I8, I8, V1, V2, V2, V1, I8, V1, I1, I1, I8)),
    "run_naive": ("loop", (I2, V1, V1, V1, F8, F8, I8, I8, I8, I8, V1, V2, V2, V1, I8, V1, I1, I1, I8)),
    "run_members": ("members", (I2, V2, V2, V2, V2, F8, I8, I1, V3, V3, V2, V2, V2)),
    "run_member_blocks": ("members", (I2, V2, V2, V2, V2, F8, I8, I1, V3, V3, V2, V2, V2)),
    "run_twin_members": ("members", (I2, V2, V2, V2, V2, V2, V2, F8, I8, I8, V1, V2, V2)),
    "run_twin_member_blocks": ("members", (I2, V2, V2, V2, V2, V2, V2, F8, I8, I8, V1, V2, V2)),
    "set_up_members": ("members", (I2, SetupType, V2, V2, V2, V2, V2, V1)),
    "fill_tolerances": ("tolerances", (I2, V1, F8, I8, F8, F8, V1)),
}
#: the entry points that run a prange loop (Numba's threads must be started before one is loaded)
PARALLEL = ("run_members", "run_member_blocks", "run_twin_members", "run_twin_member_blocks", "set_up_members")
#: the engine's function values: name -> (module, function, signature, what it needs compiled first)
LOOPS = {
    "step": ("integrator", "rk4", STEP, ()),
    "update": ("modes", "update_contacts", UPDATE, ()),
    "crossing": ("events", "first_crossing", CROSSING, ()),
    "release": ("events", "first_release", RELEASE_AT, ()),
    "fallback": ("fallback", "fallback_step", FALLBACK_STEP, ()),
    "hold": ("loop", "hold", HOLD, ()),
    "exact": ("loop", "integrate_exact", EXACT, ("step", "update", "crossing", "release", "fallback", "hold")),
    "naive": ("loop", "integrate", NAIVE, ()),
}
_loops: dict = {}
#: the function values compiled without Numba's reference counting (``_nrt=False``): they allocate
#: nothing and their callers keep every array alive, but each call of one counted a reference on entry
#: and dropped it on return for every array it was handed, borrowed ones included (a call into Numba's
#: runtime each, null or not: about 11% of an ensemble's time near the walls). Measured, drop at
#: e = 0.6, 500 members x 3 s, one thread: 0.227 s against 0.272 s alone, 0.123 against 0.136 in lanes.
#: A plain njit callee takes the setting of the caller it is first compiled for (Numba's ConfigStack)
#: and keeps it for every caller: a function that hands back an array it did not allocate (its
#: argument, a view) must therefore say ``_nrt=True`` itself, or an nrt-free first caller would leave
#: a counting caller dropping a reference it never got (jackbox.engine.members does so).
NO_REFERENCES = ("step", "update", "crossing", "release", "hold")
#: the stages compiled on first need only: name -> its bit in Stages.missing (see jackbox.engine.loop)
LAZY = {"release": NEED_RELEASE, "fallback": NEED_FALLBACK, "hold": NEED_HOLD}
#: ``lazy=RESUME`` (see :func:`table`): for a run that resumes at the step that needs a stage left out
RESUME = "resume"
#: what each part costs to compile, in seconds on the 2-core machine of benchmarks/results/compile.md, each
#: compiled alone in a new process after the model (shaken; benchmarks/compile_parts.py --alone, one run; its
#: next, in benchmarks/results/compile_alone.md, within 1.1 s of these but for hold, 10.0): only to share
#: the parts out between two processes (:func:`share_out`)
COST = {"exact": 9.8, "update": 6.0, "fallback": 9.7, "crossing": 6.0, "naive": 6.7, "step": 4.2, "release": 5.6,
        "hold": 13.2, "run_members": 5.8, "run_member_blocks": 11.5, "run_twin_members": 6.8,
        "run_twin_member_blocks": 12.9, "set_up_members": 4.1, "run_exact": 0.2, "run_naive": 0.2,
        "fill_tolerances": 0.3}
#: what each stage compiled on first need costs once the run's own parts are compiled (their shared callees
#: cached, so far below COST's alone): a cold shaken run at e = 0 compiled them in a row in 0.9, 6.3 and 5.5 s
#: (and the model's ride in 6.8-7.8 s: loader.RIDE_COST)
LAZY_COST = {"release": 0.9, "fallback": 6.3, "hold": 5.5}
#: what a helper process costs before its first part: Python, Numba and the engine's import
HELPER_START = 0.5
#: a part -> the helper process compiling it now (see start)
_helpers: dict = {}

__all__ = ["DONE", "INSIDE", "THROUGH", "HANDOFF_STUCK", "HANDOFF_MODES", "HANDOFF_ZENO", "HANDOFF_EVENTS", "HANDOFF_DENSE", "IMPACT_LOG_FULL", "MISSING", "NONFINITE", "STALLED", "IMPULSE", "REST", "RELEASE", "FALLBACK", "WARNING",
           "WARN_LCP", "WARN_LOCATE", "MAX_EVENTS", "MODE_SLOTS", "T_GAP", "T_EVENT", "T_VREST", "T_AREST", "T_BOXV", "T_WALL", "T_RJACK", "T_RBOX", "T_SPEED", "TWIN_FIN",
           "Model", "Samples", "Events", "Setup", "LANES", "SIGNATURES", "SIZES", "ENTRIES", "LOOPS", "LAZY", "RESUME", "entry", "compiled_loop", "prepare", "start", "start_binding", "wait_binding", "bind_part",
           "binding_name", "table"]


def _dispatcher(name: str):
    module = importlib.import_module(f"{__name__}.{ENTRIES[name][0]}")
    return getattr(module, name)


def entry(name: str):
    """The compiled entry point ``name`` (compiled or loaded on first use, for its signature only)."""
    fn = _dispatcher(name)
    if not numba.config.DISABLE_JIT and not fn.signatures:
        prepare((name,))
    return fn


def compiled_loop(name: str):
    """The engine's function value ``name`` (see LOOPS; a ``cfunc``, compiled or loaded once)."""
    if name not in _loops:
        prepare((), (name,))
    return _loops[name]


def table(model: Model, loops=("exact",), lazy: bool = True) -> np.ndarray:
    """The array every entry point takes: the model, then the stages and loops it needs (see ``TABLE``).

    Row 0: integers as they are, functions as their C addresses (0 for a loop
    or stage not asked for, which must then not be called); row 1: the
    functions' native addresses. lazy: a stage of LAZY that is neither in
    memory nor in the cache is left out, and its bit set in the ``missing``
    column (the exact loop then hands back a step that needs it); lazy=RESUME:
    every such stage not in memory is left out, cached or not (a single run
    resumes at the step that needs one, so loading it waits for that need:
    an elastic run never has it); else every stage is compiled now. With
    Numba's JIT off, a tuple of the values.
    """
    wanted = set(loops).union(*(LOOPS[name][3] for name in loops))
    left_out = {name for name in LAZY if lazy and name in wanted
                and not (name in _loops if lazy == RESUME else ready(name))}
    missing = sum(LAZY[name] for name in left_out)
    values = (*model, *(missing if name == "missing" else
                        compiled_loop(name) if name in wanted and name not in left_out else 0
                        for name in TABLE[len(model):]))
    if numba.config.DISABLE_JIT:
        return values
    out = np.zeros((2, len(values)), np.int64)
    for i, value in enumerate(values):
        if isinstance(value, (int, np.integer)):
            out[0, i] = value
        else:
            out[0, i], out[1, i] = value.address, native_address(value)
    return out


def ready(name: str) -> bool:
    """Whether the part ``name`` (a loop or an entry point) is in memory or in the cache (loaded if so)."""
    if numba.config.DISABLE_JIT or name in _loops or (name in ENTRIES and _dispatcher(name).signatures):
        return True
    if not cached(name):
        return False
    compile_part(name)      # (a load: its machine code is in the cache)
    return True


def cached(name: str, names: list[str] | None = None) -> bool:
    """Whether the cache holds the machine code of the part ``name`` (its index file is there); names: the
    engine's cache folder's listing, where the caller asks of several parts."""
    fn = LOOPS[name][1] if name in LOOPS else name
    return cache.has_index(cache.engine_cache_path(), fn, names=names)


def native_address(fn) -> int:
    """Address of a cfunc's native function (the one its C wrapper calls), or 0 if it cannot be found.

    Numba keeps it in the cfunc's library under the wrapper's name without the
    "cfunc." prefix (numba/core/ccallback.py, funcdesc.py).
    """
    prefix = "cfunc."
    name = getattr(fn, "_wrapper_name", None) or ""
    library = getattr(fn, "_library", None)
    if not name.startswith(prefix) or library is None:
        return 0
    try:
        return int(library.get_pointer_to_function(name[len(prefix):]) or 0)
    except Exception:
        return 0


def parts(names, loops=(), lazy: bool = False, listing: list[str] | None = None) -> list[str]:
    """What :func:`prepare` would compile or load for these entry points and loops, in order.

    lazy: leave out the stages of LAZY that are not cached (the exact loop runs without them);
    RESUME: those not in memory, cached or not (see :func:`table`). listing: the engine's cache folder's
    (:func:`cache.listing`), if the caller has it.
    """
    out = []
    for name in loops:      # what each needs first, then itself
        for need in (*LOOPS[name][3], name):
            if need in out or need in _loops:
                continue
            if lazy and need in LAZY:
                if lazy == RESUME:
                    continue
                listing = cache.listing(cache.engine_cache_path()) if listing is None else listing
                if not cached(need, listing):
                    continue
            out.append(need)
    return out + [name for name in names if name not in out and not _dispatcher(name).signatures]


def start(names, loops=(), lazy: bool = False, busy: float = 0.0, costs: dict | None = None,
          first: bool = True) -> list[str]:
    """Hand part of what ``prepare(names, loops)`` will compile to a helper process, now.

    Compile time is user time: on a machine with two cores or more, a second
    process compiles about half of the engine's parts that are not cached
    (by their COST, :func:`share_out`; ``busy``: seconds of other compiling
    this process does first, the model's functions) into the cache, while this one compiles
    the rest; :func:`prepare` then loads the helper's parts (or compiles
    them itself if the helper failed). ``JACKBOX_COMPILE_JOBS=1`` turns it
    off. costs: the parts' costs where they differ from COST (LAZY_COST for
    the stages compiled on first need, mid-run); first: this process has
    yet to pay Numba's first compile (FIRST_COMPILE; not mid-run). Returns
    the parts handed out.
    """
    if numba.config.DISABLE_JIT or _jobs() < 2:
        return []
    listing = cache.listing(cache.engine_cache_path())
    todo = [name for name in parts(names, loops, lazy, listing) if name not in _helpers and not cached(name, listing)]
    if not todo:
        return []
    costs = costs or {}
    theirs = share_out({name: costs.get(name, COST.get(name, 1.0)) for name in todo},
                       busy + (FIRST_COMPILE if first else 0.0),
                       HELPER_START + FIRST_COMPILE)
    if not theirs:
        return []
    cool_binder()         # two processes at most: the engine's parts come first
    process = _spawn(theirs)
    if process is None:
        return []
    for name in theirs:
        _helpers[name] = process
    return theirs


#: seconds each model function takes to compile alone, as its own binding part (2 cores; measured by
#: benchmarks/compile_parts.py --scene shaken, after Numba's first compile): only to share them out
PART_COST = {"inverse_mass": 0.1, "accel": 0.15, "phi": 0.2, "gap_rate": 0.3, "contact_rows": 0.4,
             "energy": 0.1, "box_motion": 0.03, "clearance": 0.15, "flight": 1.7,
             "lane_event": 0.05, "lanes": 0.05, "ride": 0.05}
#: the same for a model's lanes and its lane's event step where they are not the stubs: a study's first
#: use of them compiles the two, one in each process (7.2-8.7 s and 6.1-6.8 s, one after the other)
LANES_COST = {"lanes": 7.5, "lane_event": 6.5}
#: what Numba's first compile in a process costs beyond the function itself (see warm_binder)
FIRST_COMPILE = 0.6
#: a binding part's file -> the helper process compiling it (see start_binding)
_binders: dict = {}


#: how a model's compiled functions treat a division by zero (see bind_part): named in each binding
#: part's text too, so that a part compiled under another model is never taken from the cache
ERROR_MODEL = "numpy"


@contextlib.contextmanager
def collector_paused():
    """Python's cyclic garbage collector off while Numba compiles (on again after, if it was on).

    A compile makes millions of small objects that live until it ends (Numba's
    IR, copied whole at each inlined call, and its types), so the collector's
    passes over them found next to nothing: timed by ``gc.callbacks``, they
    were 4.8 s of the 28.6 s that compiling drop's held steps (``ride``) took.
    Paused for each compile, a script's first result and first held contact
    (drop, from an empty cache) took 0.92 and 0.85 of their time, and the peak
    memory of compiling a run's engine rose from 364 to 416 MB (paused for all
    of it at once: 573 MB, for no more gain). The cycles a compile leaves are
    collected by the collector's next pass after it. (The ``jackbox`` program
    has it off throughout: :func:`jackbox.cli.console`.)
    """
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was:
            gc.enable()


def bind_part(name: str, fn):
    """A model function as the engine's function value: a ``cfunc`` of SIGNATURES[name], compiled or loaded.

    Called by a binding part (:func:`jackbox.loader.binding_parts`) at its
    import. The plain function when Numba's JIT is off.
    """
    if numba.config.DISABLE_JIT:
        return fn
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
        # (Numba leaves LLVM's SLP vectoriser off, which the lanes need: it runs in Numba's first,
        # per-function pass and packs pairs of a lane's operations, which keeps the loop vectoriser
        # from packing the lanes: 11.5 against 7 ns a lane-step, measured)
        # (and without reference counting: a model function allocates nothing and writes into the
        # arrays it is handed, which its caller keeps alive; see NO_REFERENCES)
        # (NumPy's error model: a division by zero in the model's terms, a shaking period T = 0 or a
        # force 1 / x_jack at x_jack = 0, gives inf or NaN, which the engine reports as a non-finite
        # state, not a ZeroDivisionError out of compiled code that an ensemble cannot even raise)
        with collector_paused():
            return numba.cfunc(SIGNATURES[name], cache=True, _nrt=False, error_model=ERROR_MODEL)(fn)


def binding_name(path) -> str:
    """The module name of the binding part at ``path`` (the same in every process that imports it)."""
    return "jackbox_model_" + Path(path).stem


def warm_binder() -> bool:
    """Start the helper of the next :func:`start_binding` now, before the model is generated.

    It starts Python and Numba and compiles a trivial function (Numba's first
    compile in a process costs about half a second more than the next) while
    this process runs the compiler; then it waits for the paths of the
    binding parts it is to compile on its standard input. Returns whether one
    was started (or runs).
    """
    global _warm
    if _warm is not None:
        return True
    if numba.config.DISABLE_JIT or _jobs() < 2 or _helpers:
        return False
    _warm = _spawn(["--parts", "-"], stdin=subprocess.PIPE)
    return _warm is not None


#: the helper warm_binder started, waiting for the paths of binding parts
_warm = None


def start_binding(todo: dict, costs: dict | None = None) -> list[str]:
    """Hand about half of the model functions to compile to a helper process, before compiling the rest here.

    todo: function name -> its binding part's file, for the functions whose
    machine code is not cached. Shared by PART_COST, or by costs where they
    name a part (:func:`share_out`); the helper of :func:`warm_binder` if
    there is one (it has paid Numba's first compile already). Only when no
    helper is compiling engine parts (two cores, two processes). Returns the
    functions handed out; :func:`wait_binding` waits for one of them.
    """
    global _warm
    if numba.config.DISABLE_JIT or _jobs() < 2 or _helpers or len(todo) < 2:
        cool_binder()
        return []
    process, _warm = _warm, None
    # (a warm helper has paid for its start and Numba's first compile already)
    costs = {**PART_COST, **(costs or {})}
    share = share_out({name: costs.get(name, 0.5) for name in todo}, FIRST_COMPILE,
                      0.0 if process is not None else HELPER_START + FIRST_COMPILE)
    paths = [str(Path(todo[name]).resolve()) for name in share]
    if share and process is not None:
        try:                # (lines into an empty pipe: never blocks)
            process.stdin.write("".join(f"{path}\n" for path in paths).encode())
        except OSError:     # it ended early: start another
            process = None
    if process is not None:
        try:
            process.stdin.close()        # (no work for it if share is empty: it ends)
        except OSError:
            pass
    if share and process is None:
        process = _spawn(["--parts", *paths])
    if process is None:
        return []
    for path in paths:
        _binders[path] = process
    return share


def wait_binding(path) -> None:
    """Wait for the helper compiling the binding part at ``path``, if one is."""
    process = _binders.pop(str(Path(path).resolve()), None)
    if process is not None:
        process.wait()


def cool_binder() -> None:
    """Let a helper of :func:`warm_binder` that got no work go (it ends when its input closes)."""
    global _warm
    process, _warm = _warm, None
    if process is not None:
        try:
            process.stdin.close()
        except OSError:
            pass


def _spawn(args: list[str], stdin=subprocess.DEVNULL):
    """A helper process (``python -m jackbox.engine.helper ARGS``) on this process's cache folder, or None."""
    env = os.environ | {"JACKBOX_CACHE_DIR": str(cache.cache_dir()), "JACKBOX_COMPILE_JOBS": "1"}
    env.pop("NUMBA_DISABLE_JIT", None)
    try:
        return subprocess.Popen([sys.executable, "-m", f"{__name__}.helper", *args], env=env,
                                stdin=stdin, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    except OSError:
        return None


def _jobs() -> int:
    """Processes that may compile at once (``JACKBOX_COMPILE_JOBS``, else 2 where there are two cores)."""
    try:
        return max(1, int(os.environ.get("JACKBOX_COMPILE_JOBS", "")))
    except ValueError:
        return min(2, os.cpu_count() or 1)


#: at most this many parts are shared out by trying every split (2^n of them); more, heaviest first
EXHAUSTIVE = 14


def share_out(cost: dict, mine: float, theirs: float) -> list[str]:
    """The parts a helper process compiles, so that it and this process finish as early as their costs allow.

    cost: part -> seconds; mine, theirs: the seconds each process spends
    before its first part. Every split of up to EXHAUSTIVE parts is tried and
    the one whose later process finishes first is taken (the first such in
    a fixed order: the same parts give the same split); more parts go one
    by one, the heaviest first, each to the process that would finish it
    sooner. The greedy way alone took a worse split where two ways of
    sharing were close: a cold ``jackbox run shaken`` waited 2 s more for
    its helper when a model function's estimate of 0.05 s tipped it.
    Returns the helper's parts, the heaviest first (none where a helper would
    not finish sooner than this process alone).
    """
    names = sorted(cost, key=lambda name: (-cost[name], name))
    if len(names) > EXHAUSTIVE:
        out, load, helper = [], mine, theirs
        for name in names:
            if helper < load:
                out.append(name)
                helper += cost[name]
            else:
                load += cost[name]
        return out
    total = sum(cost.values())
    sums = [0.0] * (1 << len(names))        # sums[mask]: the cost of the parts in mask
    best, best_mask = mine + total, 0       # none to the helper
    for mask in range(1, 1 << len(names)):
        low = mask & -mask
        sums[mask] = sums[mask ^ low] + cost[names[low.bit_length() - 1]]
        finish = max(mine + total - sums[mask], theirs + sums[mask])
        if finish < best:
            best, best_mask = finish, mask
    return [name for j, name in enumerate(names) if best_mask >> j & 1]


def prepare(names, loops=(), lazy: bool = False) -> str:
    """Compile (or load from the cache) the entry points and function values named.

    lazy: leave out the stages of LAZY that are not cached (see :func:`table`).
    Parts a helper process is compiling (:func:`start`) are done last, after
    waiting for it: loaded from the cache, or compiled here if it failed.
    Returns "memory" (all were ready in this process), "hit" (loaded from the
    cache, none compiled), "miss" (at least one compiled now, here or by a
    helper) or "disabled".
    """
    wanted = parts((), loops, lazy)
    if numba.config.DISABLE_JIT:
        for name in wanted:
            module, fn, _, _ = LOOPS[name]
            _loops[name] = getattr(importlib.import_module(f"{__name__}.{module}"), fn)
        return "disabled"
    todo = wanted + [name for name in names if not _dispatcher(name).signatures]
    if not todo:
        return "memory"
    todo.sort(key=lambda name: name in _helpers)         # a helper's parts last
    misses = 0
    for name in todo:
        helper = _helpers.pop(name, None)
        if helper is not None:
            misses += 1
            helper.wait()
        misses += compile_part(name)
    return "miss" if misses else "hit"


def compile_part(name: str) -> bool:
    """Compile (or load from the cache) the one part ``name``, a loop or an entry point; True if compiled."""
    with warnings.catch_warnings(), collector_paused():
        # calls through function values: the documented, tested use, not news to a user
        warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
        if name in LOOPS:
            module, fn, sig, _ = LOOPS[name]
            py_func = getattr(importlib.import_module(f"{__name__}.{module}"), fn)
            py_func = getattr(py_func, "py_func", py_func)
            compiled = numba.cfunc(sig, cache=True, _nrt=name not in NO_REFERENCES)(py_func)
            _loops[name] = compiled
            return not compiled.cache_hits
        fn = _dispatcher(name)
        if name in PARALLEL:
            # A cached function that calls a prange loop is saved with the hook that starts
            # Numba's threads on loading, unless that loop was itself loaded from the cache when
            # the caller was compiled (another process compiled it first): its library then
            # carries no hook, and loading the caller later fails with "LLVM ERROR: Symbol not
            # found: allocate_sched". Starting the threads first makes either load.
            _launch_threads()
        before = sum(fn.stats.cache_misses.values())
        fn.compile(ENTRIES[name][1])
        fn.disable_compile()
        return sum(fn.stats.cache_misses.values()) > before
