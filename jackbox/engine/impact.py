"""Impacts: the contact matrix, a small dense solver and the impulses' LCP.

With ``J`` the rows of ``phi_q`` of the contacts that take part, ``W = M^-1``
and ``v = J qd (+ phi_t)`` their normal velocities, the impulses ``lam`` solve
the linear complementarity problem

.. math::

    w = J W J^T \\lambda + b \\ge 0,\\quad \\lambda \\ge 0,\\quad w^T\\lambda = 0,
    \\qquad b_k = v_k + e_k \\min(v_k, 0),

i.e. Newton's law per contact: an approaching contact leaves at ``-e v`` or
faster, a receding one is not pulled back, and no impulse pulls. All contacts
are solved together, never one after the other. The same LCP, on
accelerations, decides which resting contacts carry a force
(:mod:`jackbox.engine.modes`).
"""

import numpy as np
from numba import njit

from .records import FLAGS, HIT, IDX, LAM, LR, LX, MAX_ENUMERATED, R, RHS, RINV, ROW_RATE, WARN_LCP, WINV, Y


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def restitution(model, p, k):
    """Contact k's coefficient of restitution: the walls' e or the ground's."""
    return p[model.e_slot] if k < model.n_wall else p[model.e_ground_slot]


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def contact_matrix(jac, winv, rows, m, A):
    """``A = J_R M^-1 J_R^T`` for the m contacts listed in rows (M diagonal: winv = diag M^-1).

    jac: the contacts' rows (:data:`~.records.ROW_BIAS`): their first n_dof entries.
    """
    n = winv.shape[0]
    for i in range(m):
        for j in range(i, m):
            s = 0.0
            for d in range(n):
                s += jac[rows[i], d] * winv[d] * jac[rows[j], d]
            A[i, j] = s
            A[j, i] = s


@njit(cache=True, no_cpython_wrapper=True)
def solve_dense(A, b, m, x, ws):
    """Solve ``A[:m, :m] x = b[:m]`` by Gaussian elimination with partial pivoting.

    Works on copies (in the scratch record); returns False when the matrix is
    singular to working precision.
    """
    a = ws.lu
    r = ws.c[R]
    for i in range(m):
        r[i] = b[i]
        for k in range(m):
            a[i, k] = A[i, k]
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


#: a row of a contact matrix whose diagonal, once the rows before it are eliminated, keeps less than this
#: fraction of itself depends on them (rank-revealing solve)
RANK_TOL = 1e-11
#: Gauss-Seidel sweeps for a contact set too large to enumerate, and its convergence test
#: (complementarity violated by less than this fraction of the right-hand side's scale)
PGS_SWEEPS, PGS_TOL = 20000, 1e-12


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def factor_rows(A, m, L, rinv):
    """Factor ``A[:m, :m]``, symmetric positive semi-definite, revealing its rank; returns the rank.

    ``A = L D L^T`` (L unit lower triangular, D diagonal: no square roots;
    on floats, ``flight.factor4``, four rows factor in 30 ns against 46 with
    them), row after row in the contacts' order, skipping a row that depends
    on those before it: what is left of its diagonal once they are eliminated
    is below RANK_TOL of the diagonal (a redundant contact set: a square jack
    flush in a corner touches four times with three degrees of freedom). Its
    column of L (and its row of L's upper triangle) is zero and its entry of
    ``rinv`` (the reciprocals of D) is 0, so :func:`solve_rows`
    gives its unknown 0 and the others carry the whole answer: for a
    consistent system (held contacts of one rigid motion) that solves it
    exactly, where a diagonal shift would leave a residual. In a fixed order,
    not pivoted, so the forces it gives move continuously while the same rows
    are held (a pivot order that flips with the state would move a redundant
    set's load from one contact to another in a jump, which event location
    would take for a release). One factorization serves several right-hand
    sides (a projection's gaps and rates).

    L's strict lower triangle holds L; its strict upper triangle the same
    entries before their scaling by D's reciprocal (``L[j, i] = L[i, j] D[j]``,
    which the later rows' eliminations read).

    On the arrays themselves: a call that passed the scratch record would
    pass each of its arrays' fields (some hundred words), which cost more
    than the factorization of a few rows.
    """
    rank = 0
    for j in range(m):
        d = A[j, j]
        for k in range(j):
            d -= L[j, k] * L[k, j]
        if d > RANK_TOL * A[j, j]:
            rank += 1
            r = 1.0 / d
            rinv[j] = r
            for i in range(j + 1, m):
                s = A[i, j]
                for k in range(j):
                    s -= L[i, k] * L[k, j]
                L[j, i] = s
                L[i, j] = s * r
        else:
            rinv[j] = 0.0
            for i in range(j + 1, m):
                L[i, j] = 0.0
                L[j, i] = 0.0
    return rank


@njit(cache=True, no_cpython_wrapper=True, inline="always")
def solve_rows(b, m, L, rinv, y, x):
    """``x`` for ``A x = b`` with A factored by :func:`factor_rows`; the dependent rows' unknowns are 0.

    Their reciprocal is 0 and their column of L too, so no row needs a test.
    b and y may be the same array.
    """
    for j in range(m):
        s = b[j]
        for k in range(j):
            s -= L[j, k] * y[k]
        y[j] = s
    for j in range(m - 1, -1, -1):
        s = y[j] * rinv[j]
        for k in range(j + 1, m):
            s -= L[k, j] * x[k]
        x[j] = s


@njit(cache=True, no_cpython_wrapper=True)
def factor_psd(A, m, ws):
    """:func:`factor_rows` into the scratch record (``ws.lu``, ``ws.c[RINV]``); returns the rank."""
    return factor_rows(A, m, ws.lu, ws.c[RINV])


@njit(cache=True, no_cpython_wrapper=True)
def solve_factored(b, m, rank, x, ws):
    """:func:`solve_rows` with the factorization :func:`factor_psd` left in the scratch record."""
    solve_rows(b, m, ws.lu, ws.c[RINV], ws.c[Y], x)


@njit(cache=True)
def solve_psd(A, b, m, x, ws):
    """Solve ``A[:m, :m] x = b[:m]`` for a symmetric positive semi-definite A (:func:`factor_psd`); returns the rank."""
    rank = factor_psd(A, m, ws)
    solve_factored(b, m, rank, x, ws)
    return rank


@njit(cache=True, no_cpython_wrapper=True)
def solve_lcp(A, b, m, lam, ws):
    """Impulses (or forces) of the LCP ``w = A lam + b >= 0, lam >= 0, w . lam = 0``; False if unsolved.

    :func:`lcp` with up to PGS_SWEEPS sweeps; a failure sets WARN_LCP in ``ws.k[FLAGS, 0]``.
    """
    if lcp(A, b, m, lam, ws, np.int64(PGS_SWEEPS)):
        return True
    ws.k[FLAGS, 0] |= WARN_LCP
    return False


#: most active sets :func:`lcp` enumerates for a contact set larger than MAX_ENUMERATED
MAX_SETS = 1 << 16


@njit(cache=True, no_cpython_wrapper=True)
def sets_up_to(m, largest):
    """How many sets of 1 .. largest of m contacts there are."""
    total, count = 0, 1
    for size in range(1, min(m, largest) + 1):
        count = count * (m - size + 1) // size
        total += count
    return total


@njit(cache=True, no_cpython_wrapper=True)
def enumerate_sets(A, b, m, largest, lam, tol, ws):
    """The LCP of :func:`lcp` by its active sets of 1 .. largest contacts, smallest first (each size's sets
    in increasing order of their bit masks, visited directly): the first whose impulses are non-negative and
    whose inactive contacts do not approach, into lam; False if none passes (tolerance tol)."""
    sub, rhs, x, idx = ws.sub, ws.c[LR], ws.c[LX], ws.k[IDX]
    for size in range(1, min(m, largest) + 1):
        mask = (1 << size) - 1           # the sets of this size in increasing order (Gosper's successor)
        while mask < 1 << m:
            count = 0
            for k in range(m):
                if mask >> k & 1:
                    idx[count] = k
                    count += 1
            low = mask & -mask
            ripple = mask + low
            this, mask = mask, (((ripple ^ mask) >> 2) // low) | ripple
            for i in range(size):
                rhs[i] = -b[idx[i]]
                for j in range(size):
                    sub[i, j] = A[idx[i], idx[j]]
            if not solve_dense(sub, rhs, size, x, ws):
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
                if not this >> k & 1:
                    w = b[k]
                    for j in range(m):
                        w += A[k, j] * lam[j]
                    if w < -tol:
                        ok = False
            if ok:
                return True
    return False


@njit(cache=True, no_cpython_wrapper=True)
def lcp(A, b, m, lam, ws, sweeps):
    """The LCP ``w = A lam + b >= 0, lam >= 0, w . lam = 0`` into lam; False if unsolved (flags nothing).

    Exact for up to MAX_ENUMERATED contacts: no impulse where nothing
    approaches (every ``b >= 0``); else tries every active set, smallest
    first (:func:`enumerate_sets`), and keeps the first whose impulses are
    non-negative and whose inactive contacts do not approach. ``A = J M^-1
    J^T`` is positive semi-definite, so a solution exists and the velocities it
    gives are unique (the impulses are not, on a redundant set: the smallest
    set that works is kept). A solution whose active rows are independent
    exists too, so no more than the coordinates' count of them: a larger set
    is enumerated up to that size while that takes at most MAX_SETS sets
    (every set of 20 contacts and 6 coordinates). Else, or where no
    enumerated set passes the tolerances (round-off on a degenerate set),
    projected Gauss-Seidel, run until complementarity holds to PGS_TOL;
    returns False if it does not within ``sweeps``. (Gauss-Seidel had failed,
    after 20000 sweeps, on 11 contacts of rank 5 under a jack 5000 times as
    heavy as its box.)
    """
    bscale = 0.0
    for k in range(m):
        bscale = max(bscale, abs(b[k]))
    tol = 1e-10 * bscale
    still = True                 # the empty set: nothing approaches, no impulse (the answer every larger
    for k in range(m):           # set would come to, after all of them, through Gauss-Seidel's first sweep)
        if not b[k] >= 0.0:
            still = False
    if still:
        for k in range(m):
            lam[k] = 0.0
        return True
    if m <= MAX_ENUMERATED:
        if enumerate_sets(A, b, m, m, lam, tol, ws):
            return True
    else:
        largest = ws.n.shape[1]              # (the rank of A is at most the coordinates' count)
        if sets_up_to(m, largest) <= MAX_SETS and enumerate_sets(A, b, m, largest, lam, tol, ws):
            return True
    # no enumerated set passed the tolerances (round-off on a degenerate set), or too many sets: Gauss-Seidel
    # Projected Gauss-Seidel: converges for PSD A.
    for k in range(m):
        lam[k] = 0.0
    for sweep in range(sweeps):
        for k in range(m):
            w = b[k]
            for j in range(m):
                w += A[k, j] * lam[j]
            lam[k] = max(0.0, lam[k] - w / max(A[k, k], 1e-300))
        worst = 0.0
        for k in range(m):
            w = b[k]
            for j in range(m):
                w += A[k, j] * lam[j]
            # violated: w < 0, or a force where w > 0 (measured as the w it leaves)
            worst = max(worst, -w, min(w, lam[k] * A[k, k]))
        if worst <= PGS_TOL * bscale:
            return True
    return False


@njit(cache=True, no_cpython_wrapper=True)
def resolve_impacts(model, t, q, qd, p, gap, active_tol, ws, log, n_imp):
    """Method "naive": the impulses of every contact with ``gap < active_tol``, all at once.

    Changes qd in place; logs each contact that received an impulse into
    ``log`` (an Events record) from ``n_imp``. Returns the new log length.
    """
    n, C = model.n_dof, model.n_contact
    rows = ws.k[HIT]
    m = 0
    for k in range(C):
        if gap[k] < active_tol:
            rows[m] = k
            m += 1
    if m == 0:
        return n_imp
    jac = ws.jac
    model.contact_rows(t, q, qd, p, rows, np.int64(m), jac)
    winv = ws.n[WINV]
    model.inverse_mass(p, winv)
    b = ws.c[RHS]
    approaching = False
    for i in range(m):
        k = rows[i]
        s = jac[k, n + ROW_RATE]
        e = restitution(model, p, k)
        b[i] = s + e * min(s, 0.0)
        if s < 0.0:
            approaching = True
    if not approaching:
        return n_imp
    A = ws.A
    for i in range(m):
        for j in range(m):
            s = 0.0
            for d in range(n):
                s += jac[rows[i], d] * winv[d] * jac[rows[j], d]
            A[i, j] = s
    lam = ws.c[LAM]
    solve_lcp(A, b, np.int64(m), lam, ws)
    for i in range(m):
        if lam[i] > 0.0:
            k = rows[i]
            for d in range(n):
                qd[d] += winv[d] * jac[k, d] * lam[i]
            log.t[n_imp] = t
            log.k[n_imp] = k
            n_imp += 1
    return n_imp
