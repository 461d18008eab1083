"""Where the compile seconds go: each part of the engine, and a model's functions, from an empty cache.

    python benchmarks/compile_parts.py [--scene shaken] [--alone] [--out benchmarks/results]

One new process with a cache folder of its own and one compiling process
(``JACKBOX_COMPILE_JOBS=1``) compiles, in this order, the scene's model
functions one by one (after Numba's first compile, which costs on its own),
every loop and stage of the engine and every entry point, and times each (a
part compiled later reuses what earlier ones compiled of their shared callees:
the order matters, the sum does not). Writes ``compile_parts.md`` and
``.json``. ``--alone``: each engine part in a new process of its own, after
the model's functions (what it costs when nothing before it compiled its
callees; into ``compile_alone.md`` and ``.json``). These are the costs
``jackbox.engine.PART_COST`` (the model's functions) and ``COST`` (alone)
share out between two processes.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

CHILD = r"""
import json, sys, time, warnings
t0 = time.perf_counter()
import numba
from jackbox import engine, loader
from jackbox.scene import load_scene
out = {"import": time.perf_counter() - t0}
t = time.perf_counter()
numba.cfunc("float64(float64)")(lambda x: x + 1.0)
out["Numba's first compile (a trivial function)"] = time.perf_counter() - t
scene = load_scene(sys.argv[1])
t = time.perf_counter()
path = loader.ensure_model(scene)
out["generated model (found or generated)"] = time.perf_counter() - t
for name, text in loader.binding_parts(path.read_text()).items():
    t = time.perf_counter()
    loader._import_part(loader._write_part(loader.part_path(name, text), text))
    out[f"model part {name}"] = time.perf_counter() - t
loader.kernel_for(scene)
for name in engine.LOOPS:
    t = time.perf_counter()
    engine.prepare((), (name,))
    out[name] = time.perf_counter() - t
for name in engine.ENTRIES:
    t = time.perf_counter()
    engine.prepare((name,))
    out[name] = time.perf_counter() - t
print(json.dumps(out))
"""

#: one engine part (argv[2]) alone, after the model's functions
ALONE = r"""
import json, sys, time
from jackbox import engine, loader
from jackbox.scene import load_scene
loader.kernel_for(load_scene(sys.argv[1]))
t = time.perf_counter()
engine.compile_part(sys.argv[2])
print(json.dumps({sys.argv[2]: time.perf_counter() - t}))
"""


def run_child(code: str, *args: str) -> dict | None:
    """A new process running ``code`` with ``args``, on an empty cache of its own; its last line's JSON."""
    with tempfile.TemporaryDirectory(prefix="jackbox-parts-") as cache:
        env = os.environ | {"JACKBOX_CACHE_DIR": cache, "JACKBOX_COMPILE_JOBS": "1", "JACKBOX_PROGRESS": "0"}
        env.pop("NUMBA_DISABLE_JIT", None)
        done = subprocess.run([sys.executable, "-c", code, *args], env=env, capture_output=True, text=True,
                              cwd=ROOT)
    if done.returncode != 0:
        print(done.stderr, file=sys.stderr)
        return None
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="shaken")
    parser.add_argument("--alone", action="store_true", help="each engine part in a new process of its own")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "results")
    args = parser.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from jackbox.fileio import write_atomic

    from jackbox import engine

    if args.alone:
        seconds = {}
        for name in (*engine.LOOPS, *engine.ENTRIES):
            one = run_child(ALONE, args.scene, name)
            if one is None:
                return 1
            seconds.update(one)
            print(f"{name}: {one[name]:.2f} s", flush=True)
        how = (f"Measured by `python benchmarks/compile_parts.py --scene {args.scene} --alone`: each part in a new "
               f"process of its own with an empty cache, after the model's functions (nothing before it compiled "
               f"its callees); one compiling process. `jackbox.engine.COST` holds these.")
        stem = "compile_alone"
    else:
        seconds = run_child(CHILD, args.scene)
        if seconds is None:
            return 1
        how = (f"Measured by `python benchmarks/compile_parts.py --scene {args.scene}`: one new process, an empty "
               f"cache, one compiling process, the parts in this order (later parts reuse what earlier ones "
               f"compiled of shared callees).")
        stem = "compile_parts"
    lines = ["# Compile time by part", "", how, "", "| part | seconds |", "| --- | --- |"]
    lines += [f"| {name} | {s:.2f} |" for name, s in seconds.items()]
    lines += [] if args.alone else [f"| total | {sum(seconds.values()):.2f} |"]
    lines.append("")
    text = "\n".join(lines)
    print(text)
    args.out.mkdir(parents=True, exist_ok=True)
    write_atomic(args.out / f"{stem}.md", text)
    write_atomic(args.out / f"{stem}.json", json.dumps({"scene": args.scene, "seconds": seconds}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
