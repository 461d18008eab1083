"""Regenerate the README's pictures: ``python docs/images/make.py`` (needs chromium).

* ``timeseries.png``: ``jackbox run drop --set restitution=0.6``'s time series;
* ``comparison.png``: ``jackbox compare drop --restitution 1.0 0.6``;
* ``animation_frame.png``: a frame of ``jackbox run shaken``'s animation with an
  impulse on it, as headless Chromium shows it (driven by ``tests/chromium.py``);
* ``chaos.png``: ``jackbox chaos shaken --n 2000 --perturb theta_jack=1e-3
  --perturb x_jack_dot=1e-2``.
"""

from __future__ import annotations

import base64
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent.parent))

import jackbox  # noqa: E402 (after the path set-up above)
from jackbox import animate, ensemble, plots  # noqa: E402
from tests.chromium import Browser  # noqa: E402


def main() -> None:
    study = ensemble.chaos("shaken", 2000, perturb={"theta_jack": 1e-3, "x_jack_dot": 1e-2})
    plots.write_chaos(study, HERE / "chaos.png")
    runs = {e: jackbox.simulate("drop", params={"e": e, "e_ground": e}) for e in (1.0, 0.6)}
    plots.write_timeseries(runs[0.6], HERE / "timeseries.png")
    plots.write_comparison(list(runs.values()), ["e = 1", "e = 0.6"], HERE / "comparison.png")

    traj = jackbox.simulate("shaken")
    fig = animate.figure(traj)
    names = [d["name"] for d in fig["data"]]
    hit = names.index("impulse") - (len(names) - len(fig["frames"][0]["data"]))
    frame = next(f for f in fig["frames"] if f["t"] > 4.0 and f["data"][hit]["x"] != [None])
    with tempfile.TemporaryDirectory() as tmp, Browser() as browser:
        page = browser.open(animate.write_animation(traj, Path(tmp) / "animation.html"))
        gd = f"document.getElementById('{animate.DIV_ID}')"
        page.wait_for(f"{gd} && {gd}._transitionData && {gd}._transitionData._frames.length")
        page.eval(f"Plotly.animate({gd}, ['{frame['name']}'], {{frame: {{duration: 0, redraw: false}}, "
                  "transition: {duration: 0}, mode: 'immediate'}).then(() => true)")
        time.sleep(0.3)
        box = page.eval(f"(() => {{ const r = {gd}.getBoundingClientRect(); "
                        "return {x: r.x, y: r.y, width: r.width, height: r.height}; })()")
        png = page.send("Page.captureScreenshot", {"format": "png", "clip": box | {"scale": 1}})["data"]
        (HERE / "animation_frame.png").write_bytes(base64.b64decode(png))
        assert page.errors == [], page.errors
    print(f"wrote chaos.png, timeseries.png, comparison.png, animation_frame.png (t = {frame['t']:.3f} s) "
          f"in {HERE}")


if __name__ == "__main__":
    main()
