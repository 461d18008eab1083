"""The exact method against closed-form answers: located impacts, simultaneous
contacts, Zeno accumulation into resting contact, and lift-off.

Every scene here has a box that is held still or moved by a known formula and
a jack whose flight between impacts is a parabola, so the times and states to
expect follow from school physics, not from the code under test.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import jackbox
from jackbox.engine.records import DRIFT
from jackbox.scene import contact_gaps

from .conftest import write_scene

G = 9.81
L = 1.0          # inner half-width of every box below
A_JACK = 0.25    # half-size of the square jack
#: persistent contacts are held where events are located, gap = -EVENT_TOL L / 2
HELD = 0.5 * jackbox.api.EVENT_TOL * L

#: A box held by a hand that can move it up and down by y = A (1 - cos(w t)), here
#: held still (A = 0); a square jack starts at rest, flat, at the box's centre.
STILL = """
name = "still"
[params]
A = 0.0
w = 20.0
[box]
inner_half_width = 1.0
wall_thickness = 0.1
mass = 4.0
motion = "prescribed"
x = "0"
y = "A*(1 - cos(w*t))"
theta = "0"
[jack]
shape = "square"
half_size = 0.25
mass = 1.0
[world]
gravity = 9.81
[impact]
restitution = 0.5
[initial]
q = [0, 0, 0, 0, 0, 0]
qd = [0, 0, 0, 0, 0, 0]
[run]
t_end = 2.0
dt = 1e-3
"""

#: The same box moved (A = 0.05), the jack resting on its floor: one structure, one compile.
SHAKEN_FLOOR = STILL.replace("A = 0.0", "A = 0.05").replace(
    "q = [0, 0, 0, 0, 0, 0]", "q = [0, 0, 0, 0, -0.75, 0]").replace('name = "still"', 'name = "floor"')


@pytest.fixture(scope="module")
def still(tmp_path_factory):
    return jackbox.load_scene(write_scene(tmp_path_factory.mktemp("still"), STILL))


@pytest.fixture(scope="module")
def shaken_floor(tmp_path_factory):
    return jackbox.load_scene(write_scene(tmp_path_factory.mktemp("floor"), SHAKEN_FLOOR))


def jack_gaps(traj, scene):
    return np.array([contact_gaps(q, scene.points, L, 0.1, False) for q in traj.q])


def test_first_impact_is_located_to_round_off_even_with_a_coarse_step(still):
    # Free fall from the centre: the jack's bottom face (0.25 below its centre)
    # meets the floor (1.0 below the box's centre) after sqrt(2 h / g), h = 0.75.
    # A parabola is integrated exactly by RK4, so only the root finding can err.
    t_hit = math.sqrt(2 * (L - A_JACK) / G)
    for dt in (1e-3, 0.05):
        traj = jackbox.simulate(still, t_end=0.5, dt=dt)
        assert traj.impact_t[0] == pytest.approx(t_hit, abs=1e-12)
        # naive: the impulse comes at the end of the step that crossed
        naive = jackbox.simulate(still, t_end=0.5, dt=dt, method="naive")
        assert naive.impact_t[0] - t_hit == pytest.approx(dt * math.ceil(t_hit / dt) - t_hit, abs=1e-12)


def test_square_landing_flat_hits_with_both_corners_and_leaves_without_spin(still):
    # Both bottom corners touch at the same instant: one LCP gives them equal
    # impulses, so the jack rebounds at e v with exactly zero spin.
    traj = jackbox.simulate(still, t_end=0.5, params={"e": 1.0})
    t_hit = math.sqrt(2 * (L - A_JACK) / G)
    first = traj.impacts[traj.impact_t < t_hit + 1e-9]
    assert sorted(first["name"]) == ["bottom:2", "bottom:3"]
    assert np.all(traj.qd[:, 5] == 0.0) and np.all(traj.q[:, 5] == 0.0)
    # elastic: the energy is that of the start to round-off of the energy
    # exchanged (m g h, about 7.4 J; the start's is 0)
    assert np.abs(traj.energy - traj.energy[0]).max() < 1e-13 * G * (L - A_JACK)


@pytest.mark.parametrize("e", [0.3, 0.5, 0.7])
def test_zeno_bounces_accumulate_into_rest_at_the_analytic_time(still, e):
    # Bounce k lasts 2 e^k v0 / g, so the bounces end at t0 (1 + e) / (1 - e);
    # the contact must become persistent there, then the jack lies on the floor
    # exactly: held at the event level (gap -0.5e-12 L) to round-off, no motion,
    # no more impulses.
    # The cascade is cut where what is left of it would be over within
    # ZENO_TOL dt (a bounce slower than g ZENO_TOL dt (1 - e) / 2): the jack is
    # held from that impact on, and its rest is logged where the bounces it
    # skipped would have ended, 2 e v / (g (1 - e)) later (v the speed it came
    # in with). So the logged time is the accumulation time itself, to the
    # round-off of the impact times (measured 4.8e-14, 7.8e-13 and 4.1e-12 s at
    # e = 0.3, 0.5, 0.7; it was logged at the cut, 5.9e-7 to 2.4e-6 s early, before).
    t0 = math.sqrt(2 * (L - A_JACK) / G)
    t_rest = t0 * (1 + e) / (1 - e)
    traj = jackbox.simulate(still, t_end=t_rest + 0.2, params={"e": e})
    changes = traj.contact_changes
    assert list(changes["event"]) == ["rest", "rest"]
    assert sorted(changes["name"]) == ["bottom:2", "bottom:3"]
    assert abs(changes["t"][0] - t_rest) <= 1e-11, changes["t"][0] - t_rest
    # the last impact: where the cascade was cut, less than ZENO_TOL dt before it would have ended
    assert t_rest - jackbox.api.ZENO_TOL * still.dt < traj.impact_t.max() < changes["t"][0]
    after = traj.t > t_rest + 1e-3
    assert np.all(np.abs(traj.q[after, 4] - (A_JACK - L - HELD)) < 1e-15)
    # no motion: the held contacts' rates are projected to zero (a rate of 1e-33 rad/s
    # is left at e = 0.7: round-off of the hand's motion terms, which are 0 * cos(w t))
    assert np.abs(traj.qd[after]).max() < 1e-30
    assert np.ptp(traj.energy[after]) == 0.0
    # every bounce left at e times the speed it came in with: both corners hit
    # together at t_k = t0 (1 + 2 e (1 - e^k) / (1 - e)). Located where the gap is
    # -0.5e-12 L, each time is late by ~0.5e-12 L / v_k: for landings faster than
    # 1 cm/s that and the round-off of t (eps t per impact) stay below 5e-13 s
    # (measured 2.7e-13, 3.7e-13, 6.3e-13 s at e = 0.3, 0.5, 0.7).
    hits = traj.impact_t[0::2]
    np.testing.assert_array_equal(hits, traj.impact_t[1::2])
    k = np.arange(len(hits))
    fast = G * t0 * e ** k > 1e-2
    assert fast.sum() >= 5
    np.testing.assert_allclose(hits[fast], t0 * (1 + 2 * e * (1 - e ** k[fast]) / (1 - e)), rtol=0, atol=2e-12)


@pytest.mark.parametrize("e", [0.3, 0.5, 0.7])
def test_zeno_bounces_on_the_floor_of_a_box_the_ground_holds_accumulate_at_the_analytic_time(e):
    # The built-in drop, level: box and square jack fall together from rest, the box's bottom 5 cm
    # above the ground. The box lands flat and plastically (ground restitution 0) at t1 = sqrt(2 h / g)
    # and the ground holds it; the jack falls on at v1 = g t1 and strikes the floor (0.75 below it)
    # after tau, at v0 = sqrt(v1^2 + 2 g 0.75), then bounces at e times each landing speed: the
    # cascade ends at t1 + tau + 2 e v0 / (g (1 - e)). Both fall together, so by the free
    # accelerations nothing presses the jack onto the floor: the cascade must be judged under the
    # force of the ground that holds the box (modes.held_press). Judged by the free ones, it ran on
    # to T_VREST, with half again as many impulses, and its rest was logged 5.5e-8, 9.6e-8 and
    # 2.0e-7 s early at e = 0.3, 0.5, 0.7 (now: 8.7e-13, 6.1e-13, -2.8e-12 s).
    h, w = 0.05, 0.1
    y = L + w + h
    scene = jackbox.load_scene("drop", {"restitution": e, "ground_restitution": 0.0,
                                        "initial.q": [0.0, y, 0.0, 0.0, y, 0.0], "initial.qd": [0.0] * 6})
    t1 = math.sqrt(2 * h / G)
    v1 = G * t1
    v0 = math.sqrt(v1 ** 2 + 2 * G * (L - A_JACK))
    t_hit = t1 + (v0 - v1) / G
    t_rest = t_hit + 2 * e * v0 / (G * (1 - e))
    traj = jackbox.simulate(scene, t_end=t_rest + 0.1)
    assert len(traj.fallback_t) == 0
    changes = traj.contact_changes
    assert list(changes["event"]) == ["rest"] * 4
    assert sorted(changes["name"][:2]) == ["ground:2", "ground:3"]
    assert sorted(changes["name"][2:]) == ["bottom:2", "bottom:3"]
    assert np.abs(changes["t"][:2] - t1).max() <= 1e-12
    assert np.abs(changes["t"][2:] - t_rest).max() <= 1e-11, changes["t"][2:] - t_rest
    # the box lies still on the ground from t1 on, the jack on its floor from t_rest on
    landed, lying = traj.t > t1 + 1e-9, traj.t > t_rest + 1e-9
    assert np.abs(traj.qd[landed, :3]).max() < 1e-12
    assert np.abs(traj.q[lying, 4] - (traj.q[lying, 1] - L + A_JACK - HELD)).max() < 1e-12
    # each of the jack's landings, both corners together, at t_k = t_hit + 2 e v0 (1 - e^k) / (g (1 - e))
    hits = traj.impacts[np.char.startswith(traj.impacts["name"], "bottom")]["t"]
    np.testing.assert_array_equal(hits[0::2], hits[1::2])
    k = np.arange(len(hits) // 2)
    fast = v0 * e ** k > 1e-2
    assert fast.sum() >= 5
    expected = t_hit + 2 * e * v0 * (1 - e ** k[fast]) / (G * (1 - e))
    np.testing.assert_allclose(hits[0::2][fast], expected, rtol=0, atol=2e-12)


def test_a_rest_logged_ahead_moves_to_its_release_when_that_comes_first():
    # A rest is logged where the cascade it ended would have come to rest, up to ZENO_TOL dt ahead of the
    # update that held the contact. Released before then (the cascade did not finish), the rest moves to the
    # release: the log stays in order for that contact, and the others' entries are left alone.
    import numba

    from jackbox.engine.modes import unlog_rest_ahead
    from jackbox.engine.records import IMPULSE, REST, T_AREST, T_EVENT, Events

    @numba.njit
    def release(t, k, tol, times, ks, kinds, n_ev):
        unlog_rest_ahead(t, k, tol, Events(times, ks, kinds), n_ev)

    dt = 1e-3
    tol = np.zeros(16)
    tol[T_EVENT], tol[T_AREST] = 1e-12, 1e-12 / dt ** 2
    ahead = 0.5 * jackbox.api.ZENO_TOL * dt
    times = np.array([0.5, 1.0 + ahead, 1.0 + ahead, 1.0 + 0.1 * ahead, 0.0])
    log = (times, np.array([3, 3, 4, 1, 0], np.int64), np.array([REST, REST, REST, IMPULSE, 0], np.int64))
    release(1.0 + 0.2 * ahead, 3, tol, *log, 4)
    np.testing.assert_array_equal(times, [0.5, 1.0 + 0.2 * ahead, 1.0 + ahead, 1.0 + 0.1 * ahead, 0.0])
    release(2.0, 4, tol, *log, 4)                    # logged before 2 - ZENO_TOL dt: left as it is
    release(0.6, 3, tol, *log, 1)                    # the earlier rest, not ahead of 0.6
    release(1.0 + 0.5 * ahead, 1, tol, *log, 4)      # an impulse, not a rest
    np.testing.assert_array_equal(times, [0.5, 1.0 + 0.2 * ahead, 1.0 + ahead, 1.0 + 0.1 * ahead, 0.0])


def test_jack_lifts_off_when_the_floor_falls_faster_than_g_and_lands_again(shaken_floor):
    # The floor's acceleration is A w^2 cos(w t): the normal force m (g + A w^2 cos w t)
    # first vanishes at cos(w t) = -g / (A w^2).
    A, w = 0.05, 20.0
    traj = jackbox.simulate(shaken_floor, t_end=0.5)
    t_lift = math.acos(-G / (A * w * w)) / w
    changes = traj.contact_changes
    assert list(changes["event"][:4]) == ["rest", "rest", "release", "release"]
    assert changes["t"][0] == 0.0
    # the release is located to ~4 eps t (measured 3e-17 s)
    assert changes["t"][2] == pytest.approx(t_lift, abs=1e-14)
    # before lift-off the jack rides the floor exactly (held at the event level,
    # gap -0.5e-12 L: measured 1.1e-16 off, an ulp of |y|); afterwards it lands again
    riding = traj.t < t_lift - 1e-3
    floor = A * (1 - np.cos(w * traj.t)) - L + A_JACK
    assert np.abs(traj.q[riding, 4] - (floor[riding] - HELD)).max() < 1e-14
    assert len(traj.impact_t) and traj.impact_t[0] > t_lift
    # and never sinks into the moving floor
    assert (traj.q[:, 4] - floor).min() > -HELD - 1e-14


def test_lift_off_shorter_than_a_step_is_found_every_period(shaken_floor):
    # A floor vibrating with a peak acceleration of 1.03 g pulls the jack's
    # contacts for 8% of a period, 0.85 ms here, less than a step (dt = 1 ms);
    # w puts each pull between two step ends (centred at (2k + 1) 5.5 dt), so
    # the force is positive at both ends of the step that holds it and only
    # its inside shows the lift-off. Physics: one every period, where
    # cos(w t) = -g / (A w^2). The engine used to see none at all.
    dt = 1e-3
    w = math.pi / (5.5 * dt)
    A = 1.03 * G / w**2
    traj = jackbox.simulate(shaken_floor, t_end=0.2, dt=dt, params={"A": A, "w": w, "e": 0.0})
    changes = traj.contact_changes
    lift = changes["t"][changes["event"] == "release"]
    # both bottom corners let go together (measured 7e-17 s from the analytic times)
    np.testing.assert_array_equal(lift[0::2], lift[1::2])
    period = 2 * math.pi / w
    expected = math.acos(-G / (A * w * w)) / w + period * np.arange(int(0.2 / period) + 1)
    expected = expected[expected < 0.2]
    assert len(lift[0::2]) == len(expected) >= 15
    np.testing.assert_allclose(lift[0::2], expected, rtol=0, atol=1e-14)


def test_corner_hit_bounces_off_both_walls_at_once(still):
    # No gravity: the jack's corner (a, a) flies along the diagonal into the
    # box's corner and meets both walls at the same instant. Both contacts take
    # an impulse; with e = 1 the velocity reverses, with no spin.
    v = 2.0
    scene = still.with_overrides({"gravity": "0.0", "initial.qd": "[0, 0, 0, 2.0, 2.0, 0]",
                                  "restitution": "1.0"})
    traj = jackbox.simulate(scene, t_end=0.6)
    t_hit = (L - A_JACK) / v
    first = traj.impacts[np.abs(traj.impact_t - t_hit) < 1e-12]
    assert sorted(first["name"]) == ["right:0", "top:0"], traj.impacts[:4]   # corner (+a, +a)
    after = traj.t > t_hit + 1e-6
    # one 2x2 LCP with equal rows: exact in floating point (measured 0)
    np.testing.assert_allclose(traj.qd[after][0, 3:5], [-v, -v], rtol=4 * np.finfo(float).eps)
    assert np.all(traj.qd[:, 5] == 0.0)


def test_a_jack_that_starts_below_the_held_level_and_comes_back_within_a_step_lands_there(still):
    # the jack's bottom face starts 2.5e-12 L into the floor (below the held level, where a
    # projection of other contacts can leave a free one) and leaves at 1 mm/s: it flies
    # 51 nm high and is back after 0.2 ms, inside the first 1 ms step. Leaving takes no
    # event (its level for the step is set T_EVENT below where it starts), but its return,
    # above the held level in between, is an event at the held level, as any landing is.
    # (It was taken at its deep start's level, 3.5e-12 L: 3e-9 s late. A box corner
    # chattering on an elastic ground left a sample 3.85e-12 L deep that way.)
    v, g0 = 1e-3, -2.5e-12 * L
    y0 = -L + A_JACK + g0
    scene = jackbox.load_scene(still, {"initial.q": [0, 0, 0, 0, y0, 0], "initial.qd": [0, 0, 0, 0, v, 0],
                                       "restitution": 1.0})
    traj = jackbox.simulate(scene, t_end=2e-3)
    b2, b3 = scene.constraint_names.index("bottom:2"), scene.constraint_names.index("bottom:3")
    start = jack_gaps(traj, scene)[0]
    assert start[b2] == start[b3] and abs(start[b2] - g0) < 1e-15    # left as they were
    assert len(traj.contact_changes) == 0                              # leaving: nothing held
    # the landing: g0 + v t - G t^2 / 2 = -HELD
    t_land = (v + math.sqrt(v * v + 2.0 * G * (start[b2] + HELD))) / G
    assert len(traj.impact_t) >= 2 and sorted(traj.impacts["name"][:2]) == ["bottom:2", "bottom:3"]
    assert abs(traj.impact_t[0] - t_land) < 1e-11, traj.impact_t[0] - t_land
    assert jack_gaps(traj, scene)[1:].min() >= -HELD - 1e-15          # every landing at the held level


def test_a_jack_sliding_on_the_floor_coasts_into_the_wall_at_the_analytic_time(still):
    # a jack resting flat on the floor of the still box, pushed sideways at 0.5 m/s:
    # frictionless, it slides at that speed (its held accelerations vanish, so the
    # held loop coasts) until its right side meets the wall, 0.5 m away, bounces
    # with e = 0.5 and slides back at 0.25 m/s; the floor holds it throughout
    v = 0.5
    y_rest = -L + A_JACK - HELD
    scene = jackbox.load_scene(still, {"initial.q": [0, 0, 0, 0.0, y_rest, 0.0], "initial.qd": [0, 0, 0, v, 0.0, 0.0]})
    traj = jackbox.simulate(scene, t_end=2.0)
    t_hit = (L - A_JACK + HELD) / v           # the side at the event level, -HELD past the wall
    assert len(traj.impact_t) == 2 and set(traj.impact_constraint) == {0, 3}, traj.impact_t   # right:0, right:3
    assert np.abs(traj.impact_t - t_hit).max() < 1e-12, traj.impact_t - t_hit
    before, after = traj.t < t_hit, traj.t > t_hit
    x_hit = L - A_JACK + HELD
    np.testing.assert_allclose(traj.q[before, 3], v * traj.t[before], rtol=0, atol=1e-14)
    np.testing.assert_allclose(traj.q[after, 3], x_hit - 0.5 * v * (traj.t[after] - t_hit), rtol=0, atol=1e-12)
    np.testing.assert_allclose(traj.qd[after, 3], -0.5 * v, rtol=0, atol=1e-14)
    assert np.abs(traj.q[:, 4] - y_rest).max() < 1e-15 and np.abs(traj.q[:, 5]).max() < 1e-15
    assert np.abs(traj.qd[:, 4:]).max() < 1e-15
    # the floor's two corners held from the start, never let go
    assert list(traj.contact_changes["event"]) == ["rest", "rest"]
    kinetic = 0.5 * 1.0 * np.array([v, 0.5 * v]) ** 2
    np.testing.assert_allclose(traj.energy[before] - traj.energy[0], 0.0, atol=1e-14)
    np.testing.assert_allclose(traj.energy[after] - traj.energy[0], kinetic[1] - kinetic[0], atol=1e-13)


def test_a_jack_resting_in_a_box_carried_at_constant_speed_coasts_with_it(tmp_path):
    # the box is carried sideways at 0.3 m/s (its contact rows move with time) and the
    # jack rests flat on its floor moving with it: nothing accelerates, so every held
    # step coasts, and the jack must keep the box's pace exactly, on the held level
    v = 0.3
    text = STILL.replace('name = "still"', 'name = "carried"').replace('x = "0"', f'x = "{v}*t"')
    scene = jackbox.load_scene(write_scene(tmp_path, text))
    y_rest = -L + A_JACK - HELD
    scene = jackbox.load_scene(scene, {"initial.q": [0, 0, 0, 0.0, y_rest, 0.0], "initial.qd": [0, 0, 0, v, 0, 0]})
    traj = jackbox.simulate(scene, t_end=2.0)
    assert len(traj.impact_t) == 0 and list(traj.contact_changes["event"]) == ["rest", "rest"]
    np.testing.assert_allclose(traj.q[:, 3], v * traj.t, rtol=0, atol=1e-14)
    assert np.abs(traj.q[:, 4] - y_rest).max() < 1e-15 and np.abs(traj.q[:, 5]).max() < 1e-15
    np.testing.assert_allclose(traj.qd[:, 3], v, rtol=0, atol=1e-15)
    assert np.abs(traj.qd[:, 4:]).max() < 1e-15
    gaps = jack_gaps(traj, scene)
    assert np.abs(gaps[:, [14, 15]] + HELD).max() < 1e-15        # bottom:2, bottom:3 on the held level



def test_a_jack_on_a_floor_that_starts_to_rise_stops_coasting_when_it_does(tmp_path):
    # the box is lifted by y = c t^4: its acceleration, 12 c t^2, is below what a held
    # step takes for none (it coasts) until about 0.3 s and grows past it after, while
    # the jack rests on its floor and slides along it at 0.3 m/s. Stretches of steps that
    # coast are looked at at their ends only, so one that began coasting and ends
    # lifted must be stepped again: the jack follows the floor at every sample (a
    # stretch kept to t = 2 s would leave it 1.6e-11 m below), and slides on uniformly
    c, v = 1e-12, 0.3
    text = STILL.replace('name = "still"', 'name = "lifted"').replace('y = "A*(1 - cos(w*t))"', f'y = "{c}*t**4"')
    scene = jackbox.load_scene(write_scene(tmp_path, text))
    y_rest = -L + A_JACK - HELD
    scene = jackbox.load_scene(scene, {"initial.q": [0, 0, 0, 0.0, y_rest, 0.0], "initial.qd": [0, 0, 0, v, 0, 0]})
    for record_every in (1, 1000):      # samples inside the stretches, and none but the ends
        traj = jackbox.simulate(scene, t_end=2.0, record_every=record_every)
        assert len(traj.impact_t) == 0 and list(traj.contact_changes["event"]) == ["rest", "rest"]
        y_box = c * traj.t ** 4
        assert y_box[-1] > 1e4 * 1e-15
        np.testing.assert_allclose(traj.q[:, 4] - y_box, y_rest, rtol=0, atol=1e-15)
        # (a held row's rate is left where it moves the gap by less than round-off in a step)
        np.testing.assert_allclose(traj.qd[:, 4], 4 * c * traj.t ** 3, rtol=0, atol=DRIFT * HELD / 0.5e-3)
        np.testing.assert_allclose(traj.q[:, 3], v * traj.t, rtol=0, atol=1e-14)
        assert np.abs(traj.q[:, 5]).max() < 1e-15

def test_inelastic_drop_settles_with_the_box_resting_on_the_ground():
    # drop with e = 0.6: the box rocks on its corners, the bounces accumulate
    # and it comes to rest flat on the ground (y_box = L + w exactly, no tilt),
    # with the jack resting on its floor. Nothing sinks, nothing chatters: no
    # impulse after the last contact came to rest, and the energy is constant.
    traj = jackbox.simulate("drop", params={"e": 0.6, "e_ground": 0.6})
    changes = traj.contact_changes
    resting = {}
    for name, event in zip(changes["name"], changes["event"]):
        resting[name] = event == "rest"
    # the box's two lower corners on the ground, two corners of the jack (turned
    # by pi by then, so its corners 0 and 1 are at the bottom) on the box's floor
    assert {n for n, r in resting.items() if r} == {"ground:2", "ground:3", "bottom:0", "bottom:1"}, resting
    settled = changes["t"].max()
    assert settled < 4.5 and traj.impact_t.max() <= settled
    # in time order (a rest is logged where the cascade it cut would have ended, after the update)
    assert np.all(np.diff(changes["t"]) >= 0)
    after = traj.t > settled
    # held contacts are projected to the event level (gap -0.5e-12 L) and rate 0:
    # round-off of |q| ~ 1 remains (measured 0, 5e-17, 2e-17, 0 and -2.2e-16 for
    # the five checks below)
    assert np.abs(traj.q[after, 1] - (1.1 - HELD)).max() < 1e-14          # box on the ground
    assert np.abs(traj.q[after, 2]).max() < 1e-15                # flat
    assert np.abs(traj.qd[after][:, [1, 2, 4, 5]]).max() < 1e-15  # only sliding is left
    assert np.ptp(traj.energy[after]) < 1e-15 * traj.energy[0]
    # it never went through the ground
    corners = np.array([contact_gaps(q, np.zeros((0, 2)), L, 0.1, True) for q in traj.q])
    assert corners.min() > -HELD - 1e-14
