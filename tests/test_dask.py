"""Ensembles on Dask: a real cluster of worker processes on loopback gives the results of one
process bit for bit, loses no member when a worker is killed mid-chunk, and reports a bad
scheduler address in one line."""

from __future__ import annotations

import dataclasses
import os
import signal
import socket
import subprocess
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

distributed = pytest.importorskip("distributed")

from jackbox import distributed as jd  # noqa: E402
from jackbox.errors import SimulationError  # noqa: E402


@dataclasses.dataclass(frozen=True)
class ToySpec:
    seed: int
    delay: float = 0.0          # seconds per chunk: slow enough to kill a worker mid-chunk
    marker_dir: str | None = None


def toy_chunk(spec: ToySpec, start: int, stop: int) -> dict[str, np.ndarray]:
    """A stand-in for run_chunk: each member's numbers depend only on its index and the seed.

    With a marker_dir it writes ``<start>.<pid>.<attempt>.start`` on entry and the same name
    with ``.done`` on return, so a test can see which process ran (or died in) which chunk.
    """
    attempt = f"{start}.{os.getpid()}.{uuid.uuid4().hex[:8]}"
    if spec.marker_dir:
        Path(spec.marker_dir, attempt + ".start").touch()
    time.sleep(spec.delay)
    members = np.arange(start, stop)
    x = np.stack([np.random.default_rng([spec.seed, i]).standard_normal(3) for i in members])
    if spec.marker_dir:
        Path(spec.marker_dir, attempt + ".done").touch()
    return {"member": members, "x": x, "hit": x[:, 0] > 0}


def short_chunk(spec: ToySpec, start: int, stop: int) -> dict[str, np.ndarray]:
    """A broken chunk function: one row short."""
    return {"x": np.zeros(stop - start - 1)}


def threads_chunk(spec: ToySpec, start: int, stop: int) -> dict[str, np.ndarray]:
    """The Numba threads a chunk was given, once per member."""
    import numba

    return {"threads": np.full(stop - start, numba.get_num_threads())}


def chunks(n: int, size: int) -> list[tuple[int, int]]:
    return [(s, min(s + size, n)) for s in range(0, n, size)]


def assert_same(parts: list[dict], whole: dict):
    """The chunks joined are `whole` bit for bit (NaNs included)."""
    assert sorted(parts[0]) == sorted(whole)
    for name in whole:
        joined = np.concatenate([p[name] for p in parts])
        assert (joined.dtype, joined.shape) == (whole[name].dtype, whole[name].shape), name
        assert joined.tobytes() == whole[name].tobytes(), name


def local_cluster(**kw):
    kw = {"n_workers": 2, "threads_per_worker": 1, "processes": True, "host": "127.0.0.1",
          **jd.QUIET_HTTP} | kw
    return distributed.LocalCluster(**kw)


@pytest.fixture(scope="module")
def cluster():
    """Two worker processes of one thread each, shared by the tests that do not kill workers."""
    with local_cluster() as cluster, distributed.Client(cluster, set_as_default=False) as client:
        yield cluster, client


def test_results_equal_one_process_bit_for_bit(cluster):
    spec = ToySpec(seed=11, delay=0.05)
    bounds = chunks(50, 7)                      # a short last chunk too
    out = jd.run_on_dask(toy_chunk, spec, bounds, address=cluster[0].scheduler_address,
                         progress=False)
    assert [len(r["member"]) for r in out] == [stop - start for start, stop in bounds]
    assert_same(out, toy_chunk(spec, 0, 50))


@pytest.fixture(scope="module")
def study():
    """A small shaken study that reaches the first impulses (near t = 1.06 s)."""
    from jackbox import ensemble

    # in blocks of lanes, whatever this machine has compiled (a study this small would go alone unless
    # its lanes are compiled already)
    return dataclasses.replace(ensemble.plan("shaken", 40, perturb={"theta_jack": 1e-2, "x_jack_dot": 0.1},
                                             t_end=1.5, samples=[0.5, 1.0], seed=4), lanes=True)


def test_run_chunk_on_dask_equals_one_process(cluster, study):
    from jackbox import ensemble

    whole = ensemble.run_chunk(study, 0, study.n)
    assert whole["impacts"].min() > 0                  # the impact code ran
    client = cluster[1]
    before = jd.worker_compile_stats(client)
    bounds = chunks(study.n, 5)
    out = jd.run_on_dask(ensemble.run_chunk, study, bounds, address=cluster[0].scheduler_address,
                         progress=False)
    assert_same(out, whole)
    # every chunk ran once; a worker loaded the kernel (from the disk cache the run above
    # filled) on its first chunk only, and kept it for the next ones: two bindings of the
    # model, its own functions and those with its lanes (the members share their parameters)
    after = jd.worker_compile_stats(client)
    calls = {w: after[w]["calls"] - before[w]["calls"] for w in after}
    assert sum(calls.values()) == len(bounds)
    for w, stats in after.items():
        loads = stats["compiling_calls"] - before[w]["compiling_calls"]
        assert loads == (1 if calls[w] and not before[w]["kernels"] else 0), stats
        assert stats["kernels"] == (2 if calls[w] or before[w]["kernels"] else 0), stats


def test_ensemble_with_a_scheduler_equals_one_process(cluster, study):
    from jackbox import ensemble

    kw = dict(perturb={"theta_jack": 1e-2, "x_jack_dot": 0.1}, t_end=1.5, samples=[0.5, 1.0], seed=4)
    here = ensemble.ensemble("shaken", 40, **kw)
    there = ensemble.ensemble("shaken", 40, **kw, scheduler=cluster[0].scheduler_address, chunk=8)
    for name in ("q", "qd", "energy", "impacts", "first_impact_t", "status", "samples_q", "params"):
        assert getattr(there, name).tobytes() == getattr(here, name).tobytes(), name


def test_run_chaos_chunk_on_dask_equals_one_process(cluster, study):
    from jackbox import ensemble

    spec = dataclasses.replace(study, renorm_steps=100, d0=1e-8)
    whole = ensemble.run_chaos_chunk(spec, 0, spec.n)
    out = jd.run_on_dask(ensemble.run_chaos_chunk, spec, chunks(spec.n, 15),
                         address=cluster[0].scheduler_address, progress=False)
    assert_same(out, whole)


def test_cli_dask_local_equals_the_run_in_this_process(tmp_path, capsys):
    """README: ``jackbox ensemble ... --dask local`` (here 2 worker processes) gives every array
    equal to the single-process run's."""
    import json

    from jackbox import ensemble

    from .conftest import run_cli

    args = ["--n", "40", "--t-end", "1.5", "--perturb", "theta_jack=1e-2", "--perturb", "x_jack_dot=0.1",
            "--samples", "0.5", "1.0", "--seed", "4"]
    status, stdout, stderr = run_cli(capsys, "ensemble", "shaken", *args, "--dask", "local", "--workers", "2",
                                     "--chunk", "8", "--out", str(tmp_path / "dask"))
    assert status == 0, stderr
    assert "dask: local cluster of 2 worker processes" in stderr
    assert "dask: 5 chunks" in stderr
    assert "member-steps/s on dask local, 2 workers" in stdout
    here = ensemble.ensemble("shaken", 40, perturb={"theta_jack": 1e-2, "x_jack_dot": 0.1}, t_end=1.5,
                             samples=[0.5, 1.0], seed=4)
    assert here.impacts.min() > 0
    with np.load(tmp_path / "dask" / "ensemble.npz") as data:
        for name in ("q", "qd", "energy", "impacts", "first_impact_t", "status", "steps", "samples_q",
                     "samples_qd", "q0", "qd0", "params"):
            want = getattr(here, name)
            assert (data[name].dtype, data[name].shape) == (want.dtype, want.shape), name
            assert data[name].tobytes() == want.tobytes(), name
        meta = json.loads(str(data["meta"]))
    assert (meta["where"], meta["chunk"]) == ("dask local, 2 workers", 8)


def test_local_cluster_is_started_and_closed(capsys):
    import psutil

    before = {p.pid for p in psutil.Process().children(recursive=True)}
    messages = []
    spec = ToySpec(seed=3)
    out = jd.run_on_dask(toy_chunk, spec, chunks(20, 6), n_workers=2, log=messages.append)
    assert_same(out, toy_chunk(spec, 0, 20))
    assert any("local cluster of 2 worker processes" in m for m in messages)
    # no worker or nanny process outlives the call
    deadline = time.monotonic() + 10
    while {p.pid for p in psutil.Process().children(recursive=True)} - before:
        assert time.monotonic() < deadline, "worker processes left running"
        time.sleep(0.1)


@dataclasses.dataclass(frozen=True)
class KillingStudy:
    """An ensemble study whose chunk `victim` (by its start) is SIGKILLed, with its worker,
    `after` seconds into its first attempt's run_chunk; markers as in toy_chunk."""

    study: object
    marker_dir: str
    victim: int
    after: float


def run_chunk_and_die_once(spec: KillingStudy, start: int, stop: int) -> dict[str, np.ndarray]:
    from jackbox import ensemble

    attempt = f"{start}.{os.getpid()}.{uuid.uuid4().hex[:8]}"
    marker = Path(spec.marker_dir)
    (marker / (attempt + ".start")).touch()
    if start == spec.victim:
        try:
            os.close(os.open(marker / "armed", os.O_CREAT | os.O_EXCL))
        except FileExistsError:
            pass                                # a second attempt: runs to its end
        else:
            # another process kills this one while the kernel runs: the kernel holds the GIL,
            # so a thread of this process could not
            subprocess.Popen(["/bin/sh", "-c", f"sleep {spec.after}; kill -9 {os.getpid()} && "
                                               f"echo {attempt} > {marker / 'killed'}"])
    result = ensemble.run_chunk(spec.study, start, stop)
    (marker / (attempt + ".done")).touch()
    return result


def test_a_worker_killed_in_the_kernel_loses_no_member(tmp_path):
    """SIGKILL a worker while it runs the ensemble kernel (run_chunk) on a chunk: the scheduler
    runs the chunk again elsewhere, the nanny starts a new worker, and every member comes back
    exactly once, equal to the bit to one process's run."""
    from jackbox import ensemble

    # dt = 1e-5 to 2 s, through the first impulses: 2e5 steps a member, ~12 ms on one core.
    # The victim chunk of 32 members runs ~0.35 s; it is killed 0.05 s in, and the kernel is
    # loaded on every worker beforehand, so the kill lands in the kernel's loop. Members alone,
    # not in lanes: in a block of 32 lanes the chunk is done in 0.03 s, before the kill.
    study = dataclasses.replace(ensemble.plan("shaken", 40, perturb={"theta_jack": 1e-2, "x_jack_dot": 0.1},
                                              t_end=2.0, dt=1e-5, samples=[0.5, 1.5], seed=6), lanes=False)
    spec = KillingStudy(study, str(tmp_path), victim=0, after=0.05)
    bounds = [(0, 32)] + chunks(40, 2)[16:]     # the victim first, then four chunks of 2
    whole = ensemble.run_chunk(study, 0, study.n)       # (and the kernel in the disk cache)
    assert whole["impacts"].min() > 0
    with local_cluster() as cluster, distributed.Client(cluster, set_as_default=False) as client:
        pids = client.run(os.getpid)            # {worker address: pid}
        client.run(ensemble.run_chunk, study, 0, 1)     # every worker loads the kernel
        out = jd.run_on_dask(run_chunk_and_die_once, spec, bounds, address=cluster.scheduler_address,
                             progress=False)
        client.wait_for_workers(2, timeout=30)  # the nanny has started a new worker
        after = client.run(os.getpid)

    names = {p.name for p in tmp_path.iterdir()}
    assert "killed" in names, "the victim chunk was not killed"
    killed = (tmp_path / "killed").read_text().strip()
    pid = int(killed.split(".")[1])
    assert pid in pids.values() and pid not in after.values() and len(after) == 2
    # the killed attempt did not finish; another process ran the chunk to its end
    assert killed + ".done" not in names
    done = [n for n in names if n.startswith("0.") and n.endswith(".done")]
    assert len(done) == 1 and int(done[0].split(".")[1]) != pid, names
    for start, _ in bounds:                     # every chunk finished at least once
        assert any(n.startswith(f"{start}.") and n.endswith(".done") for n in names), start
    # each chunk's rows came back once, in place, and equal one process's run to the bit
    assert [len(r["q"]) for r in out] == [stop - start for start, stop in bounds]
    assert_same(out, whole)


def die_until(spec: ToySpec, start: int, stop: int) -> dict[str, np.ndarray]:
    """toy_chunk, but its first `spec.delay` attempts SIGKILL their own worker
    (each leaves ``<start>.<pid>.start``)."""
    marker = Path(spec.marker_dir)
    attempts = len(list(marker.glob(f"{start}.*.start")))
    (marker / f"{start}.{os.getpid()}.start").touch()
    if attempts < spec.delay:
        os.kill(os.getpid(), signal.SIGKILL)
    return toy_chunk(ToySpec(spec.seed), start, stop)


def test_a_local_cluster_survives_more_worker_deaths_than_dask_allows(tmp_path):
    """README: a local cluster allows 10 worker deaths per chunk (Dask's default: 3, past
    which the chunk fails with KilledWorker). A chunk that kills its worker 4 times still
    comes back, from the 5th."""
    import dask

    assert dask.config.get("distributed.scheduler.allowed-failures") < 4   # Dask would give up
    spec = ToySpec(seed=8, delay=4, marker_dir=str(tmp_path))
    out = jd.run_on_dask(die_until, spec, [(0, 3)], n_workers=2, progress=False)
    assert_same(out, toy_chunk(ToySpec(seed=8), 0, 3))
    starts = [p.name for p in tmp_path.glob("0.*.start")]
    assert len(starts) == 5 and len({n.split(".")[1] for n in starts}) == 5    # 5 worker processes


def test_numba_threads_are_the_worker_cores_over_its_tasks(cluster):
    import numba

    address = cluster[0].scheduler_address   # workers of one thread: one chunk at a time
    for cores, expected in [(1, 1), (2, min(2, numba.config.NUMBA_NUM_THREADS))]:
        out = jd.run_on_dask(threads_chunk, ToySpec(seed=0), chunks(4, 2), address=address,
                             threads_per_worker=cores, progress=False)
        assert {int(t) for r in out for t in r["threads"]} == {expected}


def test_a_result_that_does_not_cover_its_chunk_is_refused(cluster):
    with pytest.raises(SimulationError, match=r"short_chunk\(0, 5\) returned 'x' with 4 rows, not 5"):
        jd.run_on_dask(short_chunk, ToySpec(seed=0), [(0, 5)], address=cluster[0].scheduler_address,
                       progress=False)


def test_bounds_are_checked():
    with pytest.raises(SimulationError, match="given twice"):
        jd.run_on_dask(toy_chunk, ToySpec(seed=0), [(0, 5), (0, 5)])
    with pytest.raises(SimulationError, match="bad chunk bounds"):
        jd.run_on_dask(toy_chunk, ToySpec(seed=0), [(5, 5)])
    with pytest.raises(SimulationError, match="n_workers must be a positive integer, got 0"):
        jd.run_on_dask(toy_chunk, ToySpec(seed=0), [(0, 5)], n_workers=0)


def test_a_scheduler_that_does_not_answer_is_named():
    with socket.socket() as s:                  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{s.getsockname()[1]}"
    t0 = time.monotonic()
    with pytest.raises(SimulationError, match=f"no Dask scheduler answered at {address} within 1 s"):
        jd.run_on_dask(toy_chunk, ToySpec(seed=0), [(0, 5)], address=address, connect_timeout=1)
    assert time.monotonic() - t0 < 10


@pytest.mark.parametrize("address", ["nonsense::", "foo", "tcp://foo"])
def test_a_malformed_address_is_named(address):
    with pytest.raises(SimulationError, match=f"bad Dask scheduler address '{address}'"):
        jd.run_on_dask(toy_chunk, ToySpec(seed=0), [(0, 5)], address=address, connect_timeout=1)


def test_the_cli_with_a_malformed_address_exits_at_once_with_one_line(tmp_path):
    # refused before a Client exists: one built from "foo" and refused waited 20 s at the
    # process's exit, then printed "Exception ignored in: <function Client.__del__ ...>" and a traceback
    import subprocess
    import sys

    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-m", "jackbox.cli", "ensemble", "drop", "--n", "2", "--t-end", "0.05",
                           "--scheduler", "foo", "--out", str(tmp_path)], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2 and time.monotonic() - t0 < 15
    assert done.stderr.strip().splitlines() == ["jackbox: error: bad Dask scheduler address 'foo' (missing port "
                                                "number in address 'foo'); expected tcp://HOST:PORT"]


def test_missing_distributed_says_what_to_install(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)   # import distributed -> ImportError
    with pytest.raises(SimulationError, match=r'pip install "jackbox\[dask\]"'):
        jd.run_on_dask(toy_chunk, ToySpec(seed=0), [(0, 5)])
