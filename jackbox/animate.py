"""Plotly animation of a trajectory: one offline HTML page with Play/Pause and a time slider.

The last stage of the pipeline next to :mod:`jackbox.plots`: this module
imports plotly and is only imported when an animation is asked for.

What a frame shows: the box's outer and inner boundary, the jack's true shape
(a cross's two arms, a square's or a polygon's outline), the ground line when
the scene has one, a trail of the jack's centre over the last ``trail``
seconds, and the contacts that took an impulse since the previous frame (a red
marker at the contact point, named, and the wall it hit drawn red). Contacts
held at rest (methods that report contact modes) are marked orange.

Frames are taken at ``fps`` frames per second of playback and play at real
time (``speed = 1``): frame ``k`` shows the recorded sample nearest to
``t0 + k * speed / fps``, never one frame per RK4 step. When that would make
more than ``max_frames`` frames the frame rate drops instead, so playback
stays at the chosen speed and the file stays small. plotly.js is inlined (the
page works offline and alone) or written beside the page.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import trajectory
from .fileio import write_atomic
from .geometry import Geometry
from .progress import progress_bar
from .trajectory import Trajectory

FPS = 25.0            #: frames per second of playback
MAX_FRAMES = 1000     #: beyond this the frame rate drops (playback speed is kept)
TRAIL = 1.0           #: seconds of simulated time in the jack centre's trail
TRAIL_PER_FRAME = 3   #: trail points per frame interval
DIV_ID = "jackbox-animation"
PLOTLYJS_NAME = "plotly.min.js"

BOX_LINE, BOX_FILL = "#1f3f6e", "#b9c8dd"
JACK_LINE, JACK_FILL = "#1e7b34", "rgba(42, 157, 58, 0.55)"
IMPULSE, RESTING, GROUND = "#d62728", "#f39c12", "#6b4f2a"


@dataclass(frozen=True)
class FramePlan:
    """Which samples become frames, and how fast they play."""

    index: np.ndarray     #: (K,) sample index of every frame
    fps: float            #: frames per second of playback actually used
    speed: float          #: simulated seconds per second of playback

    @property
    def duration_ms(self) -> float:
        """How long each frame stays on screen."""
        return 1000.0 / self.fps


def plan_frames(t: np.ndarray, fps: float = FPS, speed: float = 1.0,
                max_frames: int = MAX_FRAMES) -> FramePlan:
    """Frame times ``t0 + k * speed / fps`` (and the last sample), each shown by the nearest sample.

    The frame rate is lowered when the run would need more than ``max_frames``
    frames, or when the samples are sparser than the frames (``record_every``).
    """
    if not (fps > 0 and speed > 0 and max_frames >= 2):
        raise ValueError("fps and speed must be > 0 and max_frames >= 2")
    t = np.asarray(t, dtype=float)
    span = float(t[-1] - t[0]) if len(t) > 1 else 0.0
    if span <= 0:
        return FramePlan(np.zeros(1, dtype=np.int64), fps, speed)
    rate = min(fps, (max_frames - 1) * speed / span)
    spacing = float(np.median(np.diff(t)))
    if spacing > 0:
        rate = min(rate, speed / spacing)
    step = speed / rate
    times = t[0] + np.arange(math.floor(span / step + 1e-9) + 1) * step
    if t[-1] - times[-1] > 1e-9 * span:
        times = np.append(times, t[-1])
    index = _nearest(t, times)
    index = index[np.concatenate([[True], np.diff(index) > 0])]
    return FramePlan(index, rate, speed)


def _nearest(t: np.ndarray, times: np.ndarray) -> np.ndarray:
    right = np.clip(np.searchsorted(t, times), 1, len(t) - 1)
    left = right - 1
    return np.where(times - t[left] <= t[right] - times, left, right).astype(np.int64)


# --- the figure ------------------------------------------------------------------------------

def figure(traj: Trajectory, *, fps: float = FPS, speed: float = 1.0, max_frames: int = MAX_FRAMES,
           trail: float = TRAIL, geometry: Geometry | None = None, progress: bool = False) -> dict:
    """The animation as a plain Plotly figure dict (``data``, ``layout``, ``frames``).

    Trace names: ``"ground"`` (only when the scene has a ground), ``"box outer"``,
    ``"box inner"``, ``"trail"``, ``"jack"``, ``"wall hit"``, ``"impulse"``, and
    ``"at rest"`` when the trajectory reports contact modes. Every frame updates
    all of them but the ground; ``frame["name"]`` is its index and
    ``frame["t"]`` its time.
    """
    geometry = geometry or Geometry.from_trajectory(traj)
    plan = plan_frames(traj.t, fps, speed, max_frames)
    t, q = traj.t, traj.q
    idx = plan.index
    qf = q[idx]
    tf = t[idx]

    outer = geometry.box_corners(qf, inner=False)
    inner = geometry.box_corners(qf, inner=True)
    jack = geometry.jack_outline(qf)
    points = geometry.jack_points(qf)
    lo, hi = _extent(np.concatenate([outer.reshape(-1, 2), points.reshape(-1, 2)]), geometry.ground)
    digits = max(2, math.ceil(-math.log10(max(hi - lo) * 1e-4)))

    def xy(a: np.ndarray) -> tuple[list, list]:
        return np.round(a[..., 0], digits).tolist(), np.round(a[..., 1], digits).tolist()

    names = np.asarray(traj.constraint_names, dtype=str)
    impulse_frame = np.searchsorted(tf, traj.impact_t, side="left")
    by_frame: dict[int, set[int]] = {}
    for k, c in zip(impulse_frame, traj.impact_constraint):
        by_frame.setdefault(int(min(k, len(idx) - 1)), set()).add(int(c))
    rests = _rest_intervals(traj)
    has_rest = bool(rests)
    trail_idx = _trail_samples(t, plan)

    static, animated = [], []
    if geometry.ground:
        static.append(_trace("ground", [lo[0], hi[0]], [0.0, 0.0], mode="lines",
                             line={"color": GROUND, "width": 3}))
    animated += [
        _trace("box outer", *xy(_closed(outer[0])), fill="toself", fillcolor=BOX_FILL,
               line={"color": BOX_LINE, "width": 2}),
        _trace("box inner", *xy(_closed(inner[0])), fill="toself", fillcolor="#ffffff",
               line={"color": BOX_LINE, "width": 2}),
        _trace("trail", [], [], line={"color": "rgba(30, 123, 52, 0.45)", "width": 1.5, "dash": "dot"},
               mode="lines"),
        _jack_trace(geometry, *xy(jack[0])),
        _trace("wall hit", [], [], mode="lines", line={"color": IMPULSE, "width": 6}),
    ]
    if has_rest:
        animated.append(_trace("at rest", [], [], mode="markers",
                               marker={"color": RESTING, "size": 11, "symbol": "diamond",
                                       "line": {"color": "#fff", "width": 1}}))
    animated.append(
        _trace("impulse", [], [], mode="markers+text", textposition="top center",
               textfont={"color": IMPULSE, "size": 12},
               marker={"color": IMPULSE, "size": 13, "symbol": "circle", "line": {"color": "#fff", "width": 1.5}}))
    n_static = len(static)
    animated_ids = list(range(n_static, n_static + len(animated)))

    frames = []
    bar = progress_bar(len(idx), progress, "frame", "animation")
    for k in range(len(idx)):
        hit = sorted(by_frame.get(k, ()))
        hx, hy, wx, wy, labels, where = [], [], [], [], [], []
        for c in hit:
            x, y = _contact_point(geometry, names[c], outer[k], points[k])
            hx.append(x)
            hy.append(y)
            labels.append(str(names[c]))
            # the name on the side of the box's centre, off the wall it names
            where.append("bottom center" if y > qf[k, 1] else "top center")
            wall = names[c].partition(":")[0]
            if wall != "ground":
                seg = geometry.wall_segment(qf[k:k + 1], wall)[0]
                wx += [seg[0, 0], seg[1, 0], None]
                wy += [seg[0, 1], seg[1, 1], None]
        lo_t = tf[k] - trail
        tr = trail_idx[(t[trail_idx] >= lo_t) & (t[trail_idx] < tf[k])]
        tr = np.append(tr, idx[k])
        update = {
            "box outer": dict(zip("xy", xy(_closed(outer[k])))),
            "box inner": dict(zip("xy", xy(_closed(inner[k])))),
            "trail": dict(zip("xy", xy(q[tr][:, 3:5]))),
            "jack": dict(zip("xy", xy(jack[k]))),
            "wall hit": {"x": _round(wx, digits), "y": _round(wy, digits)},
            "impulse": {"x": _round(hx, digits), "y": _round(hy, digits), "text": labels or [""],
                        "textposition": where or ["top center"]},
        }
        if has_rest:
            resting = sorted(c for c, spans in rests.items() if any(a <= tf[k] < b for a, b in spans))
            rp = [_contact_point(geometry, names[c], outer[k], points[k]) for c in resting]
            update["at rest"] = {"x": _round([p[0] for p in rp], digits), "y": _round([p[1] for p in rp], digits),
                                 "text": [str(names[c]) for c in resting] or [""]}
        data = [update[trace["name"]] for trace in animated]
        frames.append({"name": str(k), "t": float(tf[k]), "data": data, "traces": animated_ids})
        bar.update()
    bar.close()

    # the first frame's state is the figure's own
    for trace, update in zip(animated, frames[0]["data"]):
        trace.update(update)
    layout = _layout(traj, geometry, plan, frames, lo, hi, has_rest)
    return {"data": static + animated, "layout": layout, "frames": frames}


def _layout(traj, geometry, plan: FramePlan, frames, lo, hi, has_rest: bool) -> dict:
    meta = traj.meta
    play = {"frame": {"duration": plan.duration_ms, "redraw": False}, "fromcurrent": True,
            "transition": {"duration": 0}, "mode": "immediate"}
    jump = {"frame": {"duration": 0, "redraw": False}, "transition": {"duration": 0}, "mode": "immediate"}
    speed = "real time" if plan.speed == 1 else f"{plan.speed:g}x real time"
    title = (f"{meta.get('scene', '?')}: method {meta.get('method', '?')}, {_law(meta)}"
             f"<br><sup>{speed}, {plan.fps:.3g} frames/s; red: impulse since the last frame"
             + ("; orange: contact at rest" if has_rest else "")
             + "</sup>")
    span = hi - lo
    width = 820
    # the plot area as close to the motion's aspect as fits: equal axes shrink the other way
    height = int(np.clip(240 + (width - 90) * span[1] / span[0], 560, 1000))
    axis = {"showgrid": True, "gridcolor": "#e6e6e6", "zeroline": False, "constrain": "domain",
            "ticks": "outside", "mirror": True, "showline": True, "linecolor": "#888"}
    shapes = []
    if geometry.ground:
        shapes.append({"type": "rect", "xref": "x", "yref": "y", "x0": lo[0], "x1": hi[0],
                       "y0": lo[1], "y1": 0.0, "fillcolor": "rgba(107, 79, 42, 0.15)",
                       "line": {"width": 0}, "layer": "below"})
    return {
        "title": {"text": title, "x": 0.5, "xanchor": "center"},
        "width": width, "height": height,
        "margin": {"l": 60, "r": 30, "t": 110, "b": 130},
        "plot_bgcolor": "#ffffff", "paper_bgcolor": "#ffffff",
        "xaxis": axis | {"range": [lo[0], hi[0]], "title": {"text": "x (m)"}},
        "yaxis": axis | {"range": [lo[1], hi[1]], "title": {"text": "y (m)"},
                         "scaleanchor": "x", "scaleratio": 1},
        "legend": {"orientation": "h", "x": 0.5, "xanchor": "center", "y": 1.01, "yanchor": "bottom",
                   "bgcolor": "rgba(0,0,0,0)"},
        "shapes": shapes,
        "hovermode": "closest",
        "updatemenus": [{
            "type": "buttons", "direction": "left", "showactive": False,
            "x": 0.0, "xanchor": "left", "y": -0.1, "yanchor": "top", "pad": {"r": 10, "t": 10},
            "buttons": [
                {"label": "Play", "method": "animate", "args": [None, play]},
                {"label": "Pause", "method": "animate", "args": [[None], jump]},
            ],
        }],
        "sliders": [{
            "active": 0, "x": 0.17, "len": 0.83, "xanchor": "left", "y": -0.1, "yanchor": "top",
            "pad": {"t": 10, "b": 10},
            "currentvalue": {"prefix": "t = ", "suffix": " s", "visible": True, "xanchor": "left",
                             "font": {"size": 15, "color": "#222"}},
            # one step per frame: their labels are hidden (they would overlap), the current one shows
            "font": {"color": "rgba(0,0,0,0)"}, "ticklen": 0, "minorticklen": 0,
            "transition": {"duration": 0},
            "steps": [{"label": f"{f['t']:.3f}", "method": "animate", "args": [[f["name"]], jump]}
                      for f in frames],
        }],
    }


def _law(meta: dict) -> str:
    params = meta.get("params", {})
    if "e" not in params:
        return ""
    text = f"e = {params['e']:g}"
    if params.get("e_ground", params["e"]) != params["e"]:
        text += f", e_ground = {params['e_ground']:g}"
    return text


def _trace(name: str, x, y, **kw) -> dict:
    mode = kw.pop("mode", "lines")
    return {"type": "scatter", "name": name, "x": x, "y": y, "mode": mode,
            "hoverinfo": "name+text" if "text" in mode else "name", **kw}


def _jack_trace(geometry: Geometry, x, y) -> dict:
    if geometry.shape == "cross":
        # the arms as one stroke; a point mass at each tip, none at the centre
        sizes = [10, 10, 0, 10, 10]
        return _trace("jack", x, y, mode="lines+markers", line={"color": JACK_LINE, "width": 4},
                      marker={"color": JACK_LINE, "size": sizes})
    return _trace("jack", x, y, fill="toself", fillcolor=JACK_FILL,
                  line={"color": JACK_LINE, "width": 2.5})


def _closed(corners: np.ndarray) -> np.ndarray:
    return np.vstack([corners, corners[:1]])


def _round(values: list, digits: int) -> list:
    # never empty: an animated trace whose data turns empty keeps showing its old points
    return [None if v is None else round(float(v), digits) for v in values] or [None]


def _contact_point(geometry: Geometry, name: str, outer: np.ndarray, points: np.ndarray):
    """Where a contact is in the world: a jack point (wall contacts) or a box corner (ground)."""
    wall, _, i = name.partition(":")
    p = outer[int(i)] if wall == "ground" else points[int(i)]
    return float(p[0]), float(p[1])


def _extent(points: np.ndarray, ground: bool) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = points.min(axis=0), points.max(axis=0)
    if ground:
        lo[1] = min(lo[1], 0.0)
    pad = 0.06 * max(hi - lo)
    lo, hi = lo - pad, hi + pad
    if ground:
        lo[1] = min(lo[1], -pad)
    return lo, hi


def _trail_samples(t: np.ndarray, plan: FramePlan) -> np.ndarray:
    """Samples for the trail: about TRAIL_PER_FRAME per frame interval."""
    step = plan.speed / plan.fps / TRAIL_PER_FRAME
    grid = t[0] + np.arange(int((t[-1] - t[0]) / step) + 1) * step
    return np.unique(_nearest(t, grid)) if len(t) > 1 else np.zeros(1, dtype=np.int64)


def _rest_intervals(traj: Trajectory) -> dict[int, list[tuple[float, float]]]:
    """Constraint index -> [(t_rest, t_release)] from the contact mode changes, if any."""
    times = getattr(traj, "contact_t", None)
    if times is None or len(times) == 0:
        return {}
    since: dict[int, float] = {}
    out: dict[int, list[tuple[float, float]]] = {}
    for t, k, event in zip(times, traj.contact_constraint, traj.contact_event):
        k = int(k)
        if event == trajectory.REST:
            since.setdefault(k, float(t))
        elif k in since:
            out.setdefault(k, []).append((since.pop(k), float(t)))
    for k, t in since.items():
        out.setdefault(k, []).append((t, math.inf))
    return out


# --- the page --------------------------------------------------------------------------------

def to_html(fig: dict, plotlyjs: str = "inline", title: str = "jackbox") -> str:
    """The page: ``plotlyjs`` ``"inline"`` (one file that works anywhere, ~5 MB) or
    ``"beside"`` (a ``<script src="plotly.min.js">``; see :func:`write_animation`)."""
    import plotly.io as pio

    if plotlyjs not in ("inline", "beside"):
        raise ValueError(f"plotlyjs must be 'inline' or 'beside', got {plotlyjs!r}")
    frames = [{k: v for k, v in f.items() if k != "t"} for f in fig["frames"]]
    html = pio.to_html({**fig, "frames": frames}, validate=False, auto_play=False, full_html=True,
                       include_plotlyjs=True if plotlyjs == "inline" else PLOTLYJS_NAME,
                       include_mathjax=False, div_id=DIV_ID,
                       config={"displaylogo": False, "responsive": True,
                               "modeBarButtonsToRemove": ["select2d", "lasso2d"]})
    return html.replace("<head>", f"<head><title>{_escape(title)}</title>{QUIET_INTERRUPTS}", 1)


#: Pause (or the slider) interrupts a playing animation, and plotly.js then rejects the
#: interrupted Plotly.animate promise with no reason; the buttons never catch it, so every
#: Pause would log "Uncaught (in promise)". Only those empty rejections are silenced.
QUIET_INTERRUPTS = ("<script>window.addEventListener('unhandledrejection', function (e) "
                    "{ if (e.reason === undefined) { e.preventDefault(); } });</script>")


def _escape(text: str) -> str:
    return text.replace("&", "&amp;").replace("<", "&lt;").replace(">", "&gt;")


def write_animation(traj: Trajectory, path: str | Path, *, plotlyjs: str = "inline",
                    geometry: Geometry | None = None, progress: bool = False, **kw) -> Path:
    """Write the animation page atomically; ``kw`` go to :func:`figure`.

    With ``plotlyjs="beside"`` the page loads ``plotly.min.js`` from its own
    folder, which is written there too (once: an identical file is kept).
    """
    fig = figure(traj, geometry=geometry, progress=progress, **kw)
    meta = traj.meta
    html = to_html(fig, plotlyjs, title=f"jackbox: {meta.get('scene', '')} ({meta.get('method', '')})")
    if meta.get("run_id"):
        html = html.replace("<head>", f'<head><meta name="jackbox-run" content="{_escape(meta["run_id"])}">', 1)
    path = Path(path)
    if plotlyjs == "beside":
        from plotly.offline import get_plotlyjs

        js = get_plotlyjs().encode("utf-8")
        target = path.parent / PLOTLYJS_NAME
        if not (target.is_file() and target.read_bytes() == js):
            write_atomic(target, js)
    return write_atomic(path, html)

