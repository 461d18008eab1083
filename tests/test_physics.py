"""The model against textbook mechanics written here, not derived from codegen/model.py.

Codegen, the lambdified twin and the scipy reference all start from the same
symbolic model, so comparing them cannot catch an error in how the model turns
``[potential]`` and ``[forces]`` into equations of motion, nor an error in the
box's default inertia. These tests can: a weightless free box with a cross jack
at its centre (so nothing ever touches a wall) carries, switched off by default,

* a spring between the bodies along x and a torsion spring between their angles:
  two-body oscillators at ``omega = sqrt(k / mu)``, ``mu = m_b m_j / (m_b + m_j)``
  (and its rotational twin with the inertias), energy kept;
* a linear damper on the jack's x: ``v = v0 exp(-c t / m)``, energy ``E0 exp(-2 c t / m)``;
* a constant push on the jack's y: ``y = F t^2 / (2 m)``;
* a constant torque on the box: ``theta = tau t^2 / (2 J_box)``, with ``J_box``
  the polar moment of a uniform hollow square (outer side ``so``, inner ``si``).

One scene, one compile: every term is a ``[params]`` value that a test switches
on at run time. The start state is changed with ``load_scene`` overrides, which
do not change the structure either.

Error budget. RK4 integrates a quadratic in t exactly, and ``exp(-lambda t)`` and
an oscillator with relative errors of order ``(h dt)^4 / 120`` per unit of
``h t`` (``h`` = lambda or omega); at dt = 1e-3 and h <= 3 that is 1e-11 at most,
and the rest is round-off. A 1% error in a potential, a force or the box's
inertia moves the quantities it touches here by 4e-3 to 7e-2 (measured on such
mutants of codegen/model.py and jackbox/scene.py); every tolerance below is a
small factor above the error achieved, and at least 5e6 times smaller than that.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import jackbox

from .conftest import write_scene

M_BOX, M_JACK = 2.0, 1.0     # kg
L, W = 2.0, 0.2              # m, the box's inner half-width and wall thickness
A = 0.5                      # m, the cross jack's half-size

PHYSICS = """
name = "physics"
description = "weightless free box, cross jack at its centre: springs, damper, push, torque"
[params]
k = 0.0      # N/m, spring between the bodies along x
kt = 0.0     # N m/rad, torsion spring between the bodies' angles
c = 0.0      # N s/m, linear damper on the jack's x
F = 0.0      # N, constant push on the jack's y
tau = 0.0    # N m, constant torque on the box
[box]
inner_half_width = 2.0
wall_thickness = 0.2
mass = 2.0
[jack]
shape = "cross"
half_size = 0.5
mass = 1.0
[world]
gravity = 0.0
[potential]
spring = "0.5*k*(x_jack - x_box)**2"
torsion = "0.5*kt*(theta_jack - theta_box)**2"
[forces]
x_jack = "-c*x_jack_dot"
y_jack = "F"
theta_box = "tau"
[initial]
q = [0, 0, 0, 0, 0, 0]
qd = [0, 0, 0, 0, 0, 0]
[run]
t_end = 5.0
dt = 1e-3
"""


def hollow_square_inertia(m: float, L: float, w: float) -> float:
    """Polar moment of a uniform square frame, from plates: a square plate of side
    s and mass M has ``M s^2 / 6`` about its centre; the frame is the outer plate
    less the inner one, at one areal density."""
    so, si = 2 * (L + w), 2 * L
    density = m / (so**2 - si**2)
    return (density * so**2) * so**2 / 6 - (density * si**2) * si**2 / 6


J_BOX = hollow_square_inertia(M_BOX, L, W)
J_JACK = M_JACK * A**2       # four point masses m/4 at distance a


@pytest.fixture(scope="module")
def physics(tmp_path_factory):
    return jackbox.load_scene(write_scene(tmp_path_factory.mktemp("physics"), PHYSICS))


def run(scene, q0, qd0, t_end, **params):
    start = jackbox.load_scene(scene, {"initial.q": list(q0), "initial.qd": list(qd0)})
    traj = jackbox.simulate(start, t_end=t_end, params=params)
    # nothing may touch a wall: the closed forms below are for free flight
    assert traj.impact_t.size == 0 and traj.contact_t.size == 0
    return traj


def rel_err(actual, expected, scale):
    return float(np.max(np.abs(np.asarray(actual) - np.asarray(expected))) / scale)


def test_box_inertia_default_is_the_documented_hollow_square(physics):
    # docs/scenes.md: J = m (so^2 + si^2) / 6 with so = 2 (L + w), si = 2 L; the
    # plate difference above is the same number (so^4 - si^4 = (so^2 - si^2)(so^2 + si^2)).
    p = dict(zip(physics.param_names, physics.param_values))
    so, si = 2 * (L + W), 2 * L
    assert J_BOX == pytest.approx(M_BOX * (so**2 + si**2) / 6, rel=1e-14)
    # only float round-off separates two evaluations of one formula
    assert p["J_box"] == pytest.approx(J_BOX, rel=1e-14)
    assert p["J_jack"] == pytest.approx(J_JACK, rel=1e-14)
    # and it follows the box's numbers (a runtime parameter, not compiled in)
    other = jackbox.load_scene(physics, {"box.mass": 7.0, "inner_half_width": 3.0, "wall_thickness": 0.45})
    p = dict(zip(other.param_names, other.param_values))
    assert p["J_box"] == pytest.approx(hollow_square_inertia(7.0, 3.0, 0.45), rel=1e-14)


def test_constant_torque_spins_the_box_by_its_default_inertia(physics):
    # theta = tau t^2 / (2 J), omega = tau t / J; the jack, at the centre, stays put.
    tau, t_end = 0.5, 3.0
    traj = run(physics, [0] * 6, [0] * 6, t_end, tau=tau)
    t = traj.t
    theta_end = tau * t_end**2 / (2 * J_BOX)
    err_theta = rel_err(traj.q[:, 2], tau * t**2 / (2 * J_BOX), theta_end)
    err_omega = rel_err(traj.qd[:, 2], tau * t / J_BOX, tau * t_end / J_BOX)
    # achieved 4e-15: RK4 is exact on a quadratic, so round-off only, bounded by
    # steps x eps = 3000 x 2.2e-16 = 7e-13 (a 1% inertia error gives 1e-2)
    assert err_theta < 1e-12 and err_omega < 1e-12
    assert np.all(traj.q[:, [0, 1, 3, 4, 5]] == 0.0)
    # the work done is the kinetic energy: tau theta = J omega^2 / 2 (round-off as above)
    assert traj.energy[-1] == pytest.approx(tau * traj.q[-1, 2], rel=1e-12)


def test_spring_between_the_bodies_oscillates_at_the_reduced_mass_frequency(physics):
    # Relative coordinate r = x_jack - x_box: mu r'' = -k r, mu = m_b m_j / (m_b + m_j);
    # the centre of mass stays where it was.
    k, r0, t_end = 6.0, 0.5, 5.0
    mu = M_BOX * M_JACK / (M_BOX + M_JACK)
    omega = math.sqrt(k / mu)                         # 3 rad/s: 2.4 periods in 5 s
    traj = run(physics, [0, 0, 0, r0, 0, 0], [0] * 6, t_end, k=k)
    t, q, qd = traj.t, traj.q, traj.qd
    r, rd = q[:, 3] - q[:, 0], qd[:, 3] - qd[:, 0]
    err_r = rel_err(r, r0 * np.cos(omega * t), r0)
    err_rd = rel_err(rd, -r0 * omega * np.sin(omega * t), r0 * omega)
    # the period from the upward zero crossings of r (linear interpolation: r'' = 0 there)
    up = np.flatnonzero((r[:-1] < 0) & (r[1:] >= 0))
    crossings = t[up] - r[up] * (t[up + 1] - t[up]) / (r[up + 1] - r[up])
    assert crossings.size >= 2
    period = (crossings[-1] - crossings[0]) / (crossings.size - 1)
    err_period = abs(period / (2 * math.pi / omega) - 1)
    com = (M_BOX * q[:, 0] + M_JACK * q[:, 3]) / (M_BOX + M_JACK)
    err_com = rel_err(com, M_JACK * r0 / (M_BOX + M_JACK), r0)
    e0 = 0.5 * k * r0**2
    err_energy = rel_err(traj.energy, e0, e0)
    # achieved 9.6e-12 and 8.5e-12: RK4's phase lag, (omega dt)^4 / 120 per radian
    # x omega t = 15 rad = 1.0e-11 of r0, as predicted; tolerance 3x that. A 1% error
    # in k moves omega by 0.5%: 0.075 rad of phase, 7e-2 of r0.
    assert err_r < 3e-11 and err_rd < 3e-11
    # achieved 1.4e-10: linear interpolation misses a sine's root by at most
    # 0.016 omega^2 dt^3 = 1.4e-10 s per crossing, 1.4e-10 of the period for the two
    # here; RK4 adds 1e-11 (a 1% error in k: 5e-3)
    assert err_period < 1e-9
    # achieved 1.7e-15 and 5.0e-14: the momentum is round-off; the energy is RK4's
    # loss, 2 (omega dt)^6 / 144 per step = 5e-14 over 5000 steps as predicted, plus
    # round-off below steps x eps = 1.1e-12 (a 1% error in the potential: 1e-2,
    # whether the energy carries it or only the motion does)
    assert err_com < 1e-13
    assert err_energy < 2e-12
    assert np.all(q[:, [1, 2, 4, 5]] == 0.0)


def test_torsion_spring_oscillates_at_the_reduced_inertia_frequency(physics):
    # Relative angle a = theta_jack - theta_box: I a'' = -kt a, 1/I = 1/J_box + 1/J_jack,
    # with both inertias from the documented defaults; angular momentum stays 0.
    kt, a0, t_end = 1.0, 0.5, 5.0
    omega = math.sqrt(kt * (1 / J_BOX + 1 / J_JACK))  # 2.02 rad/s
    traj = run(physics, [0, 0, 0, 0, 0, a0], [0] * 6, t_end, kt=kt)
    t, q, qd = traj.t, traj.q, traj.qd
    a, ad = q[:, 5] - q[:, 2], qd[:, 5] - qd[:, 2]
    err_a = rel_err(a, a0 * np.cos(omega * t), a0)
    err_ad = rel_err(ad, -a0 * omega * np.sin(omega * t), a0 * omega)
    spin = J_BOX * qd[:, 2] + J_JACK * qd[:, 5]
    err_spin = rel_err(spin, 0.0, J_JACK * a0 * omega)
    e0 = 0.5 * kt * a0**2
    err_energy = rel_err(traj.energy, e0, e0)
    # achieved 1.1e-12 and 1.3e-12: RK4's phase lag, (omega dt)^4 / 120 x omega t
    # = 1.4e-12 of a0 as predicted; tolerance 4x that (a 1% error in kt: 4e-2)
    assert err_a < 5e-12 and err_ad < 5e-12
    # achieved 3.9e-15 and 4.3e-15: round-off (steps x eps = 1.1e-12)
    assert err_spin < 1e-13
    assert err_energy < 2e-12
    assert np.all(q[:, [0, 1, 3, 4]] == 0.0)


def test_linear_damper_loses_velocity_and_energy_at_the_exponential_rate(physics):
    # m v' = -c v: v = v0 exp(-c t / m), x = (m v0 / c)(1 - exp(-c t / m)),
    # energy (all kinetic) E0 exp(-2 c t / m). The box feels nothing.
    c, v0, t_end = 1.0, 1.0, 3.0
    traj = run(physics, [0] * 6, [0, 0, 0, v0, 0, 0], t_end, c=c)
    t = traj.t
    decay = np.exp(-c * t / M_JACK)
    err_v = rel_err(traj.qd[:, 3], v0 * decay, v0)
    err_x = rel_err(traj.q[:, 3], M_JACK * v0 / c * (1 - decay), M_JACK * v0 / c)
    e0 = 0.5 * M_JACK * v0**2
    err_energy = rel_err(traj.energy, e0 * decay**2, e0)
    # achieved 5e-15: RK4's error on exp(-lambda t) is (lambda dt)^4 / 120 per unit
    # of lambda t, 2.5e-14 here, and round-off is below steps x eps = 7e-13.
    # A 1% error in c gives 3.7e-3 in v (0.01 lambda t exp(-lambda t) at lambda t = 1).
    assert err_v < 1e-12 and err_x < 1e-12 and err_energy < 1e-12
    assert np.all(traj.q[:, [0, 1, 2, 4, 5]] == 0.0)


def test_constant_force_gives_the_parabolic_drift(physics):
    # m y'' = F: y = F t^2 / (2 m), v = F t / m; the work F y is the kinetic energy.
    F, t_end = 0.2, 3.0
    traj = run(physics, [0] * 6, [0] * 6, t_end, F=F)
    t = traj.t
    y_end = F * t_end**2 / (2 * M_JACK)
    err_y = rel_err(traj.q[:, 4], F * t**2 / (2 * M_JACK), y_end)
    err_v = rel_err(traj.qd[:, 4], F * t / M_JACK, F * t_end / M_JACK)
    err_energy = rel_err(traj.energy, F * traj.q[:, 4], F * y_end)
    # achieved 3e-14..9e-14: RK4 is exact on a quadratic, round-off only, bounded by
    # steps x eps = 7e-13 (a 1% error in F gives 1e-2)
    assert err_y < 1e-12 and err_v < 1e-12 and err_energy < 1e-12
    assert np.all(traj.q[:, [0, 1, 2, 3, 5]] == 0.0)
