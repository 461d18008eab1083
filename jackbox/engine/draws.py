"""Draws: random numbers as a pure function of (seed, member, stream, draw).

A member of a study is set up inside the parallel loop, in any order, on any
thread, chunk or machine, so its random numbers cannot come from a generator
whose state passes from one member to the next. Each draw is instead a hash
of four integers (a counter-based generator, as Philox or Threefry): the
seed, the member's index, a stream (what the numbers are for) and the draw's
index within it. The hash chains SplitMix64's finaliser (Steele, Lea & Flood
2014, with Stafford's "Mix13" constants: a bijection of 64-bit words in which
every input bit flips every output bit with probability near 1/2) over the
four words; the top 53 bits of the result make the double.

The same functions run compiled (a member's setup, :mod:`.members`) and as
plain Python (``NUMBA_DISABLE_JIT=1``) with the same bits: Numba's uint64
arithmetic wraps, and Python's integers are masked to 64 bits to do the same.
"""

import math

import numpy as np
from numba import config, njit

#: streams: what a member's draws are for
START = 0       #: the perturbation of its start (draw j: the j-th perturbed coordinate or rate)
TWIN = 1        #: its chaos twin's direction (draw j: the j-th coordinate of the scaled state)

#: 64-bit words: numpy's uint64 compiled (wrapping arithmetic), Python's int when run as plain Python
WORD = int if config.DISABLE_JIT else np.uint64
MASK = WORD(0xFFFFFFFFFFFFFFFF)        #: (a no-op on uint64: it keeps Python's integers to 64 bits)
GAMMA = WORD(0x9E3779B97F4A7C15)       #: 2^64 / golden ratio, SplitMix64's increment
MIX1 = WORD(0xBF58476D1CE4E5B9)
MIX2 = WORD(0x94D049BB133111EB)
S11, S27, S30, S31 = WORD(11), WORD(27), WORD(30), WORD(31)
#: 2^-52 and 2^-53: 53 bits to [0, 2) and to [0, 1)
TO_TWO = 2.0 ** -52
TO_ONE = 2.0 ** -53


@njit(cache=True)
def mix(z):
    """SplitMix64's finaliser: a bijection of 64-bit words that spreads every bit over all of them."""
    z = ((z ^ (z >> S30)) * MIX1) & MASK
    z = ((z ^ (z >> S27)) * MIX2) & MASK
    return z ^ (z >> S31)


@njit(cache=True)
def hash_draw(seed, member, stream, k):
    """64 random bits for draw k of a stream of one member: a hash of the four (non-negative) integers."""
    h = mix((WORD(seed) + GAMMA) & MASK)
    h = mix(((h ^ WORD(member)) + GAMMA) & MASK)
    h = mix(((h ^ WORD(stream)) + GAMMA) & MASK)
    return mix(((h ^ WORD(k)) + GAMMA) & MASK)


@njit(cache=True)
def draw_uniform(seed, member, stream, k):
    """A double uniform in [-1, 1) (a multiple of 2^-52: the top 53 bits of the hash, exactly)."""
    return (hash_draw(seed, member, stream, k) >> S11) * TO_TWO - 1.0


@njit(cache=True)
def draw_normal(seed, member, stream, k):
    """A standard normal (Box-Muller's cosine half, from draws 2k and 2k + 1 of the stream's bits)."""
    u = ((hash_draw(seed, member, stream, 2 * k) >> S11) + WORD(1)) * TO_ONE        # in (0, 1]: log(u) is finite
    v = (hash_draw(seed, member, stream, 2 * k + 1) >> S11) * TO_ONE
    return math.sqrt(-2.0 * math.log(u)) * math.cos(2.0 * math.pi * v)
