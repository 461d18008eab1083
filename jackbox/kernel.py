"""The fused kernel: fixed-step RK4 between impacts, Newton impacts at contacts.

This file is not imported as it stands. :mod:`jackbox.loader` compiles it
*together with* one generated model: it writes one module whose text is the
generated model (``accel``, ``phi``, ``phi_q`` ... and constants such as
``N_DOF``), then these functions, and imports it. Every function in it is
``@njit(cache=True)`` and every call is to a global of the same file, so Numba
caches the whole kernel, and the module's file name is a hash of all of its
text, so cached machine code can never outlive the source it came from.

The loop reads like the algorithm: integrate a step, look at the gaps, resolve
the contacts that take part, record. Far from every wall the exact loop hands
over to :func:`fly`, which integrates on floats only (the model's tuple
functions ``accel_s``/``accel_time_s``) and looks at no gap row at all: a
broad phase (bounding circles) bounds them, so a quiet step costs one RK4
step. Ensembles (:func:`run_members`, :func:`run_twin_members`) run members
in parallel with ``prange``, each exactly as one run of ``integrate_exact``.

Impacts (``resolve_impacts``). With ``J`` the rows of ``phi_q`` of the
contacts that take part, ``W = M^-1`` and ``v = J qd (+ phi_t)`` their normal
velocities, the impulses ``lam`` solve the linear complementarity problem

.. math::

    w = J W J^T \\lambda + b \\ge 0,\\quad \\lambda \\ge 0,\\quad w^T\\lambda = 0,
    \\qquad b_k = v_k + e_k \\min(v_k, 0),

i.e. Newton's law per contact: an approaching contact leaves at ``-e v`` or
faster, a receding one is not pulled back, and no impulse pulls. All contacts
are solved together, never one after the other.

Status codes returned by :func:`integrate`: ``DONE``, ``IMPACT_LOG_FULL`` (the
caller grows the log and calls again from the returned step), ``NONFINITE``.
"""

import math

import numpy as np
from numba import njit, prange

DONE = 0
IMPACT_LOG_FULL = 1
NONFINITE = 2
STALLED = 3
#: largest contact set solved exactly by enumeration; larger ones use Gauss-Seidel
MAX_ENUMERATED = 10

# Kinds of contact events in the event log.
IMPULSE = 0          #: an impulse acted on the contact
REST = 1             #: the contact became persistent (gap held at zero)
RELEASE = 2          #: a persistent contact let go (its force would have pulled)

# Slots of the tolerance array of :func:`integrate_exact` (filled by jackbox.api).
T_GAP = 0            #: contacts closer than this take part in impacts and resting contact
T_EVENT = 1          #: an event is located where gap = -T_EVENT / 2 (round-off guard)
T_VREST = 2          #: normal speeds below this are "at rest": plastic impact, then persistent
T_BOXV = 3           #: bound on the speed of any point of a prescribed box
T_WALL = 4           #: the box's inner half-width L (broad phase)
T_RJACK = 5          #: radius of the jack's bounding circle about its centre (broad phase)
T_RBOX = 6           #: radius of the box's outer bounding circle (broad phase, ground)
T_SPEED = 7          #: T_SPEED + i: bound on |d gap / d qd_i| (1 or a radius); the last slots
#: events allowed inside one step before the run stops with STALLED
MAX_EVENTS = 10000
#: skip the gap rows of steps whose bounding circles are far from contact
#: (benchmarks compile a copy with False to show the gain)
BROAD_PHASE = True


@njit(cache=True, inline='always')
def rk4_stages(q, qd, dt, p, ta, tta, tm, ttm, tb, ttb):
    """One classical RK4 step of ``q' = qd, qd' = accel(t, q, qd)`` on tuples.

    The free-flight hot path: the state stays in registers (N_DOF-tuples) and
    the model's ``accel_s`` returns a tuple. Stage times ta, tm, tb come with
    their time terms ``tt* = accel_time_s(t*, p)`` (a shaking force's sine,
    1/m), computed once per stage time. Returns ``(q, qd)`` after the step.
    """
    h2 = 0.5 * dt
    a1 = accel_s(ta, q, qd, p, tta)
    v2 = axpy_s(h2, a1, qd)
    a2 = accel_s(tm, axpy_s(h2, qd, q), v2, p, ttm)
    v3 = axpy_s(h2, a2, qd)
    a3 = accel_s(tm, axpy_s(h2, v2, q), v3, p, ttm)
    v4 = axpy_s(dt, a3, qd)
    a4 = accel_s(tb, axpy_s(dt, v3, q), v4, p, ttb)
    h6 = dt / 6.0
    return rk4_sum_s(q, h6, qd, v2, v3, v4), rk4_sum_s(qd, h6, a1, a2, a3, a4)


@njit(cache=True, inline='always')
def free_step(t, q, qd, dt, p):
    """An RK4 step of any length dt from t (stage times t, t + dt/2, t + dt), on tuples."""
    tm, tb = t + 0.5 * dt, t + dt
    return rk4_stages(q, qd, dt, p, t, accel_time_s(t, p), tm, accel_time_s(tm, p), tb, accel_time_s(tb, p))


@njit(cache=True, inline='always')
def grid_step(t, t_next, tt, q, qd, dt, p):
    """A whole step of the time grid, t = t0 + i dt to t_next = t0 + (i + 1) dt, on tuples.

    tt: the time terms at t (the previous step's at its end). Returns
    ``(q, qd, time terms at t_next)``, so consecutive steps share them.
    """
    tm = t + 0.5 * dt
    tt_next = accel_time_s(t_next, p)
    qn, vn = rk4_stages(q, qd, dt, p, t, tt, tm, accel_time_s(tm, p), t_next, tt_next)
    return qn, vn, tt_next


@njit(cache=True)
def rk4_step(t, q, qd, dt, p, q_out, qd_out):
    """:func:`free_step` on arrays: reads q, qd; writes q_out, qd_out (they may be q and qd)."""
    qt, vt = free_step(t, tuple_of(q), tuple_of(qd), dt, p)
    for i in range(N_DOF):
        q_out[i] = qt[i]
        qd_out[i] = vt[i]


@njit(cache=True, inline='always')
def clearance(t, q, p, tol):
    """A lower bound on every gap: the broad phase.

    The jack's bounding circle (radius tol[T_RJACK] about its centre) against
    the box's inner walls, and, with a ground, the box's bounding circle
    (tol[T_RBOX]) against the ground: no gap row, one sine and one cosine.
    q: a tuple or an array of the integrated coordinates.
    """
    if PRESCRIBED:
        box = box_motion_s(t, p)
        xb, yb, th, xj, yj = box[0], box[1], box[2], q[0], q[1]
    else:
        xb, yb, th, xj, yj = q[0], q[1], q[2], q[3], q[4]
    c, s = math.cos(th), math.sin(th)
    dx, dy = xj - xb, yj - yb
    u, v = c * dx + s * dy, c * dy - s * dx
    g = tol[T_WALL] - max(abs(u), abs(v)) - tol[T_RJACK]
    if HAS_GROUND:
        g = min(g, yb - tol[T_RBOX])
    return g


@njit(cache=True)
def solve_dense(A, b, m, x):
    """Solve ``A[:m, :m] x = b[:m]`` by Gaussian elimination with partial pivoting.

    Works on copies; returns False when the matrix is singular to working precision.
    """
    a = A[:m, :m].copy()
    r = b[:m].copy()
    scale = 0.0
    for i in range(m):
        scale = max(scale, abs(a[i, i]))
    for col in range(m):
        piv = col
        for row in range(col + 1, m):
            if abs(a[row, col]) > abs(a[piv, col]):
                piv = row
        if abs(a[piv, col]) <= 1e-12 * scale:
            return False
        if piv != col:
            for k in range(m):
                a[col, k], a[piv, k] = a[piv, k], a[col, k]
            r[col], r[piv] = r[piv], r[col]
        for row in range(col + 1, m):
            f = a[row, col] / a[col, col]
            for k in range(col, m):
                a[row, k] -= f * a[col, k]
            r[row] -= f * r[col]
    for row in range(m - 1, -1, -1):
        s = r[row]
        for k in range(row + 1, m):
            s -= a[row, k] * x[k]
        x[row] = s / a[row, row]
    return True


@njit(cache=True)
def solve_lcp(A, b, m, lam):
    """Impulses of the impact LCP ``w = A lam + b >= 0, lam >= 0, w . lam = 0``.

    Exact for up to MAX_ENUMERATED contacts: tries every active set, smallest
    first, and keeps the first whose impulses are non-negative and whose
    inactive contacts do not approach. ``A = J M^-1 J^T`` is positive
    semi-definite, so a solution exists and the velocities it gives are unique.
    """
    bscale = 0.0
    for k in range(m):
        bscale = max(bscale, abs(b[k]))
    tol = 1e-10 * bscale
    if m <= MAX_ENUMERATED:
        sub = np.empty((m, m))
        rhs = np.empty(m)
        x = np.empty(m)
        idx = np.empty(m, np.int64)
        for size in range(1, m + 1):
            for mask in range(1, 1 << m):
                count = 0
                for k in range(m):
                    if mask >> k & 1:
                        idx[count] = k
                        count += 1
                if count != size:
                    continue
                for i in range(size):
                    rhs[i] = -b[idx[i]]
                    for j in range(size):
                        sub[i, j] = A[idx[i], idx[j]]
                if not solve_dense(sub, rhs, size, x):
                    continue
                ok = True
                for i in range(size):
                    if x[i] < -tol / max(A[idx[i], idx[i]], 1e-300):
                        ok = False
                if not ok:
                    continue
                for k in range(m):
                    lam[k] = 0.0
                for i in range(size):
                    lam[idx[i]] = max(x[i], 0.0)
                for k in range(m):
                    if not mask >> k & 1:
                        w = b[k]
                        for j in range(m):
                            w += A[k, j] * lam[j]
                        if w < -tol:
                            ok = False
                if ok:
                    return
    # Projected Gauss-Seidel: converges for PSD A; used for very large contact sets.
    for k in range(m):
        lam[k] = 0.0
    for sweep in range(1000):
        for k in range(m):
            w = b[k]
            for j in range(m):
                w += A[k, j] * lam[j]
            lam[k] = max(0.0, lam[k] - w / max(A[k, k], 1e-300))


@njit(cache=True)
def resolve_impacts(t, q, qd, p, gap, active_tol, rows, imp_t, imp_k, n_imp):
    """Apply the impulses of every contact with ``gap < active_tol`` that takes part.

    Changes qd in place; logs each contact that received an impulse. Returns the
    new log length. ``rows``: (N_CONTACT,) int scratch.
    """
    m = 0
    for k in range(N_CONTACT):
        if gap[k] < active_tol:
            rows[m] = k
            m += 1
    if m == 0:
        return n_imp
    jac = np.empty((N_CONTACT, N_DOF))
    phi_q(t, q, p, jac)
    v_t = np.zeros(N_CONTACT)
    if PRESCRIBED:
        phi_t(t, q, p, v_t)
    winv = np.empty(N_DOF)
    inverse_mass(p, winv)
    v = np.empty(m)
    b = np.empty(m)
    approaching = False
    for i in range(m):
        k = rows[i]
        s = v_t[k]
        for j in range(N_DOF):
            s += jac[k, j] * qd[j]
        v[i] = s
        e = p[E_SLOT] if k < N_WALL_CONTACT else p[E_GROUND_SLOT]
        b[i] = s + e * min(s, 0.0)
        if s < 0.0:
            approaching = True
    if not approaching:
        return n_imp
    A = np.empty((m, m))
    for i in range(m):
        for j in range(m):
            s = 0.0
            for d in range(N_DOF):
                s += jac[rows[i], d] * winv[d] * jac[rows[j], d]
            A[i, j] = s
    lam = np.empty(m)
    solve_lcp(A, b, m, lam)
    for i in range(m):
        if lam[i] > 0.0:
            for d in range(N_DOF):
                qd[d] += winv[d] * jac[rows[i], d] * lam[i]
            imp_t[n_imp] = t
            imp_k[n_imp] = rows[i]
            n_imp += 1
    return n_imp


@njit(cache=True)
def record(t, q, qd, p, n, rec_t, rec_q, rec_qd, rec_energy, box):
    """Store sample n: time, the 6 coordinates and rates, and the energy."""
    rec_t[n] = t
    off = 0
    if PRESCRIBED:
        box_motion(t, p, box)
        for i in range(3):
            rec_q[n, i] = box[i]
            rec_qd[n, i] = box[3 + i]
        off = 3
    for i in range(N_DOF):
        rec_q[n, off + i] = q[i]
        rec_qd[n, off + i] = qd[i]
    rec_energy[n] = energy(t, q, qd, p)


@njit(cache=True)
def integrate(q, qd, p, t0, dt, i_begin, i_end, n_total, record_every,
              rec_t, rec_q, rec_qd, rec_energy, n_rec, imp_t, imp_k, n_imp):
    """Advance the state from step ``i_begin`` to ``i_end`` (time ``t0 + i dt``).

    q, qd: (N_DOF,) state, updated in place. Samples are recorded at every step
    ``i`` with ``i % record_every == 0`` and at ``n_total``, into rec_* from
    index ``n_rec``; impulses are logged into imp_t/imp_k from ``n_imp``.
    Returns ``(step reached, n_rec, n_imp, status)``.
    """
    gap = np.empty(N_CONTACT)
    rows = np.empty(N_CONTACT, np.int64)
    box = np.empty(6)
    if i_begin == 0 and n_rec == 0:   # (not again when resumed after a full log)
        record(t0, q, qd, p, n_rec, rec_t, rec_q, rec_qd, rec_energy, box)
        n_rec += 1
    for i in range(i_begin, i_end):
        if n_imp + N_CONTACT > imp_t.shape[0]:
            return i, n_rec, n_imp, IMPACT_LOG_FULL
        t = t0 + i * dt
        t_next = t0 + (i + 1) * dt
        rk4_step(t, q, qd, dt, p, q, qd)
        phi(t_next, q, p, gap)
        n_imp = resolve_impacts(t_next, q, qd, p, gap, 0.0, rows, imp_t, imp_k, n_imp)
        for d in range(N_DOF):
            if not (math.isfinite(q[d]) and math.isfinite(qd[d])):
                return i + 1, n_rec, n_imp, NONFINITE
        if (i + 1) % record_every == 0 or i + 1 == n_total:
            record(t_next, q, qd, p, n_rec, rec_t, rec_q, rec_qd, rec_energy, box)
            n_rec += 1
    return i_end, n_rec, n_imp, DONE


# ---------------------------------------------------------------------------
# method "exact": located events, simultaneous impacts, persistent contact
# ---------------------------------------------------------------------------
#
# Between events the state follows RK4 on the dynamics with the persistent
# contacts R held closed: qdd = M^-1 f + M^-1 J_R^T lam, with lam solving
# (J_R M^-1 J_R^T) lam = -(J_R M^-1 f + gap_bias_R) (gap accelerations zero).
# A step that would end with a free gap below zero, or whose cubic through
# the gaps and rates at both ends dips below zero (a grazing corner), is
# re-stepped from its start with shorter steps (Illinois iteration on the step
# length) to the first crossing, so the state at the event is an RK4 state and
# the method keeps order four. Likewise a persistent contact whose force lam
# would turn negative is released where lam = 0.
#
# Scratch rows of the (SC, N_CONTACT) float array `sc` and the (SN, N_DOF) `sn`.
_GA, _GB, _GS, _VA, _VB, _BIAS, _RHS, _LAM = 0, 1, 2, 3, 4, 5, 6, 7
SC = 8
# Event kinds for event_value/locate. Calls pass them as np.int64(...): a bare
# literal would make Numba compile one specialisation per value.
GAP_EVENT_KIND = 0
FORCE_EVENT_KIND = 1
_QB, _QDB, _QS, _QDS, _WINV, _AF = 0, 1, 2, 3, 4, 5
SN = 6


@njit(cache=True)
def rest_index(rest, ridx):
    """Indices of the persistent contacts into ridx; returns their number."""
    m = 0
    for k in range(N_CONTACT):
        if rest[k]:
            ridx[m] = k
            m += 1
    return m


@njit(cache=True)
def contact_matrix(jac, winv, ridx, m, A):
    """``A = J_R M^-1 J_R^T`` for the m contacts listed in ridx."""
    for i in range(m):
        for j in range(i, m):
            s = 0.0
            for d in range(N_DOF):
                s += jac[ridx[i], d] * winv[d] * jac[ridx[j], d]
            A[i, j] = s
            A[j, i] = s


@njit(cache=True)
def solve_regularised(A, rhs, m, x):
    """Solve ``A x = rhs`` for PSD A; a redundant contact set gets a tiny diagonal shift."""
    if solve_dense(A, rhs, m, x):
        return
    scale = 0.0
    for i in range(m):
        scale = max(scale, A[i, i])
    B = A[:m, :m].copy()
    for i in range(m):
        B[i, i] += 1e-10 * scale
    if not solve_dense(B, rhs, m, x):
        for i in range(m):
            x[i] = 0.0


@njit(cache=True)
def contact_accel(t, q, qd, p, ridx, m, a, jac, sc, A):
    """Accelerations with the m persistent contacts in ridx held closed.

    Fills a; leaves the contact forces in ``sc[_LAM, :m]`` and ``jac = phi_q``.
    """
    accel(t, q, qd, p, a)
    if m == 0:
        return
    winv = np.empty(N_DOF)
    inverse_mass(p, winv)
    phi_q(t, q, p, jac)
    bias, rhs, lam = sc[_BIAS], sc[_RHS], sc[_LAM]
    gap_bias(t, q, qd, p, bias)
    contact_matrix(jac, winv, ridx, m, A)
    for i in range(m):
        k = ridx[i]
        s = bias[k]
        for d in range(N_DOF):
            s += jac[k, d] * a[d]
        rhs[i] = -s
    solve_regularised(A, rhs, m, lam)
    for d in range(N_DOF):
        s = 0.0
        for i in range(m):
            s += jac[ridx[i], d] * lam[i]
        a[d] += winv[d] * s


@njit(cache=True)
def rk4_contact(t, q, qd, dt, p, q_out, qd_out, work, ridx, m, jac, sc, A):
    """One RK4 step of the dynamics with the persistent contacts held (plain RK4 if none).

    The tableau repeats :func:`rk4_stages`'s on purpose: free flight runs on
    tuples in registers; routing it through contact_accel (four calls a step
    with the contact scratch arrays as arguments) made every step 2-3x slower.
    """
    if m == 0:
        rk4_step(t, q, qd, dt, p, q_out, qd_out)
        return
    qs, vs, a1, a2, a3, a4, v2, v3 = (work[0], work[1], work[2], work[3],
                                      work[4], work[5], work[6], work[7])
    h2 = 0.5 * dt
    contact_accel(t, q, qd, p, ridx, m, a1, jac, sc, A)
    for i in range(N_DOF):
        qs[i] = q[i] + h2 * qd[i]
        v2[i] = qd[i] + h2 * a1[i]
    contact_accel(t + h2, qs, v2, p, ridx, m, a2, jac, sc, A)
    for i in range(N_DOF):
        qs[i] = q[i] + h2 * v2[i]
        v3[i] = qd[i] + h2 * a2[i]
    contact_accel(t + h2, qs, v3, p, ridx, m, a3, jac, sc, A)
    for i in range(N_DOF):
        qs[i] = q[i] + dt * v3[i]
        vs[i] = qd[i] + dt * a3[i]
    contact_accel(t + dt, qs, vs, p, ridx, m, a4, jac, sc, A)
    h6 = dt / 6.0
    for i in range(N_DOF):
        q_out[i] = q[i] + h6 * (qd[i] + 2.0 * v2[i] + 2.0 * v3[i] + vs[i])
        qd_out[i] = qd[i] + h6 * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i])


@njit(cache=True)
def project_rest(t, q, qd, p, ridx, m, jac, sc, A):
    """Put the persistent contacts back on gap = 0 and rate = 0 (removes RK4's drift)."""
    winv = np.empty(N_DOF)
    inverse_mass(p, winv)
    g, rhs, x = sc[_GS], sc[_RHS], sc[_LAM]
    for _ in range(2):   # Newton on the gaps; the drift is O(dt^5), one pass is plenty
        phi(t, q, p, g)
        phi_q(t, q, p, jac)
        contact_matrix(jac, winv, ridx, m, A)
        for i in range(m):
            rhs[i] = -g[ridx[i]]
        solve_regularised(A, rhs, m, x)
        for d in range(N_DOF):
            s = 0.0
            for i in range(m):
                s += jac[ridx[i], d] * x[i]
            q[d] += winv[d] * s
    phi_q(t, q, p, jac)
    contact_matrix(jac, winv, ridx, m, A)
    gap_rate(t, q, qd, p, g)
    for i in range(m):
        rhs[i] = -g[ridx[i]]
    solve_regularised(A, rhs, m, x)
    for d in range(N_DOF):
        s = 0.0
        for i in range(m):
            s += jac[ridx[i], d] * x[i]
        qd[d] += winv[d] * s


@njit(cache=True)
def log_event(t, k, kind, ev_t, ev_k, ev_kind, n_ev):
    if n_ev < ev_t.shape[0]:
        ev_t[n_ev] = t
        ev_k[n_ev] = k
        ev_kind[n_ev] = kind
    return n_ev + 1


@njit(cache=True)
def contact_update(t, q, qd, p, tol, rest, ridx, jac, sc, A, ev_t, ev_k, ev_kind, n_ev, vscale):
    """At an event: impulses for the contacts that take part, then the persistent set.

    Contacts closer than T_GAP take part when they approach or are still.
    Approaching ones get Newton's law (restitution e, or 0 for speeds below
    T_VREST * vscale: those come to rest); all are solved together. Then the contacts that are closed and still get
    the accelerations' LCP ``w = A lam + (J a + bias) >= 0, lam >= 0, w.lam = 0``;
    those with a force stay (or become) persistent, the others are released.
    vscale (normally 1) widens "at rest" when an event made no progress.
    Returns ``(n_ev, m)`` with m the number of persistent contacts.
    """
    g, v, bias = sc[_GS], sc[_VB], sc[_BIAS]
    phi(t, q, p, g)
    gap_rate(t, q, qd, p, v)
    phi_q(t, q, p, jac)
    winv = np.empty(N_DOF)
    inverse_mass(p, winv)
    near = np.empty(N_CONTACT, np.int64)
    m = 0
    # closer than T_GAP, or than the contact travels in the time resolution at t
    dt_res = 8.0 * 2.220446049250313e-16 * max(abs(t), 1.0)
    for k in range(N_CONTACT):
        if g[k] < tol[T_GAP] + abs(v[k]) * dt_res or rest[k]:
            near[m] = k
            m += 1
    if m == 0:
        for k in range(N_CONTACT):
            if rest[k]:
                rest[k] = 0
        return n_ev, 0
    vrest = tol[T_VREST] * vscale
    tiny = 1e-3 * tol[T_VREST]  # normal speeds below this are round-off
    # The impact: contacts that approach or are closed and still. A receding
    # contact takes no part: an impulse there would push it apart while the
    # others' impulses slow it, which adds energy (it may hit again later).
    hit = np.empty(m, np.int64)
    nh = 0
    approaching = False
    for i in range(m):
        k = near[i]
        if v[k] <= tiny:
            hit[nh] = k
            nh += 1
            if v[k] < -tiny:
                approaching = True
    if approaching:
        b = np.empty(nh)
        lam = np.empty(nh)
        for i in range(nh):
            k = hit[i]
            e = p[E_SLOT] if k < N_WALL_CONTACT else p[E_GROUND_SLOT]
            b[i] = v[k] + (e * v[k] if v[k] < -vrest else 0.0)
        contact_matrix(jac, winv, hit, np.int64(nh), A)
        solve_lcp(A, b, np.int64(nh), lam)
        for d in range(N_DOF):
            s = 0.0
            for i in range(nh):
                s += jac[hit[i], d] * lam[i]
            qd[d] += winv[d] * s
        for i in range(nh):
            if lam[i] * A[i, i] > tiny:
                n_ev = log_event(t, hit[i], np.int64(IMPULSE), ev_t, ev_k, ev_kind, n_ev)
        gap_rate(t, q, qd, p, v)
    # Contacts closed and (now) at rest: which of them carry a force?
    cand = np.empty(m, np.int64)
    c = 0
    for i in range(m):
        if abs(v[near[i]]) < vrest:
            cand[c] = near[i]
            c += 1
    a = np.empty(N_DOF)
    accel(t, q, qd, p, a)
    newrest = np.zeros(N_CONTACT, np.int64)
    if c > 0:
        gap_bias(t, q, qd, p, bias)
        contact_matrix(jac, winv, cand, np.int64(c), A)
        w0 = np.empty(c)
        force = np.empty(c)
        for i in range(c):
            k = cand[i]
            s = bias[k]
            for d in range(N_DOF):
                s += jac[k, d] * a[d]
            w0[i] = s
        solve_lcp(A, w0, np.int64(c), force)
        for i in range(c):
            if force[i] > 0.0:
                newrest[cand[i]] = 1
    for k in range(N_CONTACT):
        if newrest[k] and not rest[k]:
            n_ev = log_event(t, k, np.int64(REST), ev_t, ev_k, ev_kind, n_ev)
        elif rest[k] and not newrest[k]:
            n_ev = log_event(t, k, np.int64(RELEASE), ev_t, ev_k, ev_kind, n_ev)
        rest[k] = newrest[k]
    m = rest_index(rest, ridx)
    if m > 0:
        project_rest(t, q, qd, p, ridx, m, jac, sc, A)
    return n_ev, m


@njit(cache=True)
def event_value(kind, pos, ta, q, qd, s, p, tol, ridx, m, work, jac, sc, sn, A):
    """Re-step from (ta, q, qd) to time s; the event function there.

    kind 0: gap ``pos`` plus T_EVENT / 2; kind 1: force of persistent contact
    ``ridx[pos]``. The state at s is left in sn[_QS], sn[_QDS].
    """
    qs, qds = sn[_QS], sn[_QDS]
    rk4_contact(ta, q, qd, s - ta, p, qs, qds, work, ridx, m, jac, sc, A)
    if kind == 0:
        g = sc[_GS]
        phi(s, qs, p, g)
        return g[pos] + 0.5 * tol[T_EVENT]
    contact_accel(s, qs, qds, p, ridx, m, sn[_AF], jac, sc, A)
    return sc[_LAM, pos]


@njit(cache=True)
def locate(kind, pos, ta, q, qd, tl, fl, tr, fr, p, tol, ridx, m, work, jac, sc, sn, A):
    """Illinois iteration for the root of the event function in [tl, tr] (fl >= 0 > fr).

    Returns (tl, tr) with tr - tl near machine precision, f(tl) >= 0 > f(tr).
    """
    side = 0
    ttol = 4.0 * 2.220446049250313e-16 * max(abs(tr), tr - ta)
    for _ in range(200):
        if tr - tl <= ttol:
            break
        s = (tl * fr - tr * fl) / (fr - fl)
        if not (tl < s < tr):
            s = 0.5 * (tl + tr)
        f = event_value(kind, pos, ta, q, qd, s, p, tol, ridx, m, work, jac, sc, sn, A)
        if f >= 0.0:
            tl, fl = s, f
            if side == -1:
                fr *= 0.5
            side = -1
        else:
            tr, fr = s, f
            if side == 1:
                fl *= 0.5
            side = 1
    return tl, tr


@njit(cache=True)
def hermite_extrema(fa, fb, da, db, ext):
    """Interior stationary points s in (0, 1) of the cubic with values fa, fb and slopes da, db.

    Writes up to two of them into ext (ascending); returns their number.
    """
    a3 = 2.0 * fa + da - 2.0 * fb + db
    a2 = -3.0 * fa - 2.0 * da + 3.0 * fb - db
    # H'(s) = 3 a3 s^2 + 2 a2 s + da
    A_, B_, C_ = 3.0 * a3, 2.0 * a2, da
    n = 0
    if abs(A_) < 1e-300:
        if abs(B_) > 1e-300:
            s = -C_ / B_
            if 0.0 < s < 1.0:
                ext[0] = s
                n = 1
        return n
    disc = B_ * B_ - 4.0 * A_ * C_
    if disc < 0.0:
        return 0
    r = math.sqrt(disc)
    qq = -0.5 * (B_ + math.copysign(r, B_))
    s1 = qq / A_
    s2 = C_ / qq if qq != 0.0 else s1
    lo, hi = min(s1, s2), max(s1, s2)
    if 0.0 < lo < 1.0:
        ext[n] = lo
        n += 1
    if 0.0 < hi < 1.0 and hi != lo:
        ext[n] = hi
        n += 1
    return n


@njit(cache=True)
def hermite(fa, fb, da, db, s):
    s2 = s * s
    s3 = s2 * s
    return ((2 * s3 - 3 * s2 + 1) * fa + (s3 - 2 * s2 + s) * da
            + (-2 * s3 + 3 * s2) * fb + (s3 - s2) * db)


@njit(cache=True, inline='always')
def speed_bound(qd, tol):
    """A bound on how fast any gap can change at rates qd (a tuple or an array)."""
    s = tol[T_BOXV]
    for d in range(N_DOF):
        s += abs(qd[d]) * tol[T_SPEED + d]
    return s


@njit(cache=True, inline='always')
def step_reach(qd_a, qd_b, h, tol):
    """How close to contact a gap must come, at one end of a step of length h, to need a look.

    A gap positive at both ends can only dip below zero inside the step if one
    end is within half the step's travel of contact. The travel is bounded by
    h times the larger of the two ends' speed bounds (each |qd_i| times the
    most a unit rate can move any gap, plus the prescribed box's speed); the
    band is twice the half, for the speed's change within the step.
    """
    return h * max(speed_bound(qd_a, tol), speed_bound(qd_b, tol)) + tol[T_GAP]


@njit(cache=True)
def left_bracket(k, ta, h, fa, fb, da, db, sr, q, qd, p, tol, ridx, m, work, jac, sc, sn, A):
    """Left end of the bracket of gap k's first crossing before ta + sr h.

    The step's start, or, for a gap that is opening at the start (just after a
    bounce, fa near zero), the hump of the cubic through its values and rates
    at both ends, when the RK4 state there is further from contact.
    """
    gap_kind = np.int64(GAP_EVENT_KIND)
    tl, fl = ta, fa
    if da > 0.0:
        ext = np.empty(2)
        nx = hermite_extrema(fa, fb, da, db, ext)
        for j in range(nx):
            if ext[j] < sr and hermite(fa, fb, da, db, ext[j]) > fa:
                f = event_value(gap_kind, k, ta, q, qd, ta + ext[j] * h, p, tol, ridx, m, work, jac, sc, sn, A)
                if f > fl:
                    tl, fl = ta + ext[j] * h, f
                break
    return tl, fl


@njit(cache=True)
def first_crossing(ta, tb, q, qd, p, tol, rest, ridx, m, work, jac, sc, sn, A):
    """The earliest time in (ta, tb] where a free gap crosses -T_EVENT/2, or -1.

    Uses the trial state at tb in sn[_QB], sn[_QDB] and its gaps sc[_GB]; the
    gaps at ta are sc[_GA]. On success the state just before the crossing
    (every free gap >= -T_EVENT/2) is left in sn[_QS], sn[_QDS] and the
    returned value is its time; returns ta when a contact is already closing
    at ta with nothing to separate it (a touch).
    """
    h = tb - ta
    half = 0.5 * tol[T_EVENT]
    gap_kind = np.int64(GAP_EVENT_KIND)
    ga, gb, va, vb = sc[_GA], sc[_GB], sc[_VA], sc[_VB]
    band = step_reach(qd, sn[_QDB], h, tol)
    near = False
    for k in range(N_CONTACT):
        if not rest[k] and min(ga[k], gb[k]) + half < band:
            near = True
            break
    if not near:
        return -1.0
    gap_rate(ta, q, qd, p, va)
    gap_rate(tb, sn[_QB], sn[_QDB], p, vb)
    ext = np.empty(2)
    best_l = -1.0
    best_k = -1
    t_hi = tb
    for k in range(N_CONTACT):
        if rest[k]:
            continue
        fa, fb = ga[k] + half, gb[k] + half
        if min(fa, fb) >= band:
            continue
        da, db = h * va[k], h * vb[k]
        # right end of the bracket: the step's end, or the cubic's negative dip
        nx = hermite_extrema(fa, fb, da, db, ext)
        sr = -1.0
        fr = 0.0
        if fb < 0.0:
            sr, fr = 1.0, fb
        for j in range(nx):
            if hermite(fa, fb, da, db, ext[j]) < 0.0 and (sr < 0.0 or ext[j] < sr):
                sr = ext[j]
                fr = event_value(gap_kind, k, ta, q, qd, ta + sr * h, p, tol, ridx, m, work, jac, sc, sn, A)
                if fr >= 0.0:
                    sr = 1.0 if fb < 0.0 else -1.0
                    fr = fb
                break
        if sr < 0.0:
            continue
        tr = ta + sr * h
        if best_k >= 0 and tr > t_hi:
            # a later bracket: only matters if this gap is already negative at the best time
            continue
        tl, fl = left_bracket(k, ta, h, fa, fb, da, db, sr, q, qd, p, tol, ridx, m, work, jac, sc, sn, A)
        if fl <= 0.0:
            return ta  # touching now, with no resolvable flight before the crossing
        tl, tr = locate(gap_kind, k, ta, q, qd, tl, fl, tr, fr, p, tol, ridx, m, work, jac, sc, sn, A)
        if best_k < 0 or tl < best_l:
            best_l, best_k = tl, k
            t_hi = tr
    if best_k < 0:
        return -1.0
    # The state just before the first crossing; any other gap already below
    # zero there crossed earlier: locate it within [ta, best].
    for _ in range(N_CONTACT):
        event_value(gap_kind, np.int64(best_k), ta, q, qd, best_l, p, tol, ridx, m, work, jac, sc, sn, A)
        g = sc[_GS]
        worst = -1
        for k in range(N_CONTACT):
            if not rest[k] and g[k] + half < 0.0 and (worst < 0 or g[k] < g[worst]):
                worst = k
        if worst < 0:
            return best_l
        fr = g[worst] + half
        fa, fb = ga[worst] + half, gb[worst] + half
        sr = (best_l - ta) / h
        tl, fl = left_bracket(np.int64(worst), ta, h, fa, fb, h * va[worst], h * vb[worst], sr,
                              q, qd, p, tol, ridx, m, work, jac, sc, sn, A)
        if fl <= 0.0:
            return ta
        tl, tr = locate(gap_kind, np.int64(worst), ta, q, qd, tl, fl, best_l, fr, p, tol, ridx, m, work, jac, sc, sn, A)
        best_l, best_k = tl, worst
    return best_l


@njit(cache=True)
def first_release(ta, tb, q, qd, p, tol, ridx, m, work, jac, sc, sn, A):
    """When the earliest persistent contact's force turns negative in (ta, tb], or -1.

    Returns the time just after the sign change (the force is negative there),
    or ta when a force already pulls at ta.
    """
    contact_accel(tb, sn[_QB], sn[_QDB], p, ridx, m, sn[_AF], jac, sc, A)
    lam_b = sc[_LAM, :m].copy()
    if lam_b.min() >= 0.0:
        return -1.0
    contact_accel(ta, q, qd, p, ridx, m, sn[_AF], jac, sc, A)
    lam_a = sc[_LAM, :m].copy()
    best = -1.0
    for i in range(m):
        if lam_b[i] >= 0.0:
            continue
        if lam_a[i] < 0.0:
            return ta
        tl, tr = locate(np.int64(FORCE_EVENT_KIND), i, ta, q, qd, ta, lam_a[i], tb, lam_b[i], p, tol, ridx, m, work, jac, sc, sn, A)
        if best < 0.0 or tr < best:
            best = tr
    return best


@njit(cache=True)
def advance(ta, tb, q, qd, p, tol, rest, ridx, m, work, jac, sc, sn, A, ev_t, ev_k, ev_kind, n_ev,
            trial):
    """Take the state from ta to tb through every event in between.

    On entry sc[_GA] holds the gaps at (ta, q); on return those at (tb, q).
    trial: the RK4 step from ta to tb and its gaps are already in
    sn[_QB], sn[_QDB] and sc[_GB]. Returns ``(n_ev, m, status)``.
    """
    target = tb
    releasing = False
    stuck = 0
    qb, qdb = sn[_QB], sn[_QDB]
    for _ in range(MAX_EVENTS):
        if not trial:
            rk4_contact(ta, q, qd, target - ta, p, qb, qdb, work, ridx, m, jac, sc, A)
        if m > 0 and not releasing:
            tr = first_release(ta, target, q, qd, p, tol, ridx, m, work, jac, sc, sn, A)
            if tr == ta:       # a persistent contact already pulls: let it go now
                n_ev, m = contact_update(ta, q, qd, p, tol, rest, ridx, jac, sc, A,
                                         ev_t, ev_k, ev_kind, n_ev, 1.0)
                phi(ta, q, p, sc[_GA])
                continue
            if tr > ta:        # step to where it lets go (gaps are checked on the way)
                target = tr
                releasing = True
                continue
        if not trial:
            phi(target, qb, p, sc[_GB])
        trial = False
        if stuck >= 3:
            return n_ev, m, STALLED
        te = first_crossing(ta, target, q, qd, p, tol, rest, ridx, m, work, jac, sc, sn, A)
        if te >= 0.0:
            if te > ta:
                q[:] = sn[_QS]
                qd[:] = sn[_QDS]
                ta = te
                stuck = 0
            else:
                stuck += 1
            # An event at the same instant that changed nothing: a contact
            # touching at round-off level with no resolvable motion. Next time
            # treat every slow contact as at rest; if that changes nothing
            # either, stop (STALLED) rather than let a body through a wall.
            n0, m0 = n_ev, m
            n_ev, m = contact_update(ta, q, qd, p, tol, rest, ridx, jac, sc, A, ev_t, ev_k, ev_kind, n_ev,
                                     1.0 if stuck < 2 else 1e6)
            if n_ev != n0 or m != m0:
                stuck = 0
            phi(ta, q, p, sc[_GA])
            target = tb
            releasing = False
            continue
        stuck = 0
        q[:] = qb
        qd[:] = qdb
        ta = target
        if m > 0:
            project_rest(ta, q, qd, p, ridx, m, jac, sc, A)
            phi(ta, q, p, sc[_GA])
        else:
            sc[_GA, :] = sc[_GB]
        if releasing:          # arrived where a persistent contact lets go
            n_ev, m = contact_update(ta, q, qd, p, tol, rest, ridx, jac, sc, A, ev_t, ev_k, ev_kind, n_ev, 1.0)
            phi(ta, q, p, sc[_GA])
            target = tb
            releasing = False
            continue
        if ta == tb:
            return n_ev, m, DONE
    return n_ev, m, STALLED


@njit(cache=True)
def fly(t0, dt, i, i_stop, q, qd, p, tol, clear):
    """Steps i, i+1, ... of free flight while the broad phase shows them quiet.

    q, qd: tuples. ``clear`` is a lower bound on every gap at the start; each
    step lowers it by the step's band (twice the travel bound) and only when
    that leaves too little is the clearance computed again, so far from the
    walls a step costs one RK4 step on floats and a speed bound. Stops before
    the first step that might come near contact (its trial state is returned
    so the caller need not redo it) or at i_stop. Returns
    ``(i, q, qd, clear, q_trial, qd_trial)``.
    """
    margin = tol[T_GAP] - 0.5 * tol[T_EVENT]
    qn, vn = q, qd
    tt = accel_time_s(t0 + i * dt, p)
    sa = speed_bound(qd, tol)
    while i < i_stop:
        t_next = t0 + (i + 1) * dt
        qn, vn, tt_next = grid_step(t0 + i * dt, t_next, tt, q, qd, dt, p)
        sb = speed_bound(vn, tol)
        band = dt * max(sa, sb) + margin      # step_reach(qd, vn, dt, tol) - T_EVENT / 2
        if not clear >= band:        # (also stops on a non-finite state)
            break
        if BROAD_PHASE:
            c = clear - band
            if c < band:
                c = clearance(t_next, qn, p, tol)
        else:                        # every gap row, every step
            g = phi_s(t_next, qn, p)
            c = g[0]
            for k in range(1, N_CONTACT):
                c = min(c, g[k])
        if not c >= band:
            break
        q, qd, clear, tt, sa = qn, vn, c, tt_next, sb
        i += 1
    return i, q, qd, clear, qn, vn


@njit(cache=True)
def record_step(t, q, qd, p, n_rec, rec_t, rec_q, rec_qd, rec_energy, box, regular, next_rec, record_every):
    """Record a sample; returns the new sample count and the next regular record step."""
    record(t, q, qd, p, n_rec, rec_t, rec_q, rec_qd, rec_energy, box)
    return n_rec + 1, next_rec + record_every if regular else next_rec


@njit(cache=True)
def integrate_exact(q, qd, rest, p, tol, t0, dt, i_begin, i_end, n_total, record_every,
                    rec_t, rec_q, rec_qd, rec_energy, n_rec, ev_t, ev_k, ev_kind, n_ev):
    """Method "exact": like :func:`integrate`, with every contact event located.

    rest: (N_CONTACT,) 0/1 persistent contacts, carried between calls. tol: the
    T_* slots. ev_*: the event log (time, contact, IMPULSE/REST/RELEASE).
    Returns ``(step reached, n_rec, n_ev, status)``.
    """
    work = np.empty((8, N_DOF))
    jac = np.empty((N_CONTACT, N_DOF))
    sc = np.zeros((SC, N_CONTACT))
    sn = np.zeros((SN, N_DOF))
    A = np.empty((N_CONTACT, N_CONTACT))
    ridx = np.empty(N_CONTACT, np.int64)
    box = np.empty(6)
    m = rest_index(rest, ridx)
    if i_begin == 0 and n_rec == 0:   # (not again when resumed after a full log)
        n_ev, m = contact_update(t0, q, qd, p, tol, rest, ridx, jac, sc, A, ev_t, ev_k, ev_kind, n_ev, 1.0)
        record(t0, q, qd, p, n_rec, rec_t, rec_q, rec_qd, rec_energy, box)
        n_rec += 1
    ga, gb = sc[_GA], sc[_GB]
    qb, qdb = sn[_QB], sn[_QDB]
    phi(t0 + i_begin * dt, q, p, ga)
    ga_ok = True             # ga holds the gaps of the current state
    clear = clearance(t0 + i_begin * dt, q, p, tol) if BROAD_PHASE else ga.min()   # a bound on every gap
    q0, qd0, rest0 = q.copy(), qd.copy(), rest.copy()
    half = 0.5 * tol[T_EVENT]
    next_rec = (i_begin // record_every + 1) * record_every
    i = i_begin
    while i < i_end:
        if m == 0:
            # Free flight far from every wall: the lean loop, on floats only.
            i_stop = min(i_end, next_rec)
            i_fly, qt, vt, clear, qn, vn = fly(t0, dt, i, i_stop, tuple_of(q), tuple_of(qd), p, tol, clear)
            if i_fly > i:
                for d in range(N_DOF):
                    q[d] = qt[d]
                    qd[d] = vt[d]
                ga_ok = False
                i = i_fly
                if i == next_rec or i == n_total:
                    n_rec, next_rec = record_step(t0 + i * dt, q, qd, p, n_rec, rec_t, rec_q, rec_qd,
                                                  rec_energy, box, i == next_rec, next_rec, record_every)
                if i == i_end:
                    break
            if i_fly == i_stop:    # stopped only to record: fly on
                continue
        t = t0 + i * dt
        t_next = t0 + (i + 1) * dt
        # The step with gap rows: quiet when every gap, at both ends of the
        # step, is further from contact than the step can move it.
        quiet = False
        if m == 0:             # fly() stopped before this step and left its trial in qn, vn
            band = step_reach(qd, vn, dt, tol) - half
            for d in range(N_DOF):
                qb[d] = qn[d]
                qdb[d] = vn[d]
            if not ga_ok:
                phi(t, q, p, ga)
                ga_ok = True
            phi(t_next, qb, p, gb)
            quiet = True
            for k in range(N_CONTACT):
                if min(ga[k], gb[k]) < band:
                    quiet = False
                    break
        if quiet:
            for d in range(N_DOF):
                q[d] = qb[d]
                qd[d] = qdb[d]
            for k in range(N_CONTACT):
                ga[k] = gb[k]
        else:
            if not ga_ok:
                phi(t, q, p, ga)
                ga_ok = True
            q0[:] = q
            qd0[:] = qd
            rest0[:] = rest
            n0 = n_ev
            n_ev, m, status = advance(t, t_next, q, qd, p, tol, rest, ridx, m, work, jac, sc, sn, A,
                                      ev_t, ev_k, ev_kind, n_ev, m == 0)
            if n_ev > ev_t.shape[0]:   # the log overflowed: undo the step, the caller grows it
                q[:] = q0
                qd[:] = qd0
                rest[:] = rest0
                return i, n_rec, n0, IMPACT_LOG_FULL
            if status != DONE:
                return i, n_rec, n_ev, status
        clear = clearance(t_next, q, p, tol) if BROAD_PHASE else ga.min()
        i += 1
        for d in range(N_DOF):
            if not (math.isfinite(q[d]) and math.isfinite(qd[d])):
                return i, n_rec, n_ev, NONFINITE
        if i == next_rec or i == n_total:
            n_rec, next_rec = record_step(t_next, q, qd, p, n_rec, rec_t, rec_q, rec_qd, rec_energy, box,
                                          i == next_rec, next_rec, record_every)
    return i_end, n_rec, n_ev, DONE


# ---------------------------------------------------------------------------
# ensembles: many members at once, one per prange iteration
# ---------------------------------------------------------------------------
#
# A member runs integrate_exact segment by segment (to each sample step, then
# to the end) with no recording in between. Its result depends on its inputs
# only, so any split of the members over threads, processes or machines gives
# the same numbers bit for bit.

#: tally slots of one member: impulses so far, time of the first one (NaN if none)
TALLY_IMPULSES = 0
TALLY_FIRST = 1


@njit(cache=True)
def run_segment(q, qd, rest, p, tol, dt, i, stop, rec_t, rec_q, rec_qd, rec_e, n_rec,
                ev_t, ev_k, ev_kind, tally):
    """Steps i..stop of one member through any number of full event logs.

    Counts impulses into tally; records a sample at stop (into rec_* at n_rec;
    on the first call, with i = 0 and n_rec = 0, also the start). Returns
    ``(step reached, n_rec, status, ev_t, ev_k, ev_kind)``: the log arrays are
    new ones when a single step needed a bigger log.
    """
    while True:
        i, n_rec, n_ev, status = integrate_exact(q, qd, rest, p, tol, 0.0, dt, i, stop, stop, stop + 1,
                                                 rec_t, rec_q, rec_qd, rec_e, n_rec, ev_t, ev_k, ev_kind, 0)
        for j in range(n_ev):
            if ev_kind[j] == IMPULSE:
                if tally[TALLY_IMPULSES] == 0.0:
                    tally[TALLY_FIRST] = ev_t[j]
                tally[TALLY_IMPULSES] += 1.0
        if status != IMPACT_LOG_FULL:
            return i, n_rec, status, ev_t, ev_k, ev_kind
        if n_ev == 0:    # one step has more events than the log holds
            size = 2 * ev_t.shape[0]
            ev_t, ev_k, ev_kind = np.empty(size), np.empty(size, np.int64), np.empty(size, np.int64)


@njit(cache=True)
def run_member(q0, qd0, p, tol, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin):
    """One ensemble member from its start state to n_steps.

    sample_steps: ascending steps in [0, n_steps] whose (6-column) state goes
    to samp_q[s], samp_qd[s]. fin_q, fin_qd: the final state (6 columns).
    fin: [energy, impulses, first impulse time, status, step reached].
    """
    q, qd = q0.copy(), qd0.copy()
    rest = np.zeros(N_CONTACT, np.int64)
    size = 256
    ev_t, ev_k, ev_kind = np.empty(size), np.empty(size, np.int64), np.empty(size, np.int64)
    rec_t, rec_e = np.empty(2), np.empty(2)
    rec_q, rec_qd = np.empty((2, 6)), np.empty((2, 6))
    tally = np.zeros(2)
    tally[TALLY_FIRST] = np.nan
    # step 0: the start, after any impulse a touching start state gets
    i, n_rec, status, ev_t, ev_k, ev_kind = run_segment(q, qd, rest, p, tol, dt, 0, 0, rec_t, rec_q, rec_qd,
                                                        rec_e, 0, ev_t, ev_k, ev_kind, tally)
    s = 0
    if s < sample_steps.shape[0] and sample_steps[s] == 0:
        samp_q[s, :] = rec_q[0]
        samp_qd[s, :] = rec_qd[0]
        s += 1
    fin_q[:] = rec_q[0]
    fin_qd[:] = rec_qd[0]
    fin[0] = rec_e[0]
    while status == DONE and i < n_steps:
        stop = sample_steps[s] if s < sample_steps.shape[0] else n_steps
        i, n_rec, status, ev_t, ev_k, ev_kind = run_segment(q, qd, rest, p, tol, dt, i, stop, rec_t, rec_q,
                                                            rec_qd, rec_e, 1, ev_t, ev_k, ev_kind, tally)
        if status != DONE:
            break
        if s < sample_steps.shape[0] and stop == sample_steps[s]:
            samp_q[s, :] = rec_q[1]
            samp_qd[s, :] = rec_qd[1]
            s += 1
        fin_q[:] = rec_q[1]
        fin_qd[:] = rec_qd[1]
        fin[0] = rec_e[1]
    fin[1] = tally[TALLY_IMPULSES]
    fin[2] = tally[TALLY_FIRST]
    fin[3] = status
    fin[4] = i


@njit(cache=True, parallel=True)
def run_members(Q0, QD0, P, TOL, dt, n_steps, sample_steps, samp_q, samp_qd, fin_q, fin_qd, fin):
    """:func:`run_member` for every row of Q0, QD0, P, TOL, in parallel (prange)."""
    for j in prange(Q0.shape[0]):
        run_member(Q0[j], QD0[j], P[j], TOL[j], dt, n_steps, sample_steps, samp_q[j], samp_qd[j],
                   fin_q[j], fin_qd[j], fin[j])


@njit(cache=True)
def run_twins(q0, qd0, dq, dqd, p, tol, dt, n_steps, renorm_steps, scale, stretch, fin):
    """Twin trajectories of one member for the finite-time Lyapunov exponent.

    The twin starts at (q0 + dq, qd0 + dqd). Every renorm_steps steps the
    separation d (state difference divided by ``scale``, per coordinate) is
    measured, log(d / d0) goes to stretch[k], and the twin is put back at
    distance d0 along the current separation (Benettin's renormalisation).
    fin: [impulses of the reference, status, step reached].
    """
    n = N_DOF
    q, qd = q0.copy(), qd0.copy()
    qt, qdt = q0 + dq, qd0 + dqd
    d0 = 0.0
    for d in range(n):
        d0 += (dq[d] / scale[d]) ** 2 + (dqd[d] / scale[n + d]) ** 2
    d0 = math.sqrt(d0)
    rest, rest_t = np.zeros(N_CONTACT, np.int64), np.zeros(N_CONTACT, np.int64)
    size = 256
    ev = (np.empty(size), np.empty(size, np.int64), np.empty(size, np.int64))
    ev2 = (np.empty(size), np.empty(size, np.int64), np.empty(size, np.int64))
    rec_t, rec_e = np.empty(2), np.empty(2)
    rec_q, rec_qd = np.empty((2, 6)), np.empty((2, 6))
    tally, tally_t = np.zeros(2), np.zeros(2)
    i = 0
    i2 = 0
    status = DONE
    n_rec = 0
    k = 0
    while i < n_steps:
        stop = min(i + renorm_steps, n_steps)
        i, _, status, e0, e1, e2 = run_segment(q, qd, rest, p, tol, dt, i, stop, rec_t, rec_q, rec_qd, rec_e,
                                               n_rec, ev[0], ev[1], ev[2], tally)
        ev = (e0, e1, e2)
        if status != DONE:
            break
        i2, _, status, e0, e1, e2 = run_segment(qt, qdt, rest_t, p, tol, dt, i2, stop, rec_t, rec_q, rec_qd,
                                                rec_e, n_rec, ev2[0], ev2[1], ev2[2], tally_t)
        ev2 = (e0, e1, e2)
        n_rec = 1
        if status != DONE:
            break
        dist = 0.0
        for d in range(n):
            dist += ((qt[d] - q[d]) / scale[d]) ** 2 + ((qdt[d] - qd[d]) / scale[n + d]) ** 2
        dist = math.sqrt(dist)
        if not dist > 0.0:      # the twins met (round-off): no stretch to measure, restart the twin
            stretch[k] = np.nan
            for d in range(n):
                qt[d] = q[d] + dq[d]
                qdt[d] = qd[d] + dqd[d]
        else:
            stretch[k] = math.log(dist / d0)
            f = d0 / dist
            for d in range(n):
                qt[d] = q[d] + f * (qt[d] - q[d])
                qdt[d] = qd[d] + f * (qdt[d] - qd[d])
        rest_t[:] = rest
        k += 1
    for j in range(k, stretch.shape[0]):
        stretch[j] = np.nan
    fin[0] = tally[TALLY_IMPULSES]
    fin[1] = status
    fin[2] = i


@njit(cache=True, parallel=True)
def run_twin_members(Q0, QD0, DQ, DQD, P, TOL, dt, n_steps, renorm_steps, scale, stretch, fin):
    """:func:`run_twins` for every member, in parallel (prange)."""
    for j in prange(Q0.shape[0]):
        run_twins(Q0[j], QD0[j], DQ[j], DQD[j], P[j], TOL[j], dt, n_steps, renorm_steps, scale,
                  stretch[j], fin[j])


@njit(cache=True)
def box_speed_bound(p, t_end, n_samples, r_box):
    """Largest speed of any point of a prescribed box over [0, t_end], sampled at n_samples times."""
    speed = 0.0
    box = np.empty(6)
    for j in range(n_samples):
        box_motion(t_end * j / max(n_samples - 1, 1), p, box)
        speed = max(speed, math.hypot(box[3], box[4]) + abs(box[5]) * r_box)
    return speed


@njit(cache=True)
def start_gaps(Q0, P):
    """(n,) the smallest gap of each member's start state (negative: inside a wall)."""
    out = np.empty(Q0.shape[0])
    gap = np.empty(N_CONTACT)
    for j in range(Q0.shape[0]):
        phi(0.0, Q0[j], P[j], gap)
        out[j] = gap.min()
    return out
