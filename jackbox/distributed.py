"""Run the chunks of an ensemble on a Dask cluster: a local one, or a scheduler you started.

:func:`jackbox.ensemble.ensemble` splits a study into chunks of members and,
when asked for Dask, hands them here. Each chunk is one task, run in a worker
process by a module-level function of jackbox (``run_chunk(spec, start,
stop)``), so workers import it rather than receive its code; a member's result
depends only on its index and the seed, so the results are the same however
the chunks are spread.

Keys are deterministic (the function, a hash of the pickled spec, the
bounds): a task that is run again is the same task, and two identical studies
on one scheduler share their results instead of computing them twice.

A worker that dies (killed, out of memory, its machine gone) loses the
chunks it was running or holding; the scheduler sends them to other workers.
It gives up on a chunk, with ``KilledWorker``, once the chunk has been on more
than ``distributed.scheduler.allowed-failures`` workers that died. A local
cluster is started with at least :data:`ALLOWED_FAILURES`; a scheduler you
started keeps its own setting (Dask's default is 3; raise it with
``DASK_DISTRIBUTED__SCHEDULER__ALLOWED_FAILURES=10`` in the scheduler's
environment). The spec travels inside every task rather than being scattered
once: scattered data lost with a worker cannot be recomputed.

Workers must have the same jackbox as the client. Each compiles (or loads from
its ``$JACKBOX_CACHE_DIR``) the kernel on its first chunk and keeps it for the
next ones; :func:`worker_compile_stats` shows it.
"""

from __future__ import annotations

import hashlib
import os
import pickle
import time
from contextlib import contextmanager

import numba
import numpy as np

from . import engine, loader
from .errors import SimulationError
from .progress import progress_bar

#: the least ``allowed-failures`` of a local cluster: deaths of workers a chunk survives
ALLOWED_FAILURES = 10
#: seconds to wait for a scheduler given by address before giving up
CONNECT_TIMEOUT = 10.0
#: a local scheduler's HTTP server (health checks; it always has one) on a free loopback
#: port, without the dashboard: dashboard_address=None would take 8787, or warn when in use
QUIET_HTTP = {"dashboard_address": "127.0.0.1:0", "scheduler_kwargs": {"dashboard": False}}


def run_on_dask(fn, spec, bounds, *, address=None, n_workers=None, threads_per_worker=1,
                progress=True, log=None, connect_timeout=CONNECT_TIMEOUT) -> list[dict[str, np.ndarray]]:
    """``[fn(spec, start, stop) for start, stop in bounds]``, each call a task on a Dask cluster.

    fn: a module-level function (workers import it by name) returning a dict of
    arrays whose first dimension is ``stop - start``. bounds: distinct ``(start,
    stop)`` pairs. address: ``"tcp://HOST:PORT"`` of a running scheduler; None
    starts a local cluster of `n_workers` processes (default: one per core) on
    127.0.0.1 and closes it at the end. threads_per_worker: the cores one worker
    process may use; a chunk's Numba threads are that divided among the chunks a
    worker runs at once, so the processes do not oversubscribe the cores.
    Returns the results in the order of `bounds`. Raises SimulationError for an
    address that does not answer within `connect_timeout` seconds, a chunk whose
    workers kept dying, or a result that does not cover its chunk.
    """
    distributed = _import_distributed()
    bounds = _checked(bounds)
    for name, value in [("n_workers", n_workers), ("threads_per_worker", threads_per_worker)]:
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1):
            raise SimulationError(f"{name} must be a positive integer, got {value!r}")
    if not bounds:
        return []
    with _client(distributed, address, n_workers, threads_per_worker, connect_timeout, log) as client:
        return _run(distributed, client, fn, spec, bounds, threads_per_worker, progress, log)


def worker_compile_stats(client) -> dict[str, dict]:
    """What each worker process of `client`'s cluster compiled, by worker address.

    Per worker: ``pid``; ``calls``, chunks run; ``compiling_calls``, chunks
    during which a kernel was loaded or a new signature compiled (at most one
    per kernel and method when the kernel is reused); ``kernels``, kernel modules
    loaded; ``signatures``, machine-code signatures in them; ``compiled`` and
    ``from_disk``, how many of those Numba compiled or loaded from its cache;
    ``seconds``, wall time of each chunk. A restarted worker starts from zero.
    """
    return client.run(_worker_stats)


# -- on the client --------------------------------------------------------------------------

def _import_distributed():
    try:
        import distributed
    except ImportError:
        raise SimulationError(
            'running ensembles on Dask needs dask.distributed: pip install "jackbox[dask]"') from None
    return distributed


def _checked(bounds) -> list[tuple[int, int]]:
    out = []
    for pair in bounds:
        start, stop = (int(x) for x in pair)
        if not 0 <= start < stop:
            raise SimulationError(f"bad chunk bounds ({start}, {stop}): need 0 <= start < stop")
        out.append((start, stop))
    if len(set(out)) != len(out):
        twice = sorted({b for b in out if out.count(b) > 1})
        raise SimulationError(f"chunk bounds given twice: {twice}")
    return out


@contextmanager
def _client(distributed, address, n_workers, threads_per_worker, connect_timeout, log):
    if address is not None:
        # the address checked before a Client exists: one made from a bad address and refused stays half
        # built, and its finaliser waited 20 s for a connection, then printed a traceback
        from distributed.comm.addressing import parse_address, parse_host_port

        try:
            scheme, location = parse_address(address)
            if scheme in ("tcp", "tls"):
                parse_host_port(location)
        except (ValueError, TypeError) as exc:
            raise SimulationError(f"bad Dask scheduler address {address!r} ({exc}); "
                                  "expected tcp://HOST:PORT") from None
        try:
            client = distributed.Client(address, timeout=connect_timeout, set_as_default=False)
        except ValueError as exc:
            raise SimulationError(f"bad Dask scheduler address {address!r} ({exc}); "
                                  "expected tcp://HOST:PORT") from None
        except (OSError, TimeoutError):
            raise SimulationError(f"no Dask scheduler answered at {address} within {connect_timeout:g} s: "
                                  "is one running there (dask scheduler), and its port reachable?") from None
        with client:
            workers = client.scheduler_info()["workers"]
            if log:
                log(f"dask: scheduler {address}, {len(workers)} workers"
                    + ("" if workers else " yet: waiting for some"))
            yield client
        return

    import dask

    n_workers = n_workers or os.cpu_count() or 1
    allowed = max(dask.config.get("distributed.scheduler.allowed-failures"), ALLOWED_FAILURES)
    # the scheduler reads it when it starts; a local cluster's scheduler runs in this process
    with dask.config.set({"distributed.scheduler.allowed-failures": allowed}):
        cluster = distributed.LocalCluster(
            n_workers=n_workers, threads_per_worker=threads_per_worker, processes=True,
            host="127.0.0.1", **QUIET_HTTP)
    with cluster, distributed.Client(cluster, set_as_default=False) as client:
        if log:
            log(f"dask: local cluster of {n_workers} worker processes, {threads_per_worker} "
                f"thread{'s' if threads_per_worker > 1 else ''} each, at {cluster.scheduler_address}")
        yield client


def _run(distributed, client, fn, spec, bounds, threads, progress, log):
    token = hashlib.sha256(pickle.dumps((fn.__module__, fn.__qualname__, spec))).hexdigest()[:16]
    futures = [client.submit(_call, fn, spec, start, stop, threads,
                             key=f"jackbox-{fn.__name__}-{start}-{stop}-{token}")
               for start, stop in bounds]
    index = {future.key: i for i, future in enumerate(futures)}
    results: list[dict | None] = [None] * len(bounds)
    bar = progress_bar(sum(stop - start for start, stop in bounds), progress, "member", "ensemble")
    started = time.perf_counter()
    try:
        done = distributed.as_completed(futures, with_results=True, raise_errors=False,
                                        loop=client.loop)
        for future, result in done:
            i = index[future.key]
            start, stop = bounds[i]
            if future.status != "finished":
                _raise(distributed, future, start, stop)
            if results[i] is not None:
                raise SimulationError(f"members {start}..{stop - 1} came back twice from Dask")
            results[i] = _covering(result, fn, start, stop)
            future.release()   # the client has it: free the worker's copy
            bar.update(stop - start)
    finally:
        bar.close()
    missing = [bounds[i] for i, r in enumerate(results) if r is None]
    if missing:
        raise SimulationError(f"Dask returned no result for chunks {missing}")
    if log:
        log(f"dask: {len(bounds)} chunks in {time.perf_counter() - started:.2f} s")
    return results


def _raise(distributed, future, start, stop):
    if future.status == "cancelled":
        raise SimulationError(f"members {start}..{stop - 1} were cancelled by the Dask scheduler "
                              f"at {future.client.scheduler.address} (connection lost?)")
    exc = future.exception()
    if isinstance(exc, distributed.KilledWorker):
        raise SimulationError(
            f"members {start}..{stop - 1}: the Dask workers running them died "
            f"{exc.allowed_failures + 1} times (out of memory? a crash?); last worker "
            f"{exc.last_worker.address}") from None
    future.result()   # re-raises the chunk's own error with its traceback


def _covering(result, fn, start, stop) -> dict:
    where = f"{fn.__name__}({start}, {stop})"
    if not isinstance(result, dict):
        raise SimulationError(f"{where} returned {type(result).__name__}, not a dict of arrays")
    for name, value in result.items():
        rows = np.shape(value)[0] if np.ndim(value) else None
        if rows != stop - start:
            raise SimulationError(f"{where} returned {name!r} with {rows} rows, not {stop - start}")
    return result


# -- in the worker --------------------------------------------------------------------------

_stats = {"calls": 0, "compiling_calls": 0, "seconds": []}


def _call(fn, spec, start, stop, threads):
    """`fn(spec, start, stop)` in a worker, with Numba's threads limited and compiles counted."""
    numba.set_num_threads(_numba_threads(threads))
    before = _kernel_state()
    t0 = time.perf_counter()
    result = fn(spec, start, stop)
    _stats["seconds"].append(time.perf_counter() - t0)
    _stats["calls"] += 1
    _stats["compiling_calls"] += _kernel_state() != before
    return result


def _numba_threads(threads: int) -> int:
    """The Numba threads of one chunk: the worker's cores over the chunks it runs at once."""
    try:
        from distributed import get_worker

        at_once = get_worker().state.nthreads
    except (ImportError, ValueError):   # not in a Dask worker
        at_once = 1
    return max(1, min(threads // at_once, numba.config.NUMBA_NUM_THREADS))


def _dispatchers():
    seen = {}
    for module in loader._parts.values():
        for value in vars(module).values():
            if isinstance(value, numba.core.dispatcher.Dispatcher):
                seen[id(value)] = value
    for name in engine.ENTRIES:
        fn = engine._dispatcher(name)
        seen[id(fn)] = fn
    return seen.values()


def _kernel_state() -> tuple[int, int]:
    """(binding modules loaded, compiled signatures and engine function values) in this process."""
    return len(loader._loaded), sum(len(d.signatures) for d in _dispatchers()) + len(engine._loops)


def _worker_stats() -> dict:
    kernels, signatures = _kernel_state()
    hits = misses = 0
    for d in _dispatchers():
        hits += sum(d.stats.cache_hits.values())
        misses += sum(d.stats.cache_misses.values())
    return {"pid": os.getpid(), "calls": _stats["calls"], "compiling_calls": _stats["compiling_calls"],
            "kernels": kernels, "signatures": signatures, "compiled": misses, "from_disk": hits,
            "seconds": list(_stats["seconds"])}
