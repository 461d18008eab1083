"""Pictures: the geometry they draw, the time series and comparison PNGs, the animation's
frames and page, and the commands that write them (run, compare, animate, plot).

Most checks use synthetic trajectories (known poses, impulses at known times) so the
expected pictures can be computed independently; the CLI tests run the built-in
'drop' for short horizons with its cached kernel. The page in a real browser is
tested in test_browser.py.
"""

from __future__ import annotations

import inspect
import io
import json
import math
import re
import subprocess
import sys

import numpy as np
import pytest
from matplotlib import image as mpimg

import jackbox
from jackbox import animate, api, plots
from jackbox.cli import main
from jackbox.geometry import Geometry
from jackbox.scene import contact_gaps

from .conftest import FREE_FLOAT, run_cli, write_scene

# --- helpers -------------------------------------------------------------------------------

def synthetic(scene, t_end=4.0, dt=0.01, impacts=(), params=None, contact=None):
    """A trajectory of `scene` with made-up smooth motion and impulses at given (t, name)."""
    t = np.round(np.arange(0.0, t_end + dt / 2, dt), 12)
    q = np.empty((len(t), 6))
    q[:, 0] = 0.1 * np.sin(t)
    q[:, 1] = 3.0 + 0.2 * np.cos(2 * t)
    q[:, 2] = 0.3 * np.sin(0.7 * t)
    q[:, 3] = q[:, 0] + 0.2 * np.sin(3 * t)
    q[:, 4] = q[:, 1] - 0.1 * np.cos(3 * t)
    q[:, 5] = 2.0 * t
    names = scene.constraint_names
    p = scene.params() | dict(params or {})
    meta = {"scene": scene.name, "method": "naive", "dt": dt, "params": p}
    traj = jackbox.Trajectory(
        t=t, q=q, qd=np.gradient(q, dt, axis=0), energy=100.0 - 5.0 * (1 - np.exp(-t)),
        impact_t=np.array([ti for ti, _ in impacts], dtype=float),
        impact_constraint=np.array([names.index(n) for _, n in impacts], dtype=np.int64),
        constraint_names=names, scene=scene.text, meta=meta)
    if contact is not None:
        traj.contact_t = np.array([c[0] for c in contact], dtype=float)
        traj.contact_constraint = np.array([names.index(c[1]) for c in contact], dtype=np.int64)
        traj.contact_event = np.array([c[2] for c in contact], dtype=np.int64)
    return traj


def rotate(points, x, y, theta):
    """Body-frame points placed at (x, y, theta), written out by hand."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[x + c * px - s * py, y + s * px + c * py] for px, py in points])


def read_png(path_or_bytes):
    data = path_or_bytes if isinstance(path_or_bytes, bytes) else path_or_bytes.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return mpimg.imread(io.BytesIO(data), format="png")


def assert_not_blank(img, min_colors=50):
    """A picture, not an empty canvas: pixel values vary and take many values."""
    rgb = img[..., :3]
    assert rgb.std() > 0.05, rgb.std()
    colors = np.unique((rgb.reshape(-1, 3) * 255).astype(np.uint8), axis=0)
    assert len(colors) >= min_colors, len(colors)


@pytest.fixture(scope="module")
def polygon_scene(prescribed_scene):
    return prescribed_scene   # the hexagon jack in a prescribed box


@pytest.fixture(autouse=True)
def _in_tmp(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)




def assert_one_line_error(status, out, err, word=""):
    assert status == 2, (status, out, err)
    assert "Traceback" not in err
    assert len(err.splitlines()) == 1, err
    assert err.startswith("jackbox: error: ") and word in err, err
    assert out == ""


# --- geometry --------------------------------------------------------------------------------

def test_simulating_imports_no_plotting_library():
    code = ("import sys, jackbox, jackbox.cli; jackbox.simulate('drop', t_end=0.01); "
            "print(sorted(m for m in ('matplotlib', 'plotly') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                          check=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


@pytest.mark.parametrize("name", ["drop", "shaken", "spring"])
def test_gaps_match_the_scene_gaps(name):
    scene = jackbox.load_scene(name)
    geometry = Geometry.from_scene(scene)
    rng = np.random.default_rng(5)
    q = rng.normal(size=(20, 6)) * [0.3, 0.3, 0.5, 0.3, 0.3, 2.0] + [0, 2, 0, 0, 2, 0]
    got = geometry.gaps(q)
    for i in range(len(q)):
        want = contact_gaps(q[i], scene.points, scene.params()["L"], scene.params()["w_box"],
                            scene.has_ground_contacts)
        np.testing.assert_allclose(got[i], want, rtol=0, atol=1e-12)
    assert geometry.constraint_names == scene.constraint_names


def test_geometry_reads_the_polygon_and_sizes_the_run_used(polygon_scene):
    # a run with other vertex and wall values is drawn as it ran, not as the scene file says
    params = {"jack_x0": 0.35, "L": 1.2, "w_box": 0.3}
    traj = synthetic(polygon_scene, params=params)
    g = Geometry.from_trajectory(traj)
    assert g.shape == "polygon" and not g.ground
    want = polygon_scene.points.copy()
    want[0, 0] = 0.35
    np.testing.assert_array_equal(g.points, want)
    assert (g.L, g.w) == (1.2, 0.3)


def test_cross_outline_is_its_two_arms():
    g = Geometry.from_scene(jackbox.load_scene("shaken"))
    q = np.array([[0, 0, 0, 1.0, 2.0, math.pi / 2]])
    path = g.jack_outline(q)[0]
    # tip 0 (a, 0) -> tip 2 (-a, 0) -> centre -> tip 1 (0, a) -> tip 3 (0, -a), rotated by 90 deg
    np.testing.assert_allclose(path, [[1, 3], [1, 1], [1, 2], [0, 2], [2, 2]], atol=1e-12)


# --- numbers ---------------------------------------------------------------------------------

def test_settle_time(polygon_scene):
    traj = synthetic(polygon_scene, t_end=10.0)
    t = traj.t
    traj.energy = 50.0 + 100.0 * np.exp(-2.0 * t)       # loses 100 J, within 1 J after ln(100)/2 s
    assert plots.settle_time(traj) == pytest.approx(math.log(100.0) / 2.0, abs=0.011)
    traj.energy = np.full(len(t), 216.89) + 1e-13 * np.sin(t)   # elastic: keeps its energy
    assert plots.settle_time(traj) is None
    traj.energy = 50.0 + t                              # gains energy (forced)
    assert plots.settle_time(traj) is None
    traj.energy = 150.0 - 10.0 * t                      # still losing at the end
    assert plots.settle_time(traj) is None
    traj.energy = np.where(t < 9.5, 150.0, 50.0)        # settles too late to tell (last 10%)
    assert plots.settle_time(traj) is None


def test_thinning_keeps_extremes_and_every_bin():
    t = np.linspace(0, 100, 1_000_001)
    y = np.sin(t)
    y[123_457] = 9.0                                    # a one-sample spike must survive
    tt, yy = plots.thin_line(t, y, bins=500)
    assert len(tt) <= 1000 and yy.max() == 9.0 and yy.min() == y.min()
    assert np.all(np.diff(tt) > 0)
    times = np.sort(np.random.default_rng(1).uniform(0, 10, 50_000))
    kept = plots.thin_times(times, 0.0, 10.0, bins=100)
    assert len(kept) == 100
    assert set(np.floor(kept / 0.1).astype(int)) == set(range(100))


def test_rest_intervals(polygon_scene):
    traj = synthetic(polygon_scene, contact=[(1.0, "bottom:0", 1), (1.5, "bottom:0", 2),
                                             (2.0, "left:3", 1)])
    assert plots.rest_intervals(traj) == {"bottom:0": [(1.0, 1.5)], "left:3": [(2.0, traj.t[-1])]}


# --- time series and comparison (Matplotlib) ---------------------------------------------------

def test_timeseries_png(polygon_scene, tmp_path):
    impacts = [(0.5, "bottom:2"), (0.5, "left:1"), (2.25, "top:0")] + [(3.0 + i * 1e-4, "right:4")
                                                                       for i in range(5000)]
    traj = synthetic(polygon_scene, impacts=impacts, contact=[(1.0, "bottom:0", 1)])
    fig = plots.timeseries(traj)
    # units on every axis, the scene and the method in the title
    labels = [ax.get_ylabel() for ax in fig.axes]
    assert labels[:5] == ["x (m)", "y (m)", "angle (rad)", "energy (J)", "smallest gap (m)"]
    assert fig.axes[-1].get_xlabel() == "time t (s)"
    title = fig._suptitle.get_text()
    assert "hand" in title and "method naive" in title and "5003 impulses" in title
    # the contacts that took impulses (or rested) are named on the impulse panel, in wall order
    ticks = [tick.get_text() for tick in fig.axes[-1].get_yticklabels()]
    assert ticks == ["right:4 (5000)", "top:0 (1)", "left:1 (1)", "bottom:0 (0)", "bottom:2 (1)"]
    path = plots.save_figure(fig, tmp_path / "ts.png")
    img = read_png(path)
    h, w = img.shape[:2]
    assert w == 1100 and 1000 < h < 2000
    assert 30_000 < path.stat().st_size < 1_000_000
    assert_not_blank(img)


def test_comparison_png(polygon_scene, tmp_path):
    a = synthetic(polygon_scene, impacts=[(0.5, "bottom:2")])
    a.energy = np.full(len(a.t), 100.0)
    b = synthetic(polygon_scene, impacts=[(0.5, "bottom:2"), (0.7, "bottom:3")], t_end=4.0)
    b.energy = 60.0 + 40.0 * np.exp(-3 * b.t)
    fig = plots.comparison([a, b], ["e = 1", "e = 0.6"])
    titles = [ax.get_title() for ax in fig.axes]
    assert titles[:3] == ["energy (dotted: settled)", "bounce heights: the jack's y at each impulse",
                          "impulse counts"]
    assert "hand" in fig._suptitle.get_text()
    path = plots.save_figure(fig, tmp_path / "cmp.png")
    img = read_png(path)
    assert img.shape[:2] == (950, 1400)
    assert_not_blank(img)
    table = plots.summary_table([plots.summarize(a, "1"), plots.summarize(b, "0.6")])
    lines = table.splitlines()
    assert len(lines) == 3 and lines[1].split()[:1] == ["1"] and "did not settle" in lines[1]
    assert "at t = " in lines[2] and "40 J" in lines[2]


# --- the animation (Plotly figure and page) ---------------------------------------------------

@pytest.mark.parametrize("t_end, dt, fps, speed, max_frames", [
    (5.0, 1e-3, 25, 1.0, 1000),     # real time: 125 intervals
    (100.0, 1e-3, 25, 1.0, 300),    # too long: the frame rate drops, playback stays real time
    (4.0, 0.1, 25, 1.0, 1000),      # samples sparser than frames: one frame per sample
    (2.0, 1e-3, 30, 0.25, 1000),    # slow motion: 4x the frames
])
def test_frame_plan(t_end, dt, fps, speed, max_frames):
    t = np.arange(0.0, t_end + dt / 2, dt)
    plan = animate.plan_frames(t, fps, speed, max_frames)
    k = len(plan.index)
    assert k <= max_frames
    assert k <= math.floor(t_end / dt) + 1
    assert k <= fps * t_end / speed + 2
    assert plan.fps <= fps
    assert plan.index[0] == 0 and plan.index[-1] == len(t) - 1
    assert np.all(np.diff(plan.index) > 0)
    # playback lasts the simulated time over the speed (real time at speed 1)
    shown = t[plan.index]
    assert (k - 1) * plan.duration_ms / 1000 == pytest.approx((t_end) / speed, rel=0.05, abs=0.05)
    np.testing.assert_allclose(np.diff(shown)[:-1], speed / plan.fps, rtol=0.02, atol=dt)


def test_animation_frames_show_the_trajectory(polygon_scene):
    impacts = [(0.53, "bottom:2"), (0.53, "left:4"), (1.2, "top:0")]
    traj = synthetic(polygon_scene, impacts=impacts, contact=[(2.0, "bottom:1", 1), (2.5, "bottom:1", 2)])
    fig = animate.figure(traj, fps=10)
    names = [d["name"] for d in fig["data"]]
    # a prescribed box: no ground contacts and no ground in this scene
    assert names == ["box outer", "box inner", "trail", "jack", "wall hit", "at rest", "impulse"]
    frames = fig["frames"]
    assert len(frames) == 41                                     # 4 s at 10 frames/s, both ends
    lay = fig["layout"]
    assert lay["yaxis"]["scaleanchor"] == "x" and lay["yaxis"]["scaleratio"] == 1
    assert lay["updatemenus"][0]["buttons"][0]["label"] == "Play"
    assert lay["updatemenus"][0]["buttons"][0]["args"][1]["frame"]["duration"] == pytest.approx(100.0)
    assert len(lay["sliders"][0]["steps"]) == len(frames)
    jack_i, outer_i, hit_i = names.index("jack"), names.index("box outer"), names.index("impulse")
    rest_i = names.index("at rest")
    verts = polygon_scene.points
    (xr0, xr1), (yr0, yr1) = lay["xaxis"]["range"], lay["yaxis"]["range"]
    for f in frames:
        k = int(f["name"])
        i = int(np.argmin(np.abs(traj.t - f["t"])))
        assert traj.t[i] == pytest.approx(k * 0.1)
        xb, yb, tb, xj, yj, tj = traj.q[i]
        want = rotate(verts, xj, yj, tj)
        jack = np.column_stack([f["data"][jack_i]["x"], f["data"][jack_i]["y"]])
        np.testing.assert_allclose(jack[:-1], want, atol=1e-3)   # rounded to 1e-4 of the view
        np.testing.assert_allclose(jack[-1], want[0], atol=1e-3)  # closed
        h = polygon_scene.params()["L"] + polygon_scene.params()["w_box"]
        outer = np.column_stack([f["data"][outer_i]["x"], f["data"][outer_i]["y"]])
        np.testing.assert_allclose(outer[:-1], rotate(h * np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]]),
                                                      xb, yb, tb), atol=1e-3)
        assert xr0 <= outer[:, 0].min() and outer[:, 0].max() <= xr1
        assert yr0 <= outer[:, 1].min() and outer[:, 1].max() <= yr1
        # impulses in (previous frame, this frame] are on this frame, at the jack's vertex
        hit = f["data"][hit_i]
        expected = {0.6: ["bottom:2", "left:4"], 1.2: ["top:0"]}.get(round(f["t"], 6), [])
        assert sorted(s for s in hit["text"] if s) == expected, f["t"]
        for name, x, y in zip(hit["text"], hit["x"], hit["y"]):
            if name:
                v = int(name.partition(":")[2])
                np.testing.assert_allclose([x, y], want[v], atol=1e-3)
        if not expected:
            assert hit["x"] == [None]          # never empty: plotly would keep old markers
        resting = [s for s in f["data"][rest_i]["text"] if s]
        assert resting == (["bottom:1"] if 2.0 <= f["t"] < 2.5 else [])


def test_animation_of_a_cross_with_ground(tmp_path):
    scene = jackbox.load_scene("drop").with_overrides({"jack.shape": "cross"})
    traj = synthetic(scene, impacts=[(1.0, "ground:2")])
    traj.scene = traj.scene.replace('shape = "square"', 'shape = "cross"')
    fig = animate.figure(traj)
    names = [d["name"] for d in fig["data"]]
    assert names[0] == "ground" and "at rest" not in names
    assert fig["data"][0]["y"] == [0.0, 0.0]
    assert fig["layout"]["yaxis"]["range"][0] < 0.0
    jack = fig["data"][names.index("jack")]
    assert len(jack["x"]) == 5 and jack["marker"]["size"] == [10, 10, 0, 10, 10]
    frame = next(f for f in fig["frames"] if f["t"] == pytest.approx(1.0))
    hit = frame["data"][names.index("impulse") - 1]         # frames skip the static ground
    assert hit["text"] == ["ground:2"]
    i = int(np.argmin(np.abs(traj.t - 1.0)))
    xb, yb, tb = traj.q[i, :3]
    corner = rotate([[-1.1, -1.1]], xb, yb, tb)[0]          # corner 2 is (-, -), L + w = 1.1
    np.testing.assert_allclose([hit["x"][0], hit["y"][0]], corner, atol=1e-3)


def test_animation_page_is_offline_and_small(polygon_scene, tmp_path):
    traj = synthetic(polygon_scene, t_end=20.0)
    path = animate.write_animation(traj, tmp_path / "a.html")
    html = path.read_text(encoding="utf-8")
    assert not re.search(r"<script[^>]+src=", html)            # nothing loaded from anywhere
    assert not re.search(r"<link[^>]+href=", html)
    assert "Plotly.newPlot" in html and "Plotly.addFrames" in html
    assert "<title>jackbox: hand (naive)</title>" in html
    js = len(_plotlyjs())
    assert js in range(3_000_000, 6_000_000)
    # 20 s at 25 frames/s: 501 frames in well under 1 MB beside plotly.js
    assert len(html.encode()) - js < 1_000_000
    assert len(page_frames(html)) == 501

    beside = animate.write_animation(traj, tmp_path / "b" / "a.html", plotlyjs="beside")
    small = beside.read_text(encoding="utf-8")
    assert '<script charset="utf-8" src="plotly.min.js"></script>' in small
    assert len(small.encode()) < 1_000_000
    assert (beside.parent / "plotly.min.js").stat().st_size == js


def page_frames(html: str) -> list:
    """The frames a page hands to Plotly.addFrames."""
    return json.loads(re.search(r"Plotly\.addFrames\('[^']+', (\[.*\])\);", html).group(1))


def _plotlyjs() -> bytes:
    from plotly.offline import get_plotlyjs

    return get_plotlyjs().encode()


# --- the commands ----------------------------------------------------------------------------

def test_run_writes_trajectory_timeseries_and_animation(capsys, tmp_path):
    status, out, err = run_cli(capsys, "run", "drop", "--t-end", "1", "--out", "out")
    assert status == 0, err
    folder = tmp_path / "out"
    files = {"trajectory.npz", "timeseries.png", "animation.html", "plotly.min.js"}
    assert {p.name for p in folder.iterdir()} == files
    for name in files:
        assert f"wrote      {folder.relative_to(tmp_path) / name}" in out
    assert_not_blank(read_png(folder / "timeseries.png"))
    html = (folder / "animation.html").read_text(encoding="utf-8")
    assert '"name":"ground"' in html and '"name":"jack"' in html and '"name":"box inner"' in html
    assert not list(folder.glob(".*"))                       # no temporary files left


def test_runs_share_one_copy_of_plotly_beside_their_pages(capsys, tmp_path):
    # Every run wrote a 5 MB page, most of it plotly.js. Now the page loads plotly.min.js
    # from its folder (offline still), written there once: a second run into the folder
    # keeps the same file (not rewritten), and its page stays small. --plotlyjs inline
    # writes the self-contained page where it is wanted.
    js = _plotlyjs()
    assert run_cli(capsys, "run", "drop", "--t-end", "0.5", "--out", "r", "-q")[0] == 0
    lib = tmp_path / "r" / "plotly.min.js"
    assert lib.read_bytes() == js
    stamp = lib.stat().st_mtime_ns, lib.stat().st_ino
    assert run_cli(capsys, "run", "drop", "--t-end", "0.5", "--out", "r", "-q", "--set", "restitution=0.3")[0] == 0
    assert (lib.stat().st_mtime_ns, lib.stat().st_ino) == stamp
    page = (tmp_path / "r" / "animation.html").read_text(encoding="utf-8")
    assert '<script charset="utf-8" src="plotly.min.js"></script>' in page
    assert len(page) < len(js) / 4
    assert run_cli(capsys, "run", "drop", "--t-end", "0.5", "--out", "i", "-q", "--plotlyjs", "inline")[0] == 0
    assert not (tmp_path / "i" / "plotly.min.js").exists()
    assert (tmp_path / "i" / "animation.html").stat().st_size > len(js)
    # an inline page into the first folder: the library no page loads any more goes with the old pictures
    assert run_cli(capsys, "run", "drop", "--t-end", "0.5", "--out", "r", "-q", "--plotlyjs", "inline")[0] == 0
    assert not lib.exists()


def test_run_method_default_and_choice(capsys, tmp_path):
    default = inspect.signature(api.simulate).parameters["method"].default
    status, _, err = run_cli(capsys, "run", "drop", "--t-end", "0.1", "--out", "a", "-q", "--no-plots")
    assert status == 0, err
    assert jackbox.Trajectory.load(tmp_path / "a" / "trajectory.npz").meta["method"] == default
    for method in api.METHODS:
        status, _, err = run_cli(capsys, "run", "drop", "--t-end", "0.1", "--out", method, "-q",
                                 "--no-plots", "--method", method)
        assert status == 0, err
        assert jackbox.Trajectory.load(tmp_path / method / "trajectory.npz").meta["method"] == method
    status, out, err = run_cli(capsys, "run", "--help")
    assert "--method {" + ",".join(api.METHODS) + "}" in out
    assert_one_line_error(*run_cli(capsys, "run", "drop", "--method", "nope"), word="--method")


def test_compare_drop_elastic_keeps_bouncing_inelastic_settles(capsys, tmp_path):
    status, out, err = run_cli(capsys, "compare", "drop", "--restitution", "1.0", "0.6", "--out", "cmp")
    assert status == 0, err
    img = read_png(tmp_path / "cmp" / "comparison.png")
    assert img.shape[:2] == (950, 1400)
    assert_not_blank(img)
    rows = {line.split()[0]: line for line in out.splitlines() if line.split()[:1] in (["1"], ["0.6"])}
    assert "did not settle" in rows["1"]
    assert re.search(r"at t = [0-9.]+ s", rows["0.6"]), out
    assert "wrote      cmp/comparison.png" in out
    assert "e_ground" in out                                 # says what --restitution sets


def test_compare_quiet_prints_nothing(capsys, tmp_path):
    status, out, err = run_cli(capsys, "compare", "drop", "-e", "1", "0", "--t-end", "0.5", "-q",
                               "--out", "q")
    assert status == 0 and out == "" and err == "", (out, err)
    assert (tmp_path / "q" / "comparison.png").is_file()


@pytest.mark.parametrize("values, word", [
    (["1.5", "0.6"], "must be in [0, 1]"),
    (["-1", "0.6"], "must be in [0, 1]"),
    (["nan", "0.6"], "must be in [0, 1]"),
    (["abc", "0.6"], "not a number"),
    (["0.6"], "two or more"),
    (["0.6", "0.6"], "twice"),
])
def test_compare_bad_restitution(capsys, tmp_path, values, word):
    folder = tmp_path / "cmp"
    folder.mkdir()
    (folder / "comparison.png").write_bytes(b"an earlier figure")
    result = run_cli(capsys, "compare", "drop", "--restitution", *values, "--out", str(folder))
    assert_one_line_error(*result, word=word)
    assert [p.name for p in folder.iterdir()] == ["comparison.png"]
    assert (folder / "comparison.png").read_bytes() == b"an earlier figure"


def test_compare_unknown_scene(capsys):
    assert_one_line_error(*run_cli(capsys, "compare", "nosuch", "-e", "1", "0.5"), word="no such")


@pytest.fixture(scope="module")
def saved_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("saved") / "run"
    assert main(["run", "drop", "--t-end", "1.5", "--out", str(folder), "-q", "--no-plots",
                 "--set", "restitution=0.6"]) == 0
    return folder / "trajectory.npz"


def test_animate_and_plot_a_saved_trajectory(capsys, tmp_path, saved_run):
    status, out, err = run_cli(capsys, "animate", str(saved_run), "--fps", "10", "--speed", "0.5",
                               "--out", "slow.html")
    assert status == 0, err
    html = (tmp_path / "slow.html").read_text(encoding="utf-8")
    assert len(page_frames(html)) == 31                                  # 1.5 s at half speed, 10 frames/s
    assert '"duration":100.0' in html
    assert "0.5x real time" in html
    status, out, err = run_cli(capsys, "plot", str(saved_run), "--out", "ts.png")
    assert status == 0, err
    assert_not_blank(read_png(tmp_path / "ts.png"))
    # default names: beside a run's trajectory.npz
    status, out, err = run_cli(capsys, "animate", str(saved_run), "-q")
    assert status == 0 and out == "", err
    assert (saved_run.parent / "animation.html").is_file()
    copy = tmp_path / "mine.npz"
    copy.write_bytes(saved_run.read_bytes())
    status, out, err = run_cli(capsys, "plot", str(copy))
    assert status == 0 and (tmp_path / "mine.png").is_file()


@pytest.mark.parametrize("make, word", [
    (lambda d: d / "nowhere.npz", "no such file"),
    (lambda d: (d / "bad.npz").write_bytes(b"PK\x03\x04 not a zip") and d / "bad.npz", "not a trajectory"),
    # a text file: NumPy would call it a pickle and advise loading it unsafely
    (lambda d: (d / "notes.txt").write_text("root:x:0:0\n") and d / "notes.txt", "not a NumPy .npz file"),
    (lambda d: d, "is a folder"),
])
@pytest.mark.parametrize("command, out_name", [("animate", "page.html"), ("plot", "page.png")])
def test_animate_and_plot_refuse_bad_input(capsys, tmp_path, make, word, command, out_name):
    source = make(tmp_path)
    old = tmp_path / out_name
    old.write_bytes(b"an earlier picture")
    result = run_cli(capsys, command, str(source), "--out", str(old))
    assert_one_line_error(*result, word=word)
    assert old.read_bytes() == b"an earlier picture"


@pytest.mark.parametrize("option, value", [("--fps", "0"), ("--speed", "-1"), ("--max-frames", "1"),
                                           ("--trail", "x"), ("--plotlyjs", "cdn")])
def test_animate_bad_options(capsys, saved_run, option, value):
    assert_one_line_error(*run_cli(capsys, "animate", str(saved_run), option, value), word=option)


def test_help_of_the_new_commands(capsys):
    status, out, _ = run_cli(capsys, "--help")
    for command in ("compare", "animate", "plot"):
        assert command in out
    for command, options in (("compare", ["--restitution", "--method", "--out", "--quiet", "e_ground",
                                          "settled"]),
                             ("animate", ["--fps", "--speed", "--max-frames", "--trail", "--plotlyjs"]),
                             ("plot", ["--out"]),
                             ("run", ["--no-plots", "timeseries.png", "animation.html"])):
        status, out, _ = run_cli(capsys, command, "--help")
        assert status == 0
        for option in options:
            assert option in out, (command, option)


def test_geometry_of_a_saved_run_follows_its_overrides_not_the_file(tmp_path):
    # the file has a cross jack; --set jack.shape=square changes the run's shape,
    # and the saved file must draw a square. (Both structures are the tests'
    # weightless square and cross, compiled for other tests: nothing new compiles.)
    path = write_scene(tmp_path, FREE_FLOAT.replace('shape = "square"', 'shape = "cross"'), "crossed.toml")
    scene = jackbox.load_scene(path, {"jack.shape": "square"})
    jackbox.simulate(scene, t_end=0.01).save(tmp_path / "run.npz")
    geometry = Geometry.from_trajectory(jackbox.Trajectory.load(tmp_path / "run.npz"))
    assert geometry.shape == "square"
    assert Geometry.from_trajectory(jackbox.simulate(path, t_end=0.01)).shape == "cross"
