"""The integrator: one classical RK4 step, on arrays, of the dynamics with the persistent contacts held.

The tableau is written once, here (:data:`NODES`, :data:`WEIGHTS`), for two
codings of the same step: :func:`rk4` on arrays of any model's size, and the
free-flight hot path's ``rk4_stages`` (:mod:`jackbox.engine.flight`) on
tuples, compiled with each model so that its state stays in registers
(routing free flight through arrays made every step 2-3x slower). The two
give the same numbers bit for bit (tests/test_engine.py checks it).
"""

from numba import njit

from .modes import held_accel
from .records import LAM, LS, RHS, RIDX, RINV, WINV

#: the classical RK4 tableau (diagonal): stage s is evaluated at t + NODES[s] dt, at the start
#: state moved NODES[s] dt along stage s-1's slope
NODES = (0.0, 0.5, 0.5, 1.0)
#: the step is dt / sum(WEIGHTS) times the sum of the stages' slopes weighted by WEIGHTS
#: (whole numbers, so that a weight of 1 costs no rounding)
WEIGHTS = (1.0, 2.0, 2.0, 1.0)
SCALE = 6.0
assert SCALE == sum(WEIGHTS)


@njit(cache=True, no_cpython_wrapper=True)
def rk4(model, t, q, qd, dt, p, q_out, qd_out, m, ws):
    """One RK4 step from (t, q, qd) of length dt into q_out, qd_out (they may be q and qd).

    With m > 0 persistent contacts (``ws.k[RIDX]``) the accelerations hold them
    closed (:func:`jackbox.engine.modes.contact_accel`); their forces at the
    four stages are left in ``ws.c[LS + stage, :m]`` (the release test reads
    them: :func:`jackbox.engine.events.first_release`), their matrix at the
    last stage in ``ws.A``.
    """
    winv = ws.n[WINV]
    if m > 0:
        model.inverse_mass(p, winv)
    rk4_rows(model, t, q, qd, dt, p, q_out, qd_out, m, ws.work, ws.c[LS:LS + 4], ws.k[RIDX], ws.jac, winv,
             ws.A, ws.lu, ws.c[RINV], ws.c[RHS], ws.c[LAM])


@njit(cache=True, no_cpython_wrapper=True)
def rk4_rows(model, t, q, qd, dt, p, q_out, qd_out, m, w, ls, ridx, jac, winv, A, L, rinv, y, lam):
    """:func:`rk4` on the arrays themselves (``winv`` filled where m > 0), like :func:`~.modes.held_accel`.

    w: (9, n) work rows; ls: (4, C) the held forces at each stage.
    """
    n = model.n_dof
    qs = w[0]              # a stage's coordinates
    v = w[1:5]             # the stages' rates: the slopes of q
    a = w[5:9]             # the stages' accelerations: the slopes of qd
    for s in range(4):
        h = NODES[s] * dt
        if s == 0:
            for i in range(n):
                qs[i] = q[i]
                v[0, i] = qd[i]
        else:
            for i in range(n):
                qs[i] = q[i] + h * v[s - 1, i]
                v[s, i] = qd[i] + h * a[s - 1, i]
        if m == 0:
            model.accel(t + h, qs, v[s], p, a[s])
        else:
            held_accel(model, t + h, qs, v[s], p, m, a[s], ridx, jac, winv, A, L, rinv, y, lam)
            for i in range(m):
                ls[s, i] = lam[i]
    h = dt / SCALE
    for i in range(n):
        q_out[i] = q[i] + h * (WEIGHTS[0] * qd[i] + WEIGHTS[1] * v[1, i] + WEIGHTS[2] * v[2, i] + WEIGHTS[3] * v[3, i])
        qd_out[i] = qd[i] + h * (WEIGHTS[0] * a[0, i] + WEIGHTS[1] * a[1, i] + WEIGHTS[2] * a[2, i]
                                 + WEIGHTS[3] * a[3, i])
