"""Tolerances: the exact method's lengths, speeds and radii for one row of parameters.

One function fills the tolerance row (slots ``T_*`` of :mod:`.records`) for a
single run (:func:`jackbox.api.tolerances`) and for each swept member of a
study inside its parallel setup (:mod:`.members`), so a member and its re-run
alone get the same row to the last bit.

Every tolerance comes from the scene's own scales: lengths from the box's
inner half-size L, speeds from gravity (or, weightless, from L and the step
dt), accelerations from L and dt; never from the run's length, so the same
scene gives the same trajectory for any ``t_end`` (up to where the shorter
ends). Contacts closer than 1e-9 L take part in an impact; events are located
(and persistent contacts held) where a gap is -0.5e-12 L (a guard against
round-off, far below anything visible). Normal speeds below 1e-7 sqrt(g L)
(weightless: 1e-10 L / dt), or below what a bounce needs to rise one event
band (1e-12 L) against the contact's own normal acceleration, count as at
rest, and so do those whose flight would last less than 1e-3 dt, or (e < 1)
whose Zeno cascade would be over within ZENO_TOL dt (:func:`rest_speed`):
such a contact gets a plastic impulse and becomes persistent, which ends the
cascade of bounces, and an elastic contact's endless bounce at the scale of
round-off. The rest is logged where the cascade would have come to rest
(:func:`zeno_rest_ahead`). A closed contact
whose gap would accelerate away at less than 1e-12 L / dt^2 (it leaves by
less than the event depth in a step) is still: it stays held. Speed bounds (the largest rate of change
of any gap per unit of each rate, and of any point of a prescribed box,
bounded from its motion's formulas by jackbox.intervals) decide
which steps need the in-step dip test; the bounding radii of the jack and the
box feed the broad phase.
"""

import math

from numba import njit

from .records import (MODEL_AT, T_AREST, T_BOXV, T_EVENT, T_GAP, T_RBOX, T_RJACK, T_SPEED, T_VREST, T_WALL,
                      ModelType, from_table)

#: tolerances of the exact method, relative to the scene's size and speed
GAP_TOL, EVENT_TOL, REST_TOL = 1e-9, 1e-12, 1e-7
#: weightless scenes: the speed scale is this many box half-widths per step
WEIGHTLESS_SPEED = 1e-3
#: a bounce whose flight would last less than this fraction of a step is at rest
#: (jackbox.engine.modes.update_contacts)
FLIGHT_TOL = 1e-3
#: a Zeno cascade (restitution e < 1, bounces against a pressing acceleration) whose remaining
#: flights would all be over within this fraction of a step is at rest (:func:`rest_speed`)
ZENO_TOL = 0.05
#: the angles' lever arms (how far a unit turn can move a gap) are the largest slope of any gap times this:
#: a step's travel is bounded by its rates at its two ends, and a turning rate may swell between them
#: (until stop 66 each lever was a body's outer radius times 1.5: the box's 2.3 times its largest slope
#: where there is no ground; in shaken a lane's gap bound, lowered every step by the travel, ran low 17%
#: more often)
ANGLE_SPARE = 1.1
#: parameter slots read here (jackbox.scene.BASE_PARAMS: m_box, J_box, L, w_box, m_jack, J_jack, g, e,
#: e_ground), then a_jack, or each vertex's x and y of a polygon jack
L_AT, W_BOX_AT, G_AT, JACK_AT = 2, 3, 6, 9
@njit(cache=True, no_cpython_wrapper=True)
def set_tolerances(model, p, jack_factor, n_points, dt, boxv, out):
    """Fill ``out`` (T_SPEED + n_dof slots) for parameters p.

    The jack's bounding radius is a_jack times jack_factor (1 for a cross, sqrt 2
    for a square), or with n_points > 0 the farthest of a polygon's vertices.
    boxv: a bound on the speed of any point of a prescribed box (slot T_BOXV),
    which the caller derives from the motion's formulas
    (:func:`jackbox.api.box_speed_bound`); unused for a free box.
    """
    L, w, g = p[L_AT], p[W_BOX_AT], abs(p[G_AT])
    v_scale = math.sqrt(g * L) if g > 0 else WEIGHTLESS_SPEED * L / dt
    if n_points == 0:
        r_jack = p[JACK_AT] * jack_factor
    else:
        r_jack = 0.0
        for i in range(n_points):
            r_jack = max(r_jack, math.hypot(p[JACK_AT + 2 * i], p[JACK_AT + 2 * i + 1]))
    r_box = math.sqrt(2.0) * (L + w)
    for i in range(out.shape[0]):
        out[i] = 0.0
    out[T_GAP] = GAP_TOL * L
    out[T_EVENT] = EVENT_TOL * L
    out[T_VREST] = REST_TOL * v_scale
    out[T_AREST] = EVENT_TOL * L / (dt * dt)
    out[T_WALL] = L
    out[T_RJACK] = r_jack
    out[T_RBOX] = r_box
    at = T_SPEED
    if model.prescribed:
        out[T_BOXV] = boxv
    else:
        # x, y, theta of the box: turning the box moves a wall's gap at most by L (the jack point's offset
        # along the wall, inside the box), a ground gap by the corner's radius
        turn = r_box if model.has_ground else L
        out[at], out[at + 1], out[at + 2] = 1.0, 1.0, ANGLE_SPARE * turn
        at += 3
    # x, y, theta of the jack: turning it moves a gap at most by its radius
    out[at], out[at + 1], out[at + 2] = 1.0, 1.0, ANGLE_SPARE * r_jack


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def step_of(tol):
    """The step dt, read from a tolerance row (its T_AREST is T_EVENT / dt^2)."""
    return math.sqrt(tol[T_EVENT] / tol[T_AREST])


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def rest_speed(tol, rise, press, e):
    """The rest speed of a contact with restitution e, pressed at ``press`` (minus its gap acceleration, >= 0).

    A contact leaving slower than this, or arriving slower (its impulse is then
    plastic), is at rest: the accelerations' LCP decides whether it is held.
    The largest of T_VREST; what a bounce needs to rise ``rise`` (one event band
    above the held level) against ``press``; what a flight of FLIGHT_TOL dt
    needs; and for e < 1 what ends a cascade within ZENO_TOL dt. A bounce that
    leaves at v comes back after 2 v / press, and the cascade it starts, each
    flight e times the last, is over after 2 v / (press (1 - e)): cut there, the
    contact held a little before the cascade's accumulation time, the impulses
    in between add up to what holding it applies (the same total, where the
    flights sum to the same time), so the state where the cascade would have
    ended differs by a second-order term (measured on drop at e = 0.6: 1e-13 L,
    where a step's own error is 1e-11).
    """
    flight = step_of(tol) * max(FLIGHT_TOL, ZENO_TOL * (1.0 - e))
    return max(tol[T_VREST], math.sqrt(2.0 * rise * press), 0.5 * flight * press)


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def zeno_rest_ahead(tol, bounce, press, e):
    """How long after a contact is held, where it came to rest leaving at ``bounce`` (or arriving at
    ``bounce / e``) against ``press``, the Zeno cascade it ends would have come to rest: the flights
    ``2 bounce / press`` times ``1 + e + e^2 + ...``, at most ZENO_TOL dt (0 for e = 1: an elastic bounce
    has no accumulation point, nor has a contact pressed by nothing)."""
    if not (e < 1.0 and press > 0.0 and bounce > 0.0):
        return 0.0
    return min(2.0 * bounce / (press * (1.0 - e)), ZENO_TOL * step_of(tol))


@njit(cache=True)
def fill_tolerances(table, p, jack_factor, n_points, dt, boxv, out):
    """:func:`set_tolerances` for the model in ``table``."""
    set_tolerances(from_table(table, MODEL_AT, ModelType), p, jack_factor, n_points, dt, boxv, out)
