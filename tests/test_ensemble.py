"""Ensembles and chaos studies: members are the same numbers as single runs, whatever the split."""

from __future__ import annotations

import dataclasses
import json
import re

import numpy as np
import pytest

import jackbox
from jackbox import ensemble as E
from jackbox.errors import JackboxError, SimulationError

from .conftest import BUILTINS, PRESCRIBED, run_cli, write_scene

PERTURB = {"theta_jack": 1e-3, "x_jack_dot": 1e-3}


#: the study of the shaken_ensemble fixture (also run without JIT, in part)
SHAKEN_STUDY = dict(perturb=PERTURB, t_end=2.5, seed=3, samples=[0.0, 1.0, 2.5])
#: every array of one member that an Ensemble (and ensemble.npz) holds
MEMBER_ARRAYS = ("q", "qd", "energy", "impacts", "first_impact_t", "status", "steps", "samples_q",
                 "samples_qd", "q0", "qd0", "params")


def same_bits(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.fixture(scope="module")
def shaken_ensemble():
    # 2.5 s: every member has its first impulses (near t = 1.07 s) and more (three each)
    return E.ensemble("shaken", 24, **SHAKEN_STUDY)


def test_any_split_gives_the_same_numbers(shaken_ensemble):
    other = E.ensemble("shaken", 24, **SHAKEN_STUDY, chunk=5, threads=1)
    for key in MEMBER_ARRAYS:
        assert same_bits(getattr(shaken_ensemble, key), getattr(other, key)), key
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
            assert traj.t[j] == t           # both are step * dt: the same float
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


#: SplitMix64's finaliser and the chain of jackbox/engine/draws.py, in Python's integers: the reference
MASK = (1 << 64) - 1


def splitmix(z: int) -> int:
    z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) & MASK
    z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) & MASK
    return z ^ (z >> 31)


def reference_uniform(seed: int, member: int, stream: int, k: int) -> float:
    h = splitmix((seed + 0x9E3779B97F4A7C15) & MASK)
    for word in (member, stream, k):
        h = splitmix(((h ^ word) + 0x9E3779B97F4A7C15) & MASK)
    return (h >> 11) * 2.0 ** -52 - 1.0


def test_random_starts_are_the_documented_draws_and_look_uniform():
    # members' draws are a hash of (seed, member, stream, draw): a size of 1 on a coordinate and a
    # rate that start at 0 gives the draws themselves (0 + 1.0 * u, exactly)
    from jackbox.engine import draws

    n = 200_000
    spec = E.plan("shaken", n, perturb={"x_box": 1.0, "y_box_dot": 1.0}, t_end=0.01, seed=11)
    q0, qd0, _ = E.member_inputs(spec, 0, n)
    u = np.column_stack([q0[:, 0], qd0[:, 1]])
    for i in (0, 1, 12345, n - 1):
        for j in range(2):
            expected = reference_uniform(11, i, draws.START, j)
            assert u[i, j] == expected, (i, j)
            with np.errstate(over="ignore"):      # the plain-Python function (numpy's uint64 wraps)
                assert draws.draw_uniform.py_func(11, i, draws.START, j) == expected
    # in [-1, 1), multiples of 2^-52 (53 bits each), mean 0 and variance 1/3 to a few standard
    # errors (of the mean: sqrt(1/3 / n) = 1.3e-3; of the variance: sqrt(4/45 / n) = 6.7e-4),
    # flat in 20 bins (chi-square, 19 degrees of freedom: 60 is p < 1e-5), the columns uncorrelated
    assert u.min() >= -1.0 and u.max() < 1.0
    assert np.all(u * 2.0 ** 52 == np.round(u * 2.0 ** 52))
    assert np.all(np.abs(u.mean(axis=0)) < 5 * 1.3e-3)
    assert np.all(np.abs(u.var(axis=0) - 1 / 3) < 5 * 6.7e-4)
    for col in u.T:
        counts = np.histogram(col, bins=20, range=(-1, 1))[0]
        assert np.sum((counts - n / 20) ** 2 / (n / 20)) < 60
    assert abs(np.corrcoef(u.T)[0, 1]) < 5 / np.sqrt(n)
    assert len(np.unique(u[:, 0])) == n                   # no two members share a start
    # another seed, other draws
    other = E.member_inputs(E.plan("shaken", 1000, perturb={"x_box": 1.0}, t_end=0.01, seed=12), 0, 1000)[0]
    assert not np.any(other[:, 0] == u[:1000, 0])


def test_chaos_twins_point_in_normal_random_directions():
    # a twin's offset is d0 times a unit vector of standard normal draws (Box-Muller), scaled:
    # over many members each scaled component has mean 0 and variance 1 / (2 n_dof)
    spec = E.plan("shaken", 20_000, t_end=0.5, seed=4)
    spec = dataclasses.replace(spec, renorm_steps=100, d0=1e-8)
    rows = E._set_up(spec, E._kernel(spec), 0, spec.n)
    unit = rows["offset"] / E._chaos_scale(spec) / 1e-8
    np.testing.assert_allclose(np.linalg.norm(unit, axis=1), 1.0, rtol=1e-14)
    # standard errors: of the mean sqrt(1/12 / n) = 2e-3, of the variance ~ sqrt(2) / 12 / sqrt(n) = 8e-4
    assert np.all(np.abs(unit.mean(axis=0)) < 5 * 2e-3)
    assert np.all(np.abs(unit.var(axis=0) - 1 / 12) < 5 * 8e-4)
    # the direction is uniform on the sphere: its components are uncorrelated
    c = np.corrcoef(unit.T) - np.eye(12)
    assert np.abs(c).max() < 5 / np.sqrt(spec.n)


def test_any_split_sets_members_up_the_same():
    # a member's setup depends on (seed, i) alone: chunks of any size give the same rows as the
    # whole, chaos twins' offsets included
    spec = E.plan("shaken", 50, perturb=PERTURB, sweep={"A": (200.0, 400.0)}, t_end=0.5, seed=9)
    spec = dataclasses.replace(spec, renorm_steps=100, d0=1e-8)
    kernel = E._kernel(spec)
    whole = E._set_up(spec, kernel, 0, 50)
    for bounds in ([(0, 7), (7, 8), (8, 50)], [(a, min(a + 13, 50)) for a in range(0, 50, 13)]):
        parts = [E._set_up(spec, kernel, a, b) for a, b in bounds]
        for key in whole:
            assert same_bits(np.concatenate([p[key] for p in parts]), whole[key]), (bounds, key)


def test_member_tolerances_are_those_of_the_single_run(tmp_path):
    # every member's tolerance row equals api.tolerances for its single run, to the bit: the
    # shared row, swept sizes (L, the jack's, the box's wall), g (its speed scale), and for a
    # prescribed box a sweep that moves it (amp: one speed bound over the swept range, which the
    # member's single run, E.member_run, takes too) and one that does not (e: the shared bound kept)
    from jackbox import api

    hand = write_scene(tmp_path, PRESCRIBED)
    # (scene, sweep, perturb, whether the rows differ)
    cases = [("shaken", {}, PERTURB, False), ("shaken", {"L": (4.5, 6.0), "a_jack": (0.5, 1.2)}, {}, True),
             ("shaken", {"g": (0.0, 20.0)}, {}, True), ("drop", {"w_box": (0.05, 0.3)}, {}, True),
             ("spring", {"a_jack": (0.1, 0.3)}, {}, True), (hand, {"amp": (0.1, 0.5)}, {}, False),
             (hand, {"restitution": (0.5, 1.0)}, {"theta_jack": 0.01}, False),
             (hand, {"jack_x0": (0.25, 0.35)}, {}, True)]
    for scene, sweep, perturb, differ in cases:
        n = 16 if len(sweep) == 2 else 5
        # (a polygon's vertex is swept with its inertia fixed: the scene derives it from the vertices)
        fixed = {"J_jack": jackbox.load_scene(scene).params()["J_jack"]} if "jack_x0" in sweep else None
        spec = E.plan(scene, n, sweep=sweep, perturb=perturb, params=fixed, t_end=0.3)
        kernel = E._kernel(spec)
        rows = E._set_up(spec, kernel, 0, n)
        for i in range(n):
            run = E.member_run(spec, i)
            assert same_bits(run.p, rows["params"][i])
            expected = api.tolerances(run, kernel)
            assert same_bits(rows["tol"][i], expected), (scene, sweep, i)
        assert (len({r.tobytes() for r in rows["tol"]}) > 1) == differ, (scene, sweep)


def test_the_engine_reads_the_parameter_slots_of_the_scene():
    from jackbox.engine import tolerances as T
    from jackbox.scene import BASE_PARAMS

    assert [BASE_PARAMS[i] for i in (T.L_AT, T.W_BOX_AT, T.G_AT)] == ["L", "w_box", "g"]
    assert T.JACK_AT == len(BASE_PARAMS)
    for name in BUILTINS:
        names = jackbox.load_scene(name).param_names
        assert names[T.JACK_AT] in ("a_jack", "jack_x0")


def test_grid_perturbation_and_two_parameter_sweep():
    spec = E.plan("shaken", 9, perturb={"x_jack": 0.1, "y_jack": 0.2}, grid=True, t_end=0.01)
    q0, _, _ = E.member_inputs(spec, 0, 9)
    x = q0[:, 3] - 1.0
    y = q0[:, 4] - 1.5
    # start + size * u, u in {-1, 0, 1} exactly, then minus the start: the rounding of the
    # sum (half an ulp of 1.5: measured 9e-17) and no more
    ulp = np.spacing(1.5)
    np.testing.assert_allclose(np.unique(x), [-0.1, 0.0, 0.1], rtol=0, atol=ulp)
    np.testing.assert_allclose(np.unique(y), [-0.2, 0.0, 0.2], rtol=0, atol=ulp)
    # exactly start + size * (2 k / (side - 1) - 1), the first coordinate the slower (numpy's C order)
    u = 2.0 * np.array([[a, b] for a in range(3) for b in range(3)]) / 2 - 1.0
    assert same_bits(q0[:, 3], 1.0 + 0.1 * u[:, 0]) and same_bits(q0[:, 4], 1.5 + 0.2 * u[:, 1])
    spec = E.plan("drop", 16, sweep={"restitution": (0.5, 1.0), "m_jack": (1.0, 4.0)}, t_end=0.01)
    _, _, P = E.member_inputs(spec, 0, 16)
    names = spec.scene.param_names
    e, eg, m = (P[:, names.index(k)] for k in ("e", "e_ground", "m_jack"))
    assert np.array_equal(e, eg)
    # lo + (hi - lo) * k / 3: measured 1.1e-16 from the exact values (5/6), one ulp of 1
    np.testing.assert_allclose(np.unique(e), [0.5, 2 / 3, 5 / 6, 1.0], rtol=0, atol=np.spacing(1.0))
    np.testing.assert_array_equal(np.unique(m), [1.0, 2.0, 3.0, 4.0])
    assert len({(a, b) for a, b in zip(e, m)}) == 16
    # exactly lo + (hi - lo) * k / (side - 1), restitution the slower axis
    k = np.arange(16)
    assert same_bits(e, 0.5 + (1.0 - 0.5) * (k // 4) / 3) and same_bits(m, 1.0 + (4.0 - 1.0) * (k % 4) / 3)
    # one parameter: spread over all the members
    spec = E.plan("drop", 7, sweep={"m_jack": (0.3, 2.9)}, t_end=0.01)
    P = E.member_inputs(spec, 0, 7)[2][:, names.index("m_jack")]
    assert same_bits(P, 0.3 + (2.9 - 0.3) * np.arange(7) / 6)


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
    # a sweep that moves the box: one speed bound over the swept range, which each member's single run
    # (ens.trajectory) takes too
    ens = E.ensemble(scene, 3, sweep={"amp": (0.1, 0.5)}, perturb={"theta_jack": 0.01}, t_end=0.5, seed=1)
    for i in range(3):
        traj = ens.trajectory(i)
        assert np.array_equal(traj.q[-1], ens.q[i]) and len(traj.impact_t) == ens.impacts[i]


@pytest.mark.parametrize("kwargs, message", [
    ({"perturb": {"theta_box": 1e-3}}, "not a degree of freedom"),
    ({"perturb": {"spin": 1e-3}}, "unknown coordinate"),
    ({"perturb": {"x_jack": -1.0}}, ">= 0"),
    ({"perturb": {"x_jack": 0.1, "y_jack": 0.1}, "grid": True}, "n = m^2"),
    ({"sweep": {"mass": (1, 2)}}, "unknown parameter"),
    ({"sweep": {"restitution": (0.5, 1.5)}}, "[0, 1]"),
    ({"sweep": {"e": (0.5, 1.0)}, "params": {"restitution": 0.5}}, "e is given both in params and in the sweep"),
    ({"samples": [99.0]}, "between 0 and t_end"),
    ({"seed": 2**63}, "seed must be an integer from 0 to 2^63 - 1"),
    ({"seed": -1}, "seed must be"),
])
def test_bad_studies_are_refused(tmp_path, kwargs, message):
    # refused before anything runs, with an error the CLI prints as one line (a JackboxError:
    # SimulationError for the study's own arguments, SceneError for a swept value that breaks
    # the scene format's rules)
    scene = write_scene(tmp_path, PRESCRIBED)
    with pytest.raises(JackboxError, match=message.replace("[", r"\[").replace("^", r"\^")) as info:
        E.ensemble(scene, 10, t_end=0.1, **kwargs)
    assert "\n" not in str(info.value)


def test_a_start_inside_a_wall_is_refused(monkeypatch):
    """Refused before any member runs (each member's setup, in parallel, measures its start's gap),
    in one line naming the first such member and how deep it is, by the scene checker's geometry."""
    from jackbox.loader import Kernel
    from jackbox.scene import contact_gaps

    def no_run(*args):
        raise AssertionError("a member ran")

    monkeypatch.setattr(Kernel, "run_members", no_run)
    monkeypatch.setattr(Kernel, "run_twin_members", no_run)
    scene = jackbox.load_scene("shaken")

    def first_inside(starts, sizes):
        worst = np.array([contact_gaps(q, scene.points * a, 5.0, 0.5, False).min() for q, a in zip(starts, sizes)])
        i = int(np.flatnonzero(worst < 0)[0])
        return i, -worst[i]

    # the cross's tips sit about 3 m from the walls: a 5 m perturbation puts some inside
    spec = E.plan("shaken", 20, perturb={"x_jack": 5.0}, t_end=0.1)
    i, depth = first_inside(E.member_inputs(spec, 0, 20)[0], np.ones(20))
    for study in (E.ensemble, E.chaos):
        with pytest.raises(SimulationError, match=rf"member {i}'s perturbed start reaches {depth:.3g} into a wall "
                                                  ".*use smaller perturbations$") as info:
            study("shaken", 20, perturb={"x_jack": 5.0}, t_end=0.1)
        assert "\n" not in str(info.value)
    # a sweep of the jack's size (arms 1 to 6 m, the centre 3.5 m from the top wall)
    sizes = np.linspace(1.0, 6.0, 11)
    i, depth = first_inside([scene.q0] * 11, sizes)
    assert 0 < i < 10
    with pytest.raises(SimulationError, match=rf"member {i}'s start reaches {depth:.3g} into a wall .*narrow the sweep$"):
        E.ensemble("shaken", 11, sweep={"a_jack": (1.0, 6.0)}, t_end=0.1)


@pytest.mark.parametrize("name", ["shaken", "drop"])
def test_final_states_inside_a_wall_are_found_in_every_block(name, monkeypatch):
    """api.inside checks the final states of a study in blocks (1e6 at once took a second): its verdict on
    each state is the one-state geometry's (scene.contact_gaps, every gap and the ground's), whatever block the
    state falls in, each member with its own jack size."""
    from jackbox import api
    from jackbox.scene import contact_gaps

    monkeypatch.setattr(api, "INSIDE_BLOCK", 7)        # blocks of 7: 100 states end in a short one
    scene = jackbox.load_scene(name)
    rng = np.random.default_rng(3)
    n = 100
    P = {k: np.full(n, v) for k, v in zip(scene.param_names, scene.param_values)}
    Q = scene.q0 + rng.normal(0.0, 1.0, (n, 6)) * np.array([0.2, 0.2, 0.0, 0.6, 0.6, 0.0]) * P["L"][0] \
        + rng.normal(0.0, 1.0, (n, 6)) * np.array([0.0, 0.0, 0.5, 0.0, 0.0, 1.5])
    for key in ("a_jack", "L", "w_box"):               # each member its own jack, box and wall
        P[key] = P[key] * rng.uniform(0.7, 1.3, n)
    points = scene.points / scene.param_values[scene.param_names.index("a_jack")]       # (a jack of size 1)
    want = np.array([contact_gaps(q, points * a, L, w, scene.has_ground_contacts).min() < -api.INSIDE_LIMIT * L
                     for q, a, L, w in zip(Q, P["a_jack"], P["L"], P["w_box"])])
    assert 10 < want.sum() < n - 10                   # both kinds, in many blocks
    np.testing.assert_array_equal(api.inside(scene, Q, P), want)


def test_chaos_of_free_flight_is_the_linear_growth():
    # Before the first impact (t ~ 1.07 s) every coordinate of shaken flies freely and the
    # forces depend on t only, so a twin's offset grows linearly: dq(t) = dq0 + dqd0 t,
    # dqd(t) = dqd0. Renormalising a linear flow does not change the product of the
    # stretches, so the logged growth must be log |S (dq0 + dqd0 t, dqd0)| / d0 exactly,
    # up to round-off: each RK4 step of either twin rounds its state at ~1e-16 of |q| ~ 1,
    # which is ~1e-10 of the scaled separation d0 = 1e-6; a random walk over 100 steps per
    # interval, summed over the intervals. Measured: 5.9e-9 at worst (3 members x 8 times;
    # it scales as 1/d0: 8e-7 at d0 = 1e-8, 5e-10 at 1e-5, so it is round-off). 2e-8 is ~3x.
    study = E.chaos("shaken", 3, d0=1e-6, renorm=0.1, t_end=0.8, seed=2)
    assert np.all(study.status == 0) and np.all(study.impacts == 0)
    np.testing.assert_allclose(study.times, 0.1 * np.arange(1, 9), rtol=1e-15)
    # the README's scaling: coordinates by L = 5 (angles by 1 rad), rates by sqrt(g L)
    L, v = 5.0, np.sqrt(9.81 * 5.0)
    scale = np.array([L, L, 1.0, L, L, 1.0, v, v, v / L, v, v, v / L])
    np.testing.assert_allclose(np.linalg.norm(study.offset / scale, axis=1), 1e-6, rtol=1e-15)
    for i in range(3):
        off = study.offset[i]
        dq0, dqd0 = off[:6], off[6:]
        for k, t in enumerate(study.times):
            expected = np.log(np.linalg.norm(np.r_[dq0 + dqd0 * t, dqd0] / scale) / 1e-6)
            assert study.growth[i, k] == pytest.approx(expected, abs=2e-8), (i, t)
    assert np.all(np.abs(study.ftle) < 1.0)


def test_chaos_shaken_separates_and_is_split_independent():
    one = E.chaos("shaken", 6, t_end=4.0, seed=5)
    two = E.chaos("shaken", 6, t_end=4.0, seed=5, chunk=4, threads=1)
    assert np.array_equal(one.stretch, two.stretch, equal_nan=True)
    # tumbling and bouncing: the twins separate by orders of magnitude in 4 s
    assert np.median(one.growth[:, -1]) > np.log(100.0)
    assert np.all(np.isfinite(one.ftle)) and np.median(one.ftle) > 1.0


def test_cli_ensemble_writes_the_api_numbers(tmp_path, capsys):
    out = tmp_path / "out"
    status, stdout, stderr = run_cli(capsys, "ensemble", "shaken", "--n", "8", "--t-end", "1.5", "--seed", "7",
                                     "--perturb", "theta_jack=1e-3", "--perturb", "x_jack_dot=0.1",
                                     "--samples", "0.25", "1.2", "--out", str(out))
    assert status == 0, stderr
    api = E.ensemble("shaken", 8, perturb={"theta_jack": 1e-3, "x_jack_dot": 0.1}, t_end=1.5, seed=7,
                     samples=[0.25, 1.2])
    assert np.all(api.status == 0) and np.all(api.impacts > 0)      # 1.5 s: past the first impulses
    with np.load(out / "ensemble.npz") as data:
        for key in MEMBER_ARRAYS:                     # the same members: to the bit
            assert same_bits(data[key], getattr(api, key)), key
        assert np.array_equal(data["sample_t"], [0.25, 1.2])
        meta = json.loads(str(data["meta"]))
    assert (meta["n"], meta["seed"], meta["dt"], meta["t_end"]) == (8, 7, 1e-3, 1.5)
    assert meta["perturb"] == {"theta_jack": 1e-3, "x_jack_dot": 0.1}
    # the printed summary, against numpy over the API's arrays
    assert "shaken: 8 members over 1.5 s (dt 0.001, 1500 steps each)" in stdout
    m = re.search(r"impulses per member: median (\S+), range (\d+)\.\.(\d+)", stdout)
    assert m, stdout
    assert abs(float(m[1]) - np.median(api.impacts)) <= 0.5            # printed as a whole number
    assert (int(m[2]), int(m[3])) == (api.impacts.min(), api.impacts.max())
    m = re.search(r"first impulse: (\d+) members, median t = (\S+) s", stdout)
    assert m, stdout
    assert int(m[1]) == np.isfinite(api.first_impact_t).sum() == 8
    assert float(m[2]) == pytest.approx(np.median(api.first_impact_t), rel=5e-4)   # 4 digits
    assert "stopped early" not in stdout
    assert f"wrote      {out / 'ensemble.npz'}" in stdout


def printed_ftle(stdout: str) -> dict[str, float]:
    m = re.search(r"FTLE: mean (\S+) 1/s, std (\S+), median (\S+) \(10-90%: (\S+)\.\.(\S+)\)", stdout)
    assert m, stdout
    return dict(zip(("mean", "std", "median", "p10", "p90"), map(float, m.groups())))


def assert_ftle_statistics(stdout: str, ftle: np.ndarray):
    """The FTLE line equals numpy's statistics of `ftle` (finite members), to its printed digits."""
    f = ftle[np.isfinite(ftle)]
    got = printed_ftle(stdout)
    # printed with 4 significant digits (std with 3): half a unit of the last digit is at
    # most 5e-4 (5e-3) of the value
    assert got["mean"] == pytest.approx(np.mean(f), rel=5e-4)
    assert got["std"] == pytest.approx(np.std(f, ddof=1), rel=5e-3)     # the sample standard deviation
    assert got["median"] == pytest.approx(np.median(f), rel=5e-4)
    p10, p90 = np.percentile(f, [10, 90])
    assert got["p10"] == pytest.approx(p10, rel=5e-4)
    assert got["p90"] == pytest.approx(p90, rel=5e-4)


CHAOS_ARRAYS = ("times", "stretch", "growth", "ftle", "impacts", "status", "steps", "q", "qd", "q0", "qd0", "params", "offset")


def test_cli_chaos_with_perturb_and_sweep(tmp_path, capsys):
    out = tmp_path / "out"
    status, stdout, stderr = run_cli(capsys, "chaos", "shaken", "--n", "6", "--t-end", "3", "--seed", "2",
                                     "--perturb", "theta_jack=1e-3", "--sweep", "A=200:400", "--d0", "1e-7",
                                     "--renorm", "0.2", "--out", str(out))
    assert status == 0, stderr
    api = E.chaos("shaken", 6, d0=1e-7, renorm=0.2, perturb={"theta_jack": 1e-3}, sweep={"A": (200.0, 400.0)},
                  t_end=3.0, seed=2)
    assert np.all(api.status == 0) and np.all(api.impacts > 0)
    with np.load(out / "chaos.npz") as data:
        for key in CHAOS_ARRAYS:
            assert same_bits(data[key], getattr(api, key)), key
        meta = json.loads(str(data["meta"]))
    assert (meta["d0"], meta["renorm_steps"], meta["sweep"]) == (1e-7, 200, {"A": [200.0, 400.0]})
    assert (out / "chaos.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # what the study is, from its definition: A spread evenly, theta_jack perturbed by up to
    # 1e-3, the rest of the start shared; growth the running sum of the stretches, the FTLE
    # their sum over t_end
    base = jackbox.load_scene("shaken")
    A = api.params[:, base.param_names.index("A")]
    np.testing.assert_allclose(A, np.linspace(200.0, 400.0, 6), rtol=1e-15)
    dq = api.q0 - base.q0
    assert np.all(np.abs(dq[:, 5]) <= 1e-3) and len(np.unique(dq[:, 5])) == 6 and np.all(dq[:, :5] == 0)
    assert np.all(api.qd0 == base.qd0)
    np.testing.assert_allclose(api.growth, np.cumsum(api.stretch, axis=1), rtol=1e-15, atol=0)
    np.testing.assert_allclose(api.ftle, api.stretch.sum(axis=1) / 3.0, rtol=1e-14, atol=0)
    # the printed statistics are numpy's over study.ftle
    assert "shaken: 6 twin pairs over 3 s, d0 = 1e-07, renormalised every 0.2 s" in stdout
    assert np.all(np.isfinite(api.ftle))
    assert_ftle_statistics(stdout, api.ftle)


def test_cli_chaos_without_perturb_shares_the_start(tmp_path, capsys):
    out = tmp_path / "out"
    status, stdout, stderr = run_cli(capsys, "chaos", "shaken", "--n", "4", "--t-end", "0.5", "--out", str(out), "-q")
    assert status == 0 and stdout == "", stderr
    api = E.chaos("shaken", 4, t_end=0.5)
    with np.load(out / "chaos.npz") as data:
        for key in CHAOS_ARRAYS:
            assert same_bits(data[key], getattr(api, key)), key
    # README: without --perturb the members share one start and differ by their twin's direction
    base = jackbox.load_scene("shaken")
    assert np.all(api.q0 == base.q0) and np.all(api.qd0 == base.qd0)
    assert len({tuple(o) for o in api.offset}) == 4


#: shaken turned into the old stall of tests/test_stress.py (a box spinning at 10 rad/s with a
#: light jack inside: it stopped with STALLED at t = 0.543 s until the contact engine's fallback
#: took such steps), with the shaking off: A = tau = 0, no gravity
SPINNING = {"box.inner_half_width": "1.0", "box.wall_thickness": "0.1", "box.mass": "1000", "jack.mass": "0.01",
            "jack.half_size": "0.1", "restitution": "0.5", "gravity": "0", "A": "0", "tau": "0",
            "initial.q": "[0, 0, 0, -0.5, 0, 0.3]", "initial.qd": "[0, 0, 10, 0, -5, 10]"}


def test_members_that_stop_early_have_the_status_of_their_single_run():
    """A member whose state turns non-finite, or that stalls, is kept with its status and the
    step it reached, which are what jackbox.simulate says about the same run; the summary
    counts them.

    T = 1e-310 puts sin(2 pi t / T) at sin(inf) = NaN within a few steps: non-finite (A = 0
    does not help, 0 * NaN is NaN). T = 3 with e = 0.5 stalled once (the old bug above); now
    it must be done, like its single run, and say how long its fallback ran.
    """
    scene = jackbox.load_scene("shaken", SPINNING)
    ens = E.ensemble(scene, 4, sweep={"T": (1e-310, 3.0), "restitution": (0.5, 1.0)}, t_end=1.0)
    names = scene.param_names
    T, e = (ens.params[:, names.index(k)] for k in ("T", "e"))
    assert np.array_equal(T, [1e-310, 1e-310, 3.0, 3.0]) and np.array_equal(e, [0.5, 1.0, 0.5, 1.0])
    assert np.array_equal(ens.status[:2], [2, 2])        # non-finite by construction
    assert np.array_equal(ens.status[2:], [0, 0])
    for i in range(4):
        try:
            traj = jackbox.simulate(scene, t_end=1.0, params={"T": T[i], "e": e[i], "e_ground": e[i]})
        except jackbox.NonFiniteStateError as err:
            step = int(re.search(r"non-finite at step (\d+)", str(err))[1])
            assert (ens.status[i], ens.steps[i]) == (2, step), (i, str(err))
            assert np.isnan(ens.first_impact_t[i]) == (ens.impacts[i] == 0)
        else:
            assert (ens.status[i], ens.steps[i]) == (0, 1000), i
            assert np.array_equal(traj.q[-1], ens.q[i]) and len(traj.impact_t) == ens.impacts[i]
            assert traj.fallback_seconds == pytest.approx(ens.fallback[i], abs=1e-12)
    # the summary says how many did not complete, and why: one line with the count of each kind
    # and their total
    counts = {"non-finite": int(np.sum(ens.status == 2)), "stalled": int(np.sum(ens.status == 3))}
    named = [line for line in ens.summary().splitlines()
             if all(re.search(rf"\b{k} {why}\b", line) for why, k in counts.items() if k)]
    assert len(named) == 1, ens.summary()
    assert re.search(rf"\b{sum(counts.values())}\b", named[0].split("non-finite")[0]), named
    m = re.search(r"first impulse: (\d+) members", ens.summary())
    assert m and int(m[1]) == np.isfinite(ens.first_impact_t).sum()


@pytest.mark.parametrize("lanes", [False, True])
def test_a_chaos_reference_ends_where_the_ensemble_member_ends(lanes):
    # the reference of each pair is the member itself, never moved by its twin's renormalisations:
    # its final state (the one the study checks for a pair that went through a wall) is the
    # ensemble's, to the bit, alone and in lanes, across a split of the study
    study = dict(t_end=1.5, seed=4, perturb={"theta_jack": 1e-3, "x_jack_dot": 0.1}, lanes=lanes)
    pairs = E.chaos("shaken", 20, renorm=0.05, chunk=7, **study)
    members = E.ensemble("shaken", 20, **study)
    assert np.all(pairs.status == 0) and np.all(members.impacts > 0)
    assert same_bits(pairs.q, members.q) and same_bits(pairs.qd, members.qd)
    assert same_bits(pairs.impacts, members.impacts)


def test_a_chaos_reference_of_a_prescribed_box_ends_where_the_ensemble_member_ends(tmp_path):
    # the box's coordinates from its motion, as the ensemble's (the first version wrote the integrated
    # coordinates only, and the study's wall check failed on them with an IndexError)
    scene = write_scene(tmp_path, PRESCRIBED)
    study = dict(t_end=1.0, seed=2, perturb={"theta_jack": 1e-2})
    pairs = E.chaos(scene, 6, renorm=0.1, **study)
    members = E.ensemble(scene, 6, **study)
    assert pairs.q.shape == (6, 6) and np.all(pairs.status == 0)
    assert same_bits(pairs.q, members.q) and same_bits(pairs.qd, members.qd)


def test_chaos_members_that_stop_early_have_no_ftle():
    # member 0 turns non-finite (T = 1e-310, see above): no FTLE (NaN, docs/scenes.md), no
    # stretch after it stopped, and the printed statistics (the summary that jackbox chaos
    # prints) are over the other three
    study = E.chaos("shaken", 4, sweep={"T": (1e-310, 3.0)}, t_end=2.0)
    assert np.array_equal(study.status, [2, 0, 0, 0])
    assert np.isnan(study.ftle[0]) and np.all(np.isfinite(study.ftle[1:]))
    assert np.all(np.isnan(study.stretch[0]))             # it stopped in its first interval
    assert np.all(np.isfinite(study.stretch[1:]))
    assert_ftle_statistics(study.summary(), study.ftle)


@pytest.mark.parametrize("args, message", [
    (["--perturb", "theta_jack"], "expected NAME=VALUE"),
    (["--sweep", "e=0.5"], "cannot read '0.5' (expected LOW:HIGH"),
    (["--perturb", "theta_jack=small"], "cannot read 'small' (expected a number)"),
    (["--perturb", "theta_jack=1e-6", "--workers", "2"], "--workers goes with --dask local"),
    (["--scheduler", "tcp://127.0.0.1:1", "--dask", "local"], "not allowed with"),
])
def test_cli_study_mistakes_are_one_line(tmp_path, capsys, args, message):
    status, _, stderr = run_cli(capsys, "ensemble", "shaken", "--n", "4", "--t-end", "0.1",
                                "--out", str(tmp_path / "o"), *args)
    assert status == 2
    assert message in stderr and "Traceback" not in stderr and len(stderr.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_ensemble_runs_without_jit(tmp_path, shaken_ensemble):
    # The prange loop as plain Python (NUMBA_DISABLE_JIT=1) gives the compiled numbers: members
    # 0..2 of the fixture's study, through their three impulses each (from t = 1.07 s on), in
    # about a second. The same operations in the same order (no fastmath, no FMA
    # contraction), as test_kernel's check of the single-run loop: to the bit.
    import os
    import subprocess
    import sys

    code = ("import json, numba; from jackbox import ensemble as E; "
            f"spec = E.plan('shaken', 24, **{SHAKEN_STUDY!r}); r = E.run_chunk(spec, 0, 3); "
            "print(json.dumps([numba.config.DISABLE_JIT, {k: v.tolist() for k, v in r.items()}]))")
    env = os.environ | {"NUMBA_DISABLE_JIT": "1", "JACKBOX_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    disabled, plain = json.loads(out.stdout)
    assert disabled
    assert min(plain["impacts"]) >= 3
    for key in MEMBER_ARRAYS:
        jit = getattr(shaken_ensemble, key)[:3]
        assert same_bits(np.array(plain[key], dtype=jit.dtype), jit), key
