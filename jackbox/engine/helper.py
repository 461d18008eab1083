"""A helper process that compiles parts of the engine into the cache (see :func:`jackbox.engine.start`).

    python -m jackbox.engine.helper PART...
    python -m jackbox.engine.helper --binding FILE FUNCTION...
    python -m jackbox.engine.helper --binding - FUNCTION...     (FILE: the first line of input)

PART: a loop or stage (:data:`jackbox.engine.LOOPS`) or an entry point
(:data:`jackbox.engine.ENTRIES`); or, with ``--binding``, functions of a
model's binding module (:func:`jackbox.engine.bind`; its other functions are
left to the process that started this one); with ``-``, it warms up first
and then reads FILE from its input (it ends if the input closes first). The cache folder is
``JACKBOX_CACHE_DIR``, as the process that started it resolved it. Exit
status 0 when every part is in the cache, 1 otherwise (that process then
compiles what is missing).
"""

import importlib.util
import sys

from . import ENTRIES, LOOPS, SIGNATURES, binding_name, compile_part


def bind_only(path: str, names: list[str]) -> int:
    """Import the binding module at path, compiling only the model functions named."""
    from .. import engine

    unknown = [name for name in names if name not in SIGNATURES]
    if unknown:
        print(f"not a model function: {', '.join(unknown)}", file=sys.stderr)
        return 1
    engine.BIND_ONLY = set(names)
    # under the name the starting process gives it: Numba's cached code names its module
    spec = importlib.util.spec_from_file_location(binding_name(path), path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return 0


def warm_up() -> None:
    """Numba's first compile in a process: what it costs beyond the function itself, paid in advance."""
    import numba

    numba.cfunc("float64(float64)")(lambda x: x + 1.0)


def main(argv: list[str]) -> int:
    if argv[:2] == ["--binding", "-"]:       # warm up, then the file's path from the first line of input
        warm_up()
        path = sys.stdin.readline().strip()
        return bind_only(path, argv[2:]) if path else 0
    if argv[:1] == ["--binding"] and len(argv) >= 2:
        return bind_only(argv[1], argv[2:])
    unknown = [name for name in argv if name not in LOOPS and name not in ENTRIES]
    if unknown:
        print(f"not a part of the engine: {', '.join(unknown)}", file=sys.stderr)
        return 1
    for name in argv:
        compile_part(name)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
