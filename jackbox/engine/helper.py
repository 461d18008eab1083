"""A helper process that compiles parts of the engine into the cache (see :func:`jackbox.engine.start`).

    python -m jackbox.engine.helper PART...

PART: a loop or stage (:data:`jackbox.engine.LOOPS`) or an entry point
(:data:`jackbox.engine.ENTRIES`). The cache folder is ``JACKBOX_CACHE_DIR``,
as the process that started it resolved it. Exit status 0 when every part is
in the cache, 1 otherwise (that process then compiles what is missing).
"""

import sys

from . import ENTRIES, LOOPS, compile_part


def main(argv: list[str]) -> int:
    unknown = [name for name in argv if name not in LOOPS and name not in ENTRIES]
    if unknown:
        print(f"not a part of the engine: {', '.join(unknown)}", file=sys.stderr)
        return 1
    for name in argv:
        compile_part(name)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
