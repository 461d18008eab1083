"""The fused kernel: fixed-step RK4 between impacts, Newton impacts at contacts.

This file is not imported as it stands. :mod:`jackbox.loader` compiles it
*together with* one generated model: it writes one module whose text is the
generated model (``accel``, ``phi``, ``phi_q`` ... and constants such as
``N_DOF``), then these functions, and imports it. Every function in it is
``@njit(cache=True)`` and every call is to a global of the same file, so Numba
caches the whole kernel, and the module's file name is a hash of all of its
text, so cached machine code can never outlive the source it came from.

The loop reads like the algorithm: integrate a step, look at the gaps, resolve
the contacts that take part, record.

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
from numba import njit

DONE = 0
IMPACT_LOG_FULL = 1
NONFINITE = 2
#: largest contact set solved exactly by enumeration; larger ones use Gauss-Seidel
MAX_ENUMERATED = 10


@njit(cache=True)
def rk4_step(t, q, qd, dt, p, q_out, qd_out, work):
    """One classical RK4 step of ``q' = qd, qd' = accel(t, q, qd)``.

    Reads q, qd; writes q_out, qd_out (they may be q and qd). ``work``: (8, N_DOF).
    """
    qs, vs, a1, a2, a3, a4, v2, v3 = (work[0], work[1], work[2], work[3],
                                      work[4], work[5], work[6], work[7])
    h2 = 0.5 * dt
    accel(t, q, qd, p, a1)
    for i in range(N_DOF):
        qs[i] = q[i] + h2 * qd[i]
        v2[i] = qd[i] + h2 * a1[i]
    accel(t + h2, qs, v2, p, a2)
    for i in range(N_DOF):
        qs[i] = q[i] + h2 * v2[i]
        v3[i] = qd[i] + h2 * a2[i]
    accel(t + h2, qs, v3, p, a3)
    for i in range(N_DOF):
        qs[i] = q[i] + dt * v3[i]
        vs[i] = qd[i] + dt * a3[i]
    accel(t + dt, qs, vs, p, a4)
    h6 = dt / 6.0
    for i in range(N_DOF):
        q_out[i] = q[i] + h6 * (qd[i] + 2.0 * v2[i] + 2.0 * v3[i] + vs[i])
        qd_out[i] = qd[i] + h6 * (a1[i] + 2.0 * a2[i] + 2.0 * a3[i] + a4[i])


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
    work = np.empty((8, N_DOF))
    gap = np.empty(N_CONTACT)
    rows = np.empty(N_CONTACT, np.int64)
    box = np.empty(6)
    if i_begin == 0:
        record(t0, q, qd, p, n_rec, rec_t, rec_q, rec_qd, rec_energy, box)
        n_rec += 1
    for i in range(i_begin, i_end):
        if n_imp + N_CONTACT > imp_t.shape[0]:
            return i, n_rec, n_imp, IMPACT_LOG_FULL
        t = t0 + i * dt
        t_next = t0 + (i + 1) * dt
        rk4_step(t, q, qd, dt, p, q, qd, work)
        phi(t_next, q, p, gap)
        n_imp = resolve_impacts(t_next, q, qd, p, gap, 0.0, rows, imp_t, imp_k, n_imp)
        for d in range(N_DOF):
            if not (math.isfinite(q[d]) and math.isfinite(qd[d])):
                return i + 1, n_rec, n_imp, NONFINITE
        if (i + 1) % record_every == 0 or i + 1 == n_total:
            record(t_next, q, qd, p, n_rec, rec_t, rec_q, rec_qd, rec_energy, box)
            n_rec += 1
    return i_end, n_rec, n_imp, DONE
