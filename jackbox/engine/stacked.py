"""A tuple's elements by an index known only at run time, without a switch over them.

Numba reads ``t[k]`` of a homogeneous tuple with a run-time ``k`` through a
``switch`` over its elements; in a loop over a model's contacts whose body is
too large for LLVM to unroll whole (a lane's near test, its crossing search)
that stays an indirect jump a read, and perf put a sixth of those functions'
samples on the jump tables' targets. :func:`stacked` stores the tuple once
into the calling function's stack frame; ``stacked(t)[k]`` is then one load,
the same number.
"""

from numba import types
from numba.core import cgutils
from numba.extending import intrinsic, overload


def stacked(tup):
    """``stacked(t)[k]`` is ``t[k]``: in Python (and numba-cuda's simulator) the tuple itself; compiled, a
    pointer to a copy of the homogeneous tuple in the calling function's frame (never return it)."""
    return tup


@intrinsic
def _on_stack(typingctx, tup):
    """The tuple stored into the frame of the function whose code this is (an alloca in its entry block)."""
    if not isinstance(tup, types.UniTuple):
        return None

    def codegen(context, builder, signature, args):
        at = cgutils.alloca_once_value(builder, args[0])
        return builder.bitcast(at, context.get_value_type(tup.dtype).as_pointer())

    return types.CPointer(tup.dtype)(tup), codegen


# inlined in Numba's IR, so that the alloca is in the caller's frame (a call would return a pointer into its own)
@overload(stacked, inline="always")
def _stacked(tup):
    if isinstance(tup, types.UniTuple):
        return lambda tup: _on_stack(tup)
    return None
