"""Stage 4: run the compiler's stages for one model: spec -> module text.

:func:`generate` is a pure function of its :class:`~codegen.spec.ModelSpec`: it
writes nothing. Where the text goes (a committed module, a cache folder) and
how it is written is the caller's business.

Importing this module does not import sympy: the stages are imported when
:func:`generate` first runs.
"""

from __future__ import annotations

import time

from .spec import ModelSpec


def generate(spec: ModelSpec) -> tuple[str, dict[str, float]]:
    """Module text for `spec`, with the time each stage took (``derive``, ``cse_emit``)."""
    from .emitter import emit_module   # sympy: only when a module is generated
    from .model import derive

    t0 = time.perf_counter()
    model = derive(spec)
    t1 = time.perf_counter()
    text = emit_module(model, spec.command)
    t2 = time.perf_counter()
    return text, {"derive": t1 - t0, "cse_emit": t2 - t1}
