"""Values a user can give through the API that used to slip past: they are refused, or mean what they say.

Each case was found by trying the API as a user would (2026-11-26): a
parameter set through ``params`` or a sweep left the inertia the scene file
derives from it unchanged (other physics than ``--set`` gives), a
division by zero in the model's terms escaped the compiled code as a raw
``ZeroDivisionError`` (and lost a whole ensemble), a parameter swept under
two names silently lost one of them, and chaos twins closer than round-off
gave exponents of nothing.
"""

import re

import numpy as np
import pytest

import jackbox
from jackbox.engine import DONE, NONFINITE
from jackbox.ensemble import chaos, ensemble
from jackbox.errors import NonFiniteStateError, RunStoppedError, SimulationError

from .conftest import PRESCRIBED, run_cli, write_scene


@pytest.mark.parametrize("overrides, params", [
    ({"box.mass": 100.0, "jack.half_size": 0.3}, {"m_box": 100.0, "a_jack": 0.3}),
    ({"box.wall_thickness": 0.2}, {"w_box": 0.2}),
    ({"jack.mass": 2.0}, {"m_jack": 2.0}),
])
def test_params_move_the_inertias_the_scene_derives_as_the_scene_file_does(overrides, params):
    # drop gives neither box.inertia nor jack.inertia: both follow the masses and sizes
    by_file = jackbox.simulate(jackbox.load_scene("drop", overrides), t_end=0.3, record_every=10)
    by_params = jackbox.simulate("drop", t_end=0.3, params=params, record_every=10)
    base = jackbox.load_scene("drop").params()
    moved = {k for k in ("J_box", "J_jack") if by_file.meta["params"][k] != base[k]}
    assert moved                                         # the case changes a derived inertia
    for k in moved:
        assert by_params.meta["params"][k] == by_file.meta["params"][k]
    assert np.array_equal(by_params.q, by_file.q) and np.array_equal(by_params.energy, by_file.energy)


def test_an_inertia_given_with_the_mass_stays_as_given():
    traj = jackbox.simulate("drop", t_end=0.05, params={"m_box": 100.0, "J_box": 3.0})
    assert traj.meta["params"]["J_box"] == 3.0 and traj.meta["params"]["m_box"] == 100.0


@pytest.mark.parametrize("scene, name, lo, hi, fixed", [
    ("drop", "m_jack", 1.0, 3.0, {}),
    ("drop", "m_box", 1.0, 3.0, {}),
    ("shaken", "a_jack", 0.2, 0.3, {}),
    ("drop", "m_jack", 1.0, 3.0, {"J_jack": 0.05}),       # the inertia fixed on purpose: it stays
])
def test_a_swept_mass_or_size_moves_its_derived_inertia_member_by_member(scene, name, lo, hi, fixed):
    ens = ensemble(scene, 3, sweep={name: (lo, hi)}, params=fixed, t_end=0.3)
    for i, value in enumerate(np.linspace(lo, hi, 3)):
        alone = jackbox.simulate(scene, t_end=0.3, params={name: float(value), **fixed})
        assert np.array_equal(alone.q[-1], ens.q[i]), (name, value)
        assert len(alone.impact_t) == ens.impacts[i]


@pytest.mark.parametrize("kwargs, match", [
    ({"sweep": {"e": (0.1, 1.0), "restitution": (0.2, 0.3)}}, r"'e' and 'restitution' both set e"),
    ({"sweep": {"e": (0.1, 1.0)}, "params": {"e": 0.3}}, r"e is given both in params and in the sweep"),
])
def test_a_parameter_set_twice_is_refused(kwargs, match):
    for study in (ensemble, chaos):
        with pytest.raises(SimulationError, match=match):
            study("drop", 4, t_end=0.05, **kwargs)


def test_a_division_by_zero_in_the_model_is_a_non_finite_state_not_an_exception():
    # shaken's force is A sin(2 pi t / T): T = 0 divides by zero in the compiled terms
    with pytest.raises(NonFiniteStateError, match="non-finite"):
        jackbox.simulate("shaken", t_end=0.01, params={"T": 0.0})
    ens = ensemble("shaken", 3, sweep={"T": (-1.0, 1.0)}, t_end=0.01, lanes=False)
    assert list(ens.status) == [DONE, NONFINITE, DONE]
    assert np.isnan(ens.q[1]).all() and np.isfinite(ens.q[[0, 2]]).all()


def test_chaos_refuses_twins_closer_than_round_off():
    with pytest.raises(SimulationError, match="d0 must be .* from 1e-12"):
        chaos("drop", 2, d0=1e-20, t_end=0.05)
    study = chaos("drop", 2, d0=1e-12, t_end=0.05)
    assert np.all(study.status == DONE)


def test_a_chaos_study_shorter_than_the_default_interval_renormalises_at_its_end():
    # (the default interval, 100 steps, was refused for t_end < 100 dt with "got None")
    study = chaos("drop", 2, t_end=0.05)
    assert study.stretch.shape == (2, 1) and np.all(study.status == DONE)
    assert study.times[-1] == pytest.approx(0.05)


def test_a_polygons_vertex_is_swept_only_with_its_inertia_fixed(tmp_path):
    scene = write_scene(tmp_path, PRESCRIBED)          # a polygon jack, its inertia derived
    for name, rng in (("jack_x0", (0.25, 0.35)), ("m_jack", (1.0, 2.0))):
        with pytest.raises(SimulationError, match="derives from the polygon: give jack.inertia"):
            ensemble(scene, 3, sweep={name: rng}, t_end=0.05)
    fixed = {"J_jack": jackbox.load_scene(scene).params()["J_jack"]}
    assert np.all(ensemble(scene, 3, sweep={"jack_x0": (0.25, 0.35)}, params=fixed, t_end=0.05).status == DONE)


@pytest.mark.parametrize("overrides, t_end", [({"box.inertia": 1e-12}, 0.5)])
def test_a_run_that_goes_through_a_wall_unseen_says_so(overrides, t_end, tmp_path, capsys):
    # an inertia far below what a step resolves: the jack ended up 1e-2 L inside a wall, with no impulse
    # and exit status 0 (g = 1e20 did so too, 3.5e13 L inside: see test_a_step_that_falls_far_beyond_the_box)
    from jackbox.errors import RunStoppedError

    scene = jackbox.load_scene("drop", overrides)
    with pytest.raises(RunStoppedError, match="went through a wall unseen"):
        jackbox.simulate(scene, t_end=t_end)
    sets = [f"--set={k}={v}" for k, v in overrides.items()]
    status, _, err = run_cli(capsys, "run", "drop", *sets, "--t-end", str(t_end), "--no-plots", "--out", str(tmp_path))
    assert status == 1 and "went through a wall unseen" in err and "Traceback" not in err
    assert not (tmp_path / "trajectory.npz").exists()


@pytest.mark.parametrize("call, match", [
    (lambda: jackbox.simulate("drop", t_end="abc"), "t_end must be a number"),
    (lambda: jackbox.simulate("drop", t_end="0.1"), "t_end must be a number"),
    (lambda: jackbox.simulate("drop", dt=True), "dt must be a number"),
    (lambda: jackbox.simulate("drop", params="e=0.5"), "params must be a dict"),
    (lambda: jackbox.simulate(None), "a scene is a built-in name"),
    (lambda: jackbox.load_scene(b"drop"), "a scene is a built-in name"),
    (lambda: jackbox.load_scene("drop", [("e", 1)]), "overrides must be a dict"),
    (lambda: ensemble("drop", 2, t_end=0.05, lanes="no"), "lanes must be True, False or None"),
    (lambda: ensemble("drop", 2, t_end=0.05, threads=1.5), "threads must be a whole number"),
    (lambda: ensemble("drop", 2, t_end=0.05, threads="2"), "threads must be a whole number"),
    (lambda: ensemble("drop", 2, t_end=0.05, samples=["a"]), "samples must be a time"),
    (lambda: ensemble("drop", 2, t_end=0.05, samples=[[0.01, 0.02]]), "samples must be a time"),
    (lambda: ensemble("drop", 2, t_end=0.05, samples=[[0.01, 0.02], [0.03]]), "samples must be a time"),
    (lambda: ensemble("drop", 2, t_end=0.05, samples=[0.04, 0.02]), "0.04 and 0.02 are out of order"),
    (lambda: ensemble("drop", 2, t_end=0.05, samples=[0.02, 0.0204]), r"fall on the same step \(t = 0.02 s\)"),
    (lambda: ensemble("drop", 2, t_end=0.05, perturb=["x_jack"]), "perturb must be a dict"),
    (lambda: chaos("drop", 2, t_end=0.05, sweep=[("e", 0.1, 1.0)]), "sweep must be a dict"),
    # (a log that is not a function failed only where a study compiled something, with a TypeError)
    (lambda: ensemble("drop", 2, t_end=0.05, log=5), "log must be a function"),
    (lambda: chaos("drop", 2, t_end=0.05, log="study.log"), "log must be a function"),
    (lambda: jackbox.simulate("drop", t_end=0.05, log=True), "log must be a function"),
    (lambda: ensemble("drop", 2, t_end=0.05, progress="yes"), "progress must be True or False"),
    (lambda: jackbox.simulate("drop", t_end=0.05, progress=None), "progress must be True or False"),
])
def test_a_wrong_type_through_the_api_is_one_clear_error(call, match):
    # (before: ValueError, TypeError or AttributeError from deep inside, or lanes="no" taken as True)
    from jackbox.errors import JackboxError

    with pytest.raises(JackboxError, match=match):
        call()


def test_a_folder_is_not_loaded_as_a_scene_nor_overwritten_by_a_save(tmp_path):
    from jackbox.errors import JackboxError

    with pytest.raises(JackboxError, match="is a folder, not a scene file"):
        jackbox.load_scene(tmp_path)
    traj = jackbox.simulate("drop", t_end=0.05)
    (tmp_path / "run.npz").mkdir()
    with pytest.raises(JackboxError, match="is a folder, not a file to write"):
        traj.save(tmp_path / "run.npz")
    (tmp_path / "file").write_text("keep")
    with pytest.raises(JackboxError, match="cannot be made"):
        traj.save(tmp_path / "file" / "run.npz")
    assert (tmp_path / "file").read_text() == "keep"


@pytest.mark.parametrize("key, bad, match", [
    ("q", lambda d: d["q"][:, :5], r"q has shape \(\d+, 5\)"),
    ("t", lambda d: d["t"][:-1], "t has"),
    ("impact_constraint", lambda d: np.full(d["impact_t"].shape, 999), "contact index outside"),
])
def test_a_trajectory_file_whose_arrays_do_not_fit_is_refused_by_plot_and_animate(tmp_path, capsys, key, bad, match):
    traj = jackbox.simulate("drop", t_end=1.0)
    assert len(traj.impact_t) > 0                       # (the contact index case needs an impulse)
    traj.save(tmp_path / "ok.npz")
    arrays = dict(np.load(tmp_path / "ok.npz"))
    arrays[key] = bad(arrays)
    np.savez(tmp_path / "bad.npz", **arrays)
    from jackbox.errors import JackboxError

    with pytest.raises(JackboxError, match=match):
        jackbox.Trajectory.load(tmp_path / "bad.npz")
    for command, out in (("plot", "p.png"), ("animate", "a.html")):
        status, _, err = run_cli(capsys, command, str(tmp_path / "bad.npz"), "--out", str(tmp_path / out))
        assert status == 2 and "not a consistent trajectory" in err and "Traceback" not in err
        assert not (tmp_path / out).exists()


def test_a_formula_whose_number_is_astronomical_is_refused_at_once(tmp_path):
    # 9**9**9**9 was computed as a whole number, digit by digit: load_scene never returned
    import time
    from importlib.resources import files

    from jackbox.errors import SceneError

    text = files("jackbox.scenes").joinpath("shaken.toml").read_text()
    text = text.replace('[forces]\n', '[forces]\nx_jack = "9**9**9**9"\n', 1)
    t0 = time.perf_counter()
    with pytest.raises(SceneError, match=r"forces.x_jack: cannot be evaluated"):
        jackbox.load_scene(write_scene(tmp_path, text))
    assert time.perf_counter() - t0 < 10


def test_set_with_a_parameter_slot_name_says_which_scene_key_it_is(tmp_path, capsys):
    status, _, err = run_cli(capsys, "run", "drop", "--set", "e=0.5", "--t-end", "0.1", "--out", str(tmp_path))
    assert status == 2 and "the parameter e is the scene key impact.restitution" in err


def test_animate_refuses_an_out_that_is_not_a_page(tmp_path, capsys):
    jackbox.simulate("drop", t_end=0.1).save(tmp_path / "t.npz")
    status, _, err = run_cli(capsys, "animate", str(tmp_path / "t.npz"), "--out", str(tmp_path / "x.png"))
    assert status == 2 and "an animation is written as an .html page, not .png" in err
    assert not (tmp_path / "x.png").exists()


def test_a_solver_warning_reaches_the_cli_user_as_one_line(capsys):
    from jackbox.cli import _show_warning
    from jackbox.errors import SolverWarning

    _show_warning(SolverWarning("drop: an iterative contact solve stopped before it converged at t = 0.1 s"),
                  SolverWarning, "/some/module.py", 12)
    err = capsys.readouterr().err
    assert err == "jackbox: warning: drop: an iterative contact solve stopped before it converged at t = 0.1 s\n"


@pytest.mark.parametrize("call, match", [
    (lambda: jackbox.simulate("drop", t_end=1e-300), r"t_end \(1e-300 s\) is shorter than one step"),
    (lambda: ensemble("drop", 2, t_end=0.05, dask_local=0), "dask_local must be a number of worker processes"),
    (lambda: jackbox.simulate("drop", t_end=0.05).save("/tmp/never.npz", compress="no"), "compress must be"),
])
def test_more_values_that_used_to_be_taken_or_blamed_on_something_else(call, match):
    # (t_end below dt was blamed on dt; dask_local=0 ran locally; compress="no" compressed)
    from jackbox.errors import JackboxError

    with pytest.raises(JackboxError, match=match):
        call()


def test_an_empty_out_is_refused_not_taken_for_this_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    status, _, err = run_cli(capsys, "run", "drop", "--t-end", "0.05", "--out", "")
    assert status == 2 and "--out: is empty" in err
    assert list(tmp_path.iterdir()) == []


def test_the_reference_stops_on_speeds_beyond_a_float_with_one_error_and_no_lapack_noise(capfd):
    # it printed hundreds of LAPACK "On entry to DLASCL" lines, then raised a bare RuntimeError
    import warnings

    from jackbox import reference
    from jackbox.errors import JackboxError

    scene = jackbox.load_scene("drop", {"initial.qd": [0, 0, 0, 1e200, 0, 1e200]})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        with pytest.raises(JackboxError, match="non-finite|no solution"):
            reference.simulate(scene, t_end=0.05)
    assert "DLASCL" not in capfd.readouterr().err


@pytest.mark.parametrize("g", [1e12, 1e20])
def test_a_step_that_falls_far_beyond_the_box_stops_the_run(g, tmp_path, capsys):
    """At g = 1e20 a step falls 1e14 L: the jack ended 3.5e13 L inside a wall with exit status 0, then (the
    fallback's velocity LCP over every contact within reach solved exactly, impact.lcp) the box hovered
    where it started, its energy rising, and the run ended done. A fallback step whose own motion closes
    more than fallback.UNRESOLVED_REACH L is now not taken: the state is NaN, the run stops there, and
    ensembles and chaos studies say which members did."""
    from jackbox.engine import NONFINITE
    from jackbox.errors import NonFiniteStateError

    scene = jackbox.load_scene("drop", {"world.gravity": g})
    with pytest.raises(NonFiniteStateError, match="non-finite at step 1 .* Try a smaller dt"):
        jackbox.simulate(scene, t_end=0.01)
    status, _, err = run_cli(capsys, "run", "drop", f"--set=world.gravity={g}", "--t-end", "0.01", "--no-plots",
                             "--out", str(tmp_path))
    assert status == 1 and "non-finite" in err and "Traceback" not in err
    assert list(ensemble(scene, 3, t_end=0.05, lanes=False).status) == [NONFINITE] * 3
    assert list(chaos(scene, 3, t_end=0.05).status) == [NONFINITE] * 3


def test_ensemble_members_that_went_through_a_wall_unseen_say_so():
    # the ensemble counterpart of the single run's check: every member of drop at g = 1e20 ended
    # 1e13 L inside a wall with status done (now: a box of inertia 1e-12, which the exact method lets through
    # at t = 0.43 s). Each member stops there, at the step that found a gap THROUGH L below contact: before,
    # it went on inside the ground to its end, slowly (to 0.5 s, 6 s a member)
    from jackbox.engine import INSIDE, THROUGH
    from jackbox.scene import contact_gaps, contact_gaps_many

    thin = jackbox.load_scene("drop", {"box.inertia": 1e-12})
    t_end = 0.5
    ens = ensemble(thin, 3, t_end=t_end, lanes=False)
    assert list(ens.status) == [INSIDE] * 3 and np.isnan(ens.q).all()
    assert "through a wall unseen" in ens.summary()
    # where it stopped: the member alone says it is THROUGH L or more inside the ground at that step
    stopped = ens.steps[0] * thin.dt
    assert list(ens.steps) == [ens.steps[0]] * 3 and 0.4 < stopped < t_end - 0.05
    with pytest.raises(RunStoppedError, match=f"at t = {stopped:.6g} s contact 'ground") as caught:
        ens.trajectory(0)
    depth = float(re.search(r"\(([0-9.e+-]+) L\)", str(caught.value)).group(1))
    assert depth >= THROUGH
    # and a chaos study of the same (at g = 1e12 it was 2.2 L inside the ground by t = 0.009 s): the pairs'
    # stretches measured the tunnelling, not the dynamics
    for lanes in (False, True):
        study = chaos(thin, 3, t_end=t_end, lanes=lanes)
        assert list(study.status) == [INSIDE] * 3, lanes
        assert np.isnan(study.ftle).all() and np.isnan(study.stretch).all() and np.isnan(study.q).all()
        assert "3 through a wall unseen" in study.summary()
    # the vectorised gaps are the single state's, to the bit
    scene = jackbox.load_scene("drop")
    P = scene.params()
    Q = np.random.default_rng(1).normal(size=(40, 6))
    many = contact_gaps_many(Q, np.broadcast_to(scene.points, (40,) + scene.points.shape),
                             np.full(40, P["L"]), np.full(40, P["w_box"]), True)
    one = np.array([contact_gaps(q, scene.points, P["L"], P["w_box"], True) for q in Q])
    assert np.array_equal(many, one)


@pytest.mark.parametrize("kw", [{"threads": 9}, {"threads": 0}, {"threads": "2"}, {"dask_local": 1, "threads": 0},
                                {"log": 5}])
def test_a_studys_bad_argument_is_refused_before_anything_loads_or_compiles(monkeypatch, kw):
    """(a wrong thread count was refused only after the engine's loop had compiled: a first compile on a new
    machine, a quarter of a minute, for a typo)"""
    import jackbox.ensemble as studies

    def loaded(*args, **kwargs):
        raise AssertionError("the kernel was looked up before the arguments were checked")

    monkeypatch.setattr(studies, "_kernel", loaded)
    with pytest.raises(SimulationError, match="threads must be|log must be"):
        studies.ensemble("drop", 2, t_end=0.05, **kw)
