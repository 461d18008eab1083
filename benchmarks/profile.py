"""Where the time of a run or a study goes, function by function: Linux ``perf`` on Numba's machine code.

    python benchmarks/profile.py ensemble shaken [--lanes] [--n 2000] [--t-end 10] [--seconds 4] [--top 25]
    python benchmarks/profile.py chaos shaken --lanes [--renorm 0.01] ...
    python benchmarks/profile.py run drop [--t-end 10] ...
    python benchmarks/profile.py held corner        (or riding: jackbox bench's held stretches)
    python benchmarks/profile.py ensemble shaken --lanes --annotate lanes.lanes   (its hot instructions)

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

``--annotate NAME`` also lays the samples that fell inside the first
function whose readable name, less a model part's hash, ends with NAME
(``lanes.lanes``, ``lane_event.crossing_lane``, ``ride.ride``) over
``objdump``'s disassembly of its machine code (read from this process's
memory): its samples by 512-byte stretch (a loop inlined twice shows as
two stretches), then the instructions that took at least ``--min-share`` of
them, each with the three before it (a sample lands an instruction or two
after the one that stalled).
"""

from __future__ import annotations

import argparse
import os
import platform
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def jit_functions() -> list[tuple[int, int, str]]:
    """(start, size, mangled name) of each function in Numba's execution engine, by address."""
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
    # a function's size: up to the next one (the last: 4 KiB). The last function of a module's code is given the
    # gap after it too (the next module's code may lie a megabyte on): an upper bound, never a short one
    return [(address, after - address, name)
            for (address, name), (after, _) in zip(found, found[1:] + [(found[-1][0] + 4096, "")])]


def write_perf_map(path: Path, functions) -> int:
    """perf's map of the functions compiled in this process; returns how many."""
    with path.open("w") as f:
        for address, size, name in functions:
            f.write(f"{address:x} {size:x} {name[:240]}\n")
    return len(functions)


# objdump's -m for the machine Python runs on (platform.machine())
OBJDUMP_MACHINE = {"x86_64": "i386:x86-64", "AMD64": "i386:x86-64", "aarch64": "aarch64", "arm64": "aarch64"}


def disassembly(start: int, size: int, objdump: str) -> list[tuple[int, str]]:
    """(offset, instruction) of the machine code at ``start`` in this process, by ``objdump``."""
    import ctypes

    machine = OBJDUMP_MACHINE.get(platform.machine())
    if machine is None:
        raise RuntimeError(f"objdump's name for this machine ({platform.machine()}) is not known here")
    with tempfile.NamedTemporaryFile(suffix=".bin") as f:
        f.write(ctypes.string_at(start, size))
        f.flush()
        done = subprocess.run([objdump, "-D", "-b", "binary", "-m", machine, "--no-show-raw-insn", f.name],
                              capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"objdump failed: {done.stderr.strip()}")
    text = done.stdout
    lines = []
    for line in text.splitlines():
        m = re.match(r"\s*([0-9a-f]+):\s+(.*)", line)
        if m:
            lines.append((int(m.group(1), 16), m.group(2)))
    return lines


def hot_lines(lines, samples: dict, min_share: float, before: int = 3) -> list[str]:
    """The instructions with at least ``min_share`` of the samples (offset: count), each with ``before`` ahead of
    it, as text (``share  offset  instruction``, "..." where lines are left out)."""
    total = sum(samples.values())
    shown = set()
    for i, (offset, _) in enumerate(lines):
        if total and samples.get(offset, 0) >= min_share * total:
            shown.update(range(max(0, i - before), i + 1))
    out, last = [], None
    for i in sorted(shown):
        offset, insn = lines[i]
        if last is not None and i != last + 1:
            out.append("      ...")
        out.append(f"{100 * samples.get(offset, 0) / total:6.2f}%  {offset:6x}  {insn}")
        last = i
    return out


def annotate(perf: str, data: Path, functions, name: str, min_share: float, out=sys.stdout) -> None:
    """The hot instructions of the function named ``...name``: perf's samples over objdump of its bytes."""
    from collections import Counter

    # (a model's binding parts are modules named with a hash: jackbox_model_lanes_41a93c0c913b22f1)
    chosen = [f for f in functions if re.sub(r"_[0-9a-f]{16}\b", "", demangled(f[2])).endswith(name)]
    if not chosen:
        print(f"--annotate: no compiled function's name ends with {name!r}", file=out)
        return
    start, size, mangled = chosen[0]
    script = subprocess.run([perf, "script", "-i", str(data), "-F", "ip"], capture_output=True, text=True)
    ips = Counter(int(word, 16) for word in script.stdout.split())
    inside = {ip - start: c for ip, c in ips.items() if start <= ip < start + size}
    total = sum(inside.values())
    print(f"\n{demangled(mangled)}: {size} bytes, {total} samples of {sum(ips.values())}", file=out)
    if not total:
        return
    objdump = shutil.which("objdump")
    if objdump is None:
        print("objdump is not installed (Debian: binutils)", file=out)
        return
    buckets = Counter()
    for offset, c in inside.items():
        buckets[offset // 512] += c
    print("by stretch of 512 bytes (offset: share):", file=out)
    print("  " + "  ".join(f"{512 * b:x}: {100 * c / total:.1f}%" for b, c in sorted(buckets.items())
                           if c >= 0.01 * total), file=out)
    # perf's ip is the instruction after the one that was executing (skid): the count goes to where it lands
    print("\n".join(hot_lines(disassembly(start, size, objdump), inside, min_share)), file=out)


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
    parser.add_argument("--annotate", metavar="NAME", default=None,
                        help="also the hot instructions of the function whose name ends with NAME (e.g. lanes.lanes)")
    parser.add_argument("--min-share", type=float, default=0.005,
                        help="--annotate: instructions with at least this share of its samples (default: 0.005)")
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
    functions = jit_functions()
    n = write_perf_map(map_file, functions)
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
    if args.annotate:
        annotate(perf, data, functions, args.annotate, args.min_share)
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
