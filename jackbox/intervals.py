"""Bounds on how fast a formula of time can change: interval arithmetic with derivatives.

The exact method skips a contact's gap while the bodies cannot reach it in a
step, which needs a bound on the speed of every point of a prescribed box.
Sampling its motion is not a bound: a box shaken at 100 Hz and sampled every
5 ms (20001 samples over 100 s) is seen at the turning points only, a bound
of 5e-10 for a wall that moves at 31 L/s, and the jack went through it. Here
the formulas of the scene's small grammar (:mod:`codegen.expr`: numbers,
names, ``+ - * / **`` and fifteen functions) are evaluated on intervals of
time, each node giving an interval that holds its value and one that holds
its derivative in t over the whole interval: a bound by construction, at
most loose (each occurrence of t varies on its own), never short. Where a
formula may be undefined or unbounded on an interval (``log`` of a range
reaching 0, ``tan`` across a pole) the interval is infinite, and so is the
bound: every gap is then looked at every step.

Vectorised over members (parameter values as arrays) and over the pieces of
[0, t_end] at once; numpy rounds to nearest, not outwards, so the result is
widened by :data:`MARGIN` and rounded up onto a coarse grid
(:func:`round_up`), which also makes a bound computed in a row of many the
same, to the bit, as computed alone. A parameter may be given as a range
(a study's sweep): one bound then holds for every value in it.
"""

from __future__ import annotations

import ast
import math

import numpy as np

from codegen import Expr

#: pieces of [0, t_end] on which the formulas are bounded (a finer cut bounds a non-periodic motion more tightly)
PIECES = 64
#: relative widening of the result for numpy's rounding to nearest (a few ulps a node at most)
MARGIN = 1e-9
#: the bound is rounded up to the next of 16 steps an octave (at most 4.4% above it)
STEPS_PER_OCTAVE = 16

_INF = math.inf
#: the grammar's named constants (codegen.expr.CONSTANTS; tests/test_intervals.py checks they are the same)
FORMULA_CONSTANTS = {"pi": math.pi}


def round_up(x: np.ndarray) -> np.ndarray:
    """x (>= 0) widened by MARGIN and rounded up to 2**(k / STEPS_PER_OCTAVE): the same for a last-bit difference."""
    x = np.asarray(x, float) * (1.0 + MARGIN)
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.ceil(np.log2(x) * STEPS_PER_OCTAVE)
        out = np.exp2(k / STEPS_PER_OCTAVE)
    out = np.where(out < x, out * 2.0 ** (1.0 / STEPS_PER_OCTAVE), out)
    return np.where(x > 0.0, np.where(np.isfinite(x), out, _INF), 0.0)


class Interval:
    """Intervals ``[lo, hi]`` (arrays of one shape) of a value and ``[dlo, dhi]`` of its derivative in t."""

    __slots__ = ("lo", "hi", "dlo", "dhi")

    def __init__(self, lo, hi, dlo, dhi):
        # a NaN bound (inf - inf, 0 * inf) knows nothing: the widest interval
        self.lo = np.where(np.isnan(lo), -_INF, lo)
        self.hi = np.where(np.isnan(hi), _INF, hi)
        self.dlo = np.where(np.isnan(dlo), -_INF, dlo)
        self.dhi = np.where(np.isnan(dhi), _INF, dhi)

    @property
    def rate(self) -> np.ndarray:
        """The largest |derivative| on each interval."""
        return np.maximum(np.abs(self.dlo), np.abs(self.dhi))


def _span(lo, hi):
    """A value interval (lo, hi) with derivative 0."""
    z = np.zeros_like(lo)
    return Interval(lo, hi, z, z)


def _mul(alo, ahi, blo, bhi):
    with np.errstate(invalid="ignore"):
        p = np.stack([alo * blo, alo * bhi, ahi * blo, ahi * bhi])
    p = np.where(np.isnan(p), 0.0, p)          # 0 * inf: the zero end of one factor
    return p.min(axis=0), p.max(axis=0)


def _recip(lo, hi):
    """1 / [lo, hi]: unbounded where the interval holds 0."""
    holds_zero = (lo <= 0.0) & (hi >= 0.0)
    with np.errstate(divide="ignore"):
        rlo, rhi = 1.0 / hi, 1.0 / lo
    return np.where(holds_zero, -_INF, rlo), np.where(holds_zero, _INF, rhi)


def _times(a: Interval, b: Interval) -> Interval:
    lo, hi = _mul(a.lo, a.hi, b.lo, b.hi)
    # (a b)' = a' b + a b'
    l1, h1 = _mul(a.dlo, a.dhi, b.lo, b.hi)
    l2, h2 = _mul(a.lo, a.hi, b.dlo, b.dhi)
    return Interval(lo, hi, l1 + l2, h1 + h2)


def _scale(a: Interval, lo, hi) -> Interval:
    """The derivative of f(a) where f' lies in [lo, hi] on a: the chain rule."""
    dlo, dhi = _mul(lo, hi, a.dlo, a.dhi)
    return dlo, dhi


def _sin(lo, hi):
    """sin on [lo, hi]: the ends, or +-1 where a peak lies inside."""
    wide = ~((hi - lo) < 2.0 * math.pi)          # (an infinite interval too)
    with np.errstate(invalid="ignore"):
        a, b = np.sin(lo), np.sin(hi)
        top = np.ceil((lo - math.pi / 2) / (2 * math.pi)) * 2 * math.pi + math.pi / 2 <= hi
        bottom = np.ceil((lo + math.pi / 2) / (2 * math.pi)) * 2 * math.pi - math.pi / 2 <= hi
    slo = np.where(bottom | wide, -1.0, np.minimum(a, b))
    shi = np.where(top | wide, 1.0, np.maximum(a, b))
    return slo, shi


def _monotone(f, lo, hi, rising=True):
    with np.errstate(all="ignore"):
        a, b = f(lo), f(hi)
    return (a, b) if rising else (b, a)


def _call(name: str, args: list[Interval]) -> Interval:
    a = args[0]
    lo, hi = a.lo, a.hi
    if name in ("sin", "cos"):
        shift = 0.0 if name == "sin" else math.pi / 2
        vlo, vhi = _sin(lo + shift, hi + shift)
        # sin' = cos, cos' = -sin
        plo, phi = _sin(lo + shift + math.pi / 2, hi + shift + math.pi / 2)
        return Interval(vlo, vhi, *_scale(a, plo, phi))
    if name == "tan":
        # a pole (pi/2 + k pi) inside, or an infinite interval: unbounded
        with np.errstate(invalid="ignore"):
            pole = ~((np.floor((lo - math.pi / 2) / math.pi) == np.floor((hi - math.pi / 2) / math.pi))
                     & np.isfinite(lo) & np.isfinite(hi))
        vlo, vhi = _monotone(np.tan, lo, hi)
        vlo, vhi = np.where(pole, -_INF, vlo), np.where(pole, _INF, vhi)
        slo, shi = _mul(vlo, vhi, vlo, vhi)
        slo = np.maximum(slo, 0.0)
        return Interval(vlo, vhi, *_scale(a, 1.0 + slo, 1.0 + shi))
    if name in ("asin", "acos"):
        outside = (lo < -1.0) | (hi > 1.0)
        c_lo, c_hi = np.clip(lo, -1.0, 1.0), np.clip(hi, -1.0, 1.0)
        vlo, vhi = _monotone(np.arcsin if name == "asin" else np.arccos, c_lo, c_hi, rising=name == "asin")
        # the derivative +-1 / sqrt(1 - x^2): largest where |x| is
        m = np.maximum(np.abs(c_lo), np.abs(c_hi))
        with np.errstate(divide="ignore", invalid="ignore"):
            big = 1.0 / np.sqrt(1.0 - m * m)
        big = np.where(outside | (m >= 1.0), _INF, big)
        plo, phi = (np.ones_like(big), big) if name == "asin" else (-big, -np.ones_like(big))
        return Interval(vlo, vhi, *_scale(a, np.minimum(plo, phi), np.maximum(plo, phi)))
    if name == "atan":
        vlo, vhi = _monotone(np.arctan, lo, hi)
        m = np.where((lo <= 0.0) & (hi >= 0.0), 0.0, np.minimum(np.abs(lo), np.abs(hi)))
        M = np.maximum(np.abs(lo), np.abs(hi))
        with np.errstate(over="ignore"):
            return Interval(vlo, vhi, *_scale(a, 1.0 / (1.0 + M * M), 1.0 / (1.0 + m * m)))
    if name == "atan2":
        y, x = args
        # value within [-pi, pi]; (atan2(y, x))' = (x y' - y x') / (x^2 + y^2)
        l1, h1 = _mul(x.lo, x.hi, y.dlo, y.dhi)
        l2, h2 = _mul(y.lo, y.hi, x.dlo, x.dhi)
        xx = _mul(x.lo, x.hi, x.lo, x.hi)
        yy = _mul(y.lo, y.hi, y.lo, y.hi)
        rlo, rhi = _recip(np.maximum(xx[0], 0.0) + np.maximum(yy[0], 0.0), xx[1] + yy[1])
        dlo, dhi = _mul(l1 - h2, h1 - l2, rlo, rhi)
        # its cut: where x <= 0 and y crosses 0 the value jumps by 2 pi (a box that jumps: no speed bounds it)
        cut = (x.lo <= 0.0) & (y.lo <= 0.0) & (y.hi >= 0.0)
        full = np.full_like(dlo, math.pi)
        return Interval(-full, full, np.where(cut, -_INF, dlo), np.where(cut, _INF, dhi))
    if name in ("exp", "sinh", "tanh"):
        f = {"exp": np.exp, "sinh": np.sinh, "tanh": np.tanh}[name]
        vlo, vhi = _monotone(f, lo, hi)
        if name == "exp":
            plo, phi = vlo, vhi
        elif name == "sinh":
            plo, phi = _cosh(lo, hi)
        else:
            # tanh' = 1 - tanh^2, in (0, 1]
            s = np.maximum(np.abs(vlo), np.abs(vhi))
            plo, phi = 1.0 - s * s, np.where((lo <= 0.0) & (hi >= 0.0), 1.0,
                                             1.0 - np.minimum(np.abs(vlo), np.abs(vhi)) ** 2)
        return Interval(vlo, vhi, *_scale(a, plo, phi))
    if name == "cosh":
        vlo, vhi = _cosh(lo, hi)
        plo, phi = _monotone(np.sinh, lo, hi)
        return Interval(vlo, vhi, *_scale(a, plo, phi))
    if name in ("log", "sqrt"):
        # undefined below 0: where the interval reaches there, nothing is known
        bad = lo < 0.0
        c_lo = np.maximum(lo, 0.0)
        f = np.log if name == "log" else np.sqrt
        vlo, vhi = _monotone(f, c_lo, hi)
        # log' = 1 / x, sqrt' = 1 / (2 sqrt x): largest at the low end
        with np.errstate(divide="ignore", invalid="ignore"):
            phi = 1.0 / c_lo if name == "log" else 0.5 / vlo
            plo = 1.0 / hi if name == "log" else 0.5 / vhi
        vlo, vhi = np.where(bad, -_INF, vlo), np.where(bad, _INF, vhi)
        plo, phi = np.where(bad, -_INF, plo), np.where(bad, _INF, phi)
        return Interval(vlo, vhi, *_scale(a, plo, phi))
    assert name == "abs", name
    across = (lo < 0.0) & (hi > 0.0)
    vlo = np.where(across, 0.0, np.minimum(np.abs(lo), np.abs(hi)))
    vhi = np.maximum(np.abs(lo), np.abs(hi))
    plo = np.where(hi <= 0.0, -1.0, np.where(lo >= 0.0, 1.0, -1.0))
    phi = np.where(lo >= 0.0, 1.0, np.where(hi <= 0.0, -1.0, 1.0))
    return Interval(vlo, vhi, *_scale(a, plo, phi))


def _cosh(lo, hi):
    m = np.where((lo <= 0.0) & (hi >= 0.0), 0.0, np.minimum(np.abs(lo), np.abs(hi)))
    with np.errstate(over="ignore"):
        return np.cosh(m), np.cosh(np.maximum(np.abs(lo), np.abs(hi)))


def _power(a: Interval, b: Interval) -> Interval:
    whole = np.all(b.lo == b.hi) and np.all(b.dlo == 0.0) and np.all(b.dhi == 0.0)
    if whole and np.all(b.lo == np.round(b.lo)) and np.all(np.abs(b.lo) <= 64):
        n = int(b.lo.flat[0]) if b.lo.size else 0
        if np.all(b.lo == n):
            return _integer_power(a, n)
    if whole:
        c = b.lo
        # x^c for a constant c that is not a whole number: defined for x >= 0 (x > 0 where c < 0)
        bad = (a.lo < 0.0) | ((c < 0.0) & (a.lo <= 0.0))
        base_lo = np.maximum(a.lo, 0.0)
        with np.errstate(all="ignore"):
            p1, p2 = base_lo ** c, a.hi ** c
            # (x^c)' = c x^(c - 1)
            q1, q2 = c * base_lo ** (c - 1.0), c * a.hi ** (c - 1.0)
        vlo, vhi = np.minimum(p1, p2), np.maximum(p1, p2)
        plo, phi = np.minimum(q1, q2), np.maximum(q1, q2)
        # c - 1 < 0: x^(c - 1) grows without bound at 0
        phi = np.where((c < 1.0) & (base_lo == 0.0) & (c > 0.0), _INF, phi)
        vlo, vhi = np.where(bad, -_INF, vlo), np.where(bad, _INF, vhi)
        plo, phi = np.where(bad, -_INF, plo), np.where(bad, _INF, phi)
        return Interval(vlo, vhi, *_scale(a, plo, phi))
    # a^b = exp(b log a): a > 0
    return _call("exp", [_times(b, _call("log", [a]))])


def _integer_power(a: Interval, n: int) -> Interval:
    if n == 0:
        return _span(np.ones_like(a.lo), np.ones_like(a.lo))
    if n < 0:
        p = _integer_power(a, -n)
        rlo, rhi = _recip(p.lo, p.hi)
        # (1 / p)' = -p' / p^2
        r2lo, r2hi = _mul(rlo, rhi, rlo, rhi)
        dlo, dhi = _mul(-p.dhi, -p.dlo, np.maximum(r2lo, 0.0), r2hi)
        return Interval(rlo, rhi, dlo, dhi)
    with np.errstate(over="ignore", invalid="ignore"):
        e1, e2 = a.lo ** n, a.hi ** n
    if n % 2:
        vlo, vhi = e1, e2
    else:
        vlo = np.where((a.lo <= 0.0) & (a.hi >= 0.0), 0.0, np.minimum(e1, e2))
        vhi = np.maximum(e1, e2)
    # (x^n)' = n x^(n - 1)
    p = _integer_power(_span(a.lo, a.hi), n - 1)
    return Interval(vlo, vhi, *_scale(a, n * p.lo, n * p.hi))


def _node(node: ast.expr, env: dict[str, Interval], shape) -> Interval:
    if isinstance(node, ast.Constant):
        v = np.full(shape, float(node.value))
        return _span(v, v)
    if isinstance(node, ast.Name):
        if node.id in env:
            return env[node.id]
        v = np.full(shape, FORMULA_CONSTANTS[node.id])
        return _span(v, v)
    if isinstance(node, ast.UnaryOp):
        a = _node(node.operand, env, shape)
        return Interval(-a.hi, -a.lo, -a.dhi, -a.dlo) if isinstance(node.op, ast.USub) else a
    if isinstance(node, ast.BinOp):
        a, b = _node(node.left, env, shape), _node(node.right, env, shape)
        if isinstance(node.op, ast.Add):
            return Interval(a.lo + b.lo, a.hi + b.hi, a.dlo + b.dlo, a.dhi + b.dhi)
        if isinstance(node.op, ast.Sub):
            return Interval(a.lo - b.hi, a.hi - b.lo, a.dlo - b.dhi, a.dhi - b.dlo)
        if isinstance(node.op, ast.Mult):
            return _times(a, b)
        if isinstance(node.op, ast.Div):
            return _times(a, _integer_power(b, -1))
        return _power(a, b)
    assert isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
    return _call(node.func.id, [_node(arg, env, shape) for arg in node.args])


def rate_bounds(formula: Expr, t_end: float, values: dict, pieces: int = PIECES):
    """(m, pieces) bounds on |d formula / dt| on each piece of [0, t_end], for m members' parameter values.

    values: each name the formula uses besides t, a float or an (m,) array,
    or a tuple (lo, hi) of them: every value in that range (a study's sweep).
    t_end may be infinite: a bound for all time (finite where the formula's
    rate is bounded, a periodic motion say).
    """
    m = max([np.size(v) for v in values.values() if not isinstance(v, tuple)] + [1])
    # (t_end = inf: every t >= 0, in pieces of which the last reaches infinity)
    edges = np.append(np.linspace(0.0, 1.0, pieces), _INF) if t_end == _INF else np.linspace(0.0, float(t_end),
                                                                                               pieces + 1)
    shape = (m, pieces)
    ones = np.ones(shape)
    env = {"t": Interval(edges[:-1] * ones, edges[1:] * ones, ones, ones)}
    for name in formula.names - {"t"}:
        lo, hi = values[name] if isinstance(values[name], tuple) else (values[name], values[name])
        env[name] = _span(np.asarray(lo, float).reshape(-1, 1) * ones, np.asarray(hi, float).reshape(-1, 1) * ones)
    with np.errstate(all="ignore"):
        return _node(formula.tree, env, shape).rate
