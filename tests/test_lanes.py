"""Ensemble blocks: members that share their parameters (but for the restitution) fly together in SIMD lanes
(jackbox.engine.lanes, jackbox.engine.members.run_block) and get the bits they get alone.

A lane takes a step only where the exact loop would take it as a plain RK4 step, with
the same operations in the same order; every other step (near contact, held contacts,
the fallback) the member takes alone through the exact loop. So every array of a study
must be bit-identical with and without lanes, for free flight (shaken), many impacts and
resting contact (drop at e = 0.6 and 0), a spring and a member that turns non-finite.
"""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path

import numpy as np
import pytest
from numba import njit

import jackbox
from jackbox import engine, loader
from jackbox.engine import LANES, NONFINITE
from jackbox.ensemble import LANES_WORTH, chaos, ensemble, plan, use_lanes

from .conftest import PRESCRIBED, write_scene

#: every array of one member that an Ensemble holds
ARRAYS = ("q", "qd", "energy", "impacts", "first_impact_t", "status", "steps", "fallback", "warnings",
          "samples_q", "samples_qd", "q0", "qd0", "params")


@pytest.fixture
def entries(monkeypatch):
    """The engine entry points the studies of a test called, in order."""
    called = []
    real = engine.entry

    def spy(name):
        called.append(name)
        return real(name)

    monkeypatch.setattr(engine, "entry", spy)
    return called


def both(scene, n, entries, **kw):
    """The study with lanes and without; asserts the first went through blocks and the second not."""
    entries.clear()
    lanes = ensemble(scene, n, lanes=True, **kw)
    assert "run_member_blocks" in entries and "run_members" not in entries, entries
    entries.clear()
    alone = ensemble(scene, n, lanes=False, **kw)
    assert "run_members" in entries and "run_member_blocks" not in entries, entries
    return lanes, alone


def same_bits(a, b) -> bool:
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@pytest.mark.parametrize("name, over, t_end", [
    ("shaken", {}, 3.0),                              # free flight, a few impacts each
    ("drop", {"restitution": "0.6"}, 2.0),            # hundreds of impulses, then resting contact
    ("drop", {"restitution": "0.0"}, 1.5),            # plastic: held contacts early
    ("spring", {"restitution": "0.1"}, 2.0),
])
def test_members_in_lanes_have_the_bits_they_have_alone(name, over, t_end, entries):
    scene = jackbox.load_scene(name, over)
    # two blocks and a part of a third (its lanes padded): members 0 .. 2 LANES + 2
    lanes, alone = both(scene, 2 * LANES + 3, entries, perturb={"theta_jack": 1e-3, "x_jack_dot": 1e-3},
                        t_end=t_end, seed=5, samples=[0.0, t_end / 3, t_end])
    assert np.all(alone.status == 0) and alone.impacts.sum() > 0
    for key in ARRAYS:
        assert same_bits(getattr(lanes, key), getattr(alone, key)), key


#: a cross jack whose tips nearly reach the walls (0.95 L), spinning at 100 rad/s with a long step (w h = 0.5):
#: its tips graze the walls within a step, where the cubic through a gap's ends stays above zero and the
#: exact loop steps into the step to look (a dip); a lane near a wall must ask the same (lanes.calm)
SPINNER = """
    name = "spinner"
    [box]
    inner_half_width = 1.0
    wall_thickness = 0.1
    mass = 10.0
    motion = "free"
    [jack]
    shape = "cross"
    half_size = 0.95
    mass = 1.0
    [world]
    gravity = 0.0
    ground = false
    [impact]
    restitution = 1.0
    [initial]
    q = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
    qd = [0.0, 0.0, 0.0, 1.5, 0.7, 100.0]
    [run]
    t_end = 2.0
    dt = 5e-3
"""


def test_members_grazing_the_walls_have_the_bits_they_have_alone(entries, tmp_path):
    """Near a wall a lane takes a step only where the exact loop finds no event in it (lanes.calm).

    Measured: with calm's test for a dip left out, 3 of these 64 members differ from their runs alone.
    """
    scene = jackbox.load_scene(write_scene(tmp_path, SPINNER))
    lanes, alone = both(scene, 4 * LANES, entries, perturb={"theta_jack": 1e-2, "x_jack_dot": 1e-1}, t_end=2.0,
                        seed=3)
    assert np.all(alone.status == 0) and alone.impacts.sum() > 10_000
    for key in ARRAYS:
        assert same_bits(getattr(lanes, key), getattr(alone, key)), key


def test_members_in_a_run_of_dense_steps_have_the_bits_they_have_alone(entries):
    """A run of dense steps (loop.exact_steps, DENSE_SCORE) is scored in the member's modes across calls.

    The elastic cross of tests/test_stress.py that rocks on the wall every 50 us: its members go to the
    fallback after a run of dense steps, scored by the exact loop alone; a member in the middle of a
    run stays out of the lanes (members.is_free), where nothing would count its quiet steps.
    """
    from .test_stress import ROCKING_ELASTIC_JACK

    dt, over = ROCKING_ELASTIC_JACK
    scene = jackbox.load_scene("drop", over)
    lanes, alone = both(scene, LANES + 3, entries, perturb={"theta_jack": 1e-9}, t_end=1.0, dt=dt, seed=2)
    # (3 of the 35 rock long enough for it: the others fall into other poses)
    assert np.all(alone.status == 0) and np.count_nonzero(alone.fallback > 0) >= 2, alone.fallback
    for key in ARRAYS:
        assert same_bits(getattr(lanes, key), getattr(alone, key)), key


def test_a_study_longer_than_its_table_of_terms_of_time_has_the_bits_alone(entries):
    """The lanes read a shaken box's terms of time (its force's sine) from a table made once for the study
    (lanes.time_table) for its first TIME_ROWS steps, and compute them after: both the same numbers as alone."""
    from jackbox.engine.records import TIME_ROWS

    scene = jackbox.load_scene("shaken")
    t_end = 1.1 * TIME_ROWS * scene.dt
    lanes, alone = both(scene, LANES + 3, entries, perturb={"theta_jack": 1e-3}, t_end=t_end, seed=4,
                        samples=[0.5 * t_end, t_end])
    assert np.all(alone.status == 0) and np.all(alone.impacts > 0)
    for key in ARRAYS:
        assert same_bits(getattr(lanes, key), getattr(alone, key)), key


def test_any_split_into_blocks_gives_the_same_bits(entries):
    kw = dict(perturb={"theta_jack": 1e-3}, t_end=2.0, seed=1, samples=[1.0], lanes=True)
    whole = ensemble("shaken", 2 * LANES + 1, **kw)
    split = ensemble("shaken", 2 * LANES + 1, chunk=5, threads=1, **kw)   # blocks of 5, 5, 5, 2 members
    assert entries.count("run_member_blocks") >= 2
    for key in ARRAYS:
        assert same_bits(getattr(whole, key), getattr(split, key)), key
    # and member i is the single run from its start
    traj = whole.trajectory(LANES + 1)
    assert np.array_equal(traj.q[-1], whole.q[LANES + 1]) and len(traj.impact_t) == whole.impacts[LANES + 1]


def test_a_member_that_turns_non_finite_in_a_block_says_so_as_alone(entries):
    # T = 1e-310: sin(2 pi t / T) is NaN within a few steps, for every member (a shared parameter)
    scene = jackbox.load_scene("shaken")
    lanes, alone = both(scene, LANES + 1, entries, params={"T": 1e-310}, perturb={"theta_jack": 1e-3}, t_end=0.5,
                        samples=[0.0, 0.4])
    assert set(lanes.status) == {NONFINITE}
    for key in ARRAYS:
        assert same_bits(getattr(lanes, key), getattr(alone, key)), key


#: every array of a chaos study that the engine fills
CHAOS_ARRAYS = ("stretch", "impacts", "status", "steps", "fallback", "warnings", "q", "qd", "q0", "qd0", "params", "offset")


@pytest.mark.parametrize("name, over, t_end, kw", [
    ("shaken", {}, 3.0, {}),                                     # renormalised twins near the walls
    ("drop", {"restitution": "0.6"}, 1.5, {}),                   # impacts, held contacts, twins moved off them
    # plastic, twins far apart: a twin the renormalisation moved must have its contact set found again
    # (measured: without it, the stretches differ)
    ("drop", {"restitution": "0.0"}, 1.5, {"d0": 5e-3}),
    ("shaken", {}, 0.5, {"params": {"T": 1e-310}}),              # every pair turns non-finite
])
def test_chaos_twins_in_lanes_have_the_bits_they_have_alone(name, over, t_end, kw, entries):
    scene = jackbox.load_scene(name, over)
    # two blocks of LANES // 2 pairs and a part of a third
    study = dict(t_end=t_end, seed=2, perturb={"theta_jack": 1e-3}, renorm=0.05, **kw)
    entries.clear()
    lanes = chaos(scene, LANES + 3, lanes=True, **study)
    assert "run_twin_member_blocks" in entries and "run_twin_members" not in entries, entries
    entries.clear()
    alone = chaos(scene, LANES + 3, lanes=False, **study)
    assert "run_twin_members" in entries and "run_twin_member_blocks" not in entries, entries
    assert alone.impacts.sum() > 0 if "params" not in kw else set(alone.status) == {NONFINITE}
    for key in CHAOS_ARRAYS:
        assert same_bits(np.asarray(getattr(lanes, key)), np.asarray(getattr(alone, key))), key


@pytest.mark.parametrize("name, over", [("shaken", {"restitution": "0.0"}), ("drop", {"restitution": "0.0"}),
                                        ("spring", {"restitution": "0.0"})])
def test_a_member_moved_where_no_contact_is_near_needs_no_contact_update(name, over):
    """members.needs_update: where it says a moved member's contact set need not be found
    again (so a renormalised chaos twin stays in its block's lanes), the contact update
    would change nothing: the same state and modes to the bit, no event. Checked on every
    sample of a plastic run (in flight, and resting on held contacts, which the update
    finds and holds), moved by a renormalisation-sized offset, and on the same states
    with one contact held, which always need the update."""
    from jackbox import api
    from jackbox.engine.members import needs_update
    from jackbox.engine.modes import update_contacts
    from jackbox.engine.records import MODE_SLOTS, MODEL_AT, Events, ModelType, from_table, scratch

    scene = jackbox.load_scene(name, over)
    traj = jackbox.simulate(scene, t_end=2.0, record_every=2)
    assert len(traj.impact_t) > 0                  # the samples come near the walls
    run = api.prepare(scene)
    kernel = loader.kernel_for(scene)
    loader.compile_kernel(kernel, "exact")
    tol = api.tolerances(run, kernel)
    off = 3 if kernel.PRESCRIBED else 0
    Q = np.ascontiguousarray(traj.q[:, off:]) + 1e-13
    QD = np.ascontiguousarray(traj.qd[:, off:]) - 1e-13

    @njit
    def check(table, T, Q, QD, p, tol, held):
        model = from_table(table, MODEL_AT, ModelType)
        C = model.n_contact
        needs = np.zeros(T.shape[0], np.bool_)
        changed = np.zeros(T.shape[0], np.bool_)
        gv = np.empty((2, C))
        for j in range(T.shape[0]):
            q, qd = Q[j].copy(), QD[j].copy()
            rest = np.zeros(C + MODE_SLOTS, np.int8)
            rest[0] = held
            needs[j] = needs_update(model, T[j], q, qd, p, tol, rest, gv)
            log = Events(np.zeros(64), np.zeros(64, np.int64), np.zeros(64, np.int64))
            n_ev, _ = update_contacts(model, T[j], q, qd, p, tol, rest, scratch(model), log, 0)
            moved = n_ev > 0 or rest[0] != held
            for d in range(q.shape[0]):
                moved |= q[d] != Q[j, d] or qd[d] != QD[j, d]
            for k in range(1, C):
                moved |= rest[k] != 0
            changed[j] = moved
        return needs, changed

    needs, changed = check(kernel.table(), traj.t, Q, QD, run.p, tol, 0)
    assert not (changed & ~needs).any(), np.flatnonzero(changed & ~needs)
    assert changed.any()                           # (the update has work on these samples)
    # the shortcut is taken wherever the jack is off the walls, and not taken near one
    assert (~needs).sum() >= len(needs) // 20 and needs.any(), (~needs).mean()
    needs_held, _ = check(kernel.table(), traj.t, Q, QD, run.p, tol, 1)
    assert needs_held.all()


@pytest.mark.parametrize("name, sweep, t_end", [
    ("shaken", {"restitution": (0.0, 1.0)}, 3.0),     # held contacts for the low ones, impacts in the lanes
    ("drop", {"restitution": (0.3, 1.0)}, 1.5),       # e and e_ground both swept
    ("drop", {"e_ground": (0.0, 1.0)}, 1.5),          # the ground's alone: the walls' e is shared
])
def test_a_restitution_sweep_goes_in_lanes_with_the_bits_alone(name, sweep, t_end, entries):
    """Members that differ in their restitution alone share a block (each lane reads its own
    e and e_ground at its impacts, and its stretches alone get its own parameters), and get
    the bits they get alone. Mutation check: with the lanes' impact reading the block's e
    (its first member's) or a stretch alone run with the block's parameters, this fails."""
    lanes, alone = both(name, 2 * LANES + 3, entries, sweep=sweep, t_end=t_end, seed=5,
                        samples=[0.0, t_end / 3, t_end])
    assert np.all(alone.status == 0) and len(np.unique(alone.params, axis=0)) == 2 * LANES + 3
    assert len(np.unique(alone.impacts)) > 5          # (the restitution tells the members apart)
    for key in ARRAYS:
        assert same_bits(getattr(lanes, key), getattr(alone, key)), key


def test_chaos_twins_of_a_restitution_sweep_in_lanes_have_the_bits_alone(entries):
    study = dict(t_end=1.5, seed=2, perturb={"theta_jack": 1e-3}, renorm=0.05, sweep={"restitution": (0.0, 1.0)})
    entries.clear()
    lanes = chaos("drop", LANES + 3, lanes=True, **study)
    assert "run_twin_member_blocks" in entries and "run_twin_members" not in entries, entries
    entries.clear()
    alone = chaos("drop", LANES + 3, lanes=False, **study)
    assert "run_twin_members" in entries and "run_twin_member_blocks" not in entries, entries
    assert np.all(alone.status == 0) and len(np.unique(alone.impacts)) > 5
    for key in CHAOS_ARRAYS:
        assert same_bits(np.asarray(getattr(lanes, key)), np.asarray(getattr(alone, key))), key


def test_a_sweep_of_what_free_flight_reads_or_a_prescribed_box_steps_its_members_alone(entries, tmp_path):
    ensemble("shaken", 4, sweep={"A": (0.5, 1.0)}, t_end=0.2, lanes=True)     # the shaking force differs
    assert "run_members" in entries and "run_member_blocks" not in entries
    entries.clear()
    ensemble("shaken", 4, sweep={"restitution": (0.5, 1.0), "A": (0.5, 1.0)}, t_end=0.2, lanes=True)
    assert "run_members" in entries and "run_member_blocks" not in entries
    entries.clear()
    ensemble(jackbox.load_scene(write_scene(tmp_path, PRESCRIBED)), 4, t_end=0.2, lanes=True)   # none for it
    assert "run_members" in entries and "run_member_blocks" not in entries


def test_lanes_sine_and_cosine_are_the_library_s_to_an_ulp():
    """The lanes' own sin and cos (a polynomial LLVM can vectorise) against the library's.

    The lanes' "quiet" keeps a margin of T_GAP = 1e-9 L over the exact loop's test, for
    gaps evaluated with these: an error of 2 eps in a sine moves a gap at 1e3 L from the
    box's centre by 4e-13 L. Measured: at most 2.2e-16 over these angles.
    """
    from jackbox.engine import lanes as lane_code

    sincos = njit(lane_code.sincos)
    rng = np.random.default_rng(0)
    angles = np.concatenate([rng.uniform(-4.0, 4.0, 20000), rng.uniform(-1e3, 1e3, 20000),
                             rng.uniform(-1e6, 1e6, 2000), np.arange(-64, 65) * math.pi / 4,
                             [0.0, -0.0, 1e-300, math.pi / 4 - 1e-16]])
    worst = 0.0
    for x in angles:
        s, c = sincos(x)
        worst = max(worst, abs(s - math.sin(x)), abs(c - math.cos(x)))
    assert worst <= 2.0 * np.finfo(float).eps, worst


def test_the_lanes_step_is_compiled_to_vector_instructions():
    """LLVM's loop vectoriser packs the lanes of the step itself, not only the bookkeeping.

    The step's loop is the only one with a speed bound (``abs``) and the every-gap loop the
    only one with a sine's quadrant (``floor``): both must be vector operations. Either
    falls back to scalar code when a loop over the lanes keeps a call or a branch, when
    the parameters are read from their array inside it, or when LLVM's SLP vectoriser
    packs pairs of one lane's operations first (all seen: 11.5 against 7 ns a lane-step).
    """
    import numba

    text = loader.binding_parts(loader.GENERATED_DIR.joinpath("shaken.py").read_text(), lanes=True)["lanes"]
    text = text.replace("cache=True", "cache=False").split("COMPILED = ")[0]
    space: dict = {}
    exec(compile(text, "lanes_part", "exec"), space)
    ir = numba.cfunc(engine.SIGNATURES["lanes"])(space["lanes"]).inspect_llvm()
    # the loop vectoriser's loops (the SLP vectoriser's pairs are not in blocks of this name)
    bodies = "".join(block for block in re.split(r"\n(?=[\w.]+:)", ir) if block.startswith("vector.body"))
    for op in ("fabs", "floor"):
        assert re.search(rf"@llvm\.{op}\.v\d+f64", bodies), f"the lanes' {op} is not in a vectorised loop"
    # the state and the trial trade rows from step to step (lanes.step_block inlined twice, its rows
    # constants): the step must be vectorised in both turns (with the rows in variables, or read
    # through signed indices, which Numba wraps around at each access, it was scalar)
    steps = [block for block in re.split(r"\n(?=[\w.]+:)", ir) if block.startswith("vector.body")
             and re.search(r"@llvm\.fabs\.v\d+f64", block)]
    assert len(steps) >= 2, f"the step is vectorised in {len(steps)} of its two turns"


def test_a_model_compiles_its_lanes_only_when_a_study_needs_them():
    shaken, drop = (loader.kernel_for(jackbox.load_scene(name)) for name in ("shaken", "drop"))
    # until a study needs them, every model's lanes are one stub, its machine code shared
    assert not shaken.module.LANES and shaken.module.PARTS["lanes"] == drop.module.PARTS["lanes"]
    own = shaken.with_lanes()
    assert own.module.LANES and own.module.PARTS["lanes"] != shaken.module.PARTS["lanes"]
    assert "rk4_stages" in own.module.PARTS["lanes"].read_text()


def test_a_study_compiles_lanes_only_where_they_win_back_their_compile_time():
    scene = jackbox.load_scene("spring")
    spec = plan(scene, 10, t_end=1.0)                   # 1e4 member-steps
    kernel = loader.kernel_for(scene)
    assert use_lanes(dataclasses.replace(spec, lanes=True), kernel)
    assert not use_lanes(dataclasses.replace(spec, lanes=False), kernel)
    big = dataclasses.replace(spec, n=int(LANES_WORTH // spec.n_steps))
    assert use_lanes(big, kernel)
    assert use_lanes(spec, kernel) == kernel.lanes_ready()       # small: only what costs nothing to compile
    kernel.with_lanes()
    engine.entry("run_member_blocks")
    assert kernel.lanes_ready() and use_lanes(spec, kernel)


@pytest.mark.parametrize("name, over, share", [
    ("shaken", {}, 0.9),
    ("drop", {"restitution": "0.9"}, 0.9),
    ("spring", {"restitution": "0.5"}, 0.5),     # (later, the jack slides on a wall: its impacts go alone)
])
def test_a_lane_takes_the_exact_loop_s_impact_step_bit_for_bit(name, over, share):
    """A lane's event step (lanes.event_lane: the exact loop's impact step, on floats) against the
    exact loop itself, on every step of a run that holds an impulse: where the lane takes it
    (one impact, no contact coming to rest), the state at the step's end, the impulse and its
    time are the exact loop's to the bit; and it takes the share of them that the scene's free
    flight gives (measured, 8 s: shaken 9 of 9, drop 157 of 158, spring 25 of 42).

    Mutation check: with the impulse's right-hand side taken from the gap rates (``gap_rate_s``)
    instead of its row's rate, or the location's first probe (the cubic's root) left out, this fails
    for each scene."""
    from jackbox import api

    scene = jackbox.load_scene(name, over)
    traj = jackbox.simulate(scene, t_end=8.0)
    run = api.prepare(scene)
    kernel = loader.kernel_for(scene)
    tol = api.tolerances(run, kernel)
    text = loader.binding_parts(Path(kernel.__file__).read_text(), lanes=True)["lane_event"]
    space: dict = {}
    exec(compile(text.replace("cache=True", "cache=False").split("COMPILED = ")[0], "lane_event_part", "exec"), space)
    event_lane, grid_step, time_terms = space["event_lane"], space["grid_step"], space["accel_time_s"]
    sc = np.zeros(LANES)
    e = run.p[kernel.E_SLOT], run.p[kernel.E_GROUND_SLOT]        # (the lane's restitution)
    dt = run.dt
    steps = np.unique(np.floor(traj.impact_t / dt).astype(np.int64))
    taken = 0
    for i in steps:
        while traj.t[i + 1] < traj.impact_t[np.searchsorted(traj.impact_t, traj.t[i])]:
            i += 1          # (floor's rounding: the step whose end is past the impulse)
        t, t_next = traj.t[i], traj.t[i + 1]
        q, qd = tuple(traj.q[i]), tuple(traj.qd[i])
        qn, vn, _ = grid_step(t, t_next, time_terms(t, run.p), q, qd, dt, run.p)     # the lanes' trial
        what, qb, vb, logged, te, _ = event_lane(t, t_next, dt, q, qd, qn, vn, run.p, tol, sc, *e)
        if what != 1:
            continue
        taken += 1
        inside = traj.impact_t[(traj.impact_t > t) & (traj.impact_t <= t_next)]
        assert logged == len(inside) == 1 and te == inside[0], (i, logged, inside, te)
        assert same_bits(np.array(qb), traj.q[i + 1]) and same_bits(np.array(vb), traj.qd[i + 1]), i
    assert taken >= share * len(steps) and taken > 0, (taken, len(steps))


@pytest.mark.parametrize("name, share", [("shaken", 0.5), ("spinner", 0.0)])
def test_a_lane_near_a_wall_is_calm_by_its_bounds_only_where_the_exact_loop_finds_no_event(name, share, tmp_path):
    """lanes.calm_by_bounds: the lane's bounds on its gaps at both ends of a step (lanes.lane_bound) against
    the exact loop's near test (lanes.calm, events.first_crossing), on every free step of a run.

    Where the bounds clear what the near test asks (no gap within the step's reach and below gaps.dip_free),
    calm finds no event in the step either; and that is most of the steps that are not quiet by the lanes'
    band on shaken (measured, 8 s: 49 of 72). On the grazing spinner (w h = 0.5) none: there the cubic's
    error is larger than the step's reach, so only gaps beyond the reach are calm by their bounds, and those
    are quiet already (400 steps near a wall in 2 s, each one for calm to read). At the bounds' level
    itself: a bound T_GAP (their margin for their own sines) and 1e-3 T_GAP above it says calm, as much
    below does not, nor a NaN.
    """
    from jackbox import api
    from jackbox.engine.gaps import cubic_error, speed_bound
    from jackbox.engine.records import T_EVENT, T_GAP

    scene = jackbox.load_scene(write_scene(tmp_path, SPINNER)) if name == "spinner" else jackbox.load_scene(name)
    t_end = 2.0 if name == "spinner" else 8.0
    traj = jackbox.simulate(scene, t_end=t_end)
    run = api.prepare(scene)
    kernel = loader.kernel_for(scene)
    tol = api.tolerances(run, kernel)
    model_text = Path(kernel.__file__).read_text()
    space: dict = {}
    for part in ("lane_event", "lanes"):
        text = loader.binding_parts(model_text, lanes=True)[part]
        exec(compile(text.replace("cache=True", "cache=False").split("COMPILED = ")[0], part, "exec"), space)
    grid_step, time_terms = space["grid_step"], space["accel_time_s"]
    calm, by_bounds, bound = space["calm"], space["calm_by_bounds"], space["lane_bound"]
    pt, tl = space["params_of"](run.p), space["tolerances_of"](tol)
    sc = np.zeros(LANES)
    dt, p = run.dt, run.p
    bound_speed = njit(speed_bound.py_func)

    def speed(v):
        return bound_speed(v, tol)

    near = yes = 0
    for i in range(len(traj.t) - 1):
        t, t_next = traj.t[i], traj.t[i + 1]
        q, qd = tuple(traj.q[i]), tuple(traj.qd[i])
        qn, vn, _ = grid_step(t, t_next, time_terms(t, p), q, qd, dt, p)          # the lanes' trial
        ba, bb = bound(t, q, pt), bound(t_next, qn, pt)
        band = dt * max(speed(qd), speed(vn)) + 2 * tol[T_GAP] - 0.5 * tol[T_EVENT]     # (lanes.step_block)
        if min(ba, bb) >= band:
            continue
        near += 1
        if by_bounds(t, t_next, qd, vn, ba, bb, tl):
            yes += 1
            assert calm(t, t_next, q, qd, qn, vn, p, tol, sc)[0], i
    assert near > 0 and yes >= share * near, (yes, near)

    # at its level: the least bound that is calm, for a step with rates qd at both ends
    qd = tuple(traj.qd[0])
    level = min(dt * speed(qd) + tol[T_GAP] - 1.5 * tol[T_EVENT],
                0.25 * (dt * speed(qd)) + njit(cubic_error.py_func)(qd, qd, dt, tol) + tol[T_GAP] - 0.5 * tol[T_EVENT])
    for ba, bb, calm_there in [(level + 1.001 * tol[T_GAP], level + 1.001 * tol[T_GAP], True),
                               (level + 0.999 * tol[T_GAP], level + 1.5 * tol[T_GAP], False),
                               (level + 1.5 * tol[T_GAP], level + 0.999 * tol[T_GAP], False),
                               (math.nan, level + 2 * tol[T_GAP], False)]:
        assert by_bounds(0.0, dt, qd, qd, ba, bb, tl) == calm_there, (ba - level, bb - level)
