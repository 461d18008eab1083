"""The compiled engine against the slow reference, and the invariants of its physics."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

import jackbox
from jackbox import api, engine, reference

from .conftest import write_scene

#: Horizons short enough that chaos has not amplified round-off, long enough for impacts.
HORIZONS = {"shaken": 1.5, "spring": 1.0, "drop": 1.0, "hand": 1.0, "float": 1.5}
#: kernel vs lambdified reference, same algorithm: round-off only (see the tests' comments)
Q_ROUND_OFF, QD_ROUND_OFF = 1e-13, 1e-12


def assert_same_trajectory(got, want, atol_q, atol_qd):
    """Compare sample by sample; fail at the first step that differs, naming it."""
    assert got.t.shape == want.t.shape, (got.t.shape, want.t.shape)
    np.testing.assert_array_equal(got.t, want.t)
    for what, a, b, tol in (("q", got.q, want.q, atol_q), ("qd", got.qd, want.qd, atol_qd)):
        err = np.abs(a - b).max(axis=1)
        bad = np.flatnonzero(err > tol)
        if len(bad):
            i = bad[0]
            col = int(np.argmax(np.abs(a[i] - b[i])))
            pytest.fail(f"{what} differs first at sample {i} (t = {got.t[i]:.6g} s): "
                        f"{jackbox.Trajectory.coords[col]} {what} = {a[i, col]!r} vs {b[i, col]!r} "
                        f"(|diff| {err[i]:.3g} > {tol:g})")
    np.testing.assert_array_equal(got.impact_constraint, want.impact_constraint)
    # naive impulses come at step ends: both give the same grid times, exactly
    np.testing.assert_array_equal(got.impact_t, want.impact_t)


@pytest.mark.parametrize("name", list(HORIZONS))
def test_kernel_matches_reference_step_by_step(name, all_scenes):
    scene = all_scenes[name]
    # the reference implements the naive method step for step
    got = jackbox.simulate(scene, t_end=HORIZONS[name], method="naive")
    want = reference.simulate(scene, t_end=HORIZONS[name], method="naive")
    assert len(want.impact_t) >= 2, "the horizon should include impacts"
    # Same float operations in another order (cse, LLVM): a few ulp of |q| ~ 5 per
    # step, amplified a little by a few impacts. Measured: 5e-15 in q, 4e-14 in qd
    # (float), 3e-16 of the largest |energy| (shaken). The bounds are ~20x that.
    assert_same_trajectory(got, want, atol_q=Q_ROUND_OFF, atol_qd=QD_ROUND_OFF)
    np.testing.assert_allclose(got.energy, want.energy, rtol=0, atol=1e-14 * np.abs(want.energy).max())


def test_kernel_matches_reference_through_many_simultaneous_impacts():
    # drop with e = 0.6: the box ends up chattering on the ground (hundreds of
    # impulses, often two corners at once), which also grows the impact log
    got = jackbox.simulate("drop", t_end=2.1, params={"e": 0.6, "e_ground": 0.6}, method="naive")
    want = reference.simulate("drop", t_end=2.1, params={"e": 0.6, "e_ground": 0.6}, method="naive")
    assert len(got.impact_t) > 600
    # measured over 809 impulses: 1.9e-15 in q, 5.3e-14 in qd (no growth per impact)
    assert_same_trajectory(got, want, atol_q=Q_ROUND_OFF, atol_qd=QD_ROUND_OFF)


@pytest.mark.parametrize("method", api.METHODS)
def test_log_growth_and_chunking_do_not_change_the_result(method, monkeypatch):
    params = {"e": 0.6, "e_ground": 0.6}
    whole = jackbox.simulate("drop", t_end=3.0, params=params, method=method)
    monkeypatch.setattr(api, "CHUNK", 37)      # many kernel calls, resumed mid-run
    monkeypatch.setattr(api, "LOG_SIZE", 8)    # and a log that must grow many times
    pieces = jackbox.simulate("drop", t_end=3.0, params=params, method=method)
    # more events than the smallest log (8 per contact): it grew at least once
    assert len(whole.impact_t) + len(whole.contact_t) > 8 * len(whole.constraint_names)
    for key in ("t", "q", "qd", "energy", "impact_t", "impact_constraint", "contact_t", "contact_event"):
        np.testing.assert_array_equal(getattr(whole, key), getattr(pieces, key), err_msg=key)


def test_a_held_stretch_resumed_at_any_step_gives_the_same_numbers(monkeypatch):
    # shaken at e = 0: the jack rides the shaken box on one, two or four held
    # contacts for most of 4 s. A quiet held step hands its factorization of the
    # held rows to the next step's first stage (modes.settle_rows); a run cut into
    # calls of 37 steps starts every 37th step without it, and must still give
    # the same numbers to the last bit
    params = {"e": 0.0, "e_ground": 0.0}
    whole = jackbox.simulate("shaken", t_end=4.0, params=params, record_every=10)
    monkeypatch.setattr(api, "CHUNK", 37)
    pieces = jackbox.simulate("shaken", t_end=4.0, params=params, record_every=10)
    rests = np.sum(whole.contact_event == engine.REST)
    assert rests >= 4 and rests - np.sum(whole.contact_event == engine.RELEASE) >= 1   # held at the end
    for key in ("q", "qd", "energy", "contact_t", "contact_event"):
        np.testing.assert_array_equal(getattr(whole, key), getattr(pieces, key), err_msg=key)


@pytest.mark.parametrize("builtin, over", [("shaken", {}), ("spring", {}), ("drop", {}),
                                           ("drop", {"restitution": "0.6"})])
def test_the_broad_phase_and_the_gap_rows_it_skips_change_nothing(builtin, over):
    """The kernel against itself built with every gap row every step (``BROAD_PHASE = False``): the same end
    state, contact modes and event log, to the bit. Which steps free flight takes and which the exact loop
    takes itself (the disc of the broad phase, the gap rows where it fails, the loop's clearance from its
    own step's rows) must never change a number: a clearance set too high would skip a step the exact loop
    had to look at, and an impact with it."""
    from jackbox import loader
    from jackbox.bench import TOGGLE, Loop
    from jackbox.scene import load_scene

    scene = load_scene(builtin, over)
    text = loader.FLIGHT_SOURCE.read_text()
    assert text.count(TOGGLE) == 1
    model_file = loader.ensure_model(scene)
    run = api.prepare(scene)
    ends = [Loop(loader.load_kernel(model_file, flight), run, "exact", lean=True).once()
            for flight in (text, text.replace(TOGGLE, "BROAD_PHASE = False"))]
    assert ends[0] == ends[1]


@pytest.mark.parametrize("name, over", [("shaken", {"restitution": 0.0}), ("spring", {"restitution": 0.0}),
                                        ("hand", {"restitution": 0.0}),
                                        ("drop", {"restitution": 0.3, "ground_restitution": 0.3})])
def test_held_steps_on_floats_and_on_arrays_give_the_same_numbers(name, over, all_scenes):
    """The model's ride (held steps on one to four contacts, on floats) against the held loop's arrays
    (a kernel whose ride is the loader's stub, ``loader.RIDE_STUB``: it takes no step, so the held loop takes
    every held step itself, as before a model's ride is compiled): every sample, the end state, the contact modes and the event log
    to the bit. Which of the two takes a held step depends on the state alone (the ride stops before a step
    that coasts or needs passes, and hands over, integrated, one that may release or comes near a free
    contact), so a single operation out of order would show. A third kernel whose ride moves each of its
    steps' rates by a part in 1e9 must differ: the ride takes steps of each of these runs; for the runs of
    IN_CORNERS, it moves only the steps on three or four rows (a jack in a corner of the box), so the corner's
    code is among those compared. (One nudged kernel a run: each is a compile of the ride, 25 s; the stub's
    ride compiles in a moment, where a copy of the ride told to return at once took as long as the ride.)"""
    import ast

    from jackbox import loader
    from jackbox.bench import Loop

    scene = all_scenes[name].with_overrides(over)
    text = loader.FLIGHT_SOURCE.read_text()
    settling = "        # the rows back on their level"
    corner = "        q, qd, pose, fac, factored = settle("
    assert text.count(settling) == 1 and text.count(corner) == 1
    ride = next(f for f in ast.parse(text).body if isinstance(f, ast.FunctionDef) and f.name == "ride")
    lines = text.splitlines(keepends=True)
    off = "".join(lines[:ride.lineno - 1]) + loader.RIDE_STUB + "".join(lines[ride.end_lineno:])
    nudge = "        qdb = axpy_s(1e-9, qdb, qdb)\n"
    nudged = (text.replace(corner, "        if m > 2:\n    " + nudge + corner) if name in IN_CORNERS
              else text.replace(settling, nudge + settling))
    model_file = loader.ensure_model(scene)
    whole = api.prepare(scene)
    run = api.prepare(scene, t_end=min(whole.n_steps * whole.dt, 6.0))
    ends, samples = [], []
    for flight in (text, off, nudged):
        loop = Loop(loader.load_kernel(model_file, flight), run, "exact", lean=False)
        ends.append(loop.once())
        samples.append([a.copy() for a in loop.rec])
    assert ends[0] == ends[1]
    for a, b in zip(samples[0], samples[1]):
        np.testing.assert_array_equal(a, b)
    assert ends[2] != ends[0]


#: the runs of test_held_steps_on_floats_and_on_arrays_give_the_same_numbers whose ride takes steps on three
#: or four held rows in their first 6 s (shaken: the jack wedged in a corner of the tilted box)
IN_CORNERS = ("shaken", "spring")


@pytest.mark.parametrize("name", ["hand", "shaken"])
def test_every_sample_is_the_state_its_model_describes(name, all_scenes):
    # Samples are written by the free-flight loop (the model's fly, on tuples),
    # the held loop and the exact loop's own steps: each row must be the recorded
    # time's box pose (a prescribed box's from its motion) and the energy of the
    # recorded state, whichever loop wrote it
    from jackbox import loader

    scene = all_scenes[name]
    traj = jackbox.simulate(scene, t_end=1.0)
    kernel = loader.kernel_for(scene)
    run = api.prepare(scene)
    prescribed = bool(kernel.PRESCRIBED)
    jack = slice(3, 6) if prescribed else slice(0, 6)
    box = np.empty(6)
    for n in range(0, len(traj.t), 7):
        t = traj.t[n]
        if prescribed:
            kernel.jit("box_motion")(t, run.p, box)
            np.testing.assert_allclose(traj.q[n, :3], box[:3], rtol=1e-15, atol=1e-15)
            np.testing.assert_allclose(traj.qd[n, :3], box[3:], rtol=1e-15, atol=1e-15)
        energy = kernel.jit("energy")(t, traj.q[n, jack].copy(), traj.qd[n, jack].copy(), run.p)
        assert abs(traj.energy[n] - energy) <= 1e-14 * max(1.0, abs(energy)), (n, traj.energy[n], energy)
    assert np.ptp(traj.q[:, 0 if prescribed else 3]) > 1e-3      # (it moved)


def test_record_every_keeps_every_kth_step_and_the_last():
    full = jackbox.simulate("spring", t_end=0.1)
    thin = jackbox.simulate("spring", t_end=0.1, record_every=7)
    idx = list(range(0, 101, 7)) + [100]
    np.testing.assert_array_equal(thin.t, full.t[idx])
    np.testing.assert_array_equal(thin.q, full.q[idx])
    np.testing.assert_array_equal(thin.energy, full.energy[idx])


def test_sampling_does_not_change_a_resting_run():
    # drop at e = 0 comes to rest early (box on the ground, jack on its floor):
    # from then on the exact loop runs its quiet held steps in one call, which
    # writes the samples on its way; sampling every step, every 7th or only the
    # ends must give the same numbers, bit for bit
    params = {"e": 0.0, "e_ground": 0.0}
    full = jackbox.simulate("drop", t_end=3.0, params=params)
    thin = jackbox.simulate("drop", t_end=3.0, params=params, record_every=7)
    ends = jackbox.simulate("drop", t_end=3.0, params=params, record_every=10**6)
    assert len(full.held) == 4 and full.contact_t.max() < 1.5
    last = len(full.t) - 1
    idx = list(range(0, last + 1, 7)) + ([last] if last % 7 else [])
    for got, at in ((thin, idx), (ends, [0, last])):
        np.testing.assert_array_equal(got.q, full.q[at])
        np.testing.assert_array_equal(got.qd, full.qd[at])
        for key in ("impact_t", "contact_t", "contact_event"):
            np.testing.assert_array_equal(getattr(got, key), getattr(full, key), err_msg=key)


def test_elastic_unforced_scene_keeps_its_energy():
    traj = jackbox.simulate("drop")   # e = 1, gravity only
    assert len(traj.impact_t) > 20
    # Between impacts the motion is a parabola, which RK4 integrates exactly, and
    # an e = 1 impulse keeps kinetic energy: only round-off remains, a random walk
    # of a few eps per impact (eps sqrt(37) ~ 1.4e-15). Measured 5e-15; 20x that.
    drift = np.abs(traj.energy - traj.energy[0]).max() / traj.energy[0]
    assert drift < 1e-13, drift


def test_inelastic_impacts_never_add_energy():
    traj = jackbox.simulate("drop", params={"e": 0.6, "e_ground": 0.6})
    # gravity is conservative, so energy can only change at an impact, and only down
    # (a rise is round-off of the energy's own evaluation: measured 2.6e-16 E0)
    rises = np.diff(traj.energy)
    assert rises.max() < 1e-14 * traj.energy[0], rises.max()
    assert traj.energy[-1] < 0.8 * traj.energy[0]


def test_momentum_is_kept_with_no_outside_force(float_scene):
    traj = jackbox.simulate(float_scene)
    assert len(traj.impact_t) >= 5
    p = float_scene.params()
    mb, mj, Jb, Jj = p["m_box"], p["m_jack"], p["J_box"], p["J_jack"]
    q, qd = traj.q, traj.qd
    linear = mb * qd[:, :2] + mj * qd[:, 3:5]
    angular = (mb * (q[:, 0] * qd[:, 1] - q[:, 1] * qd[:, 0]) + Jb * qd[:, 2]
               + mj * (q[:, 3] * qd[:, 4] - q[:, 4] * qd[:, 3]) + Jj * qd[:, 5])
    # an impulse and its reaction act at the same point: exact up to round-off
    # (measured: 1.5e-16 linear, 2.3e-14 angular, relative; the bounds are ~20x)
    assert np.abs(linear - linear[0]).max() < 3e-15 * np.abs(linear[0]).max()
    assert np.abs(angular - angular[0]).max() < 5e-13 * np.abs(angular[0])


def test_params_change_values_without_regenerating(tmp_path):
    by_set = jackbox.simulate(jackbox.load_scene("drop", {"restitution": "0.6"}), t_end=2.0)
    by_params = jackbox.simulate("drop", t_end=2.0, params={"e": 0.6, "e_ground": 0.6})
    np.testing.assert_array_equal(by_set.q, by_params.q)
    # ``restitution`` names both slots in params, as it does in a sweep
    by_alias = jackbox.simulate("drop", t_end=2.0, params={"restitution": 0.6})
    np.testing.assert_array_equal(by_alias.q, by_params.q)
    assert by_alias.meta["params"]["e"] == by_alias.meta["params"]["e_ground"] == 0.6
    assert by_set.meta["model_hash"] == by_params.meta["model_hash"] == \
        jackbox.simulate("drop", t_end=0.01).meta["model_hash"]


def test_unknown_param_and_bad_arguments_are_refused():
    with pytest.raises(jackbox.SimulationError, match="unknown parameter 'gravity'"):
        jackbox.simulate("drop", params={"gravity": 1.0})
    with pytest.raises(jackbox.SimulationError, match="'e' and 'restitution' both set e: give it once"):
        jackbox.simulate("drop", params={"e": 0.5, "restitution": 0.6})
    with pytest.raises(jackbox.SceneError, match=r"params=\.\.\.\): e \(impact\.restitution\): must be in \[0, 1\], got 1\.5"):
        jackbox.simulate("drop", params={"restitution": 1.5})
    with pytest.raises(jackbox.SimulationError, match="dt"):
        jackbox.simulate("drop", dt=-1.0)
    with pytest.raises(jackbox.SimulationError, match="record_every"):
        jackbox.simulate("drop", record_every=0)


@pytest.mark.parametrize("method", api.METHODS)
def test_non_finite_state_stops_with_a_clear_error(method, tmp_path):
    # with no ground, a torque exp(1000 t) spins the jack (which stays clear of
    # the walls until t = 0.8 s) until its rate overflows (exp(709.8) is the
    # largest double)
    text = (jackbox.builtin_scenes()["drop"].read_text().replace("ground = true", "ground = false")
            .replace("[impact]", '[forces]\ntheta_jack = "exp(1000*t)"\n\n[impact]'))
    scene = jackbox.load_scene(write_scene(tmp_path, text))
    with pytest.raises(jackbox.SimulationError, match=r"non-finite at step \d+ \(t = 0\.7"):
        jackbox.simulate(scene, t_end=1.0, method=method)


def test_kernel_runs_without_jit(tmp_path):
    # NUMBA_DISABLE_JIT=1 runs the same kernel source as plain Python (for
    # coverage and debuggers); it must give the compiled kernel's numbers.
    code = ("import jackbox, json; t = jackbox.simulate('drop', t_end=0.6); "
            "print(json.dumps([t.q[-1].tolist(), t.impact_t.tolist(), t.meta['kernel']['cache']]))")
    env = os.environ | {"NUMBA_DISABLE_JIT": "1", "JACKBOX_CACHE_DIR": str(tmp_path)}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    q_last, impact_t, cache = json.loads(out.stdout)
    assert cache == "disabled"
    jit = jackbox.simulate("drop", t_end=0.6)
    assert len(impact_t) >= 3
    # the same operations in the same order (no fastmath, no FMA contraction): to the bit
    np.testing.assert_array_equal(q_last, jit.q[-1])
    np.testing.assert_array_equal(impact_t, jit.impact_t)


def test_a_step_near_a_wall_is_the_step_fly_would_take():
    # Near a wall the exact loop takes a free step itself (the model's free_step)
    # instead of calling fly, which would stop before it: from the same state at
    # grid step i the two must give the same numbers, with the same stage times
    # (shaken's forcing reads them), taken where the grid's t0 + (i + 1) dt is not
    # t0 + i dt + dt (an ulp of time seldom reaches the state: a stage time other
    # than fly's does)
    import numba

    from jackbox import loader
    from jackbox.engine.records import MODEL_AT, ModelType, from_table

    run = api.prepare("shaken")
    kernel = loader.kernel_for(run.scene)
    loader.compile_kernel(kernel, "exact")
    tol = api.tolerances(run, kernel)

    @numba.njit
    def both(table, q, qd, p, tol, dt, i):
        model = from_table(table, MODEL_AT, ModelType)
        qa, qda, qb, qdb = q.copy(), qd.copy(), q.copy(), qd.copy()
        rows = np.zeros((2, 6))
        stop, _, _ = model.fly(0.0, dt, i, i + 1, qa, qda, p, tol, np.inf, q.copy(), qd.copy(), rows[0], rows,
                               rows, 0, -1, 1, -1)
        model.free_step(i * dt, (i + 1) * dt, q, qd, dt, p, qb, qdb)
        return stop, qa, qda, qb, qdb

    dt = run.dt
    steps = [i for i in range(1, 3000) if (i + 1) * dt != i * dt + dt][:5]
    assert steps, "no grid step whose end differs from its start plus dt"
    for i in steps:
        stop, qa, qda, qb, qdb = both(kernel.table(), run.q, run.qd, run.p, tol, dt, i)
        assert stop == i + 1                       # fly took the step
        np.testing.assert_array_equal(qa, qb)
        np.testing.assert_array_equal(qda, qdb)


@pytest.mark.parametrize("name", ["shaken", "spring", "drop"])
def test_the_two_codings_of_rk4_give_the_same_steps_to_the_bit_or_to_round_off(name):
    # The RK4 tableau is written once (jackbox/engine/integrator.py) and coded
    # twice: on arrays (rk4_rows, for any model size and with persistent
    # contacts held) and on tuples (the model's free_step and fly, compiled
    # with the model). With nothing held they must agree to the last bit, step
    # after step (the held loop's arrays and the ride on floats share the
    # tableau's order), or, for accelerations of time alone, whose tuple coding
    # sums the tableau in fewer operations, to round-off after 300 steps.
    # And the engine's step function value with nothing held
    # is the model's free_step (the exact loop's re-steps in an event search).
    import numba

    from jackbox import loader
    from jackbox.engine.integrator import rk4_rows
    from jackbox.engine.records import (FLAGS, LAM, LS, MODEL_AT, PASSES_AT, RHS, RIDX, RINV, STAGES_AT, WINV,
                                        ModelType, StagesType, from_table, scratch)

    run = api.prepare(name)
    kernel = loader.kernel_for(run.scene)
    loader.compile_kernel(kernel, "exact")

    @numba.njit
    def both(table, q, qd, p, dt, steps):
        model = from_table(table, MODEL_AT, ModelType)
        stages = from_table(table, STAGES_AT, StagesType)
        ws = scratch(model)
        qa, qda, qb, qdb = q.copy(), qd.copy(), q.copy(), qd.copy()
        qc, qdc = q.copy(), qd.copy()
        for i in range(steps):
            rk4_rows(model, i * dt, qa, qda, dt, p, qa, qda, 0, ws.work, ws.c[LS:LS + 4], ws.k[RIDX], ws.jac,
                     ws.n[WINV], ws.A, ws.lu, ws.c[RINV], ws.c[RHS], ws.c[LAM], ws.k[FLAGS, PASSES_AT],
                     False, False)
            model.free_step(i * dt, i * dt + dt, qb, qdb, dt, p, qb, qdb)     # (rk4's last stage time)
            stages.step(model, i * dt, qc, qdc, dt, p, qc, qdc, 0, ws)
        return qa, qda, qb, qdb, qc, qdc

    rng = np.random.default_rng(7)
    qd0 = run.qd + rng.uniform(-1.0, 1.0, run.qd.shape)          # some spin and drift on every coordinate
    qa, qda, qb, qdb, qc, qdc = both(kernel.table(), run.q.copy(), qd0, run.p, run.dt, 300)
    assert np.all(np.isfinite(qa)) and np.abs(qa - run.q).max() > 1e-3   # it moved
    for x, y in ((qc, qb), (qdc, qdb)):
        np.testing.assert_array_equal(x, y)
    if kernel.ACCEL_OF_TIME:
        # accelerations of time alone: the tuple coding sums the same tableau in fewer operations
        # (flight.rk4_stages), so the two agree to round-off, not to the bit
        assert not (np.array_equal(qa, qb) and np.array_equal(qda, qdb))
        np.testing.assert_allclose(qb, qa, rtol=0.0, atol=1e-13 * (1.0 + np.abs(qa).max()))
        np.testing.assert_allclose(qdb, qda, rtol=0.0, atol=1e-13 * (1.0 + np.abs(qda).max()))
    else:
        for x, y in ((qa, qb), (qda, qdb)):
            np.testing.assert_array_equal(x, y)


def test_the_held_solve_on_floats_is_the_held_loops_to_the_bit_and_solves():
    # flight.factor_held and held_push (factor2/solve2 for one or two rows, factor4/solve4 for three or four:
    # a jack wedged in a corner) and the emitted respond*_s, on floats, against the held loop's
    # contact_matrix, factor_rows, solve_rows and add_response, for m = 1..4 with no row, and each row in
    # turn, depending on those before it (the rank-revealing factorization gives it no force): the same
    # operations in their order, so the same bits, whichever row drops out. And the factorization (L D L^T)
    # solves: A x = b on the rows that stay to round-off. (Both sides are called from compiled code: the
    # engine's functions have no Python wrapper.)
    from numba import njit

    from jackbox import loader
    from jackbox.engine.impact import contact_matrix, factor_rows, solve_rows
    from jackbox.engine.modes import add_response

    kernel = loader.kernel_for(jackbox.load_scene("shaken"))
    part = loader._import_part(loader._write_part(kernel._ride_path(), kernel._ride_text()))
    factor_held, held_push = part.factor_held, part.held_push

    @njit
    def on_arrays(jac, winv, ridx, m, A, L, rinv, b, y, x, out):
        contact_matrix(jac, winv, ridx, m, A)
        rank = factor_rows(A, m, L, rinv)
        solve_rows(b, m, L, rinv, y, x)
        add_response(jac, winv, ridx, m, x, 6, out)
        return rank

    @njit
    def on_floats(w, m, r1, r2, r3, r4, b1, b2, b3, b4, a):
        f, A11, A22, A33, A44 = factor_held(w, m, r1, r2, r3, r4)
        got, x1, x2, x3, x4 = held_push(a, w, m, f, r1, r2, r3, r4, b1, b2, b3, b4)
        return f, (A11, A22, A33, A44), (x1, x2, x3, x4), got

    rng = np.random.default_rng(11)
    winv = rng.uniform(0.05, 2.0, 6)
    w = tuple(winv)
    dropped = 0
    for m, dep, _ in ((m, dep, trial) for m in (1, 2, 3, 4) for dep in range(-1, m) for trial in range(20)):
        jac = rng.normal(size=(m, 9))
        if dep == 0:
            jac[0, :6] = 0.0                             # no row before it: a zero row
        elif dep > 0:                                      # a combination of the rows before it
            jac[dep, :6] = rng.normal(size=dep) @ jac[:dep, :6]
        A, L, rinv = np.zeros((4, 4)), np.zeros((4, 4)), np.zeros(4)
        b, a = rng.normal(size=4), rng.normal(size=6)
        x, out = np.zeros(4), a.copy()
        rank = on_arrays(jac, winv, np.arange(m), m, A, L, rinv, b, np.zeros(4), x, out)
        dropped += rank < m
        r = [tuple(row) for row in jac]
        r += [r[-1]] * (4 - m)                             # the rows past m, as flight.held_rows pads them
        f, diagonal, xs, got = on_floats(w, m, *r, *b, tuple(a))
        assert f[:m] == tuple(rinv[:m]) and diagonal[:m] == tuple(np.diag(A)[:m]), (m, dep)
        lower = [(1, 0), (2, 0), (2, 1), (3, 0), (3, 1), (3, 2)]
        assert all(f[4 + j] == (L[i, k] if i < m else 0.0) for j, (i, k) in enumerate(lower)), (m, dep)
        assert xs[:m] == tuple(x[:m]) and xs[m:] == (0.0,) * (4 - m), (m, dep)
        assert got == tuple(out), (m, dep)
        # it solves: the rows that stay, A x = b; a dropped row's unknown 0
        kept = [i for i in range(m) if i != dep]
        assert rank == len(kept) and (dep < 0 or x[dep] == 0.0), (m, dep)
        if kept:
            sub = A[np.ix_(kept, kept)]
            np.testing.assert_allclose(sub @ x[kept], b[kept], rtol=0, atol=1e-10 * np.abs(sub).max()
                                       * np.abs(x[kept]).max() + 1e-12)
    assert dropped == 10 * 20    # (each dependent row did drop out, and no other; 20 draws of each)
