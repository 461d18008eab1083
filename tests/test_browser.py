"""The animation page in a real browser: headless Chromium, driven over the DevTools
protocol on a pipe (tests/chromium.py), with no network.

One browser serves the module; each page is the animation of a short run of a
built-in scene. Checked: the page loads offline with no console error, the figure
has the box, jack and ground traces with equal axes, Play advances the frames (no
faster than real time) and Pause stops them, and a screenshot shows the box and
the jack. Chromium is Debian's ``chromium`` (``.ci/run`` installs it); these tests
skip only when it is not installed.
"""

from __future__ import annotations

import io
import time

import numpy as np
import pytest
from matplotlib import image as mpimg

import jackbox
from jackbox import animate

from .chromium import Browser, find_chromium

GD = f"document.getElementById('{animate.DIV_ID}')"
READY = f"{GD} && {GD}._transitionData && {GD}._transitionData._frames.length"


@pytest.fixture(scope="module")
def browser():
    if find_chromium() is None:
        pytest.skip("chromium is not installed (apt-get install chromium; .ci/run installs it)")
    with Browser() as b:
        yield b


def _page(browser, traj, path):
    fig = animate.figure(traj)
    animate.write_animation(traj, path)
    page = browser.open(path)
    page.wait_for(READY)
    return page, fig


@pytest.fixture(scope="module")
def drop(browser, tmp_path_factory):
    """drop with e = 0.6 for 2 s: ground, a square jack, impulses."""
    traj = jackbox.simulate("drop", t_end=2.0, params={"e": 0.6, "e_ground": 0.6})
    page, fig = _page(browser, traj, tmp_path_factory.mktemp("drop") / "animation.html")
    yield page, fig, traj
    page.close()


def test_page_loads_offline_without_errors(drop):
    page, fig, _ = drop
    assert page.errors == []
    assert page.failed == []
    assert page.requests and all(url.startswith(("file:", "data:")) for url in page.requests), page.requests
    assert page.eval(READY) == len(fig["frames"])


def test_figure_has_box_jack_and_ground(drop):
    page, fig, _ = drop
    names = page.eval(f"{GD}.data.map(d => d.name)")
    assert names == [d["name"] for d in fig["data"]]
    assert {"box outer", "box inner", "jack", "ground", "impulse"} <= set(names)
    # every trace is drawn, and the axes keep the box square
    assert page.eval(f"{GD}.querySelectorAll('.scatterlayer .trace').length") == len(names)
    assert page.eval(f"{GD}._fullLayout.yaxis.scaleanchor") == "x"
    ratio = page.eval(f"""(() => {{ const l = {GD}._fullLayout;
        return (l.xaxis._length / (l.xaxis.range[1] - l.xaxis.range[0]))
             / (l.yaxis._length / (l.yaxis.range[1] - l.yaxis.range[0])); }})()""")
    assert ratio == pytest.approx(1.0, rel=0.01)          # pixels per metre, both ways
    box = page.eval(f"{GD}.querySelector('.scatterlayer .trace path.js-line').getBBox().width")
    assert box > 100                                       # the box is drawn at a visible size


def _button(page, label):
    return page.eval(f"""(() => {{
        const b = [...document.querySelectorAll('.updatemenu-button')].find(e => e.textContent === '{label}');
        const r = b.getBoundingClientRect(); return [r.x + r.width / 2, r.y + r.height / 2]; }})()""")


def test_play_advances_and_pause_stops(drop):
    page, _fig, _ = drop
    active = f"{GD}._fullLayout.sliders[0].active"
    jack = f"JSON.stringify(Array.from({GD}.data.find(d => d.name === 'jack').x))"
    assert page.eval(active) == 0
    before = page.eval(jack)
    page.click(*_button(page, "Play"))
    start = time.monotonic()
    page.wait_for(f"{active} >= 5", timeout=10)
    advanced, elapsed = page.eval(active), time.monotonic() - start
    assert page.eval(jack) != before                       # the jack moved
    label = page.eval(f"[...{GD}.querySelectorAll('.slider-container text')]"
                      ".map(e => e.textContent).find(s => s.startsWith('t = '))")
    assert label.startswith("t = ") and label != "t = 0.000 s"
    # real time: frames every 1/25 s at most (a busy machine may show them later, never sooner)
    fps = animate.FPS
    assert advanced <= fps * elapsed + 2
    page.click(*_button(page, "Pause"))
    time.sleep(0.2)
    paused = page.eval(active)
    time.sleep(0.4)
    assert page.eval(active) == paused
    assert page.errors == []


def test_screenshot_shows_the_box_and_the_jack(drop):
    page, _, _ = drop
    img = mpimg.imread(io.BytesIO(page.screenshot()), format="png")[..., :3]
    assert img.shape[0] > 500 and img.shape[1] > 500
    assert img.std() > 0.05
    pixels = (img.reshape(-1, 3) * 255).round().astype(int)

    def count(hex_color, tol=12):
        rgb = np.array([int(hex_color[i:i + 2], 16) for i in (1, 3, 5)])
        return int((np.abs(pixels - rgb).max(axis=1) <= tol).sum())

    assert count(animate.BOX_FILL) > 5_000                  # the walls
    assert count("#8ac993") > 1_000                         # the jack: its green fill, 55% over white


def test_cross_jack_without_ground(browser, tmp_path):
    traj = jackbox.simulate("shaken", t_end=1.5)
    page, _fig = _page(browser, traj, tmp_path / "animation.html")
    try:
        assert page.errors == []
        names = page.eval(f"{GD}.data.map(d => d.name)")
        assert "ground" not in names and "jack" in names
        x = page.eval(f"Array.from({GD}.data.find(d => d.name === 'jack').x)")
        assert len(x) == 5                                  # the two arms in one stroke
    finally:
        page.close()


def test_a_page_with_plotly_beside_it_loads_offline(browser, tmp_path):
    # jackbox run's default page: plotly.min.js loaded from the page's folder, no network
    traj = jackbox.simulate("drop", t_end=0.5)
    path = animate.write_animation(traj, tmp_path / "animation.html", plotlyjs="beside")
    page = browser.open(path)
    try:
        page.wait_for(READY)
        assert page.errors == [] and page.failed == []
        assert any(url.endswith("/plotly.min.js") for url in page.requests), page.requests
        assert all(url.startswith(("file:", "data:")) for url in page.requests), page.requests
        assert page.eval(READY) == len(animate.figure(traj)["frames"])
    finally:
        page.close()
