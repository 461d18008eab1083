"""The integrator: one classical RK4 step, on arrays, of the dynamics with the persistent contacts held.

The tableau (stage times ``t, t + h/2, t + h/2, t + h``, weights ``1/6, 1/3,
1/3, 1/6``) is written here for the engine, which works on arrays of any
model's size. The free-flight hot path (:mod:`jackbox.engine.flight`)
writes the same tableau once more on tuples, compiled with each model so that
its state stays in registers: routing free flight through arrays made every
step 2-3x slower.
"""

from numba import njit

from .modes import accel


@njit(cache=True)
def rk4(model, t, q, qd, dt, p, q_out, qd_out, m, ws):
    """One RK4 step from (t, q, qd) of length dt into q_out, qd_out (they may be q and qd).

    With m > 0 persistent contacts (``ws.k[RIDX]``) the accelerations hold them
    closed (:func:`jackbox.engine.modes.contact_accel`).
    """
    n = model.n_dof
    w = ws.work
    qs, vs, a1, a2, a3, a4, v2, v3 = w[0], w[1], w[2], w[3], w[4], w[5], w[6], w[7]
    h2 = 0.5 * dt
    accel(model, t, q, qd, p, m, a1, ws)
    for i in range(n):
        qs[i] = q[i] + h2 * qd[i]
        v2[i] = qd[i] + h2 * a1[i]
    accel(model, t + h2, qs, v2, p, m, a2, ws)
    for i in range(n):
        qs[i] = q[i] + h2 * v2[i]
        v3[i] = qd[i] + h2 * a2[i]
    accel(model, t + h2, qs, v3, p, m, a3, ws)
    for i in range(n):
        qs[i] = q[i] + dt * v3[i]
        vs[i] = qd[i] + dt * a3[i]
    accel(model, t + dt, qs, vs, p, m, a4, ws)
    h6 = dt / 6.0
    for i in range(n):
        q_out[i] = q[i] + h6 * (qd[i] + 2.0 * v2[i] + 2.0 * v3[i] + vs[i])
        qd_out[i] = qd[i] + h6 * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i])
