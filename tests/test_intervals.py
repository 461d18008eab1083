"""Bounds on a prescribed box's speed from its motion's formulas (jackbox.intervals).

The exact method skips a gap while nothing can reach it in a step, trusting
a bound on the box's speed. These tests hold the bounds against the formulas'
derivatives sampled finely (a bound below one sample is a bug), check that
they are tight where a formula is simple, infinite where it may be undefined
or unbounded, and that the box shaken at 100 Hz for 100 s, whose sampled
"bound" was 5e-10 for a wall moving at 31 L/s, now runs to its end.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import jackbox
from codegen import parse_formula as parse
from jackbox.intervals import PIECES, rate_bounds, round_up

from .conftest import PRESCRIBED, write_scene

PARAMS = {"a": 0.3, "b": 1.7, "w": 3.0}

#: (formula, t_end): every operator and function of the scene grammar, where each is defined
FORMULAS = [
    ("a*sin(w*t)", 10.0),
    ("cos(t) - sin(2*t)", 20.0),
    ("a*sin(w*t) + b*cos(2*t)", 10.0),
    ("tan(0.3*t)", 4.0),
    ("asin(0.4*sin(t))", 7.0),
    ("acos(0.5*cos(3*t))", 7.0),
    ("atan(t - 2)", 5.0),
    ("atan2(sin(t), 2 + cos(t))", 9.0),
    ("sinh(0.5*t) - cosh(0.4*t - 1)", 6.0),
    ("tanh(3*t - 2)", 2.0),
    ("exp(-t)*sin(5*t)", 4.0),
    ("log(1 + t**2)", 5.0),
    ("sqrt(1 + t)", 3.0),
    ("abs(sin(3*t))", 4.0),
    ("t**3 - 2*t**2", 3.0),
    ("(1 + t)**-2", 3.0),
    ("(1 + t)**0.5 + t**1.5", 3.0),
    ("2**t", 3.0),
    ("a/(2 + sin(w*t))", 5.0),
    ("-t/(1 + t) + +b", 5.0),
    ("a*b*w*t - t*t/w", 2.0),
    ("0.05*cos(2*pi*100*t)", 100.0),
]


def sampled_rates(text: str, t_end: float, values: dict, n: int = 64 * 6250 + 1) -> np.ndarray:
    """(PIECES,) the largest |d f / dt| seen on a fine grid (central differences) in each piece of [0, t_end]."""
    t = np.linspace(0.0, t_end, n)
    rate = np.abs(np.gradient(_vector(text, t, values), t))
    piece = np.minimum((np.arange(n) * PIECES) // (n - 1), PIECES - 1)
    return np.array([rate[piece == k].max() for k in range(PIECES)])


def _vector(text: str, t: np.ndarray, values: dict) -> np.ndarray:
    # the same formula with numpy's functions, on the whole grid at once
    env = {"sin": np.sin, "cos": np.cos, "tan": np.tan, "asin": np.arcsin, "acos": np.arccos, "atan": np.arctan,
           "atan2": np.arctan2, "sinh": np.sinh, "cosh": np.cosh, "tanh": np.tanh, "exp": np.exp, "log": np.log,
           "sqrt": np.sqrt, "abs": np.abs, "pi": math.pi, "t": t, **values}
    return np.broadcast_to(eval(text, {"__builtins__": {}}, env), t.shape).astype(float)


@pytest.mark.parametrize("text, t_end", FORMULAS)
def test_a_rate_bound_is_never_below_the_formulas_sampled_rate(text, t_end):
    # piece by piece (each is bounded on its own), before the bound is rounded up
    tree = parse(text, set(PARAMS) | {"t"})
    bound = rate_bounds(tree, t_end, PARAMS)[0]
    seen = sampled_rates(text, t_end, PARAMS)
    assert np.all(np.isfinite(bound))
    # central differences under-read a peak by (h w)^2 / 6 at most: 1e-6 here
    low = np.flatnonzero(bound < seen * (1.0 - 1e-6))
    assert len(low) == 0, (text, low, bound[low], seen[low])


def test_rate_bounds_are_per_member_and_per_piece():
    tree = parse("a*sin(w*t)", {"a", "w", "t"})
    a = np.array([0.1, 0.3, 0.5])
    bounds = rate_bounds(tree, 10.0, {"a": a, "w": 3.0})
    assert bounds.shape == (3, PIECES)
    # |a w cos(w t)| <= a w, reached on every piece longer than a period's half
    assert np.allclose(bounds.max(axis=1), 3.0 * a, rtol=1e-12)
    # one member alone: the same numbers as in the row of three
    one = rate_bounds(tree, 10.0, {"a": a[1:2], "w": 3.0})
    assert np.array_equal(one[0], bounds[1])


@pytest.mark.parametrize("text, t_end, exact", [
    ("a*sin(w*t)", 10.0, 0.9),                  # a w
    ("t**2", 10.0, 20.0),                       # 2 t at t_end
    ("0.05*cos(2*pi*100*t)", 100.0, 0.05 * 2 * math.pi * 100),
    ("exp(-t)", 3.0, 1.0),
])
def test_a_simple_formulas_bound_is_tight(text, t_end, exact):
    tree = parse(text, set(PARAMS) | {"t"})
    bound = rate_bounds(tree, t_end, PARAMS).max()
    assert bound == pytest.approx(exact, rel=1e-12), text
    assert exact <= float(round_up(bound)) <= exact * 2 ** (1 / 16) * (1 + 1e-6), text


@pytest.mark.parametrize("text, t_end", [
    ("log(t - 1)", 3.0),          # undefined below t = 1
    ("tan(t)", 3.0),              # a pole at pi / 2
    ("1/(t - 1)", 2.0),           # and at t = 1
    ("sqrt(t)", 1.0),             # its rate grows without bound at 0
    ("asin(t)", 2.0),             # undefined past 1
    ("t**t", 1.0),                # exp(t log t): log 0
    ("atan2(sin(t), -0.5)", 9.0),   # across its cut: a jump of 2 pi, which no speed bounds
])
def test_where_a_formula_may_be_undefined_or_unbounded_the_bound_is_infinite(text, t_end):
    tree = parse(text, {"t"})
    assert rate_bounds(tree, t_end, {}).max() == math.inf
    assert round_up(rate_bounds(tree, t_end, {}).max()) == math.inf


def test_the_constants_are_the_grammars():
    from codegen.expr import CONSTANTS

    from jackbox.intervals import FORMULA_CONSTANTS

    assert FORMULA_CONSTANTS == CONSTANTS


def test_round_up_is_a_coarse_grid_above_its_argument():
    x = np.array([0.0, 1e-300, 0.3, 1.0, 31.41592653589793, 1e300, math.inf])
    up = round_up(x)
    assert up[0] == 0.0 and up[-1] == math.inf
    assert np.all(up[1:-1] >= x[1:-1]) and np.all(up[1:-1] <= x[1:-1] * 2 ** (1 / 16) * (1 + 2e-9))
    # a last-bit difference of the argument gives the same bound
    assert np.array_equal(round_up(np.nextafter(x[1:-1], 0)), up[1:-1])


def test_a_prescribed_boxs_speed_bound_holds_its_motions_speed(tmp_path):
    # |(x', y')| + |theta'| r_box from the motion's formulas, against the motion sampled finely
    from jackbox import api

    scene = jackbox.load_scene(write_scene(tmp_path, PRESCRIBED))
    P = scene.params()
    t = np.linspace(0.0, 4.0, 400_001)
    x = 0.1 * np.sin(2 * np.pi * t)
    y = P["amp"] * np.sin(2 * np.pi * P["freq"] * t)
    theta = 0.2 * np.sin(np.pi * t)
    r_box = math.sqrt(2.0) * (P["L"] + P["w_box"])
    speed = np.hypot(np.gradient(x, t), np.gradient(y, t)) + np.abs(np.gradient(theta, t)) * r_box
    bound = api.box_speed_bound(scene, scene.param_values, 4.0)
    assert bound.shape == (1,)
    # for all time: the three rates' peaks bounded apart, where they do not come at one time (1.8x here)
    assert speed.max() * (1 - 1e-6) <= bound[0] <= 2.0 * speed.max()


def test_a_periodic_boxs_bound_does_not_depend_on_t_end(tmp_path):
    # the engine's rule: no tolerance from t_end, so a run is a prefix of a longer one; a box that
    # accelerates for ever has no bound for all time, and takes one up to t_end
    from jackbox import api

    scene = jackbox.load_scene(write_scene(tmp_path, PRESCRIBED))
    assert len({float(api.box_speed_bound(scene, scene.param_values, t)[0]) for t in (0.1, 1.0, 10.0, 1e4)}) == 1
    speeding = jackbox.load_scene(scene, {"box.x": "0.01*t**2"})
    short, long = (float(api.box_speed_bound(speeding, speeding.param_values, t)[0]) for t in (10.0, 1000.0))
    assert 0.2 <= short < long and long >= 20.0


def test_a_box_shaken_faster_than_the_old_samples_saw_is_not_gone_through(tmp_path):
    # shaken at 100 Hz for 100 s: the motion sampled 20001 times (every 5 ms, at its turning points)
    # gave a speed bound of 5e-10; the broad phase then skipped the wall's gap and the jack went
    # 0.046 L through it at t = 86 s (a RunStoppedError). The bound from the formula: 32 L/s.
    from jackbox import api, loader
    from jackbox.engine import T_BOXV

    path = write_scene(tmp_path, SHAKEN_100HZ, "shake100.toml")
    scene = jackbox.load_scene(path)
    run = api.prepare(scene, t_end=100.0)
    assert api.tolerances(run, loader.kernel_for(scene))[T_BOXV] >= 0.05 * 2 * math.pi * 100
    long = jackbox.simulate(scene, t_end=100.0, record_every=1000)
    assert len(long.impact_t) > 1000
    # and the bound does not change the trajectory: a shorter run is its prefix, to the bit
    short = jackbox.simulate(scene, t_end=10.0, record_every=1000)
    assert np.array_equal(short.q, long.q[:len(short.q)])


def test_a_studys_bound_over_a_swept_range_holds_each_member(tmp_path):
    # one bound for every member of a sweep that moves the box (each member's own cost 0.1 ms: 12 s for
    # 1e5 members), at least each member's own, and here (the speed grows with both) the largest one's
    from jackbox import api
    from jackbox import ensemble as E

    scene = jackbox.load_scene(write_scene(tmp_path, PRESCRIBED))
    spec = E.plan(scene, 16, sweep={"amp": (0.1, 0.5), "freq": (3.0, 1.0)}, t_end=2.0)
    study = E._study_box_speed(spec)
    params = E.member_inputs(spec, 0, 16)[2]
    own = api.box_speed_bound(scene, params, E._base_run(spec).n_steps * spec.dt)
    assert np.all(own <= study) and own.max() == study
    # a sweep the box's motion does not name keeps the base run's bound; so does a free box
    assert E._study_box_speed(E.plan(scene, 4, sweep={"restitution": (0.5, 1.0)}, t_end=2.0)) is None
    assert E._study_box_speed(E.plan("shaken", 4, sweep={"L": (4.5, 6.0)}, t_end=2.0)) is None


SHAKEN_100HZ = """
name = "shake100"
description = "box shaken sideways at 100 Hz, a square jack flying across it"
[box]
inner_half_width = 1.0
wall_thickness = 0.1
mass = 4.0
motion = "prescribed"
x = "0.05*cos(2*pi*100*t)"
y = "0"
theta = "0"
[jack]
shape = "square"
half_size = 0.2
mass = 0.7
[world]
gravity = 9.81
ground = false
[impact]
restitution = 0.9
[initial]
q = [0.0, 0.0, 0.0, 0.5, 0.0, 0.0]
qd = [0.0, 0.0, 0.0, 3.0, 0.0, 0.0]
[run]
t_end = 100.0
dt = 1e-3
"""


@pytest.mark.parametrize("name", ["shaken", "drop", "spring", "float"])
def test_the_lever_arms_bound_every_gaps_slope(tmp_path, name):
    """Each coordinate's lever arm (``tol[T_SPEED + d]``: how far a unit change of it can move any gap) holds
    every gap's slope in it, at random configurations with the jack inside its box and the box above any
    ground. The step's travel, the exact loop's band and the lanes' gap bounds rest on it (a lever below a
    slope lets a crossing through). And the angles' levers are the slopes' own bound times ANGLE_SPARE, not
    a looser one (stop 66: the box's turn bounds a wall gap's slope by L, the jack point's offset along the
    wall; a ground gap's by the box's radius): the largest slope seen comes within 10% of it.
    """
    from pathlib import Path

    from jackbox import api, loader
    from jackbox.engine.records import T_SPEED
    from jackbox.engine.tolerances import ANGLE_SPARE, L_AT

    from .conftest import FREE_FLOAT

    scene = jackbox.load_scene(write_scene(tmp_path, FREE_FLOAT) if name == "float" else name)
    run = api.prepare(scene)
    kernel = loader.kernel_for(scene)
    lever = api.tolerances(run, kernel)[T_SPEED:T_SPEED + 6]
    path = Path(kernel.__file__)
    model = loader.model_module(path, path.read_text())
    assert model.N_DOF == 6 and not model.PRESCRIBED
    L = run.p[L_AT]                                 # the box's inner half width
    rng = np.random.default_rng(66)
    gaps, slopes = np.empty(model.N_CONTACT), np.empty((model.N_CONTACT, 6))
    largest = np.zeros(6)
    inside = 0
    for _ in range(3000):
        tb, tj = rng.uniform(-math.pi, math.pi, 2)
        u = rng.uniform(-L, L, 2)                   # the jack's centre in the box's frame
        c, s = math.cos(tb), math.sin(tb)
        xb, yb = rng.uniform(-3.0, 3.0), 50.0 * L   # (high above a ground)
        q = np.array([xb, yb, tb, xb + c * u[0] - s * u[1], yb + s * u[0] + c * u[1], tj])
        model.phi(0.0, q, run.p, gaps)
        if gaps.min() < 0.0:
            continue
        inside += 1
        model.phi_q(0.0, q, run.p, slopes)
        largest = np.maximum(largest, np.abs(slopes).max(axis=0))
    assert inside > 300
    assert np.all(largest <= lever * (1.0 + 1e-12)), (largest, lever)
    for d in (2, 5):
        assert largest[d] >= 0.9 * lever[d] / ANGLE_SPARE, (d, largest[d], lever[d])
