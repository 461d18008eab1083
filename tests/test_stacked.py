"""engine.stacked: a tuple read by a run-time index through a copy in the caller's frame."""

import numba
import numpy as np
import pytest

from jackbox.engine.stacked import stacked


@numba.njit(cache=False)
def _read_all(t, order):
    s = stacked(t)
    out = np.empty(order.shape[0])
    for j in range(order.shape[0]):
        out[j] = s[order[j]]
    return out


@numba.njit(cache=False)
def _switch_all(t, order):
    out = np.empty(order.shape[0])
    for j in range(order.shape[0]):
        out[j] = t[order[j]]
    return out


def test_a_stacked_tuple_reads_what_the_tuple_holds_at_every_index():
    rng = np.random.default_rng(3)
    t = tuple(float(x) for x in rng.normal(size=20))
    t = t[:5] + (np.nan, -0.0, np.inf) + t[8:]
    order = rng.permutation(np.repeat(np.arange(20), 3))
    got, want = _read_all(t, order), _switch_all(t, order)
    # to the bit: the NaN, the negative zero and the infinity included
    assert got.tobytes() == want.tobytes()
    assert np.array_equal(got, np.array(t)[order], equal_nan=True)


def test_only_a_homogeneous_tuple_is_stacked_and_python_reads_the_tuple_itself():
    assert stacked((1.0, 2.0))[1] == 2.0         # (numba-cuda's simulator runs it as Python)

    @numba.njit(cache=False)
    def mixed(k):
        return stacked((1.0, 2))[k]

    with pytest.raises(numba.core.errors.TypingError):
        mixed(0)
