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

import warnings

import numba
import numpy as np
from numba.core import types
from numba.core.errors import NumbaExperimentalFeatureWarning

from . import cache
from .records import (TABLE, CROSSING, EXACT, NAIVE, RELEASE_AT, STEP, UPDATE, DONE, FALLBACK, IMPACT_LOG_FULL,
                      IMPULSE, MAX_EVENTS, MODE_SLOTS, NONFINITE, RELEASE, REST, STALLED, T_AREST, T_BOXV, T_EVENT,
                      T_GAP, T_RBOX, T_RJACK, T_SPEED, T_VREST, T_WALL, WARN_LCP, WARN_LOCATE, WARNING, Events, F8, I1,
                      I2, I8, Model, Samples, Setup, SetupType, SIGNATURES, SIZES, V1, V2)

cache.install()

V3 = types.Array(F8, 3, "C")
#: module and argument types of every njit entry point (each takes the loop it runs first)
ENTRIES = {
    "run_exact": ("loop", (I2, V1, V1, I1, V1, V1, F8, F8, I8, I8, I8, I8, V1, V2, V2, V1, I8, V1, I1, I1, I8)),
    "run_naive": ("loop", (I2, V1, V1, V1, F8, F8, I8, I8, I8, I8, V1, V2, V2, V1, I8, V1, I1, I1, I8)),
    "run_members": ("members", (I2, V2, V2, V2, V2, F8, I8, I1, V3, V3, V2, V2, V2)),
    "run_twin_members": ("members", (I2, V2, V2, V2, V2, V2, V2, F8, I8, I8, V1, V2, V2)),
    "set_up_members": ("members", (I2, SetupType, V2, V2, V2, V2, V2, V1)),
    "fill_tolerances": ("tolerances", (I2, V1, F8, I8, I8, F8, V1)),
}
#: the engine's function values: name -> (module, function, signature, what it needs compiled first)
LOOPS = {
    "step": ("integrator", "rk4", STEP, ()),
    "update": ("modes", "update_contacts", UPDATE, ()),
    "crossing": ("events", "first_crossing", CROSSING, ()),
    "release": ("events", "first_release", RELEASE_AT, ()),
    "exact": ("loop", "integrate_exact", EXACT, ("step", "update", "crossing", "release")),
    "naive": ("loop", "integrate", NAIVE, ()),
}
_loops: dict = {}

__all__ = ["DONE", "IMPACT_LOG_FULL", "NONFINITE", "STALLED", "IMPULSE", "REST", "RELEASE", "FALLBACK", "WARNING",
           "WARN_LCP", "WARN_LOCATE", "MAX_EVENTS", "MODE_SLOTS", "T_GAP", "T_EVENT", "T_VREST", "T_AREST", "T_BOXV", "T_WALL", "T_RJACK", "T_RBOX", "T_SPEED",
           "Model", "Samples", "Events", "Setup", "SIGNATURES", "SIZES", "ENTRIES", "LOOPS", "entry", "compiled_loop", "prepare", "table"]


def _dispatcher(name: str):
    import importlib

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


def table(model: Model, loops=("exact",)) -> np.ndarray:
    """The array every entry point takes: the model, then the stages and loops it needs (see ``TABLE``).

    Row 0: integers as they are, functions as their C addresses (0 for a loop
    or stage not asked for, which must then not be called); row 1: the
    functions' native addresses. With Numba's JIT off, a tuple of the values.
    """
    wanted = set(loops).union(*(LOOPS[name][3] for name in loops))
    values = (*model, *(compiled_loop(name) if name in wanted else 0 for name in TABLE[len(model):]))
    if numba.config.DISABLE_JIT:
        return values
    out = np.zeros((2, len(values)), np.int64)
    for i, value in enumerate(values):
        if isinstance(value, (int, np.integer)):
            out[0, i] = value
        else:
            out[0, i], out[1, i] = value.address, native_address(value)
    return out


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


def prepare(names, loops=()) -> str:
    """Compile (or load from the cache) the entry points and function values named.

    Returns "memory" (all were ready in this process), "hit" (loaded from the
    cache, none compiled), "miss" (at least one compiled now) or "disabled".
    """
    import importlib

    wanted = []
    for name in loops:      # what each needs first, then itself
        for need in (*LOOPS[name][3], name):
            if need not in wanted and need not in _loops:
                wanted.append(need)
    if numba.config.DISABLE_JIT:
        for name in wanted:
            module, fn, _, _ = LOOPS[name]
            _loops[name] = getattr(importlib.import_module(f"{__name__}.{module}"), fn)
        return "disabled"
    todo = [(name, _dispatcher(name)) for name in names if not _dispatcher(name).signatures]
    if not todo and not wanted:
        return "memory"
    misses = 0
    with warnings.catch_warnings():
        # calls through function values: the documented, tested use, not news to a user
        warnings.simplefilter("ignore", NumbaExperimentalFeatureWarning)
        for name in wanted:
            module, fn, sig, _ = LOOPS[name]
            py_func = getattr(importlib.import_module(f"{__name__}.{module}"), fn)
            py_func = getattr(py_func, "py_func", py_func)
            compiled = numba.cfunc(sig, cache=True)(py_func)
            misses += not compiled.cache_hits
            _loops[name] = compiled
        for name, fn in todo:
            before = sum(fn.stats.cache_misses.values())
            fn.compile(ENTRIES[name][1])
            fn.disable_compile()
            misses += sum(fn.stats.cache_misses.values()) - before
    return "miss" if misses else "hit"
