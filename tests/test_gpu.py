"""The GPU target (jackbox.engine.gpu): its code path on numba-cuda's simulator, its errors, a real GPU.

The simulator runs the kernels' Python on the CPU: the engine's own functions,
cloned for the CUDA target, with scratch of fixed size, as a GPU thread runs
them. Its numbers are the CPU engine's bit for bit (Python's float arithmetic
is the compiled code's, with no FMA contraction on either side), so these
tests ask for equality, and they check on every machine the GPU's logic: the
member and twin kernels, the fixed-size scratch and log, the model record of
device functions. On a real GPU the numbers differ by round-off (FMA, the
device's sin and cos): ``test_a_real_gpu_gives_the_cpus_numbers`` holds them
to 1e-10 where one is present.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys

import numpy as np
import pytest

from jackbox.errors import SimulationError

HAS_NUMBA_CUDA = importlib.util.find_spec("numba_cuda") is not None
needs_numba_cuda = pytest.mark.skipif(not HAS_NUMBA_CUDA, reason="numba-cuda is not installed (pip install "
                                                                 "'jackbox[dev]' installs it for its simulator)")

#: run in a process of its own: the simulator is chosen when numba.cuda is first imported
SIMULATED = r"""
import json, sys
import numpy as np
from numba.cuda.simulator import kernelapi

def poisoned(self, shape, dtype, alignment=None):
    # a GPU's local memory holds whatever was there: here NaN, or a huge integer
    out = np.empty(shape, kernelapi.numpy_support.as_dtype(dtype) if hasattr(dtype, "key") else dtype)
    out.fill(np.nan if out.dtype.kind == "f" else 1 << 40)
    return out

kernelapi.FakeCUDALocal.array = poisoned
from jackbox import api, loader
from jackbox.engine import gpu
from jackbox.ensemble import chaos, ensemble
from jackbox.scene import load_scene

gpu.ROUNDS, gpu.CALM = json.loads(sys.argv[2])
# short turns of unequal lengths, so that members are cut into many rounds at different steps
gpu.CHUNK, gpu.ALONE, gpu.EVENT_TURN, gpu.HELD_TURN = 7, 3, 1, 5
gpu.PASSES = 1      # (SHORT: members still handed back after one pass wait for the next round)

def same(a, b):
    return bool(np.array_equal(a, b, equal_nan=True))

out, finals = {}, {}
for name, path, over, n, t in json.loads(sys.argv[1]):
    scene = load_scene(path or name, over)
    kw = dict(perturb={"theta_jack": 0.3}, t_end=t, samples=[t / 2])
    gpu.TRACE = [] if gpu.ROUNDS else None        # (traced: each launch synchronised and timed)
    a, b = ensemble(scene, n, **kw), ensemble(scene, n, device="cuda", **kw)
    trace, gpu.TRACE = gpu.TRACE, None
    out[name] = {key: same(getattr(a, key), getattr(b, key))
                 for key in ("q", "qd", "energy", "impacts", "first_impact_t", "status", "steps", "fallback",
                             "warnings", "samples_q", "samples_qd")}
    out[name]["impulses"] = int(a.impacts.sum())
    out[name]["where"] = b.meta["where"]
    finals[name] = (scene, a.q[0], a.spec.n_steps * a.spec.dt)      # (the end's time, as the GPU's)
    if trace is not None:       # the last round finds no member running; the listed ones took the exact loop
        out[name]["trace"] = [trace[-1]["running"], min(r["running"] for r in trace[:-1]) if len(trace) > 1 else 1,
                              {key: sum(r.get(key, 0) for r in trace) for key in ("free", "held", "event", "calm", "passes")}
                              | {key: trace[-1][key] for key in ("calm_tests", "calm_steps", "calm_flown")},
                              all(("alone_" + key in r) == (r[key] > 0) for r in trace for key in ("free", "held", "event"))]
from jackbox.scene import contact_gaps_many
for name in ("drop", "hand"):       # final states moved in and out of the walls (and the ground): a box in
    scene, q, t = finals[name]      # drop's, a prescribed one's (its pose the run's at its end) in hand's
    P = scene.params()
    Q = np.tile(q, (64, 1))
    Q[:, 6 - len(scene.dof_names):] += np.random.default_rng(2).normal(0, 0.4, (64, len(scene.dof_names)))
    gaps = np.empty(64)
    gpu._launch(loader.kernel_for(scene).gpu().smallest_gaps, 64, (Q, np.tile(scene.param_values, (64, 1))),
                (float(t),), (), (gaps,))
    numpy_gaps = contact_gaps_many(Q, np.broadcast_to(scene.points, (64,) + scene.points.shape), np.full(64, P["L"]),
                                   np.full(64, P["w_box"]), scene.has_ground_contacts).min(axis=1)
    inside = api.inside(scene, Q, P)
    out["final_check_" + name] = {"same_inside": bool((~(gaps >= -api.INSIDE_LIMIT * P["L"]) == inside).all()),
                                  "some_inside": bool(inside.any()), "some_not": bool((~inside).any()),
                                  "gaps_within": bool(np.allclose(gaps, numpy_gaps, rtol=0, atol=1e-12))}
c = chaos("drop", 2, t_end=0.3, renorm=0.1, perturb={"theta_jack": 0.3})
d = chaos("drop", 2, t_end=0.3, renorm=0.1, perturb={"theta_jack": 0.3}, device="cuda")
out["chaos"] = {"stretch": same(c.stretch, d.stretch), "impacts": same(c.impacts, d.impacts),
                "q": same(c.q, d.q) and same(c.qd, d.qd),
                "finite": bool(np.isfinite(c.stretch).all())}
print(json.dumps(out))
"""


SETTLE = """
name = "settle"
[box]
inner_half_width = 1.0
wall_thickness = 0.1
mass = 10.0
motion = "free"
[jack]
shape = "square"
half_size = 0.25
mass = 1.0
[world]
gravity = 9.81
ground = true
[impact]
restitution = 0.0
[initial]
q = [0.0, 1.101, 0.0, 0.0, 0.46, 0.0]
qd = [0.0, 0.0, 0.0, 0.3, 0.0, 2.0]
[run]
t_end = 0.15
dt = 1e-3
"""


def _simulate(cases, rounds: bool, calm: int) -> dict:
    env = dict(os.environ, NUMBA_ENABLE_CUDASIM="1", PYTHONWARNINGS="ignore")
    proc = subprocess.run([sys.executable, "-c", SIMULATED, json.dumps(cases), json.dumps([rounds, calm])],
                          capture_output=True, text=True,
                          env=env, timeout=1200)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@needs_numba_cuda
@pytest.mark.parametrize("rounds, calm", [(False, 1), (True, 1), (True, 2), (True, 3)],
                         ids=["one-go", "rounds", "rounds-calm-in-flight", "rounds-calm-short"])
def test_the_gpus_kernels_give_the_cpus_numbers_on_the_simulator(tmp_path, rounds, calm):
    """Each member in one thread from start to end, and in rounds (fly, then the exact loop for those near
    contact, packed), the calm steps in a launch of their own for the members the lean flight stopped near
    contact (gpu.APART; gpu.SHORT: only the calm steps there, the members quiet again handed back to the
    lean flight) or in every member's flight (gpu.IN_FLIGHT): the CPU's numbers every way."""
    from .conftest import PRESCRIBED

    hand = tmp_path / "hand.toml"
    hand.write_text(PRESCRIBED)
    settle = tmp_path / "settle.toml"           # drop's box flat just above the ground, its jack just above the
    settle.write_text(SETTLE)                   # floor, plastic: both come to rest within a few steps
    cases = [("shaken", None, {}, 3, 0.3),
             ("drop", None, {"restitution": "0.6"}, 3, 0.6),       # impacts
             ("settle", str(settle), {}, 3, 0.15),                 # held contacts (in rounds: the held list)
             ("hand", str(hand), {}, 2, 0.3)]                      # a prescribed box: 3 integrated coordinates
    out = _simulate(cases, rounds, calm)
    for name, *_ in cases:
        assert out[name]["where"] == "GPU (numba-cuda simulator)"
        if rounds:              # the rounds' trace (benchmarks/gpu_probe.py) changes no number
            last, fewest, listed, timed = out[name].pop("trace")
            assert last == 0 and fewest > 0 and timed
            assert listed["event"] > 0 or name != "drop", listed        # each list taken
            assert listed["held"] > 0 or name != "settle", listed
            if calm in (1, 3) and name == "drop":
                assert listed["calm"] > 0, listed           # the lean flight's near-contact list flew on
            elif calm not in (1, 3) or name == "hand":      # (a prescribed box has no calm test)
                assert listed["calm"] == 0, listed
            if calm != 3 or name == "drop":         # only SHORT hands members back (drop's do)
                assert (listed["passes"] > 0) == (calm == 3), listed
            if name == "drop":      # the drop's approaches have calm steps, either way, flown among quiet ones
                assert 0 < listed["calm_steps"] < listed["calm_flown"], listed
            if name == "hand":      # no calm test, no flight with it
                assert listed["calm_tests"] == listed["calm_flown"] == 0, listed
        differ = [key for key, equal in out[name].items() if equal is False]
        assert not differ, f"{name}: the GPU's {', '.join(differ)} differ from the CPU's"
    assert out["drop"]["impulses"] > 0 and out["settle"]["impulses"] > 0          # the contact path ran
    # the check of the final states on the GPU (kernel smallest_gaps: the model's phi) is api.inside's, and
    # its gaps NumPy's to round-off, on states in and out of the walls and the ground
    for name in ("drop", "hand"):
        assert out["final_check_" + name] == {"same_inside": True, "some_inside": True, "some_not": True,
                                              "gaps_within": True}, (name, out["final_check_" + name])
    assert out["chaos"] == {"stretch": True, "impacts": True, "q": True, "finite": True}


@needs_numba_cuda
def test_a_gpu_thread_runs_the_engines_own_functions():
    """The stages are the CPU engine's code compiled for the GPU, not copies: one edit reaches both."""
    from jackbox.engine import events, gpu, loop, modes

    for fn in (loop.exact_steps, modes.update_contacts, events.first_crossing):
        assert gpu.device(fn).py_func.__code__ is fn.py_func.__code__
    clone = gpu.device(loop.exact_steps).py_func
    assert clone.__globals__["advance"] is gpu.device(loop.advance)        # its callees are device functions too
    assert gpu.device(loop.borrow).py_func is gpu.SUBSTITUTES[id(loop.borrow)]


#: run in a process of its own, without the simulator: each kernel of a model typed and lowered for the CUDA
#: target (what the simulator, which runs the kernels' Python, cannot check)
LOWERED = r"""
import json, sys
from jackbox import loader
from jackbox.engine import gpu
from jackbox.scene import load_scene

kernels = loader.kernel_for(load_scene(sys.argv[1])).gpu()
out = {}
for name in gpu.KERNEL_NAMES:
    cres = gpu.compile_offline(kernels, name, output="llvm")
    ir = cres.library.get_llvm_str()
    out[name] = {"lowered": cres.signature.return_type.__class__.__name__, "allocates": "NRT_MemInfo" in ir}
    if name == "alone":         # which of the functions kept out of line (and accel) are defined, and noinline
        defined = [f for mod in cres.library.modules for f in mod.functions if not f.is_declaration]
        names = gpu.OUT_OF_LINE + gpu.MORE_OUT_OF_LINE + ("accel",)
        out["out_of_line"] = {n: sorted({"noinline" in f.attributes for f in defined if f"{len(n)}{n}B" in f.name})
                              for n in names}
print(json.dumps(out))
"""


@needs_numba_cuda
@pytest.mark.parametrize("name", ["drop", "hand"])
def test_every_kernel_compiles_for_the_cuda_target(tmp_path, name):
    """The kernels the CUDA target compiles, not only the simulator's Python: every one types and lowers, for a
    free box on a ground and a prescribed box with no ground, and none allocates (scratch of fixed size). (The
    engine's code is the same for every model, a model's kind a value of its record: a box free in the air,
    shaken's, takes branches the two take, and was a third minute of compiling.) The
    functions kept out of line (the stages, the helpers called from many places: half the compile time of
    ``alone``) are marked noinline for NVVM, and ``accel`` is not.

    A GPU's compiler refuses what the simulator runs: a local array whose shape is a sum (``_N + 3``) is not
    a constant to it, and every kernel failed so with the simulator's tests passing.
    """
    from .conftest import PRESCRIBED

    path = name
    if name == "hand":
        path = tmp_path / "hand.toml"
        path.write_text(PRESCRIBED)
    env = {k: v for k, v in os.environ.items() if k not in ("NUMBA_ENABLE_CUDASIM", "JACKBOX_GPU_OUT_OF_LINE")} \
        | {"PYTHONWARNINGS": "ignore"}
    proc = subprocess.run([sys.executable, "-c", LOWERED, str(path)], capture_output=True, text=True, env=env,
                          timeout=1200)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    kept = out.pop("out_of_line")       # NVVM keeps the stages and the helpers called from many places out of line
    assert kept.pop("accel") == [False]                                 # (every stage calls accel: inlined)
    assert all(where in ([True], []) for where in kept.values()), kept         # ([]: not called in this kernel)
    assert kept["contact_rows"] == kept["lcp"] == kept["update_contacts"] == [True], kept
    assert out == {k: {"lowered": "NoneType", "allocates": False}
                   for k in ("members", "alone", "flying", "calming", "smallest_gaps", "twins")}


def test_numpy_without_row_stack_gets_the_alias_numba_cuda_registers(monkeypatch):
    """NumPy 2.5 removed ``row_stack``; numba-cuda 0.30 registers it when it first compiles or loads a kernel,
    and every kernel failed to load on a GPU machine with NumPy 2.5.2. jackbox puts the alias back before
    numba-cuda is used, and leaves a NumPy that has it alone."""
    from jackbox.engine import gpu

    own = getattr(np, "row_stack", None)
    gpu._cuda()
    assert getattr(np, "row_stack", None) is own
    monkeypatch.delattr(np, "row_stack", raising=False)
    gpu._cuda()
    assert np.row_stack is np.vstack


def test_the_check_of_the_final_states_takes_the_gpus_gaps_where_it_has_them():
    """A GPU study's final states are checked on the GPU (kernel smallest_gaps); the host reads the gaps: a
    member below -INSIDE_LIMIT L went through a wall unseen (status INSIDE, NaN), as api.inside says on the CPU;
    a NaN gap is not taken for a clear one."""
    from jackbox import api
    from jackbox.engine import DONE, INSIDE, NONFINITE
    from jackbox.ensemble import _unfinished
    from jackbox.scene import load_scene

    scene = load_scene("drop")
    L = scene.params()["L"]
    P = np.tile(scene.param_values, (4, 1))
    Q, QD = np.ones((4, 6)), np.ones((4, 6))
    status = np.array([DONE, DONE, DONE, NONFINITE])
    gaps = np.array([-0.5 * api.INSIDE_LIMIT * L, -2 * api.INSIDE_LIMIT * L, np.nan, -1.0])
    lost, inside = _unfinished(scene, status, Q, QD, P, gaps)
    assert list(inside) == [False, True, True, False] and list(lost) == [False, False, False, True]
    assert list(status) == [DONE, INSIDE, INSIDE, NONFINITE]
    assert np.isfinite(Q[0]).all() and np.isnan(Q[1:]).all() and np.isnan(QD[1:]).all()


def test_device_cuda_without_numba_cuda_says_what_to_install(monkeypatch):
    from jackbox import ensemble as ens
    from jackbox.engine import gpu

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "numba_cuda" else real(name, *a))
    why = gpu.unavailable()
    assert "numba-cuda" in why and "jackbox[cuda]" in why and "\n" not in why
    with pytest.raises(SimulationError, match="numba-cuda"):
        ens.ensemble("shaken", 2, t_end=0.01, device="cuda")


@pytest.mark.parametrize("kwargs, match", [
    ({"device": "gpu"}, "device must be 'cpu' or 'cuda'"),
    ({"device": "cuda", "dask_local": 2}, "not with a Dask"),
    ({"device": "cuda", "lanes": True}, "lanes are the CPU's"),
])
def test_bad_device_requests_are_refused_before_anything_runs(kwargs, match):
    from jackbox import ensemble as ens

    with pytest.raises(SimulationError, match=match):
        ens.ensemble("shaken", 2, t_end=0.01, **kwargs)


@needs_numba_cuda
def test_the_cli_without_a_gpu_says_so_in_one_line(tmp_path):
    from jackbox.engine import gpu

    env = {k: v for k, v in os.environ.items() if k != "NUMBA_ENABLE_CUDASIM"}
    if gpu.unavailable() is None and not gpu._simulated():
        pytest.skip("this machine has a GPU: the CLI runs there (test_a_real_gpu_gives_the_cpus_numbers)")
    proc = subprocess.run([sys.executable, "-m", "jackbox.cli", "ensemble", "shaken", "--n", "2", "--t-end", "0.01",
                           "--device", "cuda", "--out", str(tmp_path / "out")], capture_output=True, text=True,
                          env=env, timeout=600)
    assert proc.returncode != 0
    assert "Traceback" not in proc.stderr
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith("jackbox: error: device 'cuda'"), proc.stderr
    assert not (tmp_path / "out").exists()                 # nothing half-written


def _gpu_here() -> bool:
    if not HAS_NUMBA_CUDA or os.environ.get("NUMBA_ENABLE_CUDASIM", "0") not in ("", "0"):
        return False
    from jackbox.engine import gpu
    return gpu.unavailable() is None


@pytest.mark.skipif(not _gpu_here(), reason="no CUDA GPU here (the simulator test checks the GPU's code path)")
@pytest.mark.parametrize("rounds", [False, True], ids=["one-go", "rounds"])
@pytest.mark.parametrize("name, over", [("shaken", {}), ("drop", {"restitution": "0.6"}), ("spring", {})])
def test_a_real_gpu_gives_the_cpus_numbers(name, over, rounds, monkeypatch):
    from jackbox.engine import gpu
    from jackbox.ensemble import ensemble
    from jackbox.scene import load_scene

    monkeypatch.setattr(gpu, "ROUNDS", rounds)
    scene = load_scene(name, over)
    kw = dict(perturb={"theta_jack": 0.3}, t_end=1.0)
    a, b = ensemble(scene, 256, **kw), ensemble(scene, 256, device="cuda", **kw)
    assert np.array_equal(a.impacts, b.impacts) and np.array_equal(a.status, b.status)
    assert np.nanmax(np.abs(a.q - b.q)) <= 1e-10 and np.nanmax(np.abs(a.qd - b.qd)) <= 1e-10
