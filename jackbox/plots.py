"""Matplotlib pictures of trajectories: the time series of a run and the comparison of runs.

The last stage of the pipeline (``trajectory -> plots``), after the kernel and
away from it: this module imports matplotlib and is only imported when a
picture is asked for. Figures are made with ``matplotlib.figure.Figure``, never
pyplot, so no window or GUI backend is involved (headless by construction) and
a user's own pyplot state is left alone.

* :func:`timeseries` draws one run: the box's and the jack's positions and
  angles, the energy, the smallest gap, and every impulse on the time axis
  (one row per contact, named), so containment and repeated impacts can be
  checked at a glance.
* :func:`comparison` draws runs of one scene under different impact laws side
  by side: energy over time, the jack's height at each impulse, impulse counts,
  and the summary of :func:`summarize`.
* :func:`settle_time` says when a run has stopped losing energy (see there).

Long runs and thousands of impulses (a chattering contact) are thinned for
drawing only: lines keep the minimum and maximum of every pixel-wide bin, and
impulse marks keep one mark per contact and bin, so nothing that shows is lost.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from .errors import JackboxError
from .fileio import write_atomic
from .geometry import Geometry
from .scene import WALLS
from .trajectory import REST, Trajectory

#: time bins used to thin lines and impulse marks (about one per pixel column)
BINS = 1500
#: a run has settled once its energy stays within this fraction of the energy it lost ...
SETTLE_TOL = 0.01
#: ... over at least this fraction of the run, at its end
SETTLE_HOLD = 0.1
BOX_COLOR, JACK_COLOR = "#1f5fa8", "#2a9d3a"
RUN_COLORS = ("#1f5fa8", "#d1495b", "#2a9d3a", "#edae49", "#6d3a9c", "#00798c")
DPI = 100
#: impulses are also drawn as faint lines across the panels while there are at most this many
MAX_LINES = 120


# --- numbers ------------------------------------------------------------------------------

def settle_time(traj: Trajectory, tol: float = SETTLE_TOL, hold: float = SETTLE_HOLD) -> float | None:
    """When the run settled, or None if it did not.

    A run has *settled* at the earliest sample time ``t_s`` after which its
    energy stays within ``tol`` times the energy it lost, ``E(0) - E(end)``,
    of its final value ``E(end)``, for the rest of the run, provided that this
    lasts for at least the last ``hold`` fraction of the run. Impulses too
    small to move the energy that much (a contact chattering at rest) do not
    count as motion. A run that lost no energy (elastic impacts keep bouncing)
    or gained energy (forced) has not settled, and neither has a forced one
    whose energy still moves at the end.
    """
    e = traj.energy
    if len(e) < 2:
        return None
    lost = e[0] - e[-1]
    scale = max(np.abs(e).max(), 1e-300)
    if not lost > 1e-6 * scale:
        return None
    outside = np.nonzero(np.abs(e - e[-1]) > tol * lost)[0]
    i = 0 if len(outside) == 0 else outside[-1] + 1
    if i >= len(e):
        return None
    t0, t1 = traj.t[0], traj.t[-1]
    t_s = float(traj.t[i])
    return t_s if t1 - t_s >= hold * (t1 - t0) else None


@dataclass(frozen=True)
class Summary:
    """What :func:`summarize` says about one run."""

    label: str
    energy_start: float
    energy_end: float
    impulses: int
    wall_impulses: int
    ground_impulses: int
    settle: float | None

    @property
    def lost(self) -> float:
        return self.energy_start - self.energy_end

    @property
    def lost_text(self) -> str:
        """``"105.5 J (49%)"``; a loss below rounding (an elastic run) is 0."""
        lost = self.lost if abs(self.lost) > 1e-9 * max(abs(self.energy_start), 1e-300) else 0.0
        if not self.energy_start:
            return f"{lost:.4g} J"
        return f"{lost:.4g} J ({100 * lost / abs(self.energy_start):.1f}%)"

    @property
    def settle_text(self) -> str:
        return "did not settle" if self.settle is None else f"at t = {self.settle:.3g} s"


def summarize(traj: Trajectory, label: str = "") -> Summary:
    ground = _ground_mask(traj)
    return Summary(label=label, energy_start=float(traj.energy[0]), energy_end=float(traj.energy[-1]),
                   impulses=len(traj.impact_t), wall_impulses=int((~ground).sum()),
                   ground_impulses=int(ground.sum()), settle=settle_time(traj))


def summary_table(summaries: list[Summary], header: str = "e") -> str:
    """The summaries as aligned text lines (what ``jackbox compare`` prints)."""
    rows = [(header, "energy at start", "at end", "lost", "impulses", "settles")]
    for s in summaries:
        rows.append((s.label, f"{s.energy_start:.6g} J", f"{s.energy_end:.6g} J", s.lost_text,
                     str(s.impulses), s.settle_text))
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows)


# --- thinning for drawing -------------------------------------------------------------------

def thin_line(t: np.ndarray, y: np.ndarray, bins: int = BINS) -> tuple[np.ndarray, np.ndarray]:
    """``(t, y)`` with at most ``2 * bins`` points: each bin's minimum and maximum, in time order."""
    n = len(t)
    if n <= 4 * bins:
        return t, y
    edges = np.linspace(0, n, bins + 1).astype(int)
    keep = []
    for a, b in itertools.pairwise(edges):
        seg = y[a:b]
        i, j = a + int(np.argmin(seg)), a + int(np.argmax(seg))
        keep += [min(i, j), max(i, j)]
    keep = np.unique(keep)
    return t[keep], y[keep]


def thin_times(times: np.ndarray, t0: float, t1: float, bins: int = BINS) -> np.ndarray:
    """One time per occupied bin of ``[t0, t1]``: marks closer than a bin apart look the same."""
    if len(times) <= bins:
        return times
    width = (t1 - t0) / bins if t1 > t0 else 1.0
    _, first = np.unique(np.floor((times - t0) / width), return_index=True)
    return times[first]


def _ground_mask(traj: Trajectory) -> np.ndarray:
    names = np.asarray(traj.constraint_names, dtype=str)
    if len(names) == 0 or len(traj.impact_constraint) == 0:
        return np.zeros(len(traj.impact_t), dtype=bool)
    return np.char.startswith(names[traj.impact_constraint], "ground:")


def _contact_order(name: str) -> tuple[int, int]:
    wall, _, point = name.partition(":")
    order = WALLS.index(wall) if wall in WALLS else len(WALLS)
    return order, int(point) if point.isdigit() else 0


# --- the time series ------------------------------------------------------------------------

def _title(traj: Trajectory, law: bool = True) -> str:
    meta = traj.meta
    params = meta.get("params", {})
    e = params.get("e")
    eg = params.get("e_ground")
    law = "" if e is None or not law else f", e = {e:g}" + (
        "" if eg in (None, e) or not _has_ground(traj) else f", e_ground = {eg:g}")
    return (f"{meta.get('scene', '?')}: method {meta.get('method', '?')}, "
            f"dt = {meta.get('dt', float('nan')):g} s{law}")


def _has_ground(traj: Trajectory) -> bool:
    return any(n.startswith("ground:") for n in traj.constraint_names)


def timeseries(traj: Trajectory, geometry: Geometry | None = None) -> Figure:
    """The time series of one run, as a Matplotlib figure (not shown; see :func:`write_timeseries`).

    Panels, sharing the time axis: x of both bodies, y of both bodies, both
    angles, the energy, the smallest gap (walls and ground apart), and one row
    per contact that took an impulse, with a mark at every impulse. Faint
    vertical lines repeat the impulses on every panel.
    """
    geometry = geometry or Geometry.from_trajectory(traj)
    t, q = traj.t, traj.q
    names = np.asarray(traj.constraint_names, dtype=str)
    rests = rest_intervals(traj)
    hit_names = sorted({str(names[k]) for k in np.unique(traj.impact_constraint)} | set(rests),
                       key=_contact_order)
    rows = max(len(hit_names), 1)

    fig = Figure(figsize=(11, 12 + 0.16 * rows), dpi=DPI, layout="constrained")
    heights = [1, 1, 1, 1, 1, max(0.9, 0.2 * rows)]
    axes = fig.subplots(len(heights), 1, sharex=True, gridspec_kw={"height_ratios": heights})
    ax_x, ax_y, ax_th, ax_e, ax_gap, ax_imp = axes

    def line(ax, y, **kw):
        ax.plot(*thin_line(t, y), lw=1.2, **kw)

    line(ax_x, q[:, 0], color=BOX_COLOR, label="x_box")
    line(ax_x, q[:, 3], color=JACK_COLOR, label="x_jack")
    ax_x.set_ylabel("x (m)")
    line(ax_y, q[:, 1], color=BOX_COLOR, label="y_box")
    line(ax_y, q[:, 4], color=JACK_COLOR, label="y_jack")
    ax_y.set_ylabel("y (m)")
    if geometry.ground:
        ax_y.axhline(0.0, color="0.3", lw=0.8, ls="--", label="ground")
    line(ax_th, q[:, 2], color=BOX_COLOR, label="theta_box")
    line(ax_th, q[:, 5], color=JACK_COLOR, label="theta_jack")
    ax_th.set_ylabel("angle (rad)")
    drift = float(np.ptp(traj.energy)) if len(traj.energy) else 0.0
    line(ax_e, traj.energy, color="0.15", label=f"energy\n(range {drift:.3g} J)")
    ax_e.set_ylabel("energy (J)")
    _readable_energy_axis(ax_e, traj.energy)

    gaps = geometry.gaps(q)
    n_wall = 4 * len(geometry.points)
    line(ax_gap, gaps[:, :n_wall].min(axis=1), color=JACK_COLOR, label="jack to walls")
    if geometry.ground_contacts:
        line(ax_gap, gaps[:, n_wall:].min(axis=1), color=BOX_COLOR, label="box to ground")
    ax_gap.axhline(0.0, color="#c0392b", lw=0.8, ls="--", label="contact (gap 0)")
    ax_gap.set_ylabel("smallest gap (m)")

    _impulse_rows(ax_imp, traj, hit_names, rests)
    times = thin_times(traj.impact_t, t[0], t[-1], bins=BINS)
    coarse = thin_times(traj.impact_t, t[0], t[-1], bins=400)
    lines = len(coarse) <= MAX_LINES
    for ax in axes[:-1]:
        # every impulse as a tick on the panel's time axis; faint lines too while they stay few
        if len(times):   # (an empty unclipped line would break the layout)
            ax.plot(times, np.zeros(len(times)), "|", color="#c0392b", ms=7, mew=0.8,
                    transform=ax.get_xaxis_transform(), clip_on=False)
        if lines:
            for ti in coarse:
                ax.axvline(ti, color="#c0392b", lw=0.6, alpha=0.18, zorder=0)
        ax.grid(True, lw=0.4, alpha=0.5)
        ax.legend(loc="upper left", bbox_to_anchor=(1.005, 1.0), fontsize=9, frameon=False)
    ax_imp.set_xlabel("time t (s)")
    ax_imp.set_xlim(t[0], t[-1])

    n = len(traj.impact_t)
    marks = "red ticks" + (" and lines" if lines else "")
    count = f"{n} impulses, first at t = {traj.impact_t[0]:.3g} s ({marks}: impulses)" if n else "no impulses"
    fig.suptitle(f"{_title(traj)}\n{count}", fontsize=12)
    return fig


def _readable_energy_axis(ax, energy: np.ndarray) -> None:
    """Keep a constant energy readable: no 13-digit tick labels for a 1e-12 J wobble."""
    ax.ticklabel_format(axis="y", useOffset=False)
    if len(energy) == 0:
        return
    lo, hi = float(energy.min()), float(energy.max())
    span = max(1e-3 * max(abs(lo), abs(hi)), 1e-9)
    if hi - lo < span:
        mid = 0.5 * (lo + hi)
        ax.set_ylim(mid - span, mid + span)


def _impulse_rows(ax, traj: Trajectory, hit_names: list[str], rests: dict[str, list]) -> None:
    names = np.asarray(traj.constraint_names, dtype=str)
    t0, t1 = traj.t[0], traj.t[-1]
    ax.set_ylabel("impulses\n(contact)")
    if not hit_names:
        ax.set_yticks([])
        ax.text(0.5, 0.5, "no impulses", transform=ax.transAxes, ha="center", va="center", color="0.4")
        return
    hit = names[traj.impact_constraint] if len(traj.impact_t) else np.array([], dtype=str)
    for row, name in enumerate(hit_names):
        color = BOX_COLOR if name.startswith("ground:") else "#c0392b"
        for a, b in rests.get(name, []):
            ax.plot([a, b], [row, row], color=color, lw=4, alpha=0.35, solid_capstyle="butt")
        times = thin_times(traj.impact_t[hit == name], t0, t1)
        ax.plot(times, np.full(len(times), row), "|", color=color, ms=9, mew=1.2)
    counts = [int((hit == name).sum()) for name in hit_names]
    ax.set_yticks(range(len(hit_names)), [f"{n} ({c})" for n, c in zip(hit_names, counts)],
                  fontsize=8 if len(hit_names) > 12 else 9)
    ax.set_ylim(len(hit_names) - 0.5, -0.5)
    ax.grid(True, axis="x", lw=0.4, alpha=0.5)
    legend = "contact (count)\nred: jack-wall" + ("\nblue: box-ground" if _has_ground(traj) else "")
    if rests:
        legend += "\nbars: at rest"
    ax.text(1.005, 1.0, legend, transform=ax.transAxes, ha="left", va="top", fontsize=9)


def rest_intervals(traj: Trajectory) -> dict[str, list[tuple[float, float]]]:
    """Contact name -> [(t_rest, t_release), ...]: when a contact was held at rest.

    From the contact mode changes of methods that have them (``contact_t``,
    ``contact_constraint``, ``contact_event``: 1 rest, 2 release); a contact
    still at rest at the end is released at the last sample. Empty otherwise.
    """
    times = getattr(traj, "contact_t", None)
    if times is None or len(times) == 0:
        return {}
    names = np.asarray(traj.constraint_names, dtype=str)
    since: dict[str, float] = {}
    out: dict[str, list[tuple[float, float]]] = {}
    for t, k, event in zip(times, traj.contact_constraint, traj.contact_event):
        name = str(names[k])
        if event == REST:
            since.setdefault(name, float(t))
        elif name in since:
            out.setdefault(name, []).append((since.pop(name), float(t)))
    for name, t in since.items():
        out.setdefault(name, []).append((t, float(traj.t[-1])))
    return out


# --- the comparison ---------------------------------------------------------------------------

def comparison(trajs: list[Trajectory], labels: list[str], title: str = "") -> Figure:
    """Runs of one scene side by side: energy, the jack's height at each impulse, impulse counts.

    ``labels`` name the runs (``"e = 0.6"``). The fourth panel is the table of
    :func:`summarize`.
    """
    fig = Figure(figsize=(14, 9.5), dpi=DPI, layout="constrained")
    (ax_e, ax_h), (ax_n, ax_s) = fig.subplots(2, 2, gridspec_kw={"width_ratios": [1.15, 1]})
    summaries = [summarize(tr, lab) for tr, lab in zip(trajs, labels)]
    colors = [RUN_COLORS[i % len(RUN_COLORS)] for i in range(len(trajs))]

    for tr, lab, color, s in zip(trajs, labels, colors, summaries):
        ax_e.plot(*thin_line(tr.t, tr.energy), color=color, lw=1.4, label=lab)
        if s.settle is not None:
            ax_e.axvline(s.settle, color=color, ls=":", lw=1.2)
    ax_e.set_xlabel("time t (s)")
    ax_e.set_ylabel("energy (J)")
    ax_e.set_title("energy (dotted: settled)")
    _readable_energy_axis(ax_e, np.concatenate([tr.energy for tr in trajs]))
    ax_e.legend(fontsize=9)

    for tr, lab, color in zip(trajs, labels, colors):
        ax_h.plot(*thin_line(tr.t, tr.q[:, 4]), color=color, lw=0.8, alpha=0.45)
        ti = thin_times(tr.impact_t, tr.t[0], tr.t[-1], bins=600)
        idx = np.clip(np.searchsorted(tr.t, ti), 0, len(tr.t) - 1)
        ax_h.plot(ti, tr.q[idx, 4], "o", color=color, ms=3.5, label=f"{lab}: at impulses")
    ax_h.set_xlabel("time t (s)")
    ax_h.set_ylabel("jack height y_jack (m)")
    ax_h.set_title("bounce heights: the jack's y at each impulse")
    lo, hi = ax_h.get_ylim()
    ax_h.set_ylim(lo, hi + 0.22 * (hi - lo))      # room for the legend above the curves
    ax_h.legend(fontsize=9, loc="upper center", ncol=min(len(trajs), 3))

    _count_bars(ax_n, summaries, labels, colors)
    ax_s.axis("off")
    cells = [[s.label, s.lost_text, str(s.impulses), s.settle_text] for s in summaries]
    table = ax_s.table(cellText=cells, colLabels=["run", "energy lost", "impulses", "settles"],
                       loc="upper center", cellLoc="left", colLoc="left")
    table.auto_set_font_size(False)
    table.set_fontsize(10)
    table.scale(1.0, 1.6)
    ax_s.set_title("summary")
    ax_s.text(0.0, 0.05, f"settled: energy within {100 * SETTLE_TOL:g}% of the energy lost of its\n"
              f"final value from then on, for at least the last {100 * SETTLE_HOLD:g}% of the run",
              transform=ax_s.transAxes, fontsize=9, color="0.3", va="bottom")
    fig.suptitle(title or _title(trajs[0], law=False) + ": " + ", ".join(labels), fontsize=13)
    return fig


def _count_bars(ax, summaries: list[Summary], labels: list[str], colors: list[str]) -> None:
    """Impulse counts per run, jack-wall and box-ground side by side, each bar labelled."""
    x = np.arange(len(summaries))
    grounds = np.array([s.ground_impulses for s in summaries])
    kinds = [("jack-wall", np.array([s.wall_impulses for s in summaries]), None, 1.0)]
    if grounds.any():
        kinds.append(("box-ground", grounds, "//", 0.5))
    width = 0.8 / len(kinds)
    counts = np.concatenate([k[1] for k in kinds])
    log = counts.max() > 30 * max(counts[counts > 0].min(initial=1), 1)
    for j, (kind, n, hatch, alpha) in enumerate(kinds):
        xs = x + (j - (len(kinds) - 1) / 2) * width
        ax.bar(xs, n, width * 0.92, color=colors, alpha=alpha, hatch=hatch, edgecolor="0.2",
               linewidth=0.6, label=kind)
        for xi, ni in zip(xs, n):
            ax.annotate(str(int(ni)), (xi, max(ni, 0.8 if log else 0)), ha="center", va="bottom",
                        xytext=(0, 2), textcoords="offset points", fontsize=9)
    if log:
        ax.set_yscale("log")
        ax.set_ylim(0.8, counts.max() * 8)
    else:
        ax.set_ylim(0, max(counts.max(), 1) * 1.18)
    ax.set_xticks(x, labels)
    ax.set_ylabel("impulses" + (" (log scale)" if log else ""))
    ax.set_title("impulse counts" + (" (plain: jack-wall, hatched: box-ground)" if len(kinds) > 1 else ""))


# --- files ------------------------------------------------------------------------------------

#: the picture formats a file name may ask for (its extension)
FORMATS = ("png", "pdf", "svg")


def figure_format(path: str | Path) -> str:
    """The format a picture's file name asks for: png, pdf or svg (anything else is refused)."""
    ext = Path(path).suffix.lower().lstrip(".")
    if ext not in FORMATS:
        raise JackboxError(f"{path}: a picture is written as {', '.join('.' + f for f in FORMATS)}, "
                           f"not {('.' + ext) if ext else 'a name without an extension'}")
    return ext


def save_figure(fig: Figure, path: str | Path, run_id: str | None = None) -> Path:
    """Write a figure in the format its name asks for (png, pdf, svg), atomically: an
    existing file is replaced whole or not at all. run_id: the run it shows, written
    into the file's metadata (its title: ``jackbox run <id>``)."""
    fmt = figure_format(path)
    metadata = {"Title": f"jackbox run {run_id}"} if run_id else None
    return write_atomic(path, lambda fh: fig.savefig(fh, format=fmt, dpi=DPI, metadata=metadata))


def write_timeseries(traj: Trajectory, path: str | Path, geometry: Geometry | None = None) -> Path:
    return save_figure(timeseries(traj, geometry), path, traj.meta.get("run_id"))


def write_comparison(trajs: list[Trajectory], labels: list[str], path: str | Path, title: str = "") -> Path:
    return save_figure(comparison(trajs, labels, title), path)


def chaos(study) -> Figure:
    """Separation growth of the twin pairs over time, and the spread of their FTLE estimates."""
    fig = Figure(figsize=(11, 4.2), layout="constrained")
    ax, hx = fig.subplots(1, 2, width_ratios=(1.6, 1))
    t, growth = study.times, study.growth / np.log(10.0)       # log10(d / d0)
    ok = np.all(np.isfinite(growth), axis=1)
    g = growth[ok]
    if len(g):
        for row in g[: min(len(g), 30)]:
            ax.plot(t, row, color="0.75", lw=0.6)
        lo, med, hi = np.percentile(g, [10, 50, 90], axis=0)
        ax.fill_between(t, lo, hi, color="C0", alpha=0.25, lw=0, label="10-90% of pairs")
        ax.plot(t, med, color="C0", lw=2, label="median")
        lam = np.nanmean(study.ftle)
        ax.plot(t, lam * t / np.log(10.0), "--", color="C3", lw=1.2,
                label=f"mean FTLE {lam:.3g} 1/s")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("log10 separation growth, d / d0")
    ax.set_title(f"{study.spec.scene.name}: {len(study.stretch)} twin pairs, d0 = {study.spec.d0:g}, "
                 f"renormalised every {study.spec.renorm_steps * study.spec.dt:g} s", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=9)
    f = study.ftle[np.isfinite(study.ftle)]
    if len(f):
        hx.hist(f, bins=min(60, max(10, len(f) // 20)), color="C0", alpha=0.8)
        hx.axvline(f.mean(), color="C3", lw=1.2, label=f"mean {f.mean():.3g}")
        hx.axvline(np.median(f), color="k", lw=1, ls=":", label=f"median {np.median(f):.3g}")
        hx.legend(fontsize=9)
    hx.set_xlabel("finite-time Lyapunov exponent (1/s)")
    hx.set_ylabel("members")
    hx.set_title(f"over {study.spec.t_end:g} s" + (f"; std {f.std(ddof=1):.3g}" if len(f) > 1 else ""),
                 fontsize=10)
    return fig


def write_chaos(study, path: str | Path) -> Path:
    return save_figure(chaos(study), path)
