"""Work-precision: error against a reference solution versus wall time, per method.

    python benchmarks/workprecision.py [--scenes drop shaken spring] [--repeat 5] [--quick] [--out benchmarks/results]

For each scene, over a horizon short enough that the trajectory is still
predictable (a few impacts), the script computes a reference solution and
measures, for a sweep of dt (kernels) and of rtol (scipy):

* error: the largest ``|q - q_ref|`` over the samples (every ``SAMPLE`` s, so
  every dt divides it) and the six coordinates; and the largest error of the
  impact times over the matched impacts (the common prefix of the two impact
  sequences; a different sequence is reported, not hidden);
* wall time per simulated second, the median of ``--repeat`` runs, compile
  and lambdify time excluded (reported apart), for: the exact kernel, the
  naive kernel (their loop: ``meta["kernel"]["run_seconds"]``, as
  benchmarks/throughput.py; the whole ``jackbox.simulate`` call is in the CSV
  too), the lambdified reference (method naive, coarse dt only: it does about
  1e4 steps/s), and scipy's solve_ivp with event functions
  (:func:`jackbox.reference.solve_exact`; RK45 and DOP853 with the
  lambdified model, DOP853 also with the kernel's compiled model functions as
  the right-hand side), at scipy's default ``max_step``.

The reference is the exact kernel at ``dt = SAMPLE / K_REF`` (1e-4 s: RK4's
truncation error there is below 1e-14 on these scenes, while a much smaller
dt only adds round-off, which grows with the number of steps), cross-checked
against scipy DOP853 at rtol 1e-12 with ``max_step = 1e-3`` and against the
exact kernel at half its dt; the larger difference is the reference's
uncertainty, and errors below 30 times it are not used for fits.

The observed order is the least-squares slope of log(error) against log(dt)
over the asymptotic window (``FIT_WINDOW``), with the points used listed.
Speed-ups at equal error interpolate each method's Pareto front (fastest time
for a given error) in log-log.

Writes ``workprecision.csv`` (every measurement), ``workprecision.json`` (the
same, with the fitted orders and the reference's checks), ``workprecision.md``
and ``workprecision.png``. ``--quick`` measures a few points of one scene (the
smoke test in tests/test_benchmarks_smoke.py).
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import itertools
import json
import math
import os
import platform
import shlex
import statistics
import sys
import time
from pathlib import Path

import numba
import numpy as np

import jackbox
from jackbox import api, loader, reference

#: horizon per scene, s: a few impacts, before small differences grow into different sequences
HORIZONS = {"drop": 0.7, "shaken": 1.5, "spring": 1.0}
SAMPLE = 0.05                                             #: s between the compared samples
K_EXACT = (1, 2, 3, 4, 5, 6, 8, 10, 12, 15, 20, 25, 50, 100, 200)   #: dt = SAMPLE / k: 5e-2 .. 2.5e-4 s
K_NAIVE = (1, 2, 4, 5, 10, 20, 25, 50, 100, 200, 500, 1000, 2000, 5000)   # .. 1e-5 s
K_LAMBDIFIED = (1, 2, 5, 10, 25, 50)                     #: the slow twin: 5e-2 .. 1e-3 s
K_REF = 500                                               #: the reference: dt = 1e-4 s
RTOLS = tuple(10.0 ** -k for k in range(3, 14))           #: scipy: 1e-3 .. 1e-13
#: (dt_min, dt_max) of the asymptotic range used for the fitted order
FIT_WINDOW = {"exact": (2.5e-3, 2.5e-2), "naive": (1e-5, 1e-2)}
FLOOR_FACTOR = 30.0       #: errors below this many times the reference's uncertainty are not fitted
ERROR_LEVELS = (1e-6, 1e-8, 1e-10)
#: what a reader needs to know to read a scene's figures
NOTES = {
    "drop": "Between impacts drop's bodies feel gravity only (constant, diagonal M): the motion is "
            "quadratic in t, which RK4 (and DOP853, and RK45) integrate exactly. The exact kernel's error is "
            "round-off and event location at every dt, so it has no order to measure, and any method that "
            "finds the impacts is at the floor: the speed-ups compare the cheapest runs that do.",
    "shaken": "The jack's free flight is quadratic in t too; the truncation error comes from the box, "
              "driven by sin(2 pi t / T), and reaches the jack at its impacts: it is small (1e-9 at dt = 1e-2).",
}
QUICK = {"scenes": ["shaken"], "k_exact": (2, 4, 5, 10), "k_naive": (5, 20, 50, 200, 500, 2000, 5000),
         "k_lambdified": (5,), "rtols": (1e-4, 1e-8, 1e-12)}

METHOD_LABELS = {
    "exact": "exact kernel (RK4, located impacts)",
    "naive": "naive kernel (RK4, impulse at step end)",
    "lambdified": "lambdified reference (naive)",
    "scipy-RK45": "scipy RK45 + events (lambdified)",
    "scipy-DOP853": "scipy DOP853 + events (lambdified)",
    "scipy-DOP853-numba": "scipy DOP853 + events (compiled RHS)",
}


@dataclasses.dataclass
class Point:
    scene: str
    method: str
    dt: float | None          #: step of the kernels and the lambdified reference
    rtol: float | None        #: scipy's
    seconds: float            #: wall s per simulated s (median): the loop, or scipy's whole solve
    call_seconds: float       #: wall s per simulated s of the whole call (kernels: jackbox.simulate)
    error_q: float            #: max over samples and coordinates of |q - q_ref|
    error_t: float            #: max |t_imp - t_imp_ref| over the matched impacts (nan: none matched)
    impacts: int
    same_sequence: bool
    nfev: int | None = None
    fitted: bool = False
    failed: str = ""          #: why the run stopped (scipy: a crossing it could not resolve), else ""


@dataclasses.dataclass
class CompiledFunctions(reference.Functions):
    """The lambdified model with ``accel`` and ``phi`` from the scene's compiled kernel module."""

    kernel: object = None

    def accel(self, t, q, qd, p):
        out = np.empty(len(q))
        self.kernel.accel(t, q, qd, p, out)
        return out

    def compiled_phi(self, t, q, p):
        out = np.empty(self.kernel.N_CONTACT)
        self.kernel.phi(t, q, p, out)
        return out


def compiled_functions(scene) -> CompiledFunctions:
    fn = reference.functions(scene)
    kernel = loader.kernel_for(scene)
    fields = {f.name: getattr(fn, f.name) for f in dataclasses.fields(fn)}
    out = CompiledFunctions(**fields, kernel=kernel)
    out.phi = out.compiled_phi
    return out


def median_seconds(fn, repeat):
    """Median wall seconds of fn() over `repeat` runs, and the result of the first run."""
    times, first = [], None
    for i in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
        if i == 0:
            first = out
    return statistics.median(times), first


def compare(t_imp, k_imp, ref_t, ref_k):
    """(max |dt| over the matched impacts, same sequence?): the common prefix of equal contacts."""
    n = 0
    while n < min(len(k_imp), len(ref_k)) and k_imp[n] == ref_k[n]:
        n += 1
    error_t = float(np.abs(np.asarray(t_imp[:n]) - ref_t[:n]).max()) if n else math.nan
    return error_t, len(k_imp) == len(ref_k) and n == len(ref_k)


def fit_order(points, method, floor):
    """Least-squares slope of log(error) vs log(dt) over FIT_WINDOW; marks the points used."""
    lo, hi = FIT_WINDOW[method]
    used = [p for p in points if p.method == method and lo * (1 - 1e-9) <= p.dt <= hi * (1 + 1e-9)
            and p.same_sequence and p.error_q >= FLOOR_FACTOR * floor]
    for p in used:
        p.fitted = True
    if len(used) < 3:
        return math.nan, used
    slope = np.polyfit(np.log([p.dt for p in used]), np.log([p.error_q for p in used]), 1)[0]
    return float(slope), used


def pareto(points, key="seconds"):
    """(error, time) of the points no other point beats in both, sorted by error descending."""
    front, best = [], math.inf
    points = [p for p in points if not p.failed]
    for p in sorted(points, key=lambda p: (getattr(p, key), p.error_q)):
        if p.error_q < best:
            front.append((p.error_q, getattr(p, key)))
            best = p.error_q
    return front


def time_at(points, level, key="seconds"):
    """Seconds per simulated second to reach error `level` on the Pareto front (log-log), or nan.

    Returns (seconds, exact?): exact is False when even the fastest point is
    already more accurate than `level` (the time is then an upper bound).
    """
    front = pareto(points, key)
    if not front or level < front[-1][0]:
        return math.nan, True
    if level >= front[0][0]:
        return front[0][1], False
    for (e1, s1), (e2, s2) in itertools.pairwise(front):
        if e2 <= level <= e1:
            w = math.log(level / e1) / math.log(e2 / e1)
            return math.exp(math.log(s1) + w * math.log(s2 / s1)), True
    return math.nan, True


def bench_scene(name, repeat, cfg, log):
    scene = jackbox.load_scene(name)
    T = HORIZONS[name]
    # compile (or load) and lambdify first: reported apart, never timed below
    t0 = time.perf_counter()
    kernel = loader.kernel_for(scene)
    compile_info = loader.compile_kernel(kernel)
    compile_seconds = time.perf_counter() - t0
    t0 = time.perf_counter()
    fn = reference.functions(scene)
    lambdify_seconds = time.perf_counter() - t0
    cfn = compiled_functions(scene)
    jackbox.simulate(scene, t_end=scene.dt)
    reference.simulate(scene, t_end=scene.dt)

    # the reference and its cross-checks
    dt_ref = SAMPLE / K_REF
    ref = jackbox.simulate(scene, t_end=T, dt=dt_ref, record_every=K_REF)
    half = jackbox.simulate(scene, t_end=T, dt=dt_ref / 2, record_every=2 * K_REF)
    t0 = time.perf_counter()
    check = reference.simulate(scene, t_end=T, dt=SAMPLE, method="exact", rtol=1e-12, max_step=1e-3)
    check_seconds = time.perf_counter() - t0
    diff_scipy = float(np.abs(check.q - ref.q).max())
    diff_half = float(np.abs(half.q - ref.q).max())
    diff_scipy_t, same_scipy = compare(check.impact_t, check.impact_constraint, ref.impact_t, ref.impact_constraint)
    floor = max(diff_scipy, diff_half)
    log(f"{name}: reference exact kernel dt={dt_ref:g}, {len(ref.impact_t)} impacts; vs scipy DOP853 "
        f"rtol=1e-12: |dq| {diff_scipy:.2e}, |dt_imp| {diff_scipy_t:.2e} (same sequence: {same_scipy}); "
        f"vs dt/2: |dq| {diff_half:.2e}")
    ref_q = ref.q

    def point(method, dt, rtol, seconds, call_seconds, q, t_imp, k_imp, nfev=None):
        error_t, same = compare(t_imp, k_imp, ref.impact_t, ref.impact_constraint)
        # scipy's q holds the integrated DOFs only (not a prescribed box's, which is exact anyway)
        p = Point(name, method, dt, rtol, seconds / T, call_seconds / T,
                  float(np.abs(q - ref_q[:, -q.shape[1]:]).max()),
                  error_t, len(k_imp), same, nfev)
        what = f"dt={dt:.3g}" if dt is not None else f"rtol={rtol:.0e}"
        log(f"  {name:7s} {method:19s} {what:13s} error {p.error_q:9.2e}  t_imp {p.error_t:9.2e}  "
            f"{p.seconds:9.3g} s/s{'' if same else '  (impact sequence differs)'}")
        return p

    points = []
    for method, ks in (("exact", cfg["k_exact"]), ("naive", cfg["k_naive"])):
        for k in ks:
            loops, calls = [], []
            for _ in range(repeat):
                t0 = time.perf_counter()
                traj = jackbox.simulate(scene, t_end=T, dt=SAMPLE / k, record_every=k, method=method)
                calls.append(time.perf_counter() - t0)
                loops.append(traj.meta["kernel"]["run_seconds"])
            points.append(point(method, SAMPLE / k, None, statistics.median(loops), statistics.median(calls),
                                traj.q, traj.impact_t, traj.impact_constraint))
    for k in cfg["k_lambdified"]:
        seconds, traj = median_seconds(
            lambda k=k: reference.simulate(scene, t_end=T, dt=SAMPLE / k, record_every=k, method="naive"),
            max(1, repeat // 2))
        points.append(point("lambdified", SAMPLE / k, None, traj.meta["reference"]["run_seconds"], seconds,
                            traj.q, traj.impact_t, traj.impact_constraint))
    run = api.prepare(scene, T, SAMPLE, 1, None, "exact")
    for method, integrator, functions in (("scipy-RK45", "RK45", fn), ("scipy-DOP853", "DOP853", fn),
                                          ("scipy-DOP853-numba", "DOP853", cfn)):
        for rtol in cfg["rtols"]:
            try:
                seconds, sol = median_seconds(
                    lambda rtol=rtol, integrator=integrator, functions=functions: reference.solve_exact(
                        run, functions, rtol=rtol, integrator=integrator, max_step=np.inf), repeat)
            except jackbox.SimulationError as exc:   # reported, not plotted
                log(f"  {name:7s} {method:19s} rtol={rtol:<8.0e} failed: {exc}")
                points.append(Point(name, method, None, rtol, math.nan, math.nan, math.nan, math.nan, 0, False,
                                    failed=str(exc).split(": ", 1)[1]))
                continue
            points.append(point(method, None, rtol, seconds, seconds, sol.q, sol.impact_t, sol.impact_k,
                                sol.nfev))
    orders = {m: fit_order(points, m, floor) for m in ("exact", "naive")}
    info = {
        "scene": name, "horizon": T, "impacts": len(ref.impact_t), "dt_ref": dt_ref,
        "diff_scipy": diff_scipy, "diff_scipy_t": diff_scipy_t, "same_scipy": same_scipy,
        "diff_half": diff_half, "floor": floor, "check_seconds": check_seconds,
        "compile_seconds": compile_seconds, "compile_cache": compile_info["cache"],
        "lambdify_seconds": lambdify_seconds,
        "orders": {m: {"order": o, "dt": [p.dt for p in used], "error": [p.error_q for p in used]}
                   for m, (o, used) in orders.items()},
    }
    return points, info


SCIPY = ("scipy-DOP853", "scipy-RK45", "scipy-DOP853-numba")


def speedups(points, scene):
    """Rows (level, exact's loop time, exact's call time, {scipy method: time}) at ERROR_LEVELS.

    Each time is (s per simulated s, exact?) from :func:`time_at`.
    """
    mine = [p for p in points if p.scene == scene]
    exact = [p for p in mine if p.method == "exact"]
    return [(level, time_at(exact, level), time_at(exact, level, "call_seconds"),
             {m: time_at([p for p in mine if p.method == m], level) for m in SCIPY})
            for level in ERROR_LEVELS]


def fmt_speedup(t_exact, t_other):
    (te, te_exact), (to, to_exact) = t_exact, t_other
    if not (math.isfinite(te) and math.isfinite(to)):
        return "n/a"
    ratio = to / te
    # an upper bound on a time (the fastest point already beats the level) bounds the ratio
    if not te_exact and to_exact:
        return f">= {ratio:.0f}x"
    if te_exact and not to_exact:
        return f"<= {ratio:.0f}x"
    if not te_exact and not to_exact:
        return f"~{ratio:.0f}x (both at their fastest)"
    return f"{ratio:.0f}x"


def fmt_speedups(t_loop, t_call, t_other):
    return f"{fmt_speedup(t_loop, t_other)} / {fmt_speedup(t_call, t_other)}"


def fmt_time(t):
    value, exact = t
    if not math.isfinite(value):
        return "n/a"
    return f"{value:.2e}" if exact else f"<= {value:.2e}"


def plot(points, infos, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    styles = {"exact": ("C0", "o", "-"), "naive": ("C1", "s", "-"), "lambdified": ("C7", "x", ":"),
              "scipy-RK45": ("C3", "^", "--"), "scipy-DOP853": ("C2", "v", "--"),
              "scipy-DOP853-numba": ("C4", "D", "-.")}

    def err(p):
        return max(p.error_q, 1e-16)

    def sweep(pts):    # the order of the sweep: dt or rtol from coarse to fine
        return sorted(pts, key=lambda p: -(p.dt if p.dt is not None else p.rtol))

    n = len(infos)
    fig, axes = plt.subplots(n, 2, figsize=(13, 4.4 * n + 1.0), squeeze=False)
    for row, info in zip(axes, infos):
        name = info["scene"]
        mine = [p for p in points if p.scene == name]
        floor = max(info["floor"], 1e-16)
        ax = row[0]
        for method, (color, marker, ls) in styles.items():
            pts = sweep(p for p in mine if p.method == method and not p.failed)
            if pts:
                ax.loglog([p.seconds for p in pts], [err(p) for p in pts], color=color, marker=marker, ls=ls,
                          ms=5, label=METHOD_LABELS[method])
            if method == "exact":
                ax.loglog([p.call_seconds for p in pts], [err(p) for p in pts], color=color, marker=marker,
                          ls=":", ms=3, alpha=0.5, label="exact kernel, whole jackbox.simulate call")
        ax.axhline(floor, color="k", lw=0.8, ls=":", label="reference uncertainty")
        ax.set_xlabel("wall time per simulated second [s/s]")
        ax.set_ylabel("max |q - q_ref| over samples [m, rad]")
        ax.set_title(f"{name}: work-precision ({info['horizon']:g} s, {info['impacts']} impacts)")
        ax.grid(True, which="major", alpha=0.3)
        ax = row[1]
        for method in ("exact", "naive", "lambdified"):
            color, marker, ls = styles[method]
            pts = sweep(p for p in mine if p.method == method)
            ax.loglog([p.dt for p in pts], [err(p) for p in pts], color=color, marker=marker, ls=ls, ms=5)
            fitted = [p for p in pts if p.fitted]
            if fitted:
                ax.loglog([p.dt for p in fitted], [p.error_q for p in fitted], ls="none", marker="o", ms=11,
                          mfc="none", color=color)
        ax.axhline(floor, color="k", lw=0.8, ls=":")
        # slope guides, a decade below the fitted points
        for method, slope in (("exact", 4), ("naive", 1)):
            o = info["orders"][method]
            if o["dt"]:
                d0, e0 = o["dt"][-1], o["error"][-1] / 10
                ds = np.array([min(o["dt"]) / 3, max(o["dt"]) * 1.5])
                ax.loglog(ds, e0 * (ds / d0) ** slope, color="k", lw=1, ls="--", alpha=0.7)
                ax.annotate(f"slope {slope}", (ds[1], e0 * (ds[1] / d0) ** slope), fontsize=9,
                            ha="left", va="top")
        orders = ", ".join(f"{m} {_order_text(info['orders'][m]['order'])}" for m in ("exact", "naive"))
        ax.set_xlabel("dt [s]")
        ax.set_ylabel("max |q - q_ref| over samples [m, rad]")
        ax.set_title(f"{name}: error vs dt (observed order: {orders})")
        ax.grid(True, which="major", alpha=0.3)
    height = 4.4 * n + 1.0
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.suptitle("jackbox work-precision: error against a reference solution "
                 "(right: circled points are those of the order fit)", fontsize=12, y=1 - 0.1 / height,
                 va="top")
    fig.legend(handles, labels, loc="upper center", ncol=4, fontsize=9, frameon=False,
               bbox_to_anchor=(0.5, 1 - 0.35 / height))
    fig.tight_layout(rect=(0, 0, 1, 1 - 1.0 / height))
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _order_text(order):
    return f"{order:.2f}" if math.isfinite(order) else "n/a"


def markdown(points, infos, machine, command):
    out = [f"Measured by `{command}` on {machine}; medians of one run of the script.", ""]
    out.append(f"Error: the largest |q - q_ref| over the samples (every {SAMPLE:g} s) and the six coordinates. "
               "Time: wall seconds per simulated second (kernels: the compiled loop, "
               "`meta['kernel']['run_seconds']`; scipy: the whole `reference.solve_exact` call, at scipy's "
               "default max_step); compile and lambdify time apart (below).")
    out += ["", "## Reference", ""]
    out.append("| scene | horizon | impacts | reference | vs scipy DOP853 rtol=1e-12 (max_step 1e-3): dq, dt_imp "
               "| vs exact kernel at dt/2: dq | compile (cache) | lambdify |")
    out.append("|---|---|---|---|---|---|---|---|")
    for i in infos:
        out.append(f"| {i['scene']} | {i['horizon']:g} s | {i['impacts']} | exact kernel, dt = {i['dt_ref']:g} s "
                   f"| {i['diff_scipy']:.1e}, {i['diff_scipy_t']:.1e}"
                   f"{'' if i['same_scipy'] else ' (different impacts!)'} "
                   f"| {i['diff_half']:.1e} | {i['compile_seconds']:.2f} s ({i['compile_cache']}) "
                   f"| {i['lambdify_seconds']:.2f} s |")
    out += ["", "## Observed order", ""]
    out.append(f"Least-squares slope of log(error) vs log(dt) over dt in {FIT_WINDOW['exact']} s (exact) and "
               f"{FIT_WINDOW['naive']} s (naive), points with the reference's impact sequence and an error at "
               f"least {FLOOR_FACTOR:g} times the reference's uncertainty (the larger difference above).")
    out += ["", "| scene | method | order | points (dt) | errors |", "|---|---|---|---|---|"]
    for i in infos:
        for m in ("exact", "naive"):
            o = i["orders"][m]
            dts = ", ".join(f"{d:g}" for d in o["dt"]) or "none"
            errs = f"{max(o['error']):.1e} .. {min(o['error']):.1e}" if o["error"] else "-"
            out.append(f"| {i['scene']} | {m} | {_order_text(o['order'])} | {dts} | {errs} |")
    notes = [f"* {i['scene']}: {NOTES[i['scene']]}" for i in infos if i["scene"] in NOTES]
    if notes:
        out += [""] + notes
    out += ["", "## Speed-up of the exact kernel at equal error", ""]
    out.append("Time per simulated second to reach the error, interpolated on each method's Pareto front "
               "(log-log); `<=`: the method's fastest point is already more accurate; n/a: not reached. "
               "Speed-ups are given twice: kernel loop / whole `jackbox.simulate` call (the call adds "
               "a fixed ~0.3 ms, argument checks and the kernel lookup, that longer runs amortise; "
               "scipy's times are whole calls).")
    out += ["", ("| scene | error | exact kernel s/s: loop, call | scipy DOP853 s/s | speed-up "
                 "| scipy RK45 s/s | speed-up | DOP853 compiled RHS s/s | speed-up |"),
            "|---|---|---|---|---|---|---|---|---|"]
    for i in infos:
        for level, t_loop, t_call, others in speedups(points, i["scene"]):
            cells = []
            for m in SCIPY:
                cells += [fmt_time(others[m]), fmt_speedups(t_loop, t_call, others[m])]
            out.append(f"| {i['scene']} | {level:.0e} | {fmt_time(t_loop)}, {fmt_time(t_call)} | "
                       + " | ".join(cells) + " |")
    out += ["", "## All measurements", ""]
    out.append("| scene | method | dt [s] | rtol | s per simulated s | whole call | error q | error t_imp "
               "| impacts | same sequence | fitted |")
    out.append("|---|---|---|---|---|---|---|---|---|---|---|")
    for p in points:
        if p.failed:
            out.append(f"| {p.scene} | {p.method} | | {p.rtol:.0e} | failed: {p.failed} | | | | | | |")
            continue
        out.append(f"| {p.scene} | {p.method} | {'' if p.dt is None else f'{p.dt:.3g}'} "
                   f"| {'' if p.rtol is None else f'{p.rtol:.0e}'} | {p.seconds:.3g} | {p.call_seconds:.3g} "
                   f"| {p.error_q:.2e} | {p.error_t:.2e} | {p.impacts} | {'yes' if p.same_sequence else 'NO'} "
                   f"| {'yes' if p.fitted else ''} |")
    return "\n".join(out) + "\n"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenes", nargs="*", default=None, help=f"default: {' '.join(HORIZONS)}")
    parser.add_argument("--repeat", type=int, default=5, help="runs per timing (median)")
    parser.add_argument("--quick", action="store_true", help="few points, one scene (a smoke test)")
    parser.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = parser.parse_args(argv)
    cfg = dict(QUICK) if args.quick else {"scenes": list(HORIZONS), "k_exact": K_EXACT, "k_naive": K_NAIVE,
                                          "k_lambdified": K_LAMBDIFIED, "rtols": RTOLS}
    scenes = args.scenes or cfg["scenes"]
    unknown = [s for s in scenes if s not in HORIZONS]
    if unknown:
        parser.error(f"no horizon for {', '.join(unknown)} (scenes: {', '.join(HORIZONS)})")
    repeat = 1 if args.quick else args.repeat

    def log(line):
        print(line, file=sys.stderr, flush=True)

    start = time.perf_counter()
    points, infos = [], []
    for name in scenes:
        p, info = bench_scene(name, repeat, cfg, log)
        points += p
        infos.append(info)
    machine = (f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python "
               f"{platform.python_version()}, Numba {numba.__version__}, NumPy {np.__version__}, "
               f"SciPy {__import__('scipy').__version__}")
    command = "python benchmarks/workprecision.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:]))
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "workprecision.csv", "w", newline="") as fh:
        writer = csv.writer(fh)
        writer.writerow([f.name for f in dataclasses.fields(Point)])
        for p in points:
            writer.writerow([getattr(p, f.name) for f in dataclasses.fields(Point)])
    (args.out / "workprecision.json").write_text(json.dumps(
        {"machine": machine, "command": command.strip(), "scenes": infos,
         "points": [dataclasses.asdict(p) for p in points]}, indent=1, default=float) + "\n")
    md = markdown(points, infos, machine, command.strip())
    (args.out / "workprecision.md").write_text(md)
    plot(points, infos, args.out / "workprecision.png")
    print(md.split("## All measurements")[0])
    log(f"done in {time.perf_counter() - start:.0f} s; wrote {args.out}/workprecision.{{csv,json,md,png}}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
