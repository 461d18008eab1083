"""Stress tests of the exact method: invariants over random scenes and start
states (hypothesis), and named hard cases.

Every run records every step and is checked against what does not depend on
the code under test:

* no gap below -2e-12 L at any recorded sample, evaluated by
  :func:`jackbox.scene.contact_gaps` (numpy, not the generated code): the exact
  method locates every event at -0.5e-12 L;
* a finite state everywhere;
* the energy column equals kinetic + gravity recomputed here from q and qd;
* with gravity only (no forces, no potential) the energy never rises: between
  impacts a free flight is a polynomial of degree 2 that RK4 integrates
  exactly, and Newton's law with e <= 1 takes energy out or keeps it, so a
  step without resting contact may raise the energy by round-off only (a
  step with one, by RK4's error on the constrained motion);
* with no gravity, total linear and angular momentum (orbital r x m v plus
  spins J omega) are kept: every impulse acts on both bodies at one point;
* every run completes: no draw is rejected, a run that stops or needs more
  than EVENT_BUDGET contact events fails the test. Stretches the exact
  method hands to its fallback (Moreau-Jean time-stepping, first order) are
  checked like the rest, with the energy allowances of a first-order method
  (FALLBACK_RISE per step, and no net gain over a stretch).

Each tolerance is a small factor over what the code was measured to achieve,
with the measurement beside it.

The named cases check closed-form answers: 1D collisions at mass ratios
1e-3 .. 1e3, a corner hit, hit times of a jack at 1e4 L/s with dt = 0.01 s,
a grazing corner, wedged jacks, e = 0 and e = 1, and 2e5 elastic impacts;
and the persistent multi-contact cases that used to stall (a jack pressed
into a spinning box's wall, a plastic hexagon on a tilting floor, a spinning
drop), which must now finish.

Runs are cheap, structures are not: every scene here is one of four compiled
structures (the built-in ``drop``; the tests' ``float`` and ``hand``; a
weightless cross defined below) and everything random is a runtime value
(masses, sizes, e, g, start state, dt), so nothing is compiled per example.
"""

from __future__ import annotations

import functools
import inspect
import json
import math
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, Phase, assume, given, settings
from hypothesis import strategies as st

import jackbox
from jackbox import api, loader
from jackbox.scene import contact_gaps

from .conftest import FREE_FLOAT, PRESCRIBED, write_scene

EPS = np.finfo(float).eps
#: events are located where a gap is -EVENT/2 (in units of L): jackbox.api.EVENT_TOL
EVENT = 1e-12
#: the gap every recorded sample must keep, in units of the box's inner half-width L:
#: 4 times the depth where events are located (-EVENT/2), which leaves room for the
#: round-off of numpy's gaps at positions up to ~1e3 L (eps |x| ~ 2e-13 L). Measured,
#: over ~1000 random scenes and every named case: -5.0e-13 L, exactly the event depth.
#: (Was -1e-9 L, the tolerance the scene format grants a start state.)
GAP_FLOOR = -4 * EVENT / 2
#: the energy change a step may show from round-off alone, relative to the run's
#: energy scale, per sqrt(1 + impulses in the step): evaluating the energy and
#: applying an impulse each round off at an eps or two of the scale, and these add
#: up as a random walk (a Zeno cascade or a fast jack puts 100-350 impulses in a step).
#: Measured (max over steps of |dE| / sqrt(1 + n)): 6e-16 over ~1000 random scenes,
#: 5.5e-16 with 127 impulses a step (the fast spinning jack), 1e-15 with 348 (the
#: long elastic run); 16 eps = 3.6e-15 is 3.5 times the worst. (It was 1e-12 flat,
#: ~1000 times what any step shows.)
ROUND_OFF = 16 * EPS
#: the energy column against kinetic + gravity recomputed here, relative to the
#: run's energy scale: two sums of the same eight products in another order, each
#: within ~10 eps of the scale at worst. Measured: 5.7e-16 (2.6 eps) at most over
#: 1000 random scenes and the named cases. (Was 1e-13, 450 eps.)
ENERGY_EVAL = 16 * EPS
#: a step with a persistent contact follows RK4 on a constrained, curved motion, so its
#: energy may change by RK4's error, O((omega dt)^5) of the scale (omega: the run's
#: largest rate), but by no more than REST_CAP: omega dt is drawn up to ~2, where
#: (omega dt)^5 alone allows anything. Measured, over ~230 random runs with resting
#: contact (of ~1000): a rise of at most 4.1e-9 in a step (omega dt = 0.37, weightless
#: square; the next worst 7e-10), 1.7e-10 with gravity; the cap was 2.5 times the worst.
#: Campaign seed 61 found 1.21e-8 with gravity (a jack 6000 times its box's mass let go by
#: two of five held contacts at a step's start, omega dt = 0.096; the run's other held steps
#: 1.5e-11 at most), RK4's error on the motion that begins there: 1.8e-9 at dt / 2 and
#: 1.3e-10 at dt / 4 (test_a_heavy_jack_let_go_in_a_corner_at_a_large_step_ends_it_on_the_held_level);
#: the cap is 2.5 times that.
REST_CAP = 3e-8
#: the same for the total angular momentum of a weightless run: its drift may be
#: ANGULAR (free flight and impulses, round-off: measured 8.4e-14 over ~500 runs
#: without resting contact, so 1e-12 is already 12x and stays) plus, per resting
#: step, (omega dt)^5 but no more than ANGULAR_REST_CAP. Measured: one resting step
#: changes it by 8e-11 at most, and drift / resting steps is 4.6e-11 at most (10
#: resting steps at omega dt = 0.72), over ~150 weightless runs with resting contact;
#: the cap is 2.5 times the worst step.
ANGULAR = 1e-12
#: the angular momentum's scale is at least this fraction of the bodies' reach (box half-size plus the
#: farthest centre from the origin) times their momentum. A random weightless square set at heights and
#: angles of 1e-190 (the property test's floats), colliding head on, has angular momentum terms of 5e-190:
#: its two corners' impulses on the wall, torques of about a lambda with lever components of 1e-189 a
#: lambda, left the total off by 3e-190 (0.62 of that "scale"), round-off of torques of 0.02
ANGULAR_FLOOR = 1e-3
ANGULAR_REST_CAP = 2e-10
#: a fallback step (Moreau-Jean, first order: the drift it projects away moves the bodies by
#: O(h^2)) may raise the energy by at most this much of the scale, and a whole fallback stretch
#: may not end above the energy it began with (its impulses do no positive work). Seen: the
#: draw that first needed the fallback (a 173:1 jack in a drop, dt = 4.7e-3) lost energy on
#: every fallback step, its projection's lift included; 1e-6 is a bound on that lift, not a fit.
FALLBACK_RISE = 1e-6
#: horizontal momentum of the named drops under gravity and a frictionless ground
#: (vertical forces only), relative to its scale: round-off of the impulses' x
#: components. Measured: 3.1e-15 (the elastic drop, 111 impacts), 5.6e-16 (the plastic
#: one). (Was 1e-13; the random drops keep 1e-13, plus the velocities' roundings of their
#: steps and events (:func:`momentum_rounding`): measured up to 9.7e-15 there, the ground's
#: vertical impulses can be far larger than the horizontal momentum, and 5.7e-13 where a
#: heavy jack's 2045 impulses in one step rounded one way.)
PX_ROUND_OFF = 1e-14

#: A property-test run may log at most this many contact events (impulses, contact mode
#: changes, fallback hand-overs); one that needs more fails the test (OverBudget). A count, not a
#: clock, so the same draws fail on a loaded machine and an idle one. The exact method hands a
#: step it cannot resolve to its fallback (Moreau-Jean time-stepping), so a jack chattering on a
#: floor with e ~ 0 no longer logs 1e6 events a second (it did, before the fallback, and such
#: draws were rejected here, not failed). benchmarks/contact.py counts the events of such
#: scenes now: 577 in 10 s for shaken at e = 0, 1042 for spring.
EVENT_BUDGET = 20_000

#: A weightless cross: the second free structure (four point masses, not a plate).
CROSS = """
name = "stress_cross"
description = "weightless box, cross jack (tests/test_stress.py)"
[box]
inner_half_width = 1.0
wall_thickness = 0.1
mass = 2.0
[jack]
shape = "cross"
half_size = 0.5
mass = 1.0
[world]
gravity = 0.0
[initial]
q = [0, 0, 0, 0, 0, 0.3]
[run]
t_end = 1.0
dt = 1e-3
"""

#: Reproducible in CI (derandomize). No shrinking: one example is a simulation of
#: up to 2000 steps, shrinking takes many minutes, and the failing draw is printed
#: in full anyway (scene overrides and dt: enough to rerun it with load_scene).
PROPERTY = settings(max_examples=25, deadline=None, derandomize=True,
                    phases=[Phase.explicit, Phase.generate],
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


def scene_from_text(text: str, name: str):
    with tempfile.TemporaryDirectory() as folder:
        return jackbox.load_scene(write_scene(Path(folder), text, name))


@functools.cache
def base(structure: str):
    """The four structures every test here draws its scenes from (loaded once)."""
    if structure == "drop":
        return jackbox.load_scene("drop")
    text = {"float": FREE_FLOAT, "cross": CROSS, "hand": PRESCRIBED}[structure]
    return scene_from_text(text, f"{structure}.toml")


class OverBudget(Exception):
    """A run stopped because it needed more contact events than its budget."""

    def __init__(self, budget, n_events, step, t):
        self.budget, self.n_events, self.step, self.t = budget, n_events, step, t
        super().__init__(f"more than {budget} contact events by the end of the step from t = {t:.6g} s "
                         f"(step {step}; {n_events} before it)")


class _Budgeted:
    """A kernel module whose exact loop ends the run when its event log is full.

    simulate() sizes the log to the budget (jackbox.api.LOG_SIZE; api makes it
    8 N_CONTACT at least), so the first IMPACT_LOG_FULL means the run needs more
    events than that; the kernel has undone the step that did not fit, so the
    count and the step are exact.
    """

    def __init__(self, module):
        self._module = module

    def __getattr__(self, name):
        return getattr(self._module, name)

    def integrate_exact(self, *args, log=None):
        i, n_rec, n_ev, status = self._module.integrate_exact(*args, log=log)
        if status == self._module.IMPACT_LOG_FULL:
            a = inspect.signature(self._module.integrate_exact).bind(*args).arguments
            raise OverBudget(len(a["ev_t"]), n_ev, i, a["t0"] + i * a["dt"])
        return i, n_rec, n_ev, status


class _BudgetLoader:
    """jackbox.loader as jackbox.api sees it inside simulate(): kernels come _Budgeted."""

    def __getattr__(self, name):
        return getattr(loader, name)

    def kernel_for(self, scene, log=None, method=None):
        return _Budgeted(loader.kernel_for(scene, log, method))

    def compile_kernel(self, module, *args, **kw):
        return loader.compile_kernel(module._module, *args, **kw)

    def is_cached(self, module, method):
        return loader.is_cached(module._module, method)


def simulate(scene, budget=EVENT_BUDGET, **kw):
    """jackbox.simulate, stopped (OverBudget, which fails the test) once the run needs more than `budget` events.

    Nothing else changes: the run is jackbox.simulate's, with an event log
    sized to the budget at the start. Every run must complete: a run that
    stops (a non-finite state) fails the test too.
    """
    saved = api.LOG_SIZE, api.loader
    api.LOG_SIZE, api.loader = budget, _BudgetLoader()
    try:
        return jackbox.simulate(scene, **kw)
    finally:
        api.LOG_SIZE, api.loader = saved


# --- checks -----------------------------------------------------------------------------

def check_gaps(traj, scene):
    """No recorded sample penetrates by more than 1e-9 L (gaps from numpy, not the kernel)."""
    P = scene.params()
    L = P["L"]
    gaps = np.array([contact_gaps(q, scene.points, L, P["w_box"], scene.has_ground_contacts)
                     for q in traj.q])
    i, k = np.unravel_index(np.argmin(gaps), gaps.shape)
    assert gaps[i, k] >= GAP_FLOOR * L, (
        f"sample {i} (t = {traj.t[i]:.9g} s): contact {scene.constraint_names[k]} has gap "
        f"{gaps[i, k]:.3g} = {gaps[i, k] / L:.3g} L")
    return gaps


def check_finite(traj):
    for key in ("t", "q", "qd", "energy"):
        assert np.all(np.isfinite(getattr(traj, key))), key


def kinetic(traj, P):
    qd = traj.qd
    return 0.5 * (P["m_box"] * (qd[:, 0] ** 2 + qd[:, 1] ** 2) + P["J_box"] * qd[:, 2] ** 2
                  + P["m_jack"] * (qd[:, 3] ** 2 + qd[:, 4] ** 2) + P["J_jack"] * qd[:, 5] ** 2)


def energy_scale(traj, P):
    """The size of the terms the energy is summed from (its round-off is relative to this)."""
    gravity = P["g"] * (P["m_box"] * np.abs(traj.q[:, 1]) + P["m_jack"] * np.abs(traj.q[:, 4]))
    return max(float((kinetic(traj, P) + gravity).max()), 1e-300)


def impulses_per_step(traj):
    """(N-1,) the number of impulses in each step (t_i, t_i+1] (those at t_0 count in the first)."""
    idx = np.searchsorted(traj.t, traj.impact_t, side="left") - 1
    return np.bincount(np.clip(idx, 0, len(traj.t) - 2), minlength=len(traj.t) - 1)


def round_off(traj):
    """(N-1,) the round-off each step may show, relative to a scale: ROUND_OFF sqrt(1 + impulses)."""
    return ROUND_OFF * np.sqrt(1.0 + impulses_per_step(traj))


def omega_dt(traj, P):
    """The run's largest rate (angular, or speed / L) times its step."""
    omega = np.abs(traj.qd[:, [2, 5]]).max() + np.abs(traj.qd[:, [0, 1, 3, 4]]).max() / P["L"]
    return omega * np.diff(traj.t).max()


def resting_steps(traj):
    """(N-1,) True for each step during which some contact was persistent (held closed)."""
    busy = np.zeros(len(traj.t) - 1, bool)
    since = {}
    for t, k, kind in zip(traj.contact_t, traj.contact_constraint, traj.contact_event):
        if kind == 1:
            since.setdefault(k, t)
        elif k in since:
            start = since.pop(k)
            busy |= (traj.t[1:] >= start) & (traj.t[:-1] <= t)
    for start in since.values():
        busy |= traj.t[1:] >= start
    return busy


def fallback_steps(traj):
    """(N-1,) True for each step that overlaps a stretch the fallback integrated."""
    busy = np.zeros(len(traj.t) - 1, bool)
    for start, end in traj.fallback_t:
        busy |= (traj.t[1:] > start) & (traj.t[:-1] < end)
    return busy


def check_energy(traj, scene, elastic=False):
    """Gravity-only scene: energy as recomputed, never rising, kept between impacts.

    Steps with no persistent contact: a rise of round-off at most (ROUND_OFF per
    sqrt(1 + impulses in the step)); with no impulse either (or e = 1), no change
    beyond that. A step with a persistent contact in it follows RK4 on a
    constrained, curved motion: its energy may rise by RK4's error, (omega dt)^5
    of the scale with omega the largest rate (angular, or speed / L) of the run,
    and never by more than REST_CAP. A step of the fallback may rise by
    FALLBACK_RISE, and a whole stretch of it not at all (but for that once).
    """
    P = scene.params()
    scale = energy_scale(traj, P)
    computed = kinetic(traj, P) + P["g"] * (P["m_box"] * traj.q[:, 1] + P["m_jack"] * traj.q[:, 4])
    np.testing.assert_allclose(traj.energy, computed, rtol=0, atol=ENERGY_EVAL * scale)
    dE = np.diff(traj.energy) / scale
    resting = resting_steps(traj)
    fallback = fallback_steps(traj)
    n_imp = impulses_per_step(traj)
    allowed = (round_off(traj) + np.where(resting, min(omega_dt(traj, P) ** 5, REST_CAP), 0.0)
               + np.where(fallback, FALLBACK_RISE, 0.0))
    i = np.argmax(dE - allowed)
    assert dE[i] <= allowed[i], (
        f"energy rose by {dE[i]:.3g} of its scale (allowed {allowed[i]:.3g}) in the step to "
        f"t = {traj.t[i + 1]:.9g} s ({'with' if resting[i] else 'no'} resting contact, omega dt = "
        f"{omega_dt(traj, P):.3g}), impacts there: {[scene.constraint_names[k] for t, k in zip(traj.impact_t, traj.impact_constraint) if traj.t[i] < t <= traj.t[i + 1]]}")
    for start, end in traj.fallback_t:
        a, b = np.searchsorted(traj.t, start), np.searchsorted(traj.t, end)
        rise = (traj.energy[min(b, len(traj.t) - 1)] - traj.energy[a]) / scale
        assert rise <= FALLBACK_RISE, f"the fallback from t = {start:.9g} to {end:.9g} s gained {rise:.3g} of the energy"
    # between impacts nothing acts but gravity: kept to round-off (and by elastic impulses)
    kept = ~resting & ~fallback & ((n_imp == 0) | elastic)
    if kept.any():
        i = np.flatnonzero(kept)[np.argmax(np.abs(dE[kept]) - allowed[kept])]
        assert abs(dE[i]) <= allowed[i], (
            f"energy changed by {dE[i]:.3g} of its scale (allowed {allowed[i]:.3g}) in the step to "
            f"t = {traj.t[i + 1]:.9g} s with {n_imp[i]} impulses (elastic: {elastic})")


def momentum_rounding(traj, P, axes=slice(0, 2)):
    """The most that rounding each body's velocity where one changes can move the linear momentum (along ``axes``).

    A step that changes a velocity rounds it to half an ulp, for each body:
    at most EPS times the bodies' momentum a step, of either sign. Where a
    force acts for most steps (a light jack pressed by a heavy box) those
    roundings add up past 1e-13 of the momentum exchanged: a weightless square
    with a jack 1e4 times lighter than its box, a contact changing its
    velocities in 1986 of 2000 steps, drifted by 3.6e-12, 0.17 of this bound,
    every step's change within 1 ulp (``test_a_light_jack_pressed_for_most_steps_keeps_its_momentum``).
    Each event inside a step (an impulse, a contact mode change) rounds the
    velocities again: its impulse, the projection after it and the stretch of
    RK4 up to the next each change them, so a step counts 1 + its events. An
    internal impulse moves a heavy body's velocity by a small fraction of its
    ulp, so those roundings can all fall one way: a jack 37 times its box's
    mass held on the floor of a box rocking on an elastic ground, 2045 impulses
    in one step, drifted the horizontal momentum by 0.71 of this bound in that
    step, 0.58 over the run (campaign seed 5's draw, in
    ``test_a_heavy_jack_on_a_box_rocking_on_an_elastic_ground_keeps_its_momentum``).
    """
    qd = traj.qd
    moved = np.any(np.diff(qd, axis=0) != 0.0, axis=1)
    events = np.concatenate([traj.impact_t, traj.contact_t])
    per_step = np.bincount(np.clip(np.searchsorted(traj.t, events, side="left") - 1, 0, len(traj.t) - 2),
                           minlength=len(traj.t) - 1)
    box, jack = np.arange(2)[axes], np.arange(3, 5)[axes]
    scale = P["m_box"] * np.abs(qd[1:, box]).sum(axis=1) + P["m_jack"] * np.abs(qd[1:, jack]).sum(axis=1)
    return EPS * float((scale * (moved + per_step)).sum())


def horizontal_momentum(traj, P):
    """(N,) the bodies' horizontal momentum, and its scale: the largest sum of their |m vx|."""
    px = P["m_box"] * traj.qd[:, 0] + P["m_jack"] * traj.qd[:, 3]
    return px, (P["m_box"] * np.abs(traj.qd[:, 0]) + P["m_jack"] * np.abs(traj.qd[:, 3])).max()


def momenta(traj, P):
    """Linear (N, 2) and angular (N,) momentum about the origin, and their scales."""
    mb, mj, Jb, Jj = P["m_box"], P["m_jack"], P["J_box"], P["J_jack"]
    q, qd = traj.q, traj.qd
    linear = mb * qd[:, :2] + mj * qd[:, 3:5]
    angular = (mb * (q[:, 0] * qd[:, 1] - q[:, 1] * qd[:, 0]) + Jb * qd[:, 2]
               + mj * (q[:, 3] * qd[:, 4] - q[:, 4] * qd[:, 3]) + Jj * qd[:, 5])
    lin_scale = max((mb * np.abs(qd[:, :2]) + mj * np.abs(qd[:, 3:5])).max(), 1e-300)
    ang_scale = max((mb * (np.abs(q[:, 0] * qd[:, 1]) + np.abs(q[:, 1] * qd[:, 0])) + Jb * np.abs(qd[:, 2])
                     + mj * (np.abs(q[:, 3] * qd[:, 4]) + np.abs(q[:, 4] * qd[:, 3]))
                     + Jj * np.abs(qd[:, 5])).max(), 1e-300)
    # no less than ANGULAR_FLOOR of the bodies' reach times their momentum: an impulse's torques about the
    # origin, whose round-off the total carries, are of that size even where the total's own terms are not
    reach = np.abs(q[:, [0, 1, 3, 4]]).max() + P["L"]
    ang_scale = max(ang_scale, ANGULAR_FLOOR * reach * lin_scale)
    return linear, angular, lin_scale, ang_scale


# --- random scenes ----------------------------------------------------------------------

def log_uniform(lo, hi):
    return st.floats(math.log10(lo), math.log10(hi)).map(lambda x: 10.0 ** x)


unit = st.floats(-1.0, 1.0)
restitution = st.one_of(st.sampled_from([0.0, 1.0]), st.floats(0.0, 1.0))


def extents(points, phi):
    c, s = math.cos(phi), math.sin(phi)
    x = c * points[:, 0] - s * points[:, 1]
    y = s * points[:, 0] + c * points[:, 1]
    return x.min(), x.max(), y.min(), y.max()


@st.composite
def start_state(draw, points, L, w, ground, speed, r_jack, box_at_origin=False):
    """q0, qd0 with the jack inside the box (and the box above the ground)."""
    phi = draw(st.floats(-math.pi, math.pi))                 # jack angle in the box frame
    x0, x1, y0, y1 = extents(points, phi)
    assume(x1 - x0 < 2 * L and y1 - y0 < 2 * L)
    u = 0.5 * (-x0 - x1) + draw(unit) * 0.999 * (L - 0.5 * (x1 - x0))
    v = 0.5 * (-y0 - y1) + draw(unit) * 0.999 * (L - 0.5 * (y1 - y0))
    tb = 0.0 if box_at_origin else draw(st.floats(-math.pi, math.pi))
    xb = 0.0 if box_at_origin else draw(unit) * L
    if box_at_origin:
        yb = 0.0
    elif ground:   # lowest outer corner 1e-3 L .. 3 L above the ground
        yb = (L + w) * (abs(math.sin(tb)) + abs(math.cos(tb))) + L * draw(st.floats(1e-3, 3.0))
    else:
        yb = draw(unit) * L
    cb, sb = math.cos(tb), math.sin(tb)
    q = [xb, yb, tb, xb + cb * u - sb * v, yb + sb * u + cb * v, tb + phi]
    qd = [speed * draw(unit), speed * draw(unit), speed / L * draw(unit),
          speed * draw(unit), speed * draw(unit), speed / r_jack * draw(unit)]
    return q, qd


#: ranges of the random scenes: jack-to-box mass ratio, speeds in sqrt(g L), the square jack's
#: half-size in L (0.7: it turns freely; up to 0.99: it can be wedged)
MASS_RATIO, SPEED, SQUARE_SIZE = (1e-3, 1e3), (0.1, 10.0), 0.70


@st.composite
def free_scene(draw, structure, shape, gravity, ground):
    """Overrides for a random free-box scene of the structure `structure`, and dt."""
    L = draw(log_uniform(0.1, 10.0))
    w = L * draw(st.floats(0.02, 0.5))
    m_box = draw(log_uniform(0.1, 100.0))
    m_jack = m_box * draw(log_uniform(*MASS_RATIO))
    a = L * draw(st.floats(0.05, 0.99 if shape == "cross" else SQUARE_SIZE))
    points = structure.points / structure.params()["a_jack"] * a
    r_jack = a * (math.sqrt(2.0) if shape == "square" else 1.0)
    speed = math.sqrt(9.81 * L) * draw(log_uniform(*SPEED))
    q, qd = draw(start_state(points, L, w, ground, speed, r_jack))
    e = draw(restitution)
    over = {"box.inner_half_width": L, "box.wall_thickness": w, "box.mass": m_box,
            "jack.mass": m_jack, "jack.half_size": a, "gravity": gravity,
            "restitution": e, "ground_restitution": draw(st.one_of(st.just(e), restitution)),
            "initial.q": q, "initial.qd": qd}
    return over, draw(log_uniform(5e-4, 1e-2))


@pytest.mark.slow
@given(data=st.data())
@PROPERTY
def test_random_drops_never_penetrate_nor_gain_energy(data):
    """Box and square jack under gravity with the ground, random everything.

    Checks: finite; gaps; energy recomputed, never rising, kept between impacts
    (and everywhere with e = 1 on walls and ground); horizontal momentum kept to
    round-off (gravity and the frictionless ground push only vertically).
    """
    scene_base = base("drop")
    over, dt = data.draw(free_scene(scene_base, "square", 9.81, True))
    check_drop_run(jackbox.load_scene(scene_base, over), dt)


def check_drop_run(scene, dt):
    """The checks of :func:`test_random_drops_never_penetrate_nor_gain_energy` on a run of one second."""
    traj = simulate(scene, t_end=1.0, dt=dt)
    check_finite(traj)
    check_gaps(traj, scene)
    P = scene.params()
    check_energy(traj, scene, elastic=P["e"] == 1.0 and P["e_ground"] == 1.0)
    px, scale = horizontal_momentum(traj, P)
    drift, allowed = np.abs(px - px[0]).max(), 1e-13 * scale + momentum_rounding(traj, P, axes=slice(0, 1))
    assert drift <= allowed, ("horizontal momentum", drift / scale, allowed / scale)     # (see PX_ROUND_OFF)


@pytest.mark.slow
@pytest.mark.parametrize("shape, structure", [("square", "float"), ("cross", "cross")])
@given(data=st.data())
@PROPERTY
def test_random_weightless_scenes_keep_momentum(shape, structure, data):
    """No gravity, no ground: momentum is kept, energy never rises, nothing penetrates.

    Impulses and contact forces act on both bodies at one point, equal and
    opposite. Linear momentum is a linear invariant, which RK4 keeps exactly:
    only round-off remains, relative to the momentum exchanged (1e-13 of it),
    plus each step's rounding of the bodies' momenta where their velocities
    change (:func:`momentum_rounding`).
    Angular momentum is quadratic: kept to round-off (ANGULAR of its scale) in
    free flight and by impulses, and to RK4's error, (omega dt)^5 per step but
    no more than ANGULAR_REST_CAP, while a contact is persistent (a constrained,
    curved motion).
    """
    scene_base = base(structure)
    over, dt = data.draw(free_scene(scene_base, shape, 0.0, False))
    check_weightless_run(jackbox.load_scene(scene_base, over), dt)


def check_weightless_run(scene, dt):
    """The checks of :func:`test_random_weightless_scenes_keep_momentum` on a run of one second."""
    traj = simulate(scene, t_end=1.0, dt=dt)
    check_finite(traj)
    check_gaps(traj, scene)
    P = scene.params()
    check_energy(traj, scene, elastic=P["e"] == 1.0)
    linear, angular, lin_scale, ang_scale = momenta(traj, P)
    # a persistent contact (a force all along) can exchange far more momentum than there is
    exchanged = lin_scale + np.abs(np.diff(P["m_jack"] * traj.qd[:, 3:5], axis=0)).sum()
    drift = np.abs(linear - linear[0]).max()
    allowed = 1e-13 * exchanged + momentum_rounding(traj, P)
    assert drift <= allowed, ("linear momentum", drift, allowed)
    n_rest = np.count_nonzero(resting_steps(traj) | fallback_steps(traj))
    allowed = ANGULAR + n_rest * min(omega_dt(traj, P) ** 5, ANGULAR_REST_CAP)
    drift = np.abs(angular - angular[0]).max() / ang_scale
    assert drift <= allowed, (drift, allowed, n_rest, omega_dt(traj, P))


#: draws of the weightless cross family that failed at the issue's ranges (benchmarks/campaign.py, 300 draws):
#: a coarse step on a fast turning box (omega dt = 0.7-5.7 for the whole run) with a contact held for
#: 33-251 steps. One RK4 pass over such a step drifted the angular momentum by up to 1.8e-7 of its scale
#: per held step (the test allows 2e-10) and once raised the energy; the held steps are now cut into
#: passes that turn by integrator.TURN_PER_PASS at most, and each draw keeps it 20x below what is allowed.
COARSE_TURNS = {
    "omega dt 1.4, plastic": (0.003973589837712593, {
        "box.inner_half_width": 0.3861719670039999, "box.wall_thickness": 0.06445846694357844,
        "box.mass": 6.8891487403212475, "jack.mass": 0.13599254253170215, "jack.half_size": 0.1287239890013333,
        "restitution": 0.0, "initial.q": [-0.14615972337273173, -0.14851347778676044, 0.8284849350624874,
                                          -0.03242603033556557, -0.024531020291205533, 3.850073376848523],
        "initial.qd": [0.0, 13.660330097002511, 79.46931118412512, 30.892575577579436, 20.71412954956546,
                       227.78823089056877]}),
    "omega dt 2.0": (0.009999769744141627, {
        "box.inner_half_width": 1.0, "box.wall_thickness": 0.23183316741625615, "box.mass": 0.12311731292392789,
        "jack.mass": 0.12311731292392789, "jack.half_size": 0.05, "restitution": 0.6143913798141615,
        "initial.q": [0.0, 0.0, -0.4539800243529699, 0.0945747851216524, -1.1021649955814958, -0.4539800243529697],
        "initial.qd": [-36.73063745628996, 47.05900256627207, 0.0, 31.555584455533793, 0.0, 0.0]}),
    "omega dt 5.7, a small box": (0.009999769744141627, {
        "box.inner_half_width": 0.12311731292392789, "box.wall_thickness": 0.02854267661893257,
        "box.mass": 0.12311731292392789, "jack.mass": 0.12311731292392789, "jack.half_size": 0.006155865646196395,
        "restitution": 0.6143913798141615,
        "initial.q": [0.0, 0.0, -0.4539800243529699, 0.01164379341453571, -0.13569559265480663, -0.4539800243529697],
        "initial.qd": [-12.888074257372903, 16.512098933043593, 0.0, 11.072247689185629, 0.0, 0.0]}),
    "omega dt 1.9, energy": (0.009999769744141627, {
        "box.inner_half_width": 0.12311731292392789, "box.wall_thickness": 0.02854267661893257,
        "box.mass": 0.12311731292392789, "jack.mass": 0.12311731292392789, "jack.half_size": 0.05255726555847386,
        "restitution": 0.6143913798141615,
        "initial.q": [2.7337535107625018e-17, 0.0, -0.4539800243529699, 0.007024422439748899, -0.08186190978186922,
                      -0.4539800243529697],
        "initial.qd": [-12.888074257372903, 16.512098933043593, 0.0, 11.072247689185629, 0.0, 0.0]}),
    "omega dt 0.7, a large jack": (0.009999769744141627, {
        "box.inner_half_width": 1.0, "box.wall_thickness": 0.23183316741625615, "box.mass": 0.12311731292392789,
        "jack.mass": 0.12311731292392789, "jack.half_size": 0.4268876919929865, "restitution": 0.6143913798141615,
        "initial.q": [2.220446049250313e-16, 0.0, -0.4539800243529699, 0.05705470882140817, -0.6649098151813169,
                      -0.4539800243529697],
        "initial.qd": [-36.73063745628996, 47.05900256627207, 0.0, 31.555584455533793, 0.0, 0.0]}),
}


#: a draw of the weightless cross family (benchmarks/campaign.py --seed 2 --examples 500): a plastic cross
#: thrown into a box spinning at 29 rad/s wedges in a corner and rocks between two pairs of resting
#: contacts, the intervals shrinking to 0.3 us and staying there (a limit cycle, not Zeno)
ROCKING_IN_A_CORNER = (0.0004999999999999999, {
    "box.inner_half_width": 1.0, "box.wall_thickness": 0.1765577883520286, "box.mass": 1.5848931924611136,
    "jack.mass": 18.98746563678875, "jack.half_size": 0.3716555298431266, "restitution": 0.0,
    "initial.q": [-0.28779942463200203, 0.393282210547625, -2.543676933492173, -0.5257052134749824,
                  -0.2893685414821312, -2.543676933492173],
    "initial.qd": [-5.565266280407693e-104, -82.17504879786561, 81.02208448903599, -6.922203111887641e-262,
                   -51.59810224046483, -1.1183293390875735e-05]})


def test_a_body_rocking_between_two_resting_pairs_comes_to_rest():
    """Each impact of the rocking exchanged the held pair for the other (the set's size unchanged), which
    the mode budget did not count: 24000 impacts in 10 ms, past the tests' event budget. A step that
    exchanged the set more than SWAP_BUDGET times went to the fallback, which settled the wedge. Its
    bounces come to rest now (below the event band, or shorter than FLIGHT_TOL dt = 0.5 us), and the
    exact method settles the wedge itself (101 impacts, no fallback)."""
    dt, over = ROCKING_IN_A_CORNER
    scene = jackbox.load_scene(base("cross"), {"gravity": 0.0, **over})
    check_weightless_run(scene, dt)
    traj = simulate(scene, t_end=1.0, dt=dt)
    assert len(traj.impact_t) < 1000, len(traj.impact_t)
    assert set(traj.meta["fallback_reasons"]) <= {"too many contact mode changes"}
    assert traj.meta["fallback_seconds"] < 0.05


def test_a_head_on_collision_at_subnormal_heights_is_measured_against_its_torques():
    """A draw of test_random_weightless_scenes_keep_momentum (seed 5): the checks' angular scale (ANGULAR_FLOOR).

    Box and square jack at heights and angles of 1e-190, moving along x: the angular momentum's terms
    are 5e-190. The jack's two corners strike the wall together; their torques, about 0.06 lambda each,
    cancel, and their lever components of 1e-189 lambda are below those torques' round-off: the total
    moves by 3e-190, which the run's own terms made a drift of 0.62 (allowed 1e-12). Measured against
    the torques the impulses exchange, it is round-off.
    """
    over = {"box.inner_half_width": 0.4212306069085486, "box.wall_thickness": 0.13023431268672045,
            "box.mass": 1.0, "jack.mass": 0.45031610784581844, "jack.half_size": 0.0589559987986606,
            "gravity": 0.0, "restitution": 0.4125192650210362, "ground_restitution": 1.0,
            "initial.q": [-0.05813541780597084, -9.372692118353343e-309, 1.2235349781023913e-189,
                          0.2539467875365583, 3.8184349427991744e-190, 1.2235349781023913e-189],
            "initial.qd": [0.6201886401762168, 0.0, -0.0, -0.23913811301725518, 0.0, 2.442943247056e-312]}
    scene = jackbox.load_scene(base("float"), over)
    check_weightless_run(scene, 0.004757331632358644)
    traj = simulate(scene, t_end=1.0, dt=0.004757331632358644)
    _, angular, lin_scale, scale = momenta(traj, scene.params())
    assert len(traj.impact_t) == 2 and scale > 1e6 * np.abs(angular).max()     # (the floor, not the terms)
    assert np.abs(angular - angular[0]).max() < 1e-185                        # round-off of 1e-189 levers


@pytest.mark.parametrize("case", list(COARSE_TURNS))
def test_a_coarse_step_on_a_fast_turning_box_keeps_momentum_while_a_contact_is_held(case):
    """Held steps that would turn an angle by 0.7-5.7 rad are cut into RK4 passes (integrator.held_passes).

    Each draw holds a contact for tens of steps; the checks are the property
    test's (momentum, energy, gaps), which the whole steps failed.
    """
    dt, over = COARSE_TURNS[case]
    check_weightless_run(jackbox.load_scene(base("cross"), {"gravity": 0.0, **over}), dt)


def test_held_passes_cut_a_step_by_the_fastest_turn():
    """One pass up to TURN_PER_PASS of turn (either body's angle, forwards or backwards, or the jack's way across
    the box over L), then (turn / TURN_PER_PASS)^(5/4).

    k passes over a turn T leave RK4's error C T^5 / k^4: that many keep it C TURN_PER_PASS^5 for any turn.
    """
    from jackbox.engine.integrator import MAX_PASSES, TURN_PER_PASS
    from jackbox.engine.integrator import held_passes as compiled
    held_passes = compiled.py_func         # (compiled without a wrapper for Python callers)
    qd = np.zeros(6)
    assert held_passes(qd, 0.01, 6, 1.0) == 1
    qd[5] = -TURN_PER_PASS / 0.01            # the jack turns exactly TURN_PER_PASS in the step
    assert held_passes(qd, 0.01, 6, 1.0) == 1
    qd[2] = 2.5 * TURN_PER_PASS / 0.01       # the box 2.5 times as far: 2.5^1.25 = 3.14
    assert held_passes(qd, 0.01, 6, 1.0) == 4
    qd[2] = -16 * TURN_PER_PASS / 0.01       # 16 times: 16^1.25 = 32 exactly
    assert held_passes(qd, 0.01, 6, 1.0) == 32
    qd[:] = [1e9, 1e9, 0.0, 1e9, 1e9, 0.0]   # a pair moving as one is not turned by its speed
    assert held_passes(qd, 0.01, 6, 1.0) == 1
    # the jack crossing the box: 3 L / s against it over 0.01 s is a turn of 0.03 rad (2^1.25 = 2.38),
    # and the same across a box of 0.5 m twice that (4^1.25 = 5.66)
    qd[:] = [0.0, 2.4, 0.0, 0.0, -0.6, 0.0]
    assert held_passes(qd, 0.01, 6, 1.0) == 3
    assert held_passes(qd, 0.01, 6, 0.5) == 6
    assert held_passes(np.array([0.0, 0.0, 1e9]), 0.01, 3, 1.0) == MAX_PASSES
    assert held_passes(np.array([5.0, 5.0, 0.0]), 0.01, 3, 1.0) == 1     # (a jack alone: no box to cross)
    assert held_passes(np.array([0.0, 0.0, np.nan]), 0.01, 3, 1.0) == 1


#: a draw of the drops (campaign seed 1; dt, overrides): a box 58 times lighter than its jack pivots on a ground
#: corner while it slides at 24 m/s under the jack, nearly still
SLIDING_UNDER_A_STILL_JACK = (0.003329460190036321, {
    "box.inner_half_width": 1.0, "box.wall_thickness": 0.1794853141133878, "box.mass": 58.42321231521603,
    "jack.mass": 3413.27173722881, "jack.half_size": 0.16343909281510766, "gravity": 9.81,
    "restitution": 0.0, "ground_restitution": 0.0,
    "initial.q": [0.6860419841781038, 2.3602789502554224, -1.4026133315360068, 1.2146146868807755,
                  2.4308385561966763, 0.3172271154844659],
    "initial.qd": [-2.5868329965304673, -1.3436759589580414, 1.1213606713700426, 0.1407179571227754,
                   7.566045444740984e-62, -3.0151435544837605e-308]})


def test_a_box_sliding_fast_under_its_jack_takes_passes_for_the_jack_crossing_it():
    """Its held steps turned the box 0.018 rad each (two passes by the angle) and one gained 1.8e-8 of the
    energy's scale (the tests allow 1e-8 a held step): the jack crosses the turning box at 24 m/s, which
    curves the held motion as a turn of 0.08 rad would. Held steps now count that crossing as a turn
    (integrator.held_passes) and every check of the drops passes."""
    dt, over = SLIDING_UNDER_A_STILL_JACK
    check_drop_run(jackbox.load_scene(base("drop"), over), dt)

#: a draw of the drops (dt, overrides), seed 6: a box pivoting on one ground corner with a plastic jack held
#: against its wall, the two turning as one (0.0245 rad a step, later 0.586)
TURNING_PAIR = (0.009999769744141627, {
    "box.inner_half_width": 0.10000000000000002, "box.wall_thickness": 0.01806494689122035,
    "box.mass": 2.3441040546916248, "jack.mass": 5.494823819221716, "jack.half_size": 0.013943204434348258,
    "gravity": 9.81, "restitution": 0.3185155031881069, "ground_restitution": 0.9040842502963866,
    "initial.q": [-0.05316642795403261, 0.2909211712606221, -2.1923758462024105, -0.09356370534988077,
                  0.2333666025323359, -1.6659685211489226],
    "initial.qd": [1.0489039296771125e-199, 0.002583251731581964, 3.554801484199404e-33, -9.904544411531509e-07,
                   -3.5261582924647967e-69, 0.502292751349494]})


#: a draw of test_random_weightless_scenes_keep_momentum (square; campaign seed 7): a jack 1e4 times lighter than
#: its box, a contact changing the velocities in 1986 of 2000 steps
LIGHT_PRESSED_JACK = (0.0004999999999999999, {
    "box.inner_half_width": 1.0, "box.wall_thickness": 0.02519716488938408, "box.mass": 0.9999997255105045,
    "jack.mass": 9.999997255105045e-05, "jack.half_size": 0.3333333333333333, "gravity": 0.0,
    "restitution": 6.456330508197041e-121, "ground_restitution": 1.0,
    "initial.q": [-1e-05, -0.27614280736652075, -1.6714213085157474, -0.05862687718856346, 0.32429735851263186,
                  -1.6714213085157474],
    "initial.qd": [15.466391661031697, -33.03309747886226, 1.7540574212088553e-230, -43.73110916687199,
                   -6.501909264974962e-44, 60.03508660697581]})


def test_a_light_jack_pressed_for_most_steps_keeps_its_momentum():
    """The draw failed by 3.6e-12 against 1e-13 of the momentum exchanged (3.3e-12): no step moved the
    momentum by more than 1 ulp; the drift is the sum of the velocities' roundings, one a step, which
    the check now allows (:func:`momentum_rounding`: drift 0.17 of it). A wrong impulse is not round-off:
    one on the jack alone would move the momentum by about the jack's, 7e-3, some 3e8 times this bound."""
    dt, over = LIGHT_PRESSED_JACK
    scene = jackbox.load_scene(base("float"), over)
    check_weightless_run(scene, dt)
    traj = simulate(scene, t_end=1.0, dt=dt)
    P = scene.params()
    linear = momenta(traj, P)[0]
    assert 0.1 * momentum_rounding(traj, P) < np.abs(linear - linear[0]).max()     # the case it was kept for


#: a draw of the drops (campaign seed 5; dt, overrides): a jack 37 times its box's mass comes to rest on the
#: box's floor while the box lands on an elastic ground (e_ground = 1), nearly level
ROCKING_ON_AN_ELASTIC_GROUND = (0.009999769744141627, {
    "box.inner_half_width": 0.18815055095614047, "box.wall_thickness": 0.016528600696091095,
    "box.mass": 37.221710478956716, "jack.mass": 1385.4557309792763, "jack.half_size": 0.07470673712867713,
    "gravity": 9.81, "restitution": 0.623430025241633, "ground_restitution": 1.0,
    "initial.q": [1.453401866151839e-122, 0.3800449901631399, 1.1449765303196267e-57, -8.78902190542605e-59, 0.45680658022798204,
                  -0.25070425985857625],
    "initial.qd": [-0.6176121740282003, 4.975041754973066e-163, 9.120412219153067e-183, 2.112655942706267, 1.6114013431898044,
                   10.470143437756864]})


def test_a_heavy_jack_on_a_box_rocking_on_an_elastic_ground_keeps_its_momentum():
    """The pair pivots on one ground corner while the other bounces elastically every 13 us, 1e-9 rad high
    (an elastic ground keeps any rocking, however small, for ever): 2045 impulses in one step, then the
    fallback ("a bounce that neither shrinks nor stops"). Each internal impulse moves the heavy jack's
    velocity by a fraction of its ulp, and those roundings fell one way: the horizontal momentum drifted
    by 5.7e-13 of its scale, which the flat 1e-13 took for a failure; it is 0.58 of the velocities'
    roundings, one an event (:func:`momentum_rounding`). The run finishes, with its stretch in the fallback
    logged; a wrong impulse (one on the jack alone: its momentum, the whole scale) is 1e3 times this bound."""
    dt, over = ROCKING_ON_AN_ELASTIC_GROUND
    scene = jackbox.load_scene(base("drop"), over)
    check_drop_run(scene, dt)
    traj = simulate(scene, t_end=1.0, dt=dt)
    P = scene.params()
    px, scale = horizontal_momentum(traj, P)
    assert 1e-13 * scale < np.abs(px - px[0]).max() < 1e-3 * scale      # the case it was kept for
    assert momentum_rounding(traj, P, axes=slice(0, 1)) < 1e-3 * scale
    assert abs(traj.t[-1] - 1.0) < dt and np.isfinite(traj.q[-1]).all() and len(traj.fallback_t) >= 1


#: a draw of test_random_drops_never_penetrate_nor_gain_energy (campaign seed 8): a jack 5000 times as heavy
#: as its box, nearly as wide, striking with 11 contacts in the impact's LCP
ELEVEN_CONTACTS = (0.00695363207725997, {
    "box.inner_half_width": 0.9657106906685986, "box.wall_thickness": 0.42032712679684847,
    "box.mass": 0.8615348968752946, "jack.mass": 4596.54242631265, "jack.half_size": 0.614790520066383,
    "gravity": 9.81, "restitution": 0.44939993492664077, "ground_restitution": 0.44939993492664077,
    "initial.q": [-0.3084671175952448, 2.1418308889697197, -2.0452202281387653, -0.26760432441388776,
                  2.2214010988069703, -2.0452202281387653],
    "initial.qd": [31.140000459501213, 36.11980073072688, 17.395494324269976, 32.62648725320051,
                   -24.628100961483902, 38.74225536724814]})


def test_a_heavy_jack_striking_with_eleven_contacts_stays_out_of_the_walls():
    """The impact's LCP had 11 contacts of rank 5: Gauss-Seidel stopped unconverged after 20000 sweeps
    (a SolverWarning) and the jack ended 5.5e-8 L inside a wall. Sets larger than MAX_ENUMERATED are now
    enumerated up to the coordinates' count (impact.lcp): no warning, every check passes."""
    dt, over = ELEVEN_CONTACTS
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_drop_run(jackbox.load_scene(base("drop"), over), dt)


#: a draw of test_random_drops_never_penetrate_nor_gain_energy (campaign seed 3): a jack 1e4 times as heavy as
#: its box, spinning at 10 rad/s, e = 0.71
HEAVY_SPINNING_JACK = (0.004681775960211641, {
    "box.inner_half_width": 0.26106245020097363, "box.wall_thickness": 0.09257738102428269, "box.mass": 1.0,
    "jack.mass": 9999.999999999989, "jack.half_size": 0.04582670907021058, "gravity": 9.81,
    "restitution": 0.7145314954653456, "ground_restitution": 0.7145314954653456,
    "initial.q": [-0.20781453162613042, 0.8639825862745883, -0.0001984126982985795, -0.2078141396765553,
                  0.8659580121085101, 2.1413942408914943],
    "initial.qd": [-0.42929468053015457, -0.32511264588208777, -2.458880355899997, -0.35068179479488987,
                   0.248610688632709, 10.633171848522704]})


def test_a_box_rocking_under_a_jack_1e4_times_its_mass_stays_out_of_the_ground():
    """It went 4.6e-4 L through the floor (RunStoppedError) while the impact LCP's Gauss-Seidel failed on
    more than 10 contacts; with those enumerated (impact.lcp) it ran to the end 1e-8 L inside the ground:
    the fallback's position projection stopped after four Newton passes short of a 0.02 L correction.
    With fallback.PROJECTION_PASSES = 8 every sample is at the held level or above, and every check passes."""
    dt, over = HEAVY_SPINNING_JACK
    scene = jackbox.load_scene(base("drop"), over)
    check_drop_run(scene, dt)
    assert len(simulate(scene, t_end=1.0, dt=dt).fallback_t) >= 1       # (the case is about the fallback)


#: a draw of the drops (campaign seed 61, twice, the jack's start moved by 4e-3 L): a jack 6000 times its box's
#: mass, e = 0, dt = 8 ms, wedged in a corner of a box that lands on one corner and tips, turning 0.1 rad a step
HEAVY_JACK_LET_GO_IN_A_CORNER = (0.008053187810877667, {
    "box.inner_half_width": 0.24470605083535207, "box.wall_thickness": 0.08997131439347318,
    "box.mass": 0.27797820856163197, "jack.mass": 1658.6212778666961, "jack.half_size": 0.20561516704743577,
    "gravity": 9.81, "restitution": 0.0, "ground_restitution": 0.0,
    "initial.q": [0.020123488821369325, 0.44384255031533554, -2.00001, 0.015702945958904424, 0.44431024091212185,
                  -4.998515541409036],
    "initial.qd": [-0.00041818541949667455, 5.511478558710474e-34, 1.805065747827e-312, 0.0, -1.1197588640925782,
                   -3.9613012239061782]})


@pytest.mark.parametrize("jack_at", [(0.015702945958904424, 0.44431024091212185),
                                     (0.01953489151880575, 0.44255647573304124)])
def test_a_heavy_jack_let_go_in_a_corner_at_a_large_step_ends_it_on_the_held_level(jack_at):
    """Five contacts held (the jack flush in a corner, the box on a ground corner); two let go at a step's
    start, and RK4's drift in that step (omega dt = 0.096) was ~1e-6 L: the projection's one Newton pass left
    its square, one held gap 3.1e-12 L deep (the check's floor is 2e-12 L) and another 5e-12 L above its
    level. Passes are now repeated while a held gap is off its level by more than REPASS of it
    (modes.project_rows, and the ride's settle): every sample is within a part in ten of the level or above.
    The second start's energy rises by 1.2e-8 of its scale in that step (REST_CAP), RK4's error on the
    motion that begins there: 1.8e-9 at dt / 2, 1.3e-10 at dt / 4."""
    dt, over = HEAVY_JACK_LET_GO_IN_A_CORNER
    q0 = list(over["initial.q"])
    q0[3:5] = jack_at
    scene = jackbox.load_scene(base("drop"), {**over, "initial.q": q0})
    check_drop_run(scene, dt)
    traj = simulate(scene, t_end=1.0, dt=dt)
    L = scene.params()["L"]
    gaps = check_gaps(traj, scene)
    assert gaps.min() >= -1.1 * EVENT / 2 * L, gaps.min() / L
    released = traj.contact_t[traj.contact_event == 2]
    assert ((released > 0.12) & (released < 0.13)).sum() == 2        # (the case it was kept for: two let go)


#: a draw of test_random_weightless_scenes_keep_momentum (cross; campaign seed 5): a jack 100 times as heavy as
#: its box spinning at 308 rad/s, omega dt 3.4 for the run
FAST_CROSS = (0.003824412368067149, {
    "box.inner_half_width": 0.15728154890691343, "box.wall_thickness": 0.05934127432542424,
    "box.mass": 3.5903375353794966, "jack.mass": 364.65516828539364, "jack.half_size": 0.07864077445345671,
    "gravity": 0.0, "restitution": 0.46357081225595864, "ground_restitution": 1.0,
    "initial.q": [-3.3096521560810407e-111, 0.06545097902209247, 0.03, 0.02976940520673322, 0.06634432919942936,
                  0.029999999988640353],
    "initial.qd": [-21.592473444667394, -9.084551240366047e-187, -5.623242519970149e-237, -19.13420864471711,
                   -26.29442961444725, -308.05248139953653]})


def test_the_fallbacks_hand_over_keeps_the_angular_momentum():
    """The angular momentum drifted by 5.3e-6 of its scale (allowed 4.7e-8), all of it in one step: the
    fallback's hand-over to the exact method, whose projection onto the held rows moves the bodies at fixed
    rates. With nothing outside the pair acting, the hand-over now shifts the whole pair across its centre
    of mass's velocity to restore it (fallback.keep_angular_momentum), which moves no gap, rate or energy.

    The scene of that report no longer reaches the fallback (Zeno cascades shorter than ZENO_TOL dt end in
    rest, and the exact method resolves it): it must keep its momenta on its own. The restoring shift is
    checked by itself on its state: the jack moved out of a wall at fixed rates, as the projection moves it.
    """
    import numba

    from jackbox.engine.fallback import angular_momentum, keep_angular_momentum
    from jackbox.engine.records import MODEL_AT, ModelType, from_table

    dt, over = FAST_CROSS
    scene = jackbox.load_scene(base("cross"), over)
    check_weightless_run(scene, dt)
    run = api.prepare(scene)
    kernel = loader.kernel_for(scene)
    loader.compile_kernel(kernel, "exact")

    @numba.njit
    def hand_over(table, q, moved, qd, p):
        model = from_table(table, MODEL_AT, ModelType)
        winv = np.empty(6)
        model.inverse_mass(p, winv)
        before = angular_momentum(model, q, qd, winv)
        drifted = angular_momentum(model, moved, qd, winv) - before
        energy = model.energy(0.0, moved, qd, p)
        keep_angular_momentum(model, 0.0, moved, qd, p, before, winv)
        return drifted, angular_momentum(model, moved, qd, winv) - before, energy, model.energy(0.0, moved, qd, p)

    q, qd = np.array(scene.q0, float), np.array(scene.qd0, float)
    moved = q.copy()
    moved[3] += 1e-6 * over["box.inner_half_width"]       # what a projection moves a jack by, at fixed rates
    shifted = moved.copy()
    drifted, left, e0, e1 = hand_over(kernel.table(), q, shifted, qd, run.p)
    P = scene.params()

    class Traj:    # what momenta() reads
        pass

    state = Traj()
    state.q, state.qd = q[None], qd[None]
    scale = momenta(state, P)[3]
    assert abs(drifted) > 1e-8 * scale              # the move alone changes it
    assert abs(left) <= 1e-15 * scale, (drifted / scale, left / scale)
    assert np.abs(shifted - moved).max() > 0.0        # restored by moving both bodies
    np.testing.assert_array_equal(shifted[[2, 5]], moved[[2, 5]])
    # the whole pair moved together: the jack's place in the box, so every gap, is where the move left it
    np.testing.assert_allclose(shifted[3:5] - shifted[:2], moved[3:5] - moved[:2], rtol=0, atol=1e-16)
    assert e1 == e0


#: a draw of the drops (campaign seed 57, 1 in 2000; dt, overrides): a box lighter than its square jack (0.9
#: L) slides on an elastic ground with the jack on its floor; the fallback takes the box's rocking on one
#: corner, its other corner hovering 2.1e-4 L above the ground with no rate (a Moreau-Jean step stops an
#: approach at the velocity level wherever the step's fall would close the gap)
HOVERING_CORNER = (0.0069045205847500365, {
    "box.inner_half_width": 2.7120723698993916, "box.wall_thickness": 1.2057056407727944,
    "box.mass": 2.7120723698993916, "jack.mass": 7.355336539571702, "jack.half_size": 2.4348322607901234,
    "gravity": 9.81, "restitution": 0.0, "ground_restitution": 1.0,
    "initial.q": [-4.514519196816643e-205, 7.740661404388802, 2.7557313707070068e-06, 6.420949316067478e-07,
                  7.507657948961146, 2.7557313707070068e-06],
    "initial.qd": [1.1910106505041555e-231, -5.351156161557139, 0.1600751212908923, -0.42837651027825585,
                   -1.2406492800591398, -1.2746646741576104]})


def test_the_fallbacks_hand_over_pushes_no_contact_into_a_wall():
    """The fallback's hand-over put every contact its last step ended with no normal rate on the held level,
    also the box corner hovering 2.1e-4 L above the ground: the projection turned the box by 2.7e-5 rad and
    pushed the jack 5.6e-6 L into the box's wall (RunStoppedError at t = 0.95 s). A contact the hand-over's
    projection pushes below the level now joins it. (Holding only the contacts within T_GAP instead left
    hovering tips to chatter in the exact method: two kept draws over their event budgets.)"""
    dt, over = HOVERING_CORNER
    check_drop_run(jackbox.load_scene(base("drop"), over), dt)


#: a draw of the drops (campaign seed 59, 2 in 2000 with its mass-scaled twin; dt, overrides): a box 13 times
#: lighter than its square jack, low restitution everywhere; Zeno in several contacts sends a step to the fallback
#: with a box corner 4.8e-3 L into the ground
DEEP_CORNER_IN_THE_FALLBACK = (0.0004999999999999999, {
    "box.inner_half_width": 0.6452667264188695, "box.wall_thickness": 0.020333261336586052,
    "box.mass": 1.035142166679344, "jack.mass": 13.031667784522998, "jack.half_size": 0.5767709880715735,
    "gravity": 9.81, "restitution": 0.11729675600339665, "ground_restitution": 0.006037743413113363,
    "initial.q": [0.24321375149337368, 2.770613409272047, 1.0849382142797257, 0.2432137514889028,
                  2.7706134092744077, 1.1164496195701124],
    "initial.qd": [-2.3144599542094553e-38, 8.24257266155739, -8.79627667821213, -7.075664469422217,
                   -5.5693016349379505, -8.37748708125336]})


def test_the_fallbacks_projection_puts_a_deep_corner_on_the_level():
    """The fallback's projection (fallback.project_gaps) took the corner from 4.8e-3 L down to 1.7e-12 L below
    the level in three passes, then stalled there: the members kept from the deep first pass (the jack's tips
    1.4e-2 L above the box's floor) set its LCP's tolerance (relative to the largest right-hand side), which
    accepted the corner where it was (-2.2e-12 L at t = 0.335 s, the floor here -2e-12 L). A pass that does
    not halve the depth now starts its members afresh."""
    dt, over = DEEP_CORNER_IN_THE_FALLBACK
    check_drop_run(jackbox.load_scene(base("drop"), over), dt)


def test_a_held_pair_turning_fast_gains_no_energy():
    """A draw of test_random_drops_never_penetrate_nor_gain_energy, kept (seed 6; the same scene at four
    mass scales failed alike).

    The box pivots on one ground corner with the jack held against its wall, both turning as one: a
    held step of 0.0245 rad in one pass raised the energy by 1.6e-8 of its scale (the tests allow
    1e-8), and cut into passes of at most 0.02 rad, one of 0.586 rad raised it by 1.7e-8. The passes
    grow as the turn to the 5/4 now (integrator.held_passes), which keeps RK4's error that of one pass
    of TURN_PER_PASS.
    """
    dt, over = TURNING_PAIR
    check_drop_run(jackbox.load_scene(base("drop"), over), dt)


def test_fallback_projection_keeps_angular_momentum():
    """The fallback's position projection, on a cross whose tip is 1e-6 L inside the
    right wall while it slides along it: the tip comes out to the event level,
    linear momentum is untouched (rates are), and the angular momentum too.

    A shift at fixed rates changes it by sum m (dx vy - dy vx): here the jack
    moves out by about 1e-6 L at 3 L/s along the wall, 1e-6 of its scale if
    nothing kept it (as was seen in long fallback stretches of weightless
    scenes at coarse dt). Kept: round-off (measured 0).
    """
    import numba

    from jackbox.engine.fallback import project_gaps
    from jackbox.engine.records import MODEL_AT, ModelType, from_table, scratch

    scene = base("cross")
    run = api.prepare(scene)
    kernel = loader.kernel_for(scene)
    loader.compile_kernel(kernel, "exact")
    tol = api.tolerances(run, kernel)
    P = scene.params()
    a = P["a_jack"] if "a_jack" in P else 0.5
    q = np.array([0.0, 0.0, 0.0, 1.0 - a + 1e-6, 0.0, 0.0])    # tip (+a, 0) past the right wall
    qd = np.array([0.4, -0.2, 1.5, 0.3, 3.0, -2.0])

    @numba.njit
    def project(table, t, q, qd, p, tol):
        model = from_table(table, MODEL_AT, ModelType)
        ws = scratch(model)
        project_gaps(model, t, q, qd, p, tol, ws)

    class Traj:    # what momenta() reads
        pass

    before = Traj()
    before.q, before.qd = q[None].copy(), qd[None].copy()
    moved = q.copy()
    project(kernel.table(), 0.0, moved, qd.copy(), run.p, tol)
    after = Traj()
    after.q, after.qd = moved[None], qd[None]
    gaps = contact_gaps(moved, scene.points, 1.0, 0.1, False)
    assert gaps.min() >= -0.5 * jackbox.api.EVENT_TOL - 1e-15
    assert np.abs(moved - q).max() > 5e-7         # the tip was moved out
    (_, l0, _, scale), (_, l1, _, _) = momenta(before, P), momenta(after, P)
    assert abs(l1[0] - l0[0]) <= 1e-15 * scale, (l1[0] - l0[0]) / scale


#: a fixed box tilted by `tilt`, a square jack: set flush into the box's lowest corner, gravity presses it
#: into both walls there, four contacts on three degrees of freedom (a redundant set)
TILTED = """
name = "tilted"
[params]
tilt = 0.3
[box]
inner_half_width = 1.0
wall_thickness = 0.1
mass = 4.0
motion = "prescribed"
x = "0"
y = "0"
theta = "tilt"
[jack]
shape = "square"
half_size = 0.25
mass = 0.7
[world]
gravity = 9.81
[impact]
restitution = 0.0
[initial]
q = [0, 0, 0, 0, 0, 0]
qd = [0, 0, 0, 0, 0, 0]
"""


@pytest.mark.parametrize("tilt", [0.1, 0.3, 0.6])
def test_a_jack_pressed_into_a_corner_is_held_by_the_lcps_forces_none_pulling(tilt):
    """A redundant held set: the held dynamics' forces are the contact update's LCP forces.

    The rank-revealing solve gives the rows that depend on earlier ones no
    force; in the contacts' own order that put the load of the dependent
    contact on the others, one of them pulling (-3.1, -2.3, -0.9 N here, the
    floor for a pull -1e-5 N), so the release screen stopped every held step
    and the contact update held the same set again (a jack in a corner of the
    shaken box at e = 0 went through it on 394 of 3000 steps). The contacts
    the LCP loads now come first (modes.rest_index). The jack stays at rest
    either way: its held accelerations are zero.

    Four wall contacts on the jack's three degrees of freedom in the box are
    redundant at every pose: the update holds the three independent rows and
    marks the fourth FOLLOWS (persistent, not a row of the held dynamics;
    modes.hold_independent).
    """
    import numba

    from jackbox.engine.modes import contact_accel, update_contacts
    from jackbox.engine.records import (AF, FOLLOWS, LAM, MODE_SLOTS, MODEL_AT, RIDX, T_AREST, T_EVENT, Events,
                                        ModelType, from_table, scratch)

    scene = scene_from_text(TILTED, "tilted.toml")
    run = api.prepare(scene)
    kernel = loader.kernel_for(scene)
    loader.compile_kernel(kernel, "exact")
    tol = api.tolerances(run, kernel)
    p = run.p.copy()
    p[list(scene.params()).index("tilt")] = tilt
    c = 1.0 - 0.25 - 0.5 * tol[T_EVENT]            # the jack's centre, flush in the corner (-L, -L)
    q = np.array([-c * np.cos(tilt) + c * np.sin(tilt), -c * np.sin(tilt) - c * np.cos(tilt), tilt])

    @numba.njit
    def held(table, q, qd, p, tol):
        model = from_table(table, MODEL_AT, ModelType)
        ws = scratch(model)
        rest = np.zeros(model.n_contact + MODE_SLOTS, np.int64)
        log = Events(np.zeros(64), np.zeros(64, np.int64), np.zeros(64, np.int64))
        _, m = update_contacts(model, 0.0, q, qd, p, tol, rest, ws, log, 0)
        contact_accel(model, 0.0, q, qd, p, m, ws.n[AF], ws)
        floor = np.empty(m)
        for i in range(m):
            floor[i] = -tol[T_AREST] / ws.A[i, i]
        return (ws.k[RIDX][:m].copy(), ws.c[LAM][:m].copy(), floor, ws.A[:m, :m].copy(), ws.n[AF].copy(),
                rest[:model.n_contact].copy())

    rows, force, floor, A, accel, rest = held(kernel.table(), q, np.zeros(3), p, tol)
    persistent = np.flatnonzero(rest)
    assert len(persistent) == 4                                    # the jack flush in the corner: four contacts
    follows = [k for k in persistent if rest[k] == FOLLOWS]
    assert len(follows) == 1 and follows[0] not in rows            # redundant: one follows the three held
    assert len(rows) == 3 and np.linalg.matrix_rank(A) == 3        # the held rows independent
    assert (force >= floor).all(), (rows, force)
    assert force.sum() > 0.5 * 0.7 * 9.81                          # (they carry the jack)
    assert np.abs(accel).max() <= 1e-12 * 9.81, accel



def test_a_jack_wedged_in_the_corner_of_a_moving_box_keeps_the_contact_it_does_not_hold_closed():
    """A square jack falls into the lowest corner of a tilted box that shakes and rocks, and stays there.

    Four wall contacts on the jack's three degrees of freedom: the contact
    update holds three rows and marks the fourth FOLLOWS (modes.hold_independent),
    which no step reads, projects or watches. Its gap must follow the held
    ones' by the geometry alone: every sample's four gaps (numpy's geometry,
    not the kernel's) stay on the held level, to round-off of it, while the
    box moves under them. Holding two rows of the four (a wrong count of
    what the geometry fixes) lets the jack slide out along a wall.
    """
    from jackbox.engine.records import T_EVENT

    tilt, c = 0.3, 0.75 - 1e-4             # the jack's centre 1e-4 L from flush in the corner (-L, -L)
    x, y = -c * math.cos(tilt) + c * math.sin(tilt), -c * math.sin(tilt) - c * math.cos(tilt)
    text = TILTED.replace('x = "0"', 'x = "0.05*sin(3*t)"').replace('theta = "tilt"', 'theta = "tilt + 0.1*sin(2*t)"')
    text = text.replace("q = [0, 0, 0, 0, 0, 0]", f"q = [0, 0, 0, {x!r}, {y!r}, {tilt!r}]")
    text = text.replace("qd = [0, 0, 0, 0, 0, 0]", "qd = [0, 0, 0, 0, 0, 0.2]")
    scene = scene_from_text(text, "wedged.toml")
    traj = simulate(scene, t_end=2.0, dt=1e-3)
    check_finite(traj)
    gaps = check_gaps(traj, scene)
    names = scene.constraint_names
    corner = [names.index(n) for n in traj.held]
    assert sorted(traj.held) == ["bottom:2", "bottom:3", "left:1", "left:2"], traj.held   # (corner 2 on both)
    settled = traj.t >= (traj.contact_t.max() if len(traj.contact_t) else 0.0)
    assert settled.sum() > 0.9 * len(traj.t)            # (wedged within the first tenth of the run)
    tol = api.tolerances(api.prepare(scene), loader.kernel_for(scene))
    level = -0.5 * tol[T_EVENT]
    off = np.abs(gaps[settled][:, corner] - level).max()
    assert off <= 1e-3 * tol[T_EVENT], (off, tol[T_EVENT])


@pytest.mark.parametrize("rows", [[13], [12, 13], [12, 13, 18], [14, 15, 16, 17]])
def test_held_accelerations_hold_the_rows_as_numpy_solves_them(rows):
    """The held dynamics on one, two, three and four rows of a moving pair, against numpy's solve.

    The engine solves one and two held rows of a six-coordinate pair with its
    loops unrolled, and any other number with the same code over a count
    (modes.held_solve): each must give the accelerations ``a0 + W J^T lam``
    whose held rows' accelerations vanish, ``J a + bias = 0``.
    """
    import numba

    from jackbox.engine.modes import contact_accel
    from jackbox.engine.records import AF, LAM, MODEL_AT, RIDX, ModelType, from_table, scratch

    kernel = loader.kernel_for(jackbox.load_scene("drop"))
    loader.compile_kernel(kernel, "exact")
    p = api.prepare(jackbox.load_scene("drop")).p
    rng = np.random.default_rng(len(rows))
    q = np.array([0.1, 1.3, 0.2, -0.1, 1.2, 0.7]) + 0.05 * rng.standard_normal(6)
    qd = rng.standard_normal(6)

    @numba.njit
    def held(table, q, qd, p, rows):
        model = from_table(table, MODEL_AT, ModelType)
        ws = scratch(model)
        for i in range(rows.shape[0]):
            ws.k[RIDX][i] = rows[i]
        contact_accel(model, 0.3, q, qd, p, rows.shape[0], ws.n[AF], ws)
        return ws.n[AF].copy(), ws.c[LAM][:rows.shape[0]].copy()

    accel, lam = held(kernel.table(), q, qd, p, np.array(rows, np.int64))
    n, C = kernel.N_DOF, kernel.N_CONTACT
    J, bias, a0, w = np.zeros((C, n)), np.zeros(C), np.zeros(n), np.zeros(n)
    kernel.phi_q(0.3, q, p, J)
    kernel.gap_bias(0.3, q, qd, p, bias)
    kernel.accel(0.3, q, qd, p, a0)
    kernel.inverse_mass(p, w)
    Jr = J[rows]
    lam_ref = np.linalg.solve(Jr @ np.diag(w) @ Jr.T, -(Jr @ a0 + bias[rows]))
    a_ref = a0 + w * (Jr.T @ lam_ref)
    scale = np.abs(a0).max() + np.abs(w * (Jr.T @ lam_ref)).max()
    np.testing.assert_allclose(lam, lam_ref, rtol=1e-11, atol=1e-12 * np.abs(lam_ref).max())
    np.testing.assert_allclose(accel, a_ref, rtol=0, atol=1e-13 * scale)
    assert np.abs(Jr @ accel + bias[rows]).max() <= 1e-13 * scale * np.abs(Jr).max()

def test_a_box_corner_on_an_elastic_ground_stops_bouncing_below_the_event_band():
    """A draw of test_random_drops_never_penetrate_nor_gain_energy, kept (seed 3): a plastic
    square jack lies on the box's wall while the box pivots on one corner on an elastic
    ground (e = 1).

    After each simultaneous impact the corner left at 2.5e-6 L/s, 7 times the rest speed
    REST_TOL sqrt(g L), and came back 0.49 us later: with e = 1 every bounce as high as the
    last, 3e-13 L, inside the event band. Over 20000 events in 7 ms (OverBudget). A bounce
    that cannot rise a whole band above the held level is at rest now: the corner is held.
    """
    over = {"box.inner_half_width": 1.2517656065090836, "box.wall_thickness": 0.1674003877239431,
            "box.mass": 1.0, "jack.mass": 1.0, "jack.half_size": 0.4981757095893548, "gravity": 9.81,
            "restitution": 0.0, "ground_restitution": 1.0,
            "initial.q": [0.13632009760169858, 2.451961881030888, 1.4278358107755693, -0.07570515489944027,
                          2.482481123444938, -0.04522471736810618],
            "initial.qd": [-7.664884973496688e-166, -0.26174230839549595, -8.642709466315943e-10,
                           -0.12107770847307839, 0.13811169123086345, 1e-323]}
    scene = jackbox.load_scene(base("drop"), over)
    dt = 0.004549499233143745
    check_drop_run(scene, dt)                  # (OverBudget before: 15446 events by t = 0.819 s)
    traj = simulate(scene, t_end=1.0, dt=dt, budget=1000)
    names = list(traj.constraint_names)
    corner = names.index("ground:1")
    assert np.sum(traj.impact_constraint == corner) < 100
    held = traj.contact_t[(traj.contact_constraint == corner) & (traj.contact_event == 1)]
    assert len(held) >= 1 and held[0] < 0.82          # the corner comes to rest where it chattered
    assert len(traj.fallback_t) == 0


#: a draw of the drops (dt, overrides), seed 6: a tiny elastic cross (5% of the box) whose tip bounces
#: on the wall of a box that slides on both ground corners, every 50 us, neither shrinking nor stopping
ROCKING_ELASTIC_JACK = (0.0005, {
    "box.inner_half_width": 0.11258258637345499, "box.wall_thickness": 0.0390997242586913,
    "box.mass": 1.5848931924611136, "jack.mass": 2.5118864315095806, "jack.half_size": 0.00562912931867275,
    "gravity": 9.81, "restitution": 1.0, "ground_restitution": 0.3591523235924468,
    "initial.q": [0.07303871667917039, 0.19901981757947745, 1.1691722922917025, 0.07303872840274173,
                  0.1990198126003727, 1.1691722922917025],
    "initial.qd": [0.43881938375120844, -0.11928238798607879, -2.0633532577189525e-301, 0.43881938375120844,
                   -0.2677933359141878, 13.950785107586013]})


def test_an_elastic_bounce_that_neither_shrinks_nor_stops_goes_to_the_fallback():
    """A draw of test_random_drops_never_penetrate_nor_gain_energy, kept (seed 6): over the event budget.

    From t = 0.69 s one tip of an elastic cross (e = 1) strikes the box's wall every
    50 us at 3e-4 m/s, 15 impacts a step of 0.5 ms, as high each time: no Zeno cascade,
    and too fast for the rest speed. 25982 events in 1 s. A run of steps with
    DENSE_SLOW slow approaches or more (records.DENSE_SCORE) now hands the next steps
    to the fallback, whose plastic rule for slow approaches lays the tip down.
    """
    dt, over = ROCKING_ELASTIC_JACK
    scene = jackbox.load_scene(base("drop"), over)
    check_drop_run(scene, dt)                          # (OverBudget before, by t = 0.75 s)
    traj = simulate(scene, t_end=1.0, dt=dt, budget=5000)
    assert "a bounce that neither shrinks nor stops" in traj.meta["fallback_reasons"]
    assert 0.69 < traj.fallback_t[0, 0] < 0.75
    assert traj.impact_t.max() < 0.75                  # (at rest for good after the fallback)


def test_a_step_with_a_thousand_passes_goes_to_the_fallback():
    """A draw of test_random_drops_never_penetrate_nor_gain_energy, kept (seed 5): over the event budget.

    An elastic square jack (e = 1) lies on the floor of a box that the ground (e = 0.27)
    holds. Jack and box fall together, so the jack's free normal acceleration is zero and
    no rest speed stops its bounces: from t = 0.51 s three steps took 5225 events each,
    every 0.34 us, then the pair bounced together every 69 us, 21000 events in 60 ms. A
    step now goes to the fallback after MAX_EVENTS passes (1024; was 4096).
    """
    dt = 0.0017840580479765928
    over = {"box.inner_half_width": 0.1519873226387709, "box.wall_thickness": 0.018104965250806845,
            "box.mass": 5.332317463528418, "jack.mass": 28.43360953185014, "jack.half_size": 0.07599366131938545,
            "gravity": 9.81, "restitution": 1.0, "ground_restitution": 0.2682787478118283,
            "initial.q": [1.811830075997388e-08, 0.5107432683318945, -0.24903167413433214, -0.023126898085901473,
                          0.5612837175300548, -1.2136785739245701],
            "initial.qd": [-0.05960532066549205, 7.846233293052586e-235, -0.3040834431744944,
                           -0.036156015001770445, 0.04978881859331464, 1.0361065858598555]}
    scene = jackbox.load_scene(base("drop"), over)
    check_drop_run(scene, dt)                          # (OverBudget before, by t = 0.54 s)
    traj = simulate(scene, t_end=1.0, dt=dt, budget=5000)
    # since Zeno cascades shorter than ZENO_TOL dt end in rest, the box comes to rest on the ground a little
    # sooner, and the jack's bounce on its floor reaches the fallback through the run of dense steps
    # (records.DENSE_SCORE) at 0.54 s, before any one step takes MAX_EVENTS passes
    assert traj.meta["fallback_reasons"][0] in ("too many events in one step", "a bounce that neither shrinks nor stops")
    assert 0.5 < traj.fallback_t[0, 0] < 0.56


#: a draw of the drops (dt, overrides) that the exact method hands to the fallback for a while: a heavy
#: square jack sliding down the box's left wall while the box rocks on both ground corners
SLIDING_HEAVY_JACK = (0.003657083753810756, {
    "box.inner_half_width": 1.0, "box.wall_thickness": 0.12209745405802479, "box.mass": 1.0,
    "jack.mass": 120.2201346620432, "jack.half_size": 0.5528944423671883, "gravity": 9.81,
    "restitution": 0.0, "ground_restitution": 0.18588016644022456,
    "initial.q": [0.629263885602878, 1.887629248919853, 1.319156318177324,
                  0.9750557949057941, 1.798729748385598, 1.319156318177324],
    "initial.qd": [-0.07738873114897458, 0.0, -0.3785512285256904, 0.3460737122441467,
                   0.4974592476538934, 0.0]})


def test_fallback_pays_for_its_projections_from_the_motion():
    """A draw of test_random_drops_never_penetrate_nor_gain_energy, kept: a heavy square
    jack (120 times the box) spinning at omega dt = 0.08 slides down the box's left wall
    while the box rocks on both ground corners, at e = 0 on the walls.

    The exact method hands [0.497, 0.61] s to the fallback. Each of its steps drifts
    into the wall and the ground by some 1e-4 L (first order, fast rotation), and the
    position projection that undoes the drift lifts the bodies at fixed rates: that
    step's energy rose by 2.2e-5 of its scale, with nothing to supply it. The lift is
    now paid from the motion about the centre of mass (fallback.pay_from_motion):
    no step of it rises beyond FALLBACK_RISE, and the horizontal momentum is kept.
    """
    dt, over = SLIDING_HEAVY_JACK
    scene = jackbox.load_scene(base("drop"), over)
    traj = simulate(scene, t_end=1.0, dt=dt)
    assert len(traj.fallback_t) >= 1        # the case is about the fallback: it must be reached
    # each stretch says why the exact method handed it over
    assert len(traj.meta["fallback_reasons"]) == len(traj.fallback_t)
    assert set(traj.meta["fallback_reasons"]) <= set(jackbox.api.HANDOFF_REASONS.values())
    check_finite(traj)
    check_gaps(traj, scene)
    check_energy(traj, scene)
    P = scene.params()
    px, scale = horizontal_momentum(traj, P)
    assert np.abs(px - px[0]).max() <= 1e-13 * scale



#: two draws of the drops (campaign seeds 1 and 2; dt, overrides) whose fallback's plastic impacts lock a box
#: under a jack 190 and 1400 times its mass, as its corner falls into the ground
LOCKED_HEAVY_JACKS = {
    "rocking": (0.0047693791677545444, {
        "box.inner_half_width": 0.2246180103127523, "box.wall_thickness": 0.057112960824185106, "box.mass": 1.0,
        "jack.mass": 193.40726253374413, "jack.half_size": 0.12064095753716918, "gravity": 9.81,
        "restitution": 0.786947139098715, "ground_restitution": 0.786947139098715,
        "initial.q": [2.246180103127523e-06, 0.3398002974136569, 3.0388358689955552, 0.018818300008388127,
                      0.3467805191783466, 2.8788579679269373],
        "initial.qd": [1.9055478003572934e-261, 0.9659064829499019, -1.0775787058880761, -1.0157129130849463,
                       1.1883418986064334, 1.93593802270223e-310]}),
    "spinning": (0.004800008321217117, {
        "box.inner_half_width": 0.31622776601683794, "box.wall_thickness": 0.028075508685558317,
        "box.mass": 0.26367718978385823, "jack.mass": 1391.1699354896973, "jack.half_size": 0.046884461165772495,
        "gravity": 9.81, "restitution": 0.0, "ground_restitution": 1.0,
        "initial.q": [1.6297295825980285e-254, 0.826507564712371, -1.175494351e-38, 0.2324605387324803,
                      0.7909000743874882, -6.103515625e-05],
        "initial.qd": [-1.7298762343821526e-192, 4.923508921003018e-15, -7.204930698843062, -11.086756470992253,
                       2.4668851999240415e-307, -1.6126291394938028e-161]}),
}


@pytest.mark.parametrize("case", sorted(LOCKED_HEAVY_JACKS))
def test_a_projection_after_plastic_impacts_lock_the_pair_is_paid_from_its_fall(case):
    """A fallback step whose plastic impacts lock the pair, then lift it out of the ground, gains nothing.

    The box's corner falls into the ground within the step (the midpoint rule's first half), and the
    projection that lifts it out lifts the heavy jack resting on its floor: 0.12 J (1.4e-4 of the scale)
    and 37 J (4.2e-4) in one step, where the impacts had left no motion about the centre of mass to pay
    from. The rest is now paid from the pair's fall (fallback.pay_from_motion): every check of the drops
    passes, the horizontal momentum among them.
    """
    dt, over = LOCKED_HEAVY_JACKS[case]
    scene = jackbox.load_scene(base("drop"), over)
    check_drop_run(scene, dt)
    assert len(simulate(scene, t_end=1.0, dt=dt).fallback_t) >= 1       # (the case is about the fallback)

@pytest.mark.slow
@given(data=st.data())
@PROPERTY
def test_random_prescribed_box_never_penetrates(data):
    """A hand-shaken box (it does work, so no energy law) with a hexagon jack: gaps, finite.

    Shaking up to amp (2 pi freq)^2 = 18 g; e anywhere in [0, 1], both ends
    included (e = 0 on a moving floor was left out while it chattered for
    seconds: see test_plastic_hexagon_on_a_tilting_floor_settles_quickly).
    """
    scene_base = base("hand")
    speed = data.draw(log_uniform(0.1, 10.0)) * math.sqrt(9.81)
    # the hand holds the box at the origin at t = 0
    q, qd = data.draw(start_state(scene_base.points, 1.0, 0.1, False, speed, 0.3, box_at_origin=True))
    over = {"amp": data.draw(st.floats(0.0, 0.5)), "freq": data.draw(st.floats(0.0, 3.0)),
            "jack.mass": data.draw(log_uniform(0.01, 10.0)),
            "restitution": data.draw(restitution),
            "initial.q": q, "initial.qd": qd}
    check_prescribed_run(jackbox.load_scene(scene_base, over), data.draw(log_uniform(5e-4, 1e-2)))


def check_prescribed_run(scene, dt):
    """The checks of :func:`test_random_prescribed_box_never_penetrates` on a run of one second."""
    traj = simulate(scene, t_end=1.0, dt=dt)
    check_finite(traj)
    check_gaps(traj, scene)


# --- named cases ------------------------------------------------------------------------

L_F, A_F = 1.0, 0.3     # the float structure's box half-width and jack half-size


def float_scene(**over):
    """The weightless float structure (L = 1, w = 0.2, square jack a = 0.3) with overrides."""
    return jackbox.load_scene(base("float"), {"gravity": 0.0} | over)


def rel_angle_range(traj):
    phi = traj.q[:, 5] - traj.q[:, 2]
    return phi.min(), phi.max()


@pytest.mark.slow
def test_long_elastic_run_keeps_energy_over_200000_impacts():
    """e = 1, no gravity: a fast spinning square jack in a free box, 2.7e5 impacts in 100 s.

    Free flight is linear in t (RK4 exact) and an elastic impulse keeps the
    kinetic energy exactly in exact arithmetic, so only round-off moves the
    energy: a random walk of a few eps per impact, |E - E0| / E0 ~ eps sqrt(K).
    Allowed: 20 eps sqrt(K) (2.3e-12 at K = 2.7e5); a bias of 1e-17 per impact
    would exceed it. (Measured: 5e-13, about 2e-18 per impact, and it grows
    about linearly with K here: a bias of ~eps/100 per impact.) Total momentum
    is zero, so the bodies stay near the origin, and it stays zero to 1e-13 of
    its scale (measured 1.9e-14 over the 2.7e5 impulses; was 1e-12). Beyond ~1e6 impacts the run
    stalls: the event time's resolution, 4 eps t, times the approach speed
    exceeds the 1e-9 L contact band (reported; not tested here, it takes 10 s).
    """
    m_box, m_jack = 3.0, 1.0
    vx, vy = 2000.0, 1500.0
    scene = float_scene(**{"initial.q": [0, 0, 0.1, 0.2, -0.1, 0.5],
                           "initial.qd": [-vx * m_jack / m_box, -vy * m_jack / m_box, 0.4, vx, vy, 4000.0]})
    started = time.perf_counter()
    traj = jackbox.simulate(scene, t_end=100.0, dt=1e-3, record_every=100)
    seconds = time.perf_counter() - started
    K = len(traj.impact_t)
    rel = (traj.energy - traj.energy[0]) / traj.energy[0]
    print(f"\nlong elastic run: {K} impacts, {traj.meta['n_steps']} steps in {seconds:.2f} s; "
          f"energy drift {rel[-1]:.3g} at the end (max |.| {np.abs(rel).max():.3g}), "
          f"{abs(rel[-1]) / K:.3g} per impact; eps sqrt(K) = {EPS * math.sqrt(K):.3g}")
    assert K > 1e5
    assert np.abs(rel).max() <= 20 * EPS * math.sqrt(K)
    check_gaps(traj, scene)
    linear, _, lin_scale, _ = momenta(traj, scene.params())
    assert np.abs(linear).max() <= 1e-13 * lin_scale


@pytest.mark.parametrize("ratio", [1e-3, 1.0, 1e3])
def test_extreme_mass_ratios_give_the_one_dimensional_elastic_collision(ratio):
    """A non-rotating jack hits the walls face-on: 1D elastic collisions, m_jack/m_box 1e-3 .. 1e3.

    Both corners of the face hit together (one LCP), so nothing starts to spin,
    and each hit swaps the velocities between (v, 0) and the 1D elastic result
    ((m - M) v, 2 m v) / (m + M), with relative speed v: hits every 2 (L - a) / v.
    Every hit is located where the gap is -0.5e-12 L (by design), so each
    crossing is 1e-12 L longer than 2 (L - a). A mass ratio of 1e3 makes the
    LCP matrix entries differ by 1e3; round-off stays at eps of v and of t:
    hit times 1e-12 s allowed after 36 hits (measured 2.5e-13); velocities
    along x 1e-14 v (measured 1.8e-15 v), spurious y and spin velocities
    1e-13 v (measured 1.4e-14 v, at m/M = 1e3). (Velocities were 1e-12 v.)
    """
    v, m, M = 10.0, ratio, 1.0
    scene = float_scene(**{"box.mass": M, "jack.mass": m, "restitution": 1.0,
                           "initial.q": [0, 0, 0, 0, 0, 0], "initial.qd": [0, 0, 0, v, 0, 0]})
    traj = jackbox.simulate(scene, t_end=5.0, dt=1e-3)
    hits = traj.impacts
    assert np.array_equal(hits["t"][0::2], hits["t"][1::2])          # in pairs, at one instant
    faces = [set(pair) for pair in zip(hits["name"][0::2], hits["name"][1::2])]
    assert faces == [{"right:0", "right:3"}, {"left:1", "left:2"}] * (len(faces) // 2) + \
        [{"right:0", "right:3"}] * (len(faces) % 2)
    gap = 2 * (L_F - A_F) + EVENT * L_F
    t_hit = (gap / 2 + np.arange(len(faces)) * gap) / v
    assert len(faces) == 36
    np.testing.assert_allclose(hits["t"][0::2], t_hit, rtol=0, atol=1e-12)
    # after an odd number of hits the state is the 1D result, after an even one the start's
    n_before = np.searchsorted(hits["t"][0::2], traj.t, side="left")
    odd = n_before % 2 == 1
    jack = np.where(odd, (m - M) / (m + M) * v, v)
    box = np.where(odd, 2 * m / (m + M) * v, 0.0)
    np.testing.assert_allclose(traj.qd[:, 3], jack, rtol=0, atol=1e-14 * v)
    np.testing.assert_allclose(traj.qd[:, 0], box, rtol=0, atol=1e-14 * v)
    assert np.abs(traj.qd[:, [1, 4]]).max() <= 1e-13 * v
    assert np.abs(traj.qd[:, [2, 5]]).max() <= 1e-13 * v / L_F
    check_gaps(traj, scene)
    check_energy(traj, scene, elastic=True)


#: a square plate of half-size 0.98 L turns only |phi| <= 0.02026 rad (a (|cos| + |sin|) <= L)
_SQUARE_TURN = math.asin(1 / (0.98 * math.sqrt(2.0))) - math.pi / 4
WEDGED_SQUARE = ("float", 0.98, 0.004, (-_SQUARE_TURN, _SQUARE_TURN))
#: a cross of half-size 1.38 L is caught near 45 degrees: acos(1/1.38) <= phi <= asin(1/1.38)
WEDGED_CROSS = ("cross", 1.38, math.pi / 4, (math.acos(1 / 1.38), math.asin(1 / 1.38)))


@pytest.mark.parametrize("wedged, e", [
    pytest.param(WEDGED_SQUARE, 1.0, id="square-e1"), pytest.param(WEDGED_CROSS, 1.0, id="cross-e1"),
    pytest.param(WEDGED_SQUARE, 0.5, id="square-e0.5"), pytest.param(WEDGED_CROSS, 0.5, id="cross-e0.5"),
    # (stalled, until the contact engine held every still contact of a redundant set)
    pytest.param(WEDGED_SQUARE, 0.0, id="square-e0"),
    pytest.param(WEDGED_CROSS, 0.0, id="cross-e0"),
])
def test_jack_nearly_as_large_as_the_box_rattles_without_escaping_its_wedge(wedged, e):
    """No gravity, a jack that cannot turn, spun at 10 rad/s: impacts close together.

    Gaps at the samples cannot see a jack that passes through a wall between
    two samples; its angle can: it must stay in the only angles where it fits.
    The bound is the exact geometric one plus 1e-9 rad (the jacks here stay
    4e-4 rad or more inside it). Energy and momentum as everywhere (no outside
    force; kept if e = 1): linear momentum to 5e-15 of its scale (measured
    8.9e-16 over ~1000 impacts; was 1e-13).
    """
    structure, a, phi0, wedge = wedged
    scene = jackbox.load_scene(base(structure), {
        "gravity": 0.0, "restitution": e, "jack.half_size": a,
        "initial.q": [0, 0, 0, 0.001, -0.001, phi0], "initial.qd": [0, 0, 0, 0.3, 0.2, 10.0]})
    traj = jackbox.simulate(scene, t_end=2.0, dt=1e-3)
    assert len(traj.impact_t) > {1.0: 500, 0.5: 10, 0.0: 3}[e]
    if e == 0.0 and structure == "float":   # plastic: the square locks into its wedge, turns with the box
        assert traj.qd[-1, 5] == pytest.approx(traj.qd[-1, 2], rel=1e-9)
    low, high = rel_angle_range(traj)
    assert wedge[0] - 1e-9 <= low and high <= wedge[1] + 1e-9, (low, high, wedge)
    check_gaps(traj, scene)
    check_energy(traj, scene, elastic=e == 1.0)
    linear, _, lin_scale, _ = momenta(traj, scene.params())
    assert np.abs(linear - linear[0]).max() <= 5e-15 * lin_scale


def grazing_run(dt, depth):
    """A jack spinning in place whose corner 0 would reach `depth` L past the right wall.

    Corner 0, at radius r = a sqrt(2), points along +x at t* = 5.5 dt, mid-step:
    there its gap would be -depth, and at the step ends it is r (1 - cos(omega dt / 2)) - depth
    > 0, so only a test inside the step sees the contact.
    """
    r, omega = A_F * math.sqrt(2.0), 10.0
    t_star = 5.5 * dt
    scene = float_scene(**{"box.mass": 1e6, "restitution": 1.0,
                           "initial.q": [0, 0, 0, L_F - r + depth * L_F, 0, -math.pi / 4 - omega * t_star],
                           "initial.qd": [0, 0, 0, 0, 0, omega]})
    return jackbox.simulate(scene, t_end=10 * dt, dt=dt), r, omega, t_star


@pytest.mark.parametrize("dt", [1e-3, 1e-2])
def test_grazing_corner_is_hit_when_it_would_reach_into_the_wall(dt):
    """A corner sweeping past a wall: it hits iff it would reach past it, at the analytic time.

    Depth 1e-8 L (ten times the gap tolerance): one impulse, where
    gap = -0.5e-12 L, i.e. at t* - acos(1 - (depth - 0.5e-12) L / r) / omega
    (RK4 turns at a constant rate exactly). The gap moves at 9e-4 L/s there, so
    its round-off, a few eps of L, is ~1e-13 s (measured 1.4e-13 s): 1e-12 s
    allowed (was 1e-10). Clearance 1e-8 L: no impulse.

    At dt = 1e-2 (omega dt = 0.1) the cubic through the gap's ends stays 1e-7 r
    above zero while the corner dips 1e-8 L below it: the dip test looks at any
    dip within the cubic's own error (jackbox.engine.gaps.cubic_error), where it
    used to miss the hit and let the corner pass into the wall.
    """
    traj, r, omega, t_star = grazing_run(dt, 1e-8)
    assert list(traj.impacts["name"]) == ["right:0"]
    t_hit = t_star - math.acos(1 - (1e-8 - 0.5e-12) * L_F / r) / omega
    assert traj.impact_t[0] == pytest.approx(t_hit, abs=1e-12)
    check_gaps(traj, float_scene(**{"box.mass": 1e6}))
    miss, *_ = grazing_run(dt, -1e-8)
    assert len(miss.impact_t) == 0


@pytest.mark.parametrize("e", [1.0, 0.0])
def test_corner_hit_on_a_free_box_is_one_simultaneous_impact(e):
    """The jack's corner flies along the diagonal into the box's corner: two walls at once.

    Solved together, the two impulses are equal and the pair acts along the
    diagonal through both centres: no spin for either body, and the diagonal
    velocities follow the 1D law with restitution e between m = 1 and M = 3.
    Solved one after the other, the first wall would set the jack spinning.
    Velocities to 1e-15 v, a few roundings of one LCP solve (measured: exact,
    0; was 1e-13 v).
    """
    v, m, M = 2.0, 1.0, 3.0
    scene = float_scene(**{"restitution": e, "initial.q": [0, 0, 0, 0, 0, 0], "initial.qd": [0, 0, 0, v, v, 0]})
    traj = jackbox.simulate(scene, t_end=0.5, dt=1e-3)
    t_hit = (L_F - A_F) / v
    first = traj.impacts[np.abs(traj.impact_t - t_hit) < 1e-12]
    assert sorted(first["name"]) == ["right:0", "top:0"]
    after = traj.t > first["t"].max()      # located where the gap is -0.5e-12 L: just after t_hit
    jack = v * (m - e * M) / (m + M)
    box = v * m * (1 + e) / (m + M)
    np.testing.assert_allclose(traj.qd[after][:, [3, 4]], jack, rtol=0, atol=1e-15 * v)
    np.testing.assert_allclose(traj.qd[after][:, [0, 1]], box, rtol=0, atol=1e-15 * v)
    assert np.abs(traj.qd[:, [2, 5]]).max() <= 1e-15 * v
    check_gaps(traj, scene)
    check_energy(traj, scene, elastic=e == 1.0)


def test_very_fast_jack_with_a_coarse_step_hits_at_the_analytic_times():
    """1e4 L/s face-on with dt = 0.01 s: 70 hits per step, every one located.

    Equal masses, e = 1: each hit swaps the bodies' velocities, the relative
    speed stays v, so hit k comes at (L - a + d/2)/v + k 2(L - a + d/2)/v, with
    d = 1e-12 L the depth where events are located. Positions reach 2500 L and
    times 0.5 s, so both carry ~1e-16 s of round-off per hit; 1e-12 s allowed.
    """
    v = 1e4
    scene = float_scene(**{"box.mass": 1.0, "jack.mass": 1.0, "restitution": 1.0,
                           "initial.q": [0, 0, 0, 0, 0, 0], "initial.qd": [0, 0, 0, v, 0, 0]})
    traj = jackbox.simulate(scene, t_end=0.5, dt=1e-2)
    hits = traj.impact_t[0::2]
    assert np.array_equal(hits, traj.impact_t[1::2])
    gap = 2 * (L_F - A_F) + EVENT * L_F
    t_hit = (gap / 2 + np.arange(len(hits)) * gap) / v
    assert len(hits) == math.floor((0.5 * v - gap / 2) / gap) + 1
    np.testing.assert_allclose(hits, t_hit, rtol=0, atol=1e-12)
    check_energy(traj, scene, elastic=True)


def test_very_fast_spinning_jack_with_a_coarse_step_keeps_the_invariants():
    """1e4 L/s and 3e4 rad/s with dt = 0.01 s (300 rad per step): thousands of located impacts.

    The invariants of every run: gaps, energy (elastic), momentum (1e-15 of
    the momentum exchanged, measured 1.2e-16; hits here exchange 1e2 times the
    momentum; was 1e-13).
    """
    scene = float_scene(**{"restitution": 1.0, "initial.q": [0, 0, 0.1, 0.2, -0.1, 0.5],
                           "initial.qd": [0, 0, 0, 1e4, 7e3, 3e4]})
    traj = jackbox.simulate(scene, t_end=0.5, dt=1e-2)
    assert len(traj.impact_t) > 3000
    check_gaps(traj, scene)
    check_energy(traj, scene, elastic=True)
    P = scene.params()
    linear, _, lin_scale, _ = momenta(traj, P)
    exchanged = lin_scale + np.abs(np.diff(P["m_jack"] * traj.qd[:, 3:5], axis=0)).sum()
    assert np.abs(linear - linear[0]).max() <= 1e-15 * exchanged


def test_elastic_drop_keeps_its_energy_for_ten_seconds():
    """e = 1 on walls and ground, gravity: energy kept to round-off through dozens of impacts.

    (How many depends on round-off: the motion is chaotic, and two builds of
    the engine that differ at 1e-16 in one impact time part after 4 s; 76 and
    111 have been seen.)

    Flights are parabolas (RK4 exact), impulses elastic: round-off at every
    step, and at the end the random walk of K impulses, ROUND_OFF sqrt(1 + K)
    (4e-14; measured 7.5e-15, was 1e-12). Horizontal momentum kept (the ground
    pushes vertically) to PX_ROUND_OFF.
    """
    scene = jackbox.load_scene("drop", {"restitution": 1.0, "ground_restitution": 1.0})
    traj = jackbox.simulate(scene, t_end=10.0, dt=1e-3)
    assert len(traj.impact_t) > 50
    check_energy(traj, scene, elastic=True)
    P = scene.params()
    K = len(traj.impact_t)
    assert abs(traj.energy[-1] - traj.energy[0]) <= ROUND_OFF * math.sqrt(1 + K) * energy_scale(traj, P)
    px = P["m_box"] * traj.qd[:, 0] + P["m_jack"] * traj.qd[:, 3]
    assert np.abs(px - px[0]).max() <= PX_ROUND_OFF * np.abs(px).max()
    check_gaps(traj, scene)


def test_plastic_drop_comes_to_rest_flat_on_the_ground():
    """e = 0 on walls and ground: the box ends flat on the ground, the jack flat on its floor.

    Energy never rises (check_energy), and the end state is the rest state
    exactly (resting contacts are projected onto gap = 0, rate = 0): box at
    height L + w and angle 0 mod pi/2, jack a above the floor and angle 0 mod
    pi/2, no vertical or angular speed, two ground contacts persistent.
    Horizontally nothing stops the pair (the ground is frictionless): the
    horizontal momentum is what it was at the start (to PX_ROUND_OFF).
    Persistent contacts are held at the event level, 0.5e-12 L inside: the
    box that much below L + w, the jack that much below its floor.
    Positions and angles to 1e-15 (L = 1: a few eps; measured 2.2e-16),
    speeds to 1e-17 m/s (measured 1.4e-18: the projection leaves the
    round-off of speeds already below the 3e-7 m/s rest threshold); all were 1e-12.
    """
    scene = jackbox.load_scene("drop", {"restitution": 0.0, "ground_restitution": 0.0})
    traj = jackbox.simulate(scene, t_end=10.0, dt=1e-3)
    check_energy(traj, scene)
    check_gaps(traj, scene)
    P = scene.params()
    L, w, a = P["L"], P["w_box"], P["a_jack"]
    q, qd = traj.q[-1], traj.qd[-1]
    quarter = lambda angle: abs((angle + math.pi / 4) % (math.pi / 2) - math.pi / 4)  # noqa: E731
    held = EVENT / 2 * L
    assert q[1] == pytest.approx(L + w - held, abs=1e-15) and quarter(q[2]) < 1e-15
    assert q[4] - q[1] == pytest.approx(a - L - held, abs=1e-15) and quarter(q[5] - q[2]) < 1e-15
    assert np.abs(qd[[1, 2, 4, 5]]).max() < 1e-17
    changes = traj.contact_changes
    resting = {n for n in changes["name"] if (changes["name"] == n).sum() % 2 == 1}
    assert len({n for n in resting if n.startswith("ground")}) == 2, changes
    px = P["m_box"] * traj.qd[:, 0] + P["m_jack"] * traj.qd[:, 3]
    assert np.abs(px - px[0]).max() <= PX_ROUND_OFF * np.abs(px).max()


# --- persistent multi-contact (these stalled until the contact engine was rebuilt) -------

@pytest.mark.parametrize("structure", ["float", "cross"])
def test_jack_carried_round_by_a_spinning_box_settles_against_the_wall(structure):
    """A box spinning at 10 rad/s, the jack co-rotating at half-radius: it slides out and settles.

    The run completes; the jack ends pressed against the wall by the
    centrifugal force (a persistent contact, gap at the event level), never
    inside it. (It stalled: a contact touching at round-off level with no
    resolvable motion, on a redundant contact set.)
    """
    w, x = 10.0, -0.5
    a = 0.1
    scene = jackbox.load_scene(base(structure), {
        "box.mass": 1000.0, "jack.mass": 0.01, "jack.half_size": a, "restitution": 0.5, "gravity": 0.0,
        "initial.q": [0, 0, 0, x, 0, 0.3], "initial.qd": [0, 0, w, 0, w * x, w]})
    traj = jackbox.simulate(scene, t_end=1.0, dt=1e-3)
    gaps = check_gaps(traj, scene)
    assert len(traj.contact_t) > 0
    assert gaps[-1].min() <= 1e-9 * scene.params()["L"]      # against a wall at the end
    held = {k for k in traj.contact_constraint if np.sum(traj.contact_constraint == k) % 2 == 1}
    assert held, "no contact persistent at the end"


# (was a known bug, fixed in the kernel: kept as a regression test)
def test_flush_face_hitting_with_one_corner_gains_no_energy():
    """A square jack flush against the right wall, moving in at 0.2 and turning at -1 rad/s.

    Corner 0 approaches the wall at 0.5 m/s, corner 3 recedes at 0.1 m/s, both
    at gap 0. Whatever impulses follow, an impact with e = 1 cannot end with
    more kinetic energy than it started with.
    """
    scene = float_scene(**{"box.mass": 1e6, "jack.mass": 1.0, "restitution": 1.0,
                           "initial.q": [0, 0, 0, L_F - A_F, 0, 0], "initial.qd": [0, 0, 0, 0.2, 0, -1.0]})
    P = scene.params()
    start = 0.5 * (P["m_jack"] * 0.2 ** 2 + P["J_jack"] * 1.0 ** 2)
    traj = jackbox.simulate(scene, t_end=1e-3, dt=1e-3)
    assert len(traj.impact_t) >= 1
    assert traj.energy[0] <= start * (1 + ROUND_OFF), (traj.energy[0], start)


def test_plastic_hexagon_on_a_tilting_floor_settles_quickly():
    """The hand-shaken box (slow vertical shake), hexagon jack thrown in with e = 0.

    It lands, comes to rest on an edge and rides the floor: a few hundred
    events at most (the run is stopped, OverBudget, after 10000). It used to
    rock between its two bottom vertices forever (impulse, REST, RELEASE every
    ~5 us, ~6000 events per step).
    """
    scene = jackbox.load_scene(base("hand"), {
        "amp": 0.17, "freq": 0.23, "jack.mass": 0.65, "restitution": 0.0,
        "initial.q": [0.0, 0.0, 0.0, -0.36, 0.0, 0.0], "initial.qd": [0, 0, 0, -2.85, 2.32, 0.06]})
    traj = simulate(scene, budget=10_000, t_end=0.95, dt=1e-3)
    check_gaps(traj, scene)
    assert len(traj.impact_t) + len(traj.contact_t) < 1000


# (was a known bug, fixed in the kernel: kept as a regression test)
def test_first_step_with_more_events_than_the_log_records_each_sample_once(tmp_path):
    """A jack at 1e5 L/s with dt = 0.01 s: 1428 impulses in the first step.

    Run in a subprocess (the bug writes out of bounds). Expected: samples at
    0, 0.01, 0.02 s, each once.
    """
    path = write_scene(tmp_path, FREE_FLOAT, "float.toml")
    code = (f"import jackbox, json; s = jackbox.load_scene({str(path)!r}, "
            "{'gravity': 0.0, 'box.mass': 1.0, 'jack.mass': 1.0, 'initial.q': [0, 0, 0, 0, 0, 0], "
            "'initial.qd': [0, 0, 0, 1e5, 0, 0]}); t = jackbox.simulate(s, t_end=0.02, dt=0.01); "
            "print(json.dumps(t.t.tolist()))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-500:]
    assert json.loads(out.stdout) == [0.0, 0.01, 0.02]


@pytest.mark.parametrize("e", [0.5, 0.0])
def test_a_drop_thrown_spinning_loses_no_member(e):
    """The drop with its box thrown spinning at 15 rad/s: the jack is flung into a box corner.

    1999 of 2000 members stalled at e = 0.5 (and all at e = 0) before the
    contact engine held redundant contact sets and gained its fallback; now
    every member finishes, and the fallback's share is counted (the full
    sizes: benchmarks/contact.py).
    """
    from jackbox.ensemble import ensemble

    scene = jackbox.load_scene("drop", {"restitution": e, "ground_restitution": e,
                                        "initial.qd": [0, 0, 15, 0.8, 0, 6]})
    ens = ensemble(scene, 8, perturb={"theta_jack": 0.5, "x_jack_dot": 0.5}, t_end=2.0)
    assert ens.completed.all(), ens.summary()
    assert np.all(ens.fallback >= 0) and np.all(ens.fallback < 2.0)
    # a member re-run alone is the same run, fallback included
    traj = ens.trajectory(int(np.argmax(ens.fallback)))
    assert traj.fallback_seconds == pytest.approx(ens.fallback.max(), abs=1e-12)
    check_gaps(traj, scene)
    check_energy(traj, scene)


def test_a_weightless_spinning_box_finishes_every_member_without_a_solver_warning():
    """A weightless box spinning at 10 rad/s, a light square jack flung into its corners
    (benchmarks/contact.py's study): every run stalled before the fallback. Every member
    finishes, and none needs a solver that gives up: the fallback's projection that keeps
    the angular momentum once made the position LCP singular and warned in most members.
    A cross jack, 64 members: the exact method now resolves the square jack's runs itself
    (1 member in 400 reached the fallback; 6% of the cross jack's, for too many mode changes),
    and since bounces below the event band or shorter than FLIGHT_TOL dt are at rest, every one
    of these 64 (none reaches the fallback).
    """
    from jackbox.ensemble import ensemble

    scene = jackbox.load_scene(base("float"), {
        "box.wall_thickness": 0.1, "box.mass": 1000.0, "jack.mass": 0.01, "jack.half_size": 0.1,
        "jack.shape": "cross", "restitution": 0.5, "initial.q": [0, 0, 0, -0.5, 0, 0.3],
        "initial.qd": [0, 0, 10, 0, -5, 10]})
    ens = ensemble(scene, 64, perturb={"theta_jack": 0.5}, t_end=2.0)
    assert ens.completed.all(), ens.summary()
    assert (ens.fallback == 0).all(), ens.fallback
    assert ens.warnings.sum() == 0, ens.warnings


#: starts where the exact method's first step went to the fallback, "an event made no progress": a
#: contact left inside the event band that no contact update could resolve (c19a0a9 and d85fb97;
#: members 52 and 85 of benchmarks/contact.py's weightless square study, 94 and 119 of its
#: spinning drop at e = 0.5, each at the step it handed over, out of 200)
WEIGHTLESS_SQUARE = {"box.inner_half_width": 1.0, "box.wall_thickness": 0.1, "box.mass": 1000.0, "jack.mass": 0.01,
                     "jack.half_size": 0.1, "restitution": 0.5, "gravity": 0.0, "world.ground": False,
                     "jack.shape": "square"}
SPINNING_DROP = {"restitution": 0.5, "ground_restitution": 0.5}
UNRESOLVED = {
    "square flung into a corner (52)": (WEIGHTLESS_SQUARE, [
        -1.7353798016827364e-05, -2.3912169722654168e-05, 4.169983398645079, 1.235379801682734, 0.30621697226542,
        5.740769709864106], [
        3.047548780315694e-05, -0.00017383539901561455, 9.999906797888416, -3.0475487803156933, 12.383539901561464,
        9.972550111001661]),
    "square flung into a corner (85)": (WEIGHTLESS_SQUARE, [
        -1.6898332033564648e-05, -2.5969088879526916e-05, 4.289982427204383, 1.1898332033564667, 0.4519088879526887,
        4.289974628072678], [
        4.526284197142135e-05, -0.00016890920732039562, 9.999907043666015, -4.526284197142134, 11.89092073203955,
        10.222480738941442]),
    "spinning drop (94)": (SPINNING_DROP, [
        0.1462996735857999, 3.683632856475772, 8.099218245013526, -0.7550358898710599, 4.231184108429145,
        4.957625591423733], [
        1.3577531308904671, 7.106345531480434, 9.24543220567944, -12.439330591883863, -3.4129693314206455,
        9.245432205679442]),
    "spinning drop (119)": (SPINNING_DROP, [
        0.1279764910838498, 3.5647797533158974, 7.932885051836524, -0.6695261621206381, 4.254063883310397,
        4.791292398246731], [
        1.5255698258202526, 7.0557180302189835, 9.260856123170939, -14.24703916941267, -1.0722243188061231,
        9.260856123170937]),
}


@pytest.mark.parametrize("case", list(UNRESOLVED))
def test_a_contact_left_inside_the_event_band_is_resolved_by_the_exact_method(case):
    """A free contact the update leaves inside the event band, leaving or at rest, used to be
    taken for a touch at the next step's start that no update resolved (twice: the fallback).
    Two causes, both fixed: a rebound too slow to climb out of the band against the contact's
    own normal acceleration (back within 1e-8 s, 4e-16 L high) is now at rest (plastic, and
    held where the accelerations' LCP says it presses: modes.update_contacts); and a contact
    left a little below the deeper level (where the projection of the others moved it when
    they were let go) has its event T_EVENT below where it starts (events.first_crossing).
    The exact method now takes these steps, with the invariants of every run.
    """
    over, q, qd = UNRESOLVED[case]
    scene = jackbox.load_scene(base("drop"), over | {"initial.q": q, "initial.qd": qd})
    traj = simulate(scene, t_end=0.02)
    assert len(traj.fallback_t) == 0, traj.meta["fallback_reasons"]
    check_finite(traj)
    check_gaps(traj, scene)
    check_energy(traj, scene)


def test_plastic_shaken_box_finishes_with_few_events():
    """shaken with e = 0 for 2 s: 175,000-300,000 impulses per 10 s before; now a few hundred."""
    traj = simulate(jackbox.load_scene("shaken", {"restitution": 0.0}), budget=5000, t_end=2.0)
    assert len(traj.impact_t) + len(traj.contact_t) < 1000
    check_gaps(traj, jackbox.load_scene("shaken", {"restitution": 0.0}))


def test_same_scene_same_trajectory_for_any_t_end():
    """Tolerances come from the scene's scales and dt, never from t_end: a weightless scene run
    for 0.5 s and for 1 s is the same run up to 0.5 s, bit for bit."""
    scene = jackbox.load_scene(base("float"), {"restitution": 0.3})
    short, long = (jackbox.simulate(scene, t_end=t, dt=1e-3) for t in (0.5, 1.0))
    n = len(short.t)
    np.testing.assert_array_equal(short.q, long.q[:n])
    assert short.meta["tolerances"] == long.meta["tolerances"]
