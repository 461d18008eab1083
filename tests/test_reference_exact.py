"""The exact kernel against an independent exact solution: scipy's solve_ivp with event functions.

``jackbox.reference.simulate(..., method="exact")`` integrates the lambdified
model with DOP853 (rtol 1e-12, max_step = dt), stops at every gap's zero
crossing, applies the impact LCP and restarts. It shares nothing with the
kernel but the symbolic model, so agreement to ~1e-10 checks the kernel's event
location, its simultaneous impacts and its order; and the naive kernel, held
to the same comparison, shows what locating the impacts buys.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import jackbox
from jackbox import reference
from jackbox.errors import SimulationError

#: a few impacts each (drop 8, shaken 2, spring 2) before the motion gets too sensitive to compare
HORIZONS = {"drop": 1.0, "shaken": 1.5, "spring": 1.0}
DT, EVERY = 1e-3, 10

# Tolerances, per scene: a small factor (5-10) over what is achieved. RK4 at dt = 1e-3 has a
# global error C dt^4 ~ 1e-12..1e-11 on shaken and spring (benchmarks/results/
# workprecision.md: 1.3e-12 and 2.2e-11 at dt = 1e-3; measured here 1.2e-11 and 3.0e-11 in
# q, 9e-13 and 8e-13 s in impact times), and integrates drop's free flight (gravity only:
# quadratic in t) exactly; DOP853 at rtol 1e-12 with steps <= 1e-3 is good to ~1e-12, and
# drop's eight impacts amplify its error into 4.1e-10 in q and 3.1e-11 s at t = 1 s.
Q_TOL = {"drop": 2e-9, "shaken": 1e-10, "spring": 2e-10}
T_IMPACT_TOL = {"drop": 2e-10, "shaken": 1e-11, "spring": 1e-11}
# The naive method applies impulses at the end of the step: its impact times are late by
# up to dt (uniformly, so the largest of a few is well above dt / 100) and the state
# after an impact is off by ~ speed * dt.
NAIVE_T_MIN, NAIVE_Q_MIN = DT / 100, 1e-4


@pytest.fixture(scope="module")
def scipy_runs():
    return {name: reference.simulate(name, t_end=t_end, dt=DT, record_every=EVERY, method="exact")
            for name, t_end in HORIZONS.items()}


def matched_impact_error(traj, ref):
    """Largest |t - t_ref| over the common prefix of equal contacts, and its length."""
    n = 0
    while (n < min(len(traj.impact_t), len(ref.impact_t))
           and traj.impact_constraint[n] == ref.impact_constraint[n]):
        n += 1
    return (float(np.abs(traj.impact_t[:n] - ref.impact_t[:n]).max()) if n else math.inf), n


@pytest.mark.parametrize("name", list(HORIZONS))
def test_exact_kernel_matches_scipy_with_events(name, scipy_runs):
    ref = scipy_runs[name]
    got = jackbox.simulate(name, t_end=HORIZONS[name], dt=DT, record_every=EVERY)   # exact by default
    assert got.meta["method"] == "exact"
    np.testing.assert_array_equal(got.t, ref.t)
    assert len(ref.impact_t) >= 2, "the horizon should hold a few impacts"
    np.testing.assert_array_equal(got.impact_constraint, ref.impact_constraint,
                                  err_msg=f"{name}: impact sequences differ; kernel at {got.impact_t}, "
                                          f"scipy at {ref.impact_t}")
    dt_imp = np.abs(got.impact_t - ref.impact_t)
    assert dt_imp.max() < T_IMPACT_TOL[name], f"{name}: impact {dt_imp.argmax()} off by {dt_imp.max():.3g} s"
    err = np.abs(got.q - ref.q).max(axis=1)
    i = int(err.argmax())
    assert err[i] < Q_TOL[name], f"{name}: |q - q_scipy| = {err[i]:.3g} at sample {i} (t = {got.t[i]:.3f} s)"


@pytest.mark.parametrize("name", list(HORIZONS))
def test_naive_kernel_is_measurably_worse(name, scipy_runs):
    ref = scipy_runs[name]
    naive = jackbox.simulate(name, t_end=HORIZONS[name], dt=DT, record_every=EVERY, method="naive")
    dt_imp, matched = matched_impact_error(naive, ref)
    assert matched >= 1
    err = np.abs(naive.q - ref.q).max()
    # first order at impacts: late by a good part of a step, and a state error to match
    assert dt_imp > NAIVE_T_MIN, f"{name}: naive impact times within {dt_imp:.3g} s of scipy's"
    assert err > NAIVE_Q_MIN, f"{name}: naive |q - q_scipy| only {err:.3g}"
    # before the first impact both kernels are plain RK4: the difference is all in the impacts
    # (measured 1.6e-15, 2.3e-13, 7.0e-13: RK4's and DOP853's own errors)
    before = ref.t < ref.impact_t[0]
    assert np.abs(naive.q[before] - ref.q[before]).max() < Q_TOL[name]


def test_first_impact_time_is_the_analytic_one(scipy_runs):
    # drop: the box falls from rest, tilted by theta0 and not turning, so its lowest corner
    # (ground:2) starts at h = y0 - s (cos theta0 + sin theta0), s = L + w_box, and lands at
    # sqrt(2 h / g); the jack's corners are far from the walls until then.
    ref = scipy_runs["drop"]
    scene = jackbox.load_scene("drop")
    P = dict(zip(scene.param_names, scene.param_values))
    s, theta0, y0 = P["L"] + P["w_box"], scene.q0[2], scene.q0[1]
    t_hit = math.sqrt(2 * (y0 - s * (math.cos(theta0) + math.sin(theta0))) / P["g"])
    assert ref.constraint_names[ref.impact_constraint[0]] == "ground:2"
    # brentq on DOP853's dense output: machine precision in t, the interpolant's error ~1e-15
    assert ref.impact_t[0] == pytest.approx(t_hit, abs=1e-12)


def test_restarts_do_not_refire_and_elastic_impacts_keep_energy(scipy_runs):
    for name, ref in scipy_runs.items():
        # one solve_ivp segment per event plus the last: no zero-length segment at a restart
        events = len(np.unique(ref.impact_t))
        assert ref.meta["reference"]["segments"] == events + 1, name
    # drop has e = 1 and only gravity: every impact keeps the energy, and DOP853 integrates the
    # parabolas between them to round-off (measured 2.9e-15 relative over eight impacts)
    e = scipy_runs["drop"].energy
    assert np.abs(e - e[0]).max() < 5e-14 * abs(e[0])


def test_bounces_shorter_than_a_step():
    # drop with e = 0.3: the box's corner ground:3 bounces lower and lower (flights of 3.4e-3,
    # 1.0e-3, 3.1e-4 s before 0.7271 s) with dt = 7.3e-4 s: the kernel locates two impacts in
    # one step, and scipy restarts from a gap of ~0 with a bounce shorter than its first step.
    params, t_end = {"e": 0.3, "e_ground": 0.3}, 0.7271
    ref = reference.simulate("drop", t_end=t_end, dt=t_end / 1000, record_every=10, method="exact",
                             params=params)
    got = jackbox.simulate("drop", t_end=t_end, dt=t_end / 1000, record_every=10, params=params)
    assert np.diff(ref.impact_t).min() < t_end / 1000
    np.testing.assert_array_equal(got.impact_constraint, ref.impact_constraint)
    # 12 impacts; measured 3.5e-13 s and 4.4e-12 in q: ten times that
    assert np.abs(got.impact_t - ref.impact_t).max() < 5e-12
    assert np.abs(got.q - ref.q).max() < 5e-11


@pytest.mark.parametrize("params, t_end", [({"e_ground": 0.0}, 1.0),               # plastic at once
                                           ({"e": 0.3, "e_ground": 0.3}, 0.75)])   # after 12 bounces
def test_resting_contact_is_refused_with_a_clear_message(params, t_end):
    # the corner that lands stays on the ground (at once, or once its bounces are slower than
    # REST_TOL sqrt(g L)): sign-change events cannot follow that, the reference says so
    with pytest.raises(SimulationError, match="does not do resting contact"):
        reference.simulate("drop", t_end=t_end, method="exact", params=params)


def test_solve_exact_options_reach_solve_ivp():
    # the benchmark's entry point: scipy's own step control (max_step inf) at two tolerances
    run = jackbox.api.prepare("spring", 1.0, 0.05, 1, None, "exact")
    best = jackbox.simulate("spring", t_end=1.0, dt=1e-4, record_every=500).q     # error ~1e-12
    loose = reference.solve_exact(run, rtol=1e-6, integrator="RK45", max_step=np.inf)
    tight = reference.solve_exact(run, rtol=1e-11, integrator="DOP853", max_step=np.inf)
    np.testing.assert_array_equal(loose.t, reference.sample_times(run))
    assert loose.nfev < tight.nfev
    # global errors of 10..100 times rtol (spring: 2.9e-5 and ~1e-10, measured)
    assert 1e-7 < np.abs(loose.q - best).max() < 1e-3
    assert np.abs(tight.q - best).max() < 1e-7
