"""A helper process that compiles parts of the engine or of a model into the cache.

    python -m jackbox.engine.helper PART...
    python -m jackbox.engine.helper --parts FILE...
    python -m jackbox.engine.helper --parts -          (FILE...: the lines of its input)

PART: a loop or stage (:data:`jackbox.engine.LOOPS`) or an entry point
(:data:`jackbox.engine.ENTRIES`) (see :func:`jackbox.engine.start`); FILE: a
binding part of a model (:func:`jackbox.loader.binding_parts`), imported so
that its function compiles into the cache (see
:func:`jackbox.engine.start_binding`). With ``-`` it warms up first, then
reads the files' paths from its input until it closes (none: it ends). The
cache folder is ``JACKBOX_CACHE_DIR``, as the process that started it
resolved it. Exit status 0 when every part is in the cache, 1 otherwise (that
process then compiles what is missing).
"""

import importlib.util
import sys

from ..process import end
from . import ENTRIES, LOOPS, binding_name, compile_part


def import_parts(paths: list[str]) -> int:
    """Import the binding parts at these paths, under the names the starting process gives them."""
    status = 0
    for path in paths:
        # Numba's cached code names its module: the same name in every process
        spec = importlib.util.spec_from_file_location(binding_name(path), path)
        if spec is None:
            print(f"not a binding part: {path}", file=sys.stderr)
            status = 1
            continue
        module = importlib.util.module_from_spec(spec)
        sys.modules[spec.name] = module
        spec.loader.exec_module(module)
    return status


def warm_up() -> None:
    """Numba's first compile in a process: what it costs beyond the function itself, paid in advance."""
    import numba

    numba.cfunc("float64(float64)")(lambda x: x + 1.0)


def main(argv: list[str]) -> int:
    if argv[:2] == ["--parts", "-"]:       # warm up, then the files' paths from the lines of the input
        warm_up()
        return import_parts([line.strip() for line in sys.stdin if line.strip()])
    if argv[:1] == ["--parts"]:
        return import_parts(argv[1:])
    unknown = [name for name in argv if name not in LOOPS and name not in ENTRIES]
    if unknown:
        print(f"not a part of the engine: {', '.join(unknown)}", file=sys.stderr)
        return 1
    for name in argv:
        compile_part(name)
    return 0


if __name__ == "__main__":
    end(main(sys.argv[1:]))     # the process that waits for it goes on 0.3 s sooner than after Python's teardown
