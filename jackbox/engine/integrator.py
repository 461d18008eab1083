"""The integrator: one classical RK4 step, on arrays, of the dynamics with the persistent contacts held.

The tableau is written once, here (:data:`NODES`, :data:`WEIGHTS`), for two
codings of the same step: :func:`rk4` on arrays of any model's size, and the
free-flight hot path's ``rk4_stages`` (:mod:`jackbox.engine.flight`) on
tuples, compiled with each model so that its state stays in registers
(routing free flight through arrays made every step 2-3x slower). The two
give the same numbers bit for bit where the accelerations depend on the
state; where they are functions of time alone (the model's
``ACCEL_OF_TIME``), ``rk4_stages`` sums the same tableau in fewer operations
and the two agree to round-off (tests/test_kernel.py checks both).
"""

import math

import numpy as np

from numba import njit

from .modes import held_accel
from .records import FLAGS, LAM, LS, PASSES_AT, RHS, RIDX, RINV, WINV

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
    closed (:func:`jackbox.engine.modes.contact_accel`), in the passes the
    exact loop set for the grid step (``ws.k[FLAGS, PASSES_AT]``, from the
    state at its start and its whole length, so that a step from that state
    is the same function of its length throughout an event search); their forces at the
    four stages are left in ``ws.c[LS + stage, :m]`` (the release test reads
    them: :func:`jackbox.engine.events.first_release`), their matrix at the
    last stage in ``ws.A``. With none (m = 0) it is the model's own ``free_step``
    on floats, :func:`rk4_rows`'s step (its numbers, or for accelerations of time
    alone its sum to round-off: see the module's docstring; the re-steps of an
    event search: an impact step of shaken took 0.85 of its time so, against arrays).
    """
    if m == 0:
        # free flight: the model's own step on floats (its stage times t + dt / 2 and t + dt are rk4_rows',
        # so the same numbers), with its time terms read three times a step, not four
        model.free_step(t, t + dt, q, qd, dt, p, q_out, qd_out)
        return
    winv = ws.n[WINV]
    model.inverse_mass(p, winv)
    rk4_rows(model, t, q, qd, dt, p, q_out, qd_out, m, ws.work, ws.c[LS:LS + 4], ws.k[RIDX], ws.jac, winv,
             ws.A, ws.lu, ws.c[RINV], ws.c[RHS], ws.c[LAM], ws.k[FLAGS, PASSES_AT], np.bool_(False), np.bool_(False))


#: a step with held contacts that turns its fastest angle by more than this (rad) is cut into equal
#: RK4 passes, (turn / TURN_PER_PASS)^(5/4) of them (rounded up), so that its error stays that of one
#: pass of TURN_PER_PASS whatever the turn. RK4's error on the constrained, curved motion is
#: C (omega h)^5 a pass of length h: k passes over a turn T leave C T^5 / k^4, which is C
#: TURN_PER_PASS^5 for that k. Measured C: 0.2-1.8 on the energy (a held box and jack turning as one
#: about a ground corner, 1.6e-8 of the energy's scale in one pass of 0.0245 rad; 1.7e-8 in 30 passes
#: over 0.586 rad), against the tests' 1e-8 a step. Passes of at most 0.05 rad (a fixed cut) let the
#: error grow with the turn, and random drops raised the energy by 1.6e-8-4.7e-8 of its scale a step;
#: a cut at 0.01 rad passed them, and took 1.4x as long for a spinning plastic drop that turns 0.015
#: a step. Free flight needs no cut: its motion is not curved by a constraint.
TURN_PER_PASS = 0.015
#: the margin of held_passes' quick test below TURN_PER_PASS (far wider than the squares' round-off)
QUICK = 0.99
#: at most this many passes in one step (a non-finite rate takes one)
MAX_PASSES = 64


@njit(cache=True, no_cpython_wrapper=True)
def held_passes(qd, dt, n, length):
    """The RK4 passes a held step of length dt from rates qd takes: (turn / TURN_PER_PASS)^(5/4), rounded up.

    The turn is the fastest angle's (the coordinates 2, 5, ...: each body's
    third) over the step, or, for a pair of free bodies, the way the jack
    moves across the box in the step over the box's size ``length`` (their
    relative speed times dt over L), whichever is larger; 1 for a step whose
    turn is within TURN_PER_PASS (nearly every step) or not finite,
    MAX_PASSES at most. A pair moving as one is not turned by its speed (the
    walls and the ground are flat). A box pivoting on a ground corner while it
    slid at 24 m/s under a jack nearly still, 0.018 rad a step, took two
    passes by its angle and gained 1.8e-8 of the energy's scale in one step
    (the tests allow 1e-8): the rows of a jack crossing the turning box at
    that speed curve the held motion as a turn of 0.08 rad would.
    """
    w = 0.0
    for d in range(2, n, 3):
        w = max(w, abs(qd[d]))
    if n == 6:
        dx, dy = qd[3] - qd[0], qd[4] - qd[1]
        # (the library's hypot, some 15 ns, only where the squares leave it in doubt: a step that
        # certainly takes one pass by both takes one by the hypot too; NaN and inf take it)
        quick = TURN_PER_PASS * QUICK
        if not (w * abs(dt) <= quick and (dx * dx + dy * dy) * (dt * dt) <= (quick * length) * (quick * length)):
            w = max(w, math.hypot(dx, dy) / length)
    turn = w * abs(dt)
    if not (turn > TURN_PER_PASS and math.isfinite(turn)):
        return 1
    k = (turn / TURN_PER_PASS) ** 1.25
    return MAX_PASSES if not k < MAX_PASSES else int(math.ceil(k))


@njit(cache=True, no_cpython_wrapper=True)
def rk4_rows(model, t, q, qd, dt, p, q_out, qd_out, m, w, ls, ridx, jac, winv, A, L, rinv, y, lam, passes,
             factored, first):
    """:func:`rk4` on the arrays themselves (``winv`` filled where m > 0), like :func:`~.modes.held_accel`.

    w: (9, n) work rows; ls: (4, C) the held forces at each stage. With held
    contacts the step is taken in ``passes`` equal RK4 passes
    (:func:`held_passes`); ``ls[0]`` keeps the forces at the step's start and
    ``ls[1:]`` the smallest of each later pass's stages (the release screen
    looks at all of them). factored: the held rows' matrix at q is factored
    already (:func:`~.modes.settle_rows`; its first stage does not factor it again).
    first: the first stage is taken already, its accelerations in ``w[5]``
    and its forces in ``ls[0]`` (:func:`~.loop.hold` takes it at the step's
    start, to see whether the step may coast).
    """
    k = passes if m > 0 and passes > 1 else 1
    h = dt / k
    for j in range(k):
        # one call of the pass, so its body is compiled once (three call sites compiled the step part
        # in 5.0 s against 2.7 s); the later passes start where the one before ended
        start_q = q if j == 0 else q_out
        start_qd = qd if j == 0 else qd_out
        rk4_pass(model, t + j * h, start_q, start_qd, h, p, q_out, qd_out, m, w, ls, ridx, jac, winv, A, L, rinv, y,
                 lam, j > 0, factored and j == 0, first and j == 0)


@njit(cache=True, no_cpython_wrapper=True)
def rk4_pass(model, t, q, qd, dt, p, q_out, qd_out, m, w, ls, ridx, jac, winv, A, L, rinv, y, lam, later, factored,
             first):
    """One RK4 pass of :func:`rk4_rows` (later: not the step's first; its forces are folded into ``ls[1:]``;
    factored: its first stage's matrix is factored; first: its first stage is taken, in ``a[0]`` and ``ls[0]``)."""
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
        elif first and s == 0:
            continue
        else:
            held_accel(model, t + h, qs, v[s], p, m, a[s], ridx, jac, winv, A, L, rinv, y, lam, factored and s == 0)
            if later:
                row = max(s, 1)
                for i in range(m):
                    if not lam[i] >= ls[row, i]:      # (NaN too)
                        ls[row, i] = lam[i]
            else:
                for i in range(m):
                    ls[s, i] = lam[i]
    h = dt / SCALE
    for i in range(n):
        q_out[i] = q[i] + h * (WEIGHTS[0] * qd[i] + WEIGHTS[1] * v[1, i] + WEIGHTS[2] * v[2, i] + WEIGHTS[3] * v[3, i])
        qd_out[i] = qd[i] + h * (WEIGHTS[0] * a[0, i] + WEIGHTS[1] * a[1, i] + WEIGHTS[2] * a[2, i]
                                 + WEIGHTS[3] * a[3, i])
