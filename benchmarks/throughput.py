"""Step throughput, skip gains, the C ceiling and ensemble scaling, for every built-in scene.

    python benchmarks/throughput.py [--scenes NAME ...] [--repeat 5] [--out benchmarks/results] [--quick] [--no-cold]

The same as ``jackbox bench``: the measurements live in :mod:`jackbox.bench`
(its docstring says what each figure is). Writes ``throughput.md`` and
``throughput.json`` into ``benchmarks/results`` unless told ``--out``.
"""

from __future__ import annotations

import sys

from jackbox.bench import main

if __name__ == "__main__":
    sys.exit(main())
