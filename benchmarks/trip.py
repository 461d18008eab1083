"""What a member's trip through the exact loop costs: the call, a free step in it, an impact step.

    python benchmarks/trip.py [--scene shaken] [--members 8] [--repeat 7] [--quick] [--out benchmarks/results]

An ensemble in lanes steps its members together while none has an event; a
member whose step has one (an impact, a crossing to locate) takes that step
alone through the exact loop (``members.alone_to`` -> ``members.run_segment``
-> the loop's function value, ``loop.integrate_exact``) and rejoins. In
``shaken`` every such trip is an impact, about 14 a member in 10 s, so a trip's
cost weighs on every study of it. For ``--members`` members of the scene's
ensemble (``theta_jack`` perturbed by 1e-3), this finds the step of each
member's third impact and times, in one process (compiled first, then median
of ``--repeat`` batches of calls):

* **impact step**: that step through ``run_segment``, as a member in lanes
  takes it (from the state at its start, again and again);
* **free step**: the step 30 steps before it, the same way (a step that needs
  no care: what the call itself costs, beside one step of the hot path);
* the same two steps through the loop's body (``loop.exact_steps``) in a
  scratch made once and zeroed at each call: without the function value's
  call (its records' fields as arguments), the scratch's allocation and
  views, and their reference counts;
* **whole run**: the member's whole run through ``run_segment`` in one call,
  per step (the hot path's steps, impacts included);
* **in a lane**: the impact step as a block's lanes now take it where it is a
  plain one (one impact, no contact coming to rest: ``lanes.event_lane``, the
  model's ``lane_event`` part, on floats), from the same state and the lanes'
  trial, without a trip.

Also checked, not timed: each way of calling ends the step in the same bits
(the lane's too, where it takes the step).
Writes ``trip.json`` and ``trip.md`` to ``--out``; the README quotes the
table. ``--quick`` runs small sizes (tests/test_benchmarks_smoke.py).
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from pathlib import Path

import numpy as np
from numba import njit

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from jackbox import loader  # noqa: E402
from jackbox.bench import command_line, machine  # noqa: E402
from jackbox.engine import members as M  # noqa: E402
from jackbox.engine.loop import exact_steps  # noqa: E402
from jackbox.engine.records import MODE_SLOTS, borrow, keep, scratch  # noqa: E402
from jackbox.ensemble import _kernel, _set_up, plan  # noqa: E402

#: steps before the impact step of the free step timed
BEFORE = 30


@njit(cache=False)
def impact_step(table, q0, qd0, p, tol, dt, n_steps, which):
    """The step of a member's impact number ``which`` (0: the first), or -1."""
    model, exact, stages = M.parts(table)
    q, qd, rest = q0.copy(), qd0.copy(), M.new_modes(model)
    out, log, tally = M.new_samples(np.int64(2)), M.new_log(M.LOG_SIZE), M.new_tally()
    zero = np.int64(0)
    M.run_segment(model, exact, stages, q, qd, rest, p, tol, dt, zero, zero, out, zero, log, tally)
    seen = 0
    for j in range(n_steps):
        before = tally[M.TALLY_IMPULSES]
        M.run_segment(model, exact, stages, q, qd, rest, p, tol, dt, j, j + 1, out, np.int64(1), log, tally)
        if tally[M.TALLY_IMPULSES] > before:
            if seen == which:
                return j
            seen += 1
    return -1


@njit(cache=False)
def state_at(table, q0, qd0, p, tol, dt, k, q, qd, rest):
    """A member's state and modes at the start of step k into q, qd, rest; returns its impulses so far."""
    model, exact, stages = M.parts(table)
    out, log, tally = M.new_samples(np.int64(2)), M.new_log(M.LOG_SIZE), M.new_tally()
    zero = np.int64(0)
    M.run_segment(model, exact, stages, q, qd, rest, p, tol, dt, zero, zero, out, zero, log, tally)
    M.run_segment(model, exact, stages, q, qd, rest, p, tol, dt, zero, k, out, np.int64(1), log, tally)
    return tally[M.TALLY_IMPULSES]


@njit(cache=False)
def segment_calls(table, qs, qds, rs, p, tol, dt, k, count, q, qd, rest):
    """Step k from (qs, qds, rs), ``count`` times, as a member in lanes takes it; the last end in q, qd, rest."""
    model, exact, stages = M.parts(table)
    out, log, tally = M.new_samples(np.int64(2)), M.new_log(M.LOG_SIZE), M.new_tally()
    for _ in range(count):
        M.copy_to(q, qs)
        M.copy_to(qd, qds)
        M.copy_to(rest, rs)
        M.run_segment(model, exact, stages, q, qd, rest, p, tol, dt, k, k + 1, out, np.int64(1), log, tally)


@njit(cache=False)
def zero(ws):
    """Every array of a scratch record zeroed, as :func:`~jackbox.engine.records.scratch` makes it."""
    ws.work[:] = 0.0
    ws.jac[:] = 0.0
    ws.c[:] = 0.0
    ws.n[:] = 0.0
    ws.k[:] = 0
    ws.rest0[:] = 0
    ws.A[:] = 0.0
    ws.sub[:] = 0.0
    ws.lu[:] = 0.0
    ws.ext[:] = 0.0
    ws.box[:] = 0.0


@njit(cache=False)
def body_calls(table, qs, qds, rs, p, tol, dt, k, count, q, qd, rest):
    """:func:`segment_calls` through the loop's body, in a scratch made once and zeroed at each call."""
    model, exact, stages = M.parts(table)
    out, log = M.new_samples(np.int64(2)), M.new_log(M.LOG_SIZE)
    own = scratch(model)
    ws = borrow(own)
    for _ in range(count):
        M.copy_to(q, qs)
        M.copy_to(qd, qds)
        M.copy_to(rest, rs)
        zero(ws)
        exact_steps(model, stages, borrow(q), borrow(qd), borrow(rest), borrow(p), borrow(tol), 0.0, dt, k, k + 1,
                    k + 1, k + 2, borrow(out), np.int64(1), borrow(log), np.int64(0), ws)
    keep(own)


@njit(cache=False)
def whole_run(table, q0, qd0, p, tol, dt, n_steps):
    """A member's whole run in one call of run_segment; returns its impulses."""
    model, exact, stages = M.parts(table)
    q, qd, rest = q0.copy(), qd0.copy(), M.new_modes(model)
    out, log, tally = M.new_samples(np.int64(2)), M.new_log(M.LOG_SIZE), M.new_tally()
    zero = np.int64(0)
    M.run_segment(model, exact, stages, q, qd, rest, p, tol, dt, zero, zero, out, zero, log, tally)
    M.run_segment(model, exact, stages, q, qd, rest, p, tol, dt, zero, n_steps, out, np.int64(1), log, tally)
    return tally[M.TALLY_IMPULSES]


def lane_harness(kernel):
    """``calls(t, t_next, dt, q, qd, p, tol, count, out)``: the model's lane event step (``lanes.event_lane``, its
    part compiled here) ``count`` times from (q, qd) and the lanes' trial; its end and what it said in out."""
    text = loader.binding_parts(Path(kernel.__file__).read_text(), lanes=True)["lane_event"]
    space: dict = {}
    exec(compile(text.replace("cache=True", "cache=False").split("COMPILED = ")[0], "lane_event part", "exec"), space)
    event_lane, grid_step, time_terms = space["event_lane"], space["grid_step"], space["accel_time_s"]
    e_slot, e_ground_slot = kernel.E_SLOT, kernel.E_GROUND_SLOT

    @njit(cache=False)
    def calls(t, t_next, dt, q, qd, p, tol, count, out):
        sc = np.zeros(M.LANES)
        q, qd = (q[0], q[1], q[2], q[3], q[4], q[5]), (qd[0], qd[1], qd[2], qd[3], qd[4], qd[5])
        qn, vn, _ = grid_step(t, t_next, time_terms(t, p), q, qd, dt, p)
        for _ in range(count):
            what, qb, vb, logged, te, g = event_lane(t, t_next, dt, q, qd, qn, vn, p, tol, sc, p[e_slot],
                                                     p[e_ground_slot])
        for d in range(6):
            out[d] = qb[d]
            out[6 + d] = vb[d]
        out[12] = what
    return calls


def per_call_ns(fn, call, count: int, repeat: int, outs) -> float:
    """Median over ``repeat`` batches of ``fn(*call, count, *outs)`` (count calls each), ns a call."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn(*call, count, *outs)
        times.append((time.perf_counter() - t0) / count * 1e9)
    return statistics.median(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="shaken", help="a built-in scene or a scene file (default shaken)")
    ap.add_argument("--members", type=int, default=8, help="members timed (default 8)")
    ap.add_argument("--repeat", type=int, default=7, help="batches of calls per figure, median (default 7)")
    ap.add_argument("--quick", action="store_true", help="small sizes: a smoke test")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results", help="folder for the results")
    args = ap.parse_args(argv)
    members, repeat, count = (2, 1, 20) if args.quick else (args.members, args.repeat, 2000)

    spec = plan(args.scene, members, perturb={"theta_jack": 1e-3})
    kernel = _kernel(spec)
    rows = _set_up(spec, kernel, 0, members)
    table = kernel.table()
    dt, n_steps, slots = spec.dt, spec.n_steps, kernel.record.n_contact + MODE_SLOTS
    print(f"{args.scene}: compiling the harness ...", flush=True)
    in_lane = lane_harness(kernel)
    rows_out, same = [], True
    for m in range(members):
        q0, qd0, p, tol = (np.ascontiguousarray(rows[key][m]) for key in ("q0", "qd0", "params", "tol"))
        k = impact_step(table, q0, qd0, p, tol, dt, n_steps, 2)
        if k < BEFORE:
            continue
        row = {"member": m, "impact_step": int(k)}
        for what, step in (("impact", k), ("free", k - BEFORE)):
            qs, qds, rs = q0.copy(), qd0.copy(), np.zeros(slots, np.int64)
            state_at(table, q0, qd0, p, tol, dt, step, qs, qds, rs)
            ends = []
            for how, fn in (("call", segment_calls), ("body", body_calls)):
                outs = (np.empty(6), np.empty(6), np.empty(slots, np.int64))
                call = (table, qs, qds, rs, p, tol, dt, step)
                fn(*call, 1, *outs)
                ends.append(np.concatenate(outs))
                row[f"{what}_{how}_ns"] = per_call_ns(fn, call, count, repeat, outs)
            same = same and bool(np.array_equal(ends[0], ends[1]))
            if what == "impact":        # the same step in a lane (lanes.event_lane), where it takes it
                t = step * dt
                lane_out = np.empty(13)
                lane_call = (t, (step + 1) * dt, dt, qs, qds, p, tol)
                in_lane(*lane_call, 1, lane_out)
                row["impact_in_lane"] = bool(lane_out[12] == 1)
                if row["impact_in_lane"]:
                    same = same and bool(np.array_equal(lane_out[:12], ends[0][:12]))
                    row["impact_lane_ns"] = per_call_ns(in_lane, lane_call, count, repeat, (lane_out,))
        whole_run(table, q0, qd0, p, tol, dt, np.int64(1))       # (compiled at the first member)
        t0 = time.perf_counter()
        row["impulses"] = float(whole_run(table, q0, qd0, p, tol, dt, n_steps))
        row["run_ns_per_step"] = (time.perf_counter() - t0) / n_steps * 1e9
        rows_out.append(row)
        lane = f", in a lane {row['impact_lane_ns']:.0f} ns" if row["impact_in_lane"] else ", not in a lane"
        print(f"member {m}: impact step {row['impact_call_ns']:.0f} ns{lane}, "
              f"free step {row['free_call_ns']:.0f} ns (body: {row['impact_body_ns']:.0f} / "
              f"{row['free_body_ns']:.0f} ns), whole run {row['run_ns_per_step']:.1f} ns a step", flush=True)
    if not rows_out:
        print(f"{args.scene}: no member has three impacts: nothing to time", file=sys.stderr)
        return 1
    med = {key: statistics.median(r[key] for r in rows_out)
           for key in ("impact_call_ns", "free_call_ns", "impact_body_ns", "free_body_ns", "run_ns_per_step",
                       "impulses")}
    lane_rows = [r["impact_lane_ns"] for r in rows_out if r["impact_in_lane"]]
    med["impact_lane_ns"] = statistics.median(lane_rows) if lane_rows else None
    result = {"scene": args.scene, "members": members, "repeat": repeat, "calls_per_batch": count,
              "quick": bool(args.quick), "command": command_line(), "machine": machine(), "rows": rows_out,
              "medians": med, "same_bits": same, "t_end": spec.t_end, "dt": dt}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "trip.json").write_text(json.dumps(result, indent=2) + "\n")
    per_member = med["impulses"] * med["impact_call_ns"] / (n_steps * 1e9) * 1e9
    md = ["# A trip through the exact loop", "",
          f"Measured by `{result['command']}` on {result['machine']['description']}: {len(rows_out)} members of "
          f"`{args.scene}`'s ensemble, the step of each one's third impact and the step {BEFORE} steps before it, "
          f"each taken again from its start state {count} times a batch, median of {repeat} batches, then of the "
          "members. Compare ratios, not absolute times, across machines.", "",
          "| step | through run_segment (as a member in lanes) | through the loop's body, scratch made once |",
          "|---|---|---|",
          f"| impact step | {med['impact_call_ns']:.0f} ns | {med['impact_body_ns']:.0f} ns |",
          f"| free step | {med['free_call_ns']:.0f} ns | {med['free_body_ns']:.0f} ns |",
          f"| a step of the member's whole run ({spec.t_end:g} s, one call) | {med['run_ns_per_step']:.1f} ns | - |",
          "",
          "The impact step in a lane (`lanes.event_lane`, on floats, no trip): "
          + (f"{med['impact_lane_ns']:.0f} ns" if lane_rows else "not taken") + f", for {len(lane_rows)} of the "
          f"{len(rows_out)} members (the others' impact step goes alone: more than one impact in it, or a contact "
          "coming to rest).", "",
          f"Impulses a member in {spec.t_end:g} s: {med['impulses']:.0f}; at one trip each, "
          f"{per_member:.2f} ns a member-step of the study"
          + (f", at one step in a lane each {per_member * med['impact_lane_ns'] / med['impact_call_ns']:.2f} ns"
             if lane_rows else "")
          + f". Each way of calling ends each step in the same bits: {'yes' if same else 'NO'}.", ""]
    if args.quick:
        md.insert(2, "Quick sizes: these runs are too short for the figures to mean anything.\n")
    (args.out / "trip.md").write_text("\n".join(md))
    print("\n".join(md))
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
