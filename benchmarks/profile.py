"""Where the time of a run or a study goes, function by function: Linux ``perf`` on Numba's machine code.

    python benchmarks/profile.py ensemble shaken [--lanes] [--n 2000] [--t-end 10] [--seconds 4] [--top 25]
    python benchmarks/profile.py chaos shaken --lanes [--renorm 0.01] ...
    python benchmarks/profile.py run drop [--t-end 10] ...
    python benchmarks/profile.py held corner        (or riding: jackbox bench's held stretches)

``perf`` shows the machine code Numba compiled as ``[JIT]`` addresses without
names. This script compiles everything in this process (a cache folder of its
own, empty), then writes ``/tmp/perf-<pid>.map`` (perf's map of JIT code:
start, size and name of each function LLVM emitted, read from Numba's
execution engine), runs the workload once to warm up, starts ``perf record``
on itself and runs the workload again for ``--seconds``, and prints ``perf
report``'s top functions by their own time (one thread: ``NUMBA_NUM_THREADS=1``
unless set). Function names are Numba's mangled ones: the module and
function are readable in them (``jackbox6engine6events10cubic_root``). Needs
``perf`` and permission to use it (``/proc/sys/kernel/perf_event_paranoid``
at 2 or below for one's own processes). Nothing is written into the
repository.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def write_perf_map(path: Path) -> int:
    """perf's map of the functions in Numba's execution engine (those compiled in this process); returns how many."""
    from numba.core.registry import cpu_target

    engine = cpu_target.target_context.codegen()._engine
    found = []
    for name in engine._defined_symbols:
        try:
            address = engine.get_function_address(name)
        except Exception:       # a global variable, not a function
            continue
        if address:
            found.append((address, name))
    found.sort()
    with path.open("w") as f:
        # a function's size: up to the next one (the last: 4 KiB)
        for (address, name), (after, _) in zip(found, found[1:] + [(found[-1][0] + 4096, "")]):
            f.write(f"{address:x} {after - address:x} {name[:240]}\n")
    return len(found)


def workload(args):
    import jackbox
    from jackbox import ensemble as studies

    if args.what == "held":
        from jackbox import api, bench, loader

        riding = jackbox.load_scene(bench.SHAKEN, {"restitution": 0.0})
        kernel = loader.kernel_for(riding)
        loader.compile_kernel(kernel, "exact")
        stretch = bench.Stretch(kernel, api.prepare(riding), *{"riding": bench.RIDE, "corner": bench.CORNER}[args.scene])
        return stretch.once
    scene = jackbox.load_scene(args.scene)
    if args.what == "run":
        return lambda: jackbox.simulate(scene, t_end=args.t_end, record_every=1_000_000)
    kw = dict(perturb={"theta_jack": 1e-6}, t_end=args.t_end, seed=0, lanes=args.lanes)
    if args.what == "chaos":
        return lambda: studies.chaos(scene, args.n, renorm=args.renorm, **kw)
    return lambda: studies.ensemble(scene, args.n, **kw)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=("run", "ensemble", "chaos", "held"))
    parser.add_argument("scene", help="a built-in scene or a scene file; for held: riding or corner (the held "
                                      "stretches of shaken at e = 0 that `jackbox bench` times)")
    parser.add_argument("--n", type=int, default=2000, help="members of a study (default: 2000)")
    parser.add_argument("--t-end", type=float, default=10.0)
    parser.add_argument("--lanes", action="store_true", help="a study's members in lanes")
    parser.add_argument("--renorm", type=float, default=None,
                        help="chaos: seconds between renormalisations (default: the study's, 100 steps)")
    parser.add_argument("--seconds", type=float, default=4.0, help="how long perf records (default: 4)")
    parser.add_argument("--top", type=int, default=25, help="functions to list (default: 25)")
    args = parser.parse_args(argv)
    if args.what == "held" and args.scene not in ("riding", "corner"):
        parser.error(f"held: riding or corner, not {args.scene!r}")
    perf = shutil.which("perf")
    if perf is None:
        parser.error("perf is not installed (Debian: apt-get install linux-perf)")
    # before jackbox is imported: its functions' cache folder is fixed then; compiled here, their names are known
    os.environ.setdefault("NUMBA_NUM_THREADS", "1")
    os.environ["JACKBOX_CACHE_DIR"] = tempfile.mkdtemp(prefix="jackbox-profile-")
    sys.path.insert(0, str(ROOT))

    job = workload(args)
    job()                                    # compiles everything, here
    map_file = Path(f"/tmp/perf-{os.getpid()}.map")
    n = write_perf_map(map_file)
    data = Path(os.environ["JACKBOX_CACHE_DIR"]) / "perf.data"
    record = subprocess.Popen([perf, "record", "-q", "-F", "4000", "-o", str(data), "-p", str(os.getpid())],
                              stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    time.sleep(0.5)                          # perf attaches
    runs, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < args.seconds:
        job()
        runs += 1
    elapsed = time.perf_counter() - t0
    record.send_signal(2)
    _, err = record.communicate()
    if record.returncode not in (0, -2) or not data.exists():
        print(f"perf record failed ({record.returncode}): {err.strip()[-500:]}", file=sys.stderr)
        return 1
    report = subprocess.run([perf, "report", "-i", str(data), "--no-children", "--sort", "dso,symbol",
                             "--stdio", "-q"], capture_output=True, text=True)
    rows = [line for line in report.stdout.splitlines() if re.match(r"\s+\d+\.\d+%", line)]
    print(f"{args.what} {args.scene}: {runs} runs in {elapsed:.2f} s, {n} compiled functions named "
          f"({map_file}); self time by function:")
    for line in rows[:args.top]:
        share, rest = line.split("%", 1)
        dso, _, symbol = rest.partition("[.]")
        if not symbol:
            dso, _, symbol = rest.partition("[k]")
        dso = "jit" if dso.strip().startswith("[JIT]") else dso.strip()
        print(f"{share.strip():>6}%  {dso[:24]:<24} {demangled(symbol.split()[0] if symbol.split() else '?')}")
    map_file.unlink(missing_ok=True)
    shutil.rmtree(os.environ["JACKBOX_CACHE_DIR"], ignore_errors=True)
    return 0


def demangled(symbol: str) -> str:
    """``_ZN7jackbox6engine6events10cubic_rootB3v80...`` -> ``jackbox.engine.events.cubic_root`` (Numba's mangling)."""
    if not symbol.startswith("_ZN"):
        return symbol
    parts, rest = [], symbol[3:]
    while rest and rest[0].isdigit():
        digits = re.match(r"\d+", rest).group()
        size = int(digits)
        parts.append(rest[len(digits):len(digits) + size])
        rest = rest[len(digits) + size:]
    return ".".join(parts) or symbol


if __name__ == "__main__":
    sys.exit(main())
