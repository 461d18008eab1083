"""Ensembles and chaos studies: members are the same numbers as single runs, whatever the split."""

from __future__ import annotations

import json

import numpy as np
import pytest

import jackbox
from jackbox import ensemble as E
from jackbox.errors import SimulationError

from .conftest import PRESCRIBED, run_cli, write_scene

PERTURB = {"theta_jack": 1e-3, "x_jack_dot": 1e-3}


@pytest.fixture(scope="module")
def shaken_ensemble():
    # 2.5 s: every member has its first impulses (near t = 1.07 s), some have more
    return E.ensemble("shaken", 24, perturb=PERTURB, t_end=2.5, seed=3, samples=[0.0, 1.0, 2.5])


def test_any_split_gives_the_same_numbers(shaken_ensemble):
    other = E.ensemble("shaken", 24, perturb=PERTURB, t_end=2.5, seed=3, samples=[0.0, 1.0, 2.5],
                       chunk=5, threads=1)
    for key in ("q", "qd", "energy", "impacts", "first_impact_t", "samples_q", "samples_qd", "q0", "params"):
        assert np.array_equal(getattr(shaken_ensemble, key), getattr(other, key), equal_nan=True), key
    # a sub-range run on its own gives the same members
    part = E.run_chunk(shaken_ensemble.spec, 10, 13)
    assert np.array_equal(part["q"], shaken_ensemble.q[10:13])


def test_members_are_single_runs(shaken_ensemble):
    ens = shaken_ensemble
    assert np.all(ens.status == 0) and np.all(ens.impacts > 0)
    for i in (0, 17):
        traj = ens.trajectory(i)
        # the same kernel from the same start: equal to the last bit
        assert np.array_equal(traj.q[-1], ens.q[i]) and np.array_equal(traj.qd[-1], ens.qd[i])
        assert len(traj.impact_t) == ens.impacts[i]
        assert traj.impact_t[0] == ens.first_impact_t[i]
        for k, t in enumerate(ens.sample_times):
            j = int(np.argmin(abs(traj.t - t)))
            assert traj.t[j] == pytest.approx(t, abs=1e-12)
            assert np.array_equal(traj.q[j], ens.samples_q[i, k]), (i, t)
        assert traj.energy[-1] == ens.energy[i]


def test_perturbations_are_seeded_and_bounded(shaken_ensemble):
    ens = shaken_ensemble
    base = jackbox.load_scene("shaken")
    dq, dqd = ens.q0 - base.q0, ens.qd0 - base.qd0
    assert np.all(np.abs(dq[:, 5]) <= 1e-3) and np.all(np.abs(dqd[:, 3]) <= 1e-3)
    assert np.all(dq[:, :5] == 0) and np.all(dqd[:, [0, 1, 2, 4, 5]] == 0)
    assert len(np.unique(dq[:, 5])) == ens.n                      # every member differs
    again, _, _ = E.member_inputs(ens.spec, 0, ens.n)
    assert np.array_equal(again, ens.q0)
    other = E.plan("shaken", 24, perturb=PERTURB, t_end=2.5, seed=4)
    assert not np.array_equal(E.member_inputs(other, 0, 24)[0], ens.q0)


def test_grid_perturbation_and_two_parameter_sweep():
    spec = E.plan("shaken", 9, perturb={"x_jack": 0.1, "y_jack": 0.2}, grid=True, t_end=0.01)
    q0, _, _ = E.member_inputs(spec, 0, 9)
    x = q0[:, 3] - 1.0
    y = q0[:, 4] - 1.5
    assert sorted(set(np.round(x, 12))) == pytest.approx([-0.1, 0.0, 0.1])
    assert sorted(set(np.round(y, 12))) == pytest.approx([-0.2, 0.0, 0.2])
    spec = E.plan("drop", 16, sweep={"restitution": (0.5, 1.0), "m_jack": (1.0, 4.0)}, t_end=0.01)
    _, _, P = E.member_inputs(spec, 0, 16)
    names = spec.scene.param_names
    e, eg, m = (P[:, names.index(k)] for k in ("e", "e_ground", "m_jack"))
    assert np.array_equal(e, eg)
    assert sorted(set(e)) == pytest.approx([0.5, 2 / 3, 5 / 6, 1.0])
    assert sorted(set(m)) == pytest.approx([1.0, 2.0, 3.0, 4.0])
    assert len({(a, b) for a, b in zip(e, m)}) == 16


def test_a_sweep_member_is_the_run_with_that_parameter():
    ens = E.ensemble("drop", 3, sweep={"restitution": (0.4, 1.0)}, t_end=1.0)
    for i, e in enumerate((0.4, 0.7, 1.0)):
        traj = jackbox.simulate("drop", t_end=1.0, params={"e": e, "e_ground": e})
        assert np.array_equal(traj.q[-1], ens.q[i]), e
        assert len(traj.impact_t) == ens.impacts[i]


def test_prescribed_box_members(tmp_path):
    scene = write_scene(tmp_path, PRESCRIBED)
    ens = E.ensemble(scene, 4, perturb={"theta_jack": 0.01}, t_end=0.5, seed=1)
    traj = ens.trajectory(2)
    assert np.array_equal(traj.q[-1], ens.q[2])          # box columns filled from its motion
    assert np.all(ens.q[:, 1] == ens.q[0, 1])


@pytest.mark.parametrize("kwargs, message", [
    ({"perturb": {"theta_box": 1e-3}}, "not a degree of freedom"),
    ({"perturb": {"spin": 1e-3}}, "unknown coordinate"),
    ({"perturb": {"x_jack": -1.0}}, ">= 0"),
    ({"perturb": {"x_jack": 0.1, "y_jack": 0.1}, "grid": True}, "n = m^2"),
    ({"sweep": {"mass": (1, 2)}}, "unknown parameter"),
    ({"sweep": {"restitution": (0.5, 1.5)}}, "[0, 1]"),
    ({"samples": [99.0]}, "between 0 and t_end"),
])
def test_bad_studies_are_refused(tmp_path, kwargs, message):
    scene = write_scene(tmp_path, PRESCRIBED)
    with pytest.raises(SimulationError, match=message.replace("[", r"\[").replace("^", r"\^")):
        E.ensemble(scene, 10, t_end=0.1, **kwargs)


def test_a_start_inside_a_wall_is_refused():
    # the cross's tips sit 4 m from the walls: a 5 m perturbation puts some inside
    with pytest.raises(SimulationError, match="into a wall"):
        E.ensemble("shaken", 20, perturb={"x_jack": 5.0}, t_end=0.1)


def test_chaos_of_free_flight_is_the_linear_growth():
    # Before the first impact (t ~ 1.07 s) every coordinate of shaken flies freely and the
    # forces depend on t only, so a twin's offset grows linearly: dq(t) = dq0 + dqd0 t,
    # dqd(t) = dqd0. Renormalising a linear flow does not change the product of the
    # stretches, so the logged growth must be log |S (dq0 + dqd0 t, dqd0)| / d0 exactly
    # (to the round-off of differencing states 1e-6 apart: ~1e-9 relative).
    study = E.chaos("shaken", 3, d0=1e-6, renorm=0.1, t_end=0.8, seed=2)
    assert np.all(study.status == 0) and np.all(study.impacts == 0)
    scale = E._chaos_scale(study.spec)
    for i in range(3):
        off = study.offset[i]
        dq0, dqd0 = off[:6], off[6:]
        for k, t in enumerate(study.times):
            expected = np.log(np.linalg.norm(np.r_[dq0 + dqd0 * t, dqd0] / scale) / study.spec.d0)
            assert study.growth[i, k] == pytest.approx(expected, abs=1e-7), (i, t)
    assert np.all(np.abs(study.ftle) < 1.0)


def test_chaos_shaken_separates_and_is_split_independent():
    one = E.chaos("shaken", 6, t_end=4.0, seed=5)
    two = E.chaos("shaken", 6, t_end=4.0, seed=5, chunk=4, threads=1)
    assert np.array_equal(one.stretch, two.stretch, equal_nan=True)
    # tumbling and bouncing: the twins separate by orders of magnitude in 4 s
    assert np.median(one.growth[:, -1]) > np.log(100.0)
    assert np.all(np.isfinite(one.ftle)) and np.median(one.ftle) > 1.0


def test_cli_ensemble_and_chaos(tmp_path, capsys):
    out = tmp_path / "out"
    status, stdout, stderr = run_cli(capsys, "ensemble", "shaken", "--n", "8", "--t-end", "0.5",
                                     "--perturb", "theta_jack=1e-6", "--samples", "0.25", "--out", str(out))
    assert status == 0, stderr
    assert "member-steps/s" in stdout
    data = np.load(out / "ensemble.npz")
    assert data["q"].shape == (8, 6) and data["samples_q"].shape == (8, 1, 6)
    assert json.loads(str(data["meta"]))["n"] == 8
    status, stdout, stderr = run_cli(capsys, "chaos", "shaken", "--n", "4", "--t-end", "0.5", "--out", str(out), "-q")
    assert status == 0, stderr
    assert (out / "chaos.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert np.load(out / "chaos.npz")["stretch"].shape[0] == 4


@pytest.mark.parametrize("args, message", [
    (["--perturb", "theta_jack"], "expected NAME=VALUE"),
    (["--sweep", "e=0.5"], "cannot read"),
    (["--perturb", "theta_jack=1e-6", "--workers", "2"], "--workers goes with --dask local"),
    (["--scheduler", "tcp://127.0.0.1:1", "--dask", "local"], "not allowed with"),
])
def test_cli_study_mistakes_are_one_line(tmp_path, capsys, args, message):
    status, _, stderr = run_cli(capsys, "ensemble", "shaken", "--n", "4", "--t-end", "0.1",
                                "--out", str(tmp_path / "o"), *args)
    assert status == 2
    assert message in stderr and "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_ensemble_runs_without_jit(tmp_path):
    # the prange loops as plain Python (NUMBA_DISABLE_JIT=1) give the compiled numbers
    import os
    import subprocess
    import sys

    code = ("import json; from jackbox import ensemble as E; "
            "e = E.ensemble('shaken', 2, perturb={'theta_jack': 1e-3}, t_end=0.3, samples=[0.1]); "
            "print(json.dumps([e.q.tolist(), e.samples_q.tolist()]))")
    env = os.environ | {"NUMBA_DISABLE_JIT": "1", "JACKBOX_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    q, samples = (np.array(a) for a in json.loads(out.stdout))
    jit = E.ensemble("shaken", 2, perturb={"theta_jack": 1e-3}, t_end=0.3, samples=[0.1])
    np.testing.assert_allclose(q, jit.q, rtol=0, atol=1e-12)
    np.testing.assert_allclose(samples, jit.samples_q, rtol=0, atol=1e-12)
