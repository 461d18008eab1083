"""The engine's small dense solvers against numpy: the rank-revealing solve of held contacts, the impact LCP.

A held contact set can be redundant (a square jack flush in a corner touches
four times with three degrees of freedom): its contact matrix is singular,
and the forces are not unique. The solve must hold every row exactly, give
the dependent rows nothing, and move its answer continuously as the rows turn
(a jump would look like a force changing sign, and be taken for a release).
"""

from __future__ import annotations

import numpy as np
import pytest

from numba import njit

from jackbox.engine import records as R
from jackbox.engine.impact import lcp, solve_psd


def workspace(C=8, n=6):
    return R.Scratch(np.zeros((9, n)), np.zeros((C, n)), np.zeros((R.SC, C)), np.zeros((R.SN, n)),
                     np.zeros((R.SK, C), np.int64), np.zeros(C + R.MODE_SLOTS, np.int64), np.zeros((C, C)),
                     np.zeros((C, C)), np.zeros((C, C)), np.zeros(2), np.zeros(6))


def solve(A, b):
    m = len(b)
    C = max(m, 1)
    Af, bf, x = np.zeros((C, C)), np.zeros(C), np.zeros(C)
    Af[:m, :m], bf[:m] = A, b
    rank = solve_psd(Af, bf, m, x, workspace(C))
    return x[:m], rank


@pytest.mark.parametrize("seed", range(5))
def test_full_rank_matches_numpy(seed):
    rng = np.random.default_rng(seed)
    m = rng.integers(1, 7)
    J = rng.normal(size=(m, 6))
    A = J @ np.diag(rng.uniform(0.1, 10, 6)) @ J.T
    b = rng.normal(size=m)
    x, rank = solve(A, b)
    assert rank == m
    np.testing.assert_allclose(x, np.linalg.solve(A, b), rtol=1e-9, atol=1e-12 * np.abs(b).max())


@pytest.mark.parametrize("seed", range(5))
def test_redundant_rows_are_held_exactly_and_carry_nothing(seed):
    # rows 2 and 4 are combinations of the rows before them: a consistent,
    # singular system (held contacts of one rigid motion); every row holds,
    # the dependent ones get 0
    rng = np.random.default_rng(seed)
    J = rng.normal(size=(5, 6))
    J[2] = 0.3 * J[0] - 1.7 * J[1]
    J[4] = J[3] + 2.0 * J[1]
    A = J @ np.diag(rng.uniform(0.1, 10, 6)) @ J.T
    b = A @ rng.normal(size=5)
    x, rank = solve(A, b)
    assert rank == 3
    assert x[2] == 0.0 and x[4] == 0.0
    np.testing.assert_allclose(A @ x, b, rtol=0, atol=1e-12 * np.abs(b).max())


def test_a_redundant_set_turning_shares_its_load_continuously():
    # Three contacts on two degrees of freedom, the third the sum of the
    # others, turning with the body: their diagonals change order as they
    # turn (a solve pivoted on the largest would move the load from one
    # contact to another in a jump). The answer may be any solution; it must
    # be one that moves as little as the rows do.
    w = np.array([1.0, 5.0])
    xs = []
    for th in np.linspace(0.0, np.pi, 2001):
        r1 = np.array([np.cos(th), np.sin(th)])
        r2 = np.array([-np.sin(th), np.cos(th)])
        J = np.array([r1, r2, r1 + r2])
        A = J @ np.diag(w) @ J.T
        b = A @ np.array([1.0, 0.5, 0.25])
        x, rank = solve(A, b)
        assert rank == 2
        np.testing.assert_allclose(A @ x, b, rtol=0, atol=1e-12)
        xs.append(x)
    steps = np.abs(np.diff(np.array(xs), axis=0)).max()
    assert steps < 1e-2, steps


def test_zero_and_empty_sets():
    x, rank = solve(np.zeros((2, 2)), np.zeros(2))
    assert rank == 0 and np.all(x == 0.0)
    x, rank = solve(np.zeros((0, 0)), np.zeros(0))
    assert rank == 0


# --- the first probe of a crossing: the root of the step's cubic -------------------------------------

def _bisection(fa, fb, da, db, sl, sr):
    """The cubic's root in (sl, sr) by plain bisection to the last bit (what the engine computed before)."""
    from jackbox.engine.gaps import hermite

    h = hermite.py_func
    if not (h(fa, fb, da, db, sl) >= 0.0 > h(fa, fb, da, db, sr)):
        return -1.0
    for _ in range(60):
        mid = 0.5 * (sl + sr)
        if not sl < mid < sr:
            break
        if h(fa, fb, da, db, mid) >= 0.0:
            sl = mid
        else:
            sr = mid
    return 0.5 * (sl + sr)


def test_the_cubics_root_is_the_one_bisection_finds():
    # Newton's method where the cubic falls all the way across the bracket (one root); where it may
    # cross three times, halving until the bracket falls all the way, then Newton's method on that:
    # the crossing bisection finds in either case, to round-off (Newton alone could land on another
    # crossing, which lies far more than round-off away)
    import numba

    from jackbox.engine import events
    from jackbox.engine.gaps import hermite

    cubic_root, h = numba.njit(events.cubic_root.py_func), hermite.py_func
    rng = np.random.default_rng(11)
    several = newton = 0
    for _ in range(4000):
        fa, fb = rng.uniform(0, 1) ** 3, -rng.uniform(0, 1) ** 3
        da, db = rng.normal(0, 2), rng.normal(0, 2)
        sl, sr = rng.uniform(0, 0.4), rng.uniform(0.6, 1.0)
        got, want = cubic_root(fa, fb, da, db, sl, sr), _bisection(fa, fb, da, db, sl, sr)
        if want < 0.0:
            assert got == -1.0
            continue
        s = np.linspace(sl, sr, 2001)
        falls = bool(np.all(np.diff(h(fa, fb, da, db, s)) < 0.0))
        if falls:
            newton += 1
            assert abs(got - want) <= 64 * np.spacing(want), (fa, fb, da, db, sl, sr)
            assert abs(h(fa, fb, da, db, got)) <= 16 * np.finfo(float).eps * (abs(fa) + abs(fb) + abs(da) + abs(db))
        elif np.sum(np.diff(np.sign(h(fa, fb, da, db, s))) != 0) > 1:
            several += 1
            # the same crossing (others lie far more than 1e-9 away), a root to round-off
            assert abs(got - want) <= 1e-9, (fa, fb, da, db, sl, sr)
            assert abs(h(fa, fb, da, db, got)) <= 16 * np.finfo(float).eps * (abs(fa) + abs(fb) + abs(da) + abs(db))
    # cubics that cross three times inside the bracket: -k (s - r1)(s - r2)(s - r3), as values and slopes
    for _ in range(500):
        r1, r2, r3 = np.sort(rng.uniform(0.1, 0.9, 3))
        k = rng.uniform(0.1, 10.0)

        def c(x, r1=r1, r2=r2, r3=r3, k=k):
            return -k * (x - r1) * (x - r2) * (x - r3)

        def dc(x, r1=r1, r2=r2, r3=r3, k=k):
            return -k * ((x - r2) * (x - r3) + (x - r1) * (x - r3) + (x - r1) * (x - r2))

        sl, sr = rng.uniform(0.0, r1), rng.uniform(r3, 1.0)
        got, want = cubic_root(c(0.0), c(1.0), dc(0.0), dc(1.0), sl, sr), _bisection(c(0.0), c(1.0), dc(0.0), dc(1.0), sl, sr)
        if want >= 0.0:
            several += 1
            # the same crossing as bisection's: the root nearest to either is the same one
            assert min((r1, r2, r3), key=lambda r: abs(r - got)) == min((r1, r2, r3), key=lambda r: abs(r - want))
            assert abs(got - want) <= 1e-9, (r1, r2, r3, k, sl, sr)
            fa, fb, da, db = c(0.0), c(1.0), dc(0.0), dc(1.0)
            assert abs(h(fa, fb, da, db, got)) <= 16 * np.finfo(float).eps * (abs(fa) + abs(fb) + abs(da) + abs(db))
    assert newton > 500 and several > 400          # both branches were exercised


@njit
def _lcp(A, b, m, lam, ws, sweeps):
    return lcp(A, b, m, lam, ws, sweeps)      # (the engine's has no Python wrapper)


def projected_gauss_seidel(A, b, sweeps, tol=1e-12):
    """Sweeps of projected Gauss-Seidel until complementarity holds to tol of b's scale; the sweeps, or None."""
    lam, scale = np.zeros(len(b)), np.abs(b).max()
    for sweep in range(sweeps):
        for k in range(len(b)):
            lam[k] = max(0.0, lam[k] - (b[k] + A[k] @ lam) / A[k, k])
        w = b + A @ lam
        if max(np.max(-w), np.max(np.minimum(w, lam * np.diag(A)))) <= tol * scale:
            return sweep
    return None


@pytest.mark.parametrize("seed", range(6))
def test_an_impact_lcp_of_more_contacts_than_enumerated_is_solved_exactly(seed):
    """11 to 16 contacts of rank 5 between a box and a jack 5000 times as heavy (a random drop's impact had 11:
    Gauss-Seidel stopped after 20000 sweeps unconverged and the jack went 5.5e-8 L into a wall). The engine
    enumerates such a set's active sets up to the coordinates' count (a solution with independent active rows
    exists): complementarity to round-off, at most rank-many contacts pushing."""
    rng = np.random.default_rng(seed)
    m = 11 + seed
    J = rng.normal(size=(m, 6))
    J[:, 5] = J[:, 0] + J[:, 3]                       # rank 5
    A = J @ np.diag([1 / 0.86, 1 / 0.86, 1 / 0.05, 1 / 4596, 1 / 4596, 1 / 500]) @ J.T
    b = J @ rng.normal(size=6)                         # the contacts' velocities before the impact
    assert m > R.MAX_ENUMERATED and b.min() < 0.0
    lam = np.zeros(m)
    assert _lcp(A.copy(), b.copy(), m, lam, workspace(m), np.int64(20000))
    w, scale = A @ lam + b, np.abs(b).max()
    assert lam.min() >= 0.0 and w.min() >= -1e-9 * scale
    assert np.max(np.minimum(lam * np.diag(A), np.abs(w))) <= 1e-9 * scale       # pushing, or not touching
    assert np.count_nonzero(lam) <= 5
    assert projected_gauss_seidel(A, b, 2000) is None      # what the engine did before (unconverged at 20000 too)


# --- a step near a wall with no look at its rates: gaps.dip_free ------------------------------------------

def test_a_gap_above_dip_free_at_both_ends_never_dips_and_the_level_is_the_worst_case():
    """Above ``dip_free`` at both ends, no rates within the speed bound give the event search a dip or a
    crossing (so the exact loop and the lanes skip computing them); just below it, rates at the bound do."""
    import numba

    from jackbox.engine import events
    from jackbox.engine.gaps import dip_free, hermite

    first_dip, level = numba.njit(events.first_dip.py_func), numba.njit(dip_free.py_func)
    tol = np.zeros(R.T_SPEED + 6)
    tol[R.T_GAP] = 1e-9
    ext = np.zeros(2)
    rng = np.random.default_rng(7)
    s = np.linspace(0.0, 1.0, 2001)
    for _ in range(3000):
        travel = 10.0 ** rng.uniform(-6, -1)            # h times the larger end's speed bound
        dip = travel * 10.0 ** rng.uniform(-9, -1)      # the cubic's error
        band = travel + tol[R.T_GAP]
        clear = level(band, dip, tol)
        fa, fb = clear + travel * rng.exponential(0.05, 2) * (rng.random(2) < 0.7)
        da, db = travel * rng.uniform(-1, 1, 2) * np.where(rng.random(2) < 0.3, 1.0, rng.random(2))
        if rng.random() < 0.3:                          # the worst case: both at the bound, towards then away
            da, db = -travel, travel
        assert first_dip(fa, fb, da, db, dip, -1.0, ext) == -1.0
        assert min(hermite.py_func(fa, fb, da, db, x) for x in s[::50]) > dip
    # a hair below the level, the worst case's cubic dips below its error at mid-step: the search steps there
    travel, dip = 1e-3, 1e-9
    below = level(travel + tol[R.T_GAP], dip, tol) - 1e-3 * travel
    assert first_dip(below, below, -travel, travel, dip, -1.0, ext) == pytest.approx(0.5)
