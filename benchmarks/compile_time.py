"""Compile time, as a new user meets it: first run, a model edit, every feature once, warm start.

    python benchmarks/compile_time.py [--repeat 1] [--against CHECKOUT] [--out benchmarks/results]

The same as ``jackbox bench --compile``: the measurements live in
:mod:`jackbox.compilebench` (its docstring says what each row is). Writes
``compile.md`` and ``compile.json`` into ``benchmarks/results`` unless told
``--out``.
"""

from __future__ import annotations

import sys

from jackbox.compilebench import main

if __name__ == "__main__":
    sys.exit(main())
