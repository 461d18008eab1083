"""The benchmark scripts run end to end (their --quick modes) and their figures are sane.

Timings are never asserted (STYLE.md): only that the files are written and that
the measured convergence orders are those of the methods.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_workprecision_quick_mode(tmp_path):
    subprocess.run([sys.executable, str(ROOT / "benchmarks" / "workprecision.py"), "--quick", "--out", str(tmp_path)],
                   check=True, cwd=ROOT, capture_output=True, text=True, timeout=300)
    for ext in ("csv", "json", "md", "png"):
        assert (tmp_path / f"workprecision.{ext}").stat().st_size > 0, ext
    assert (tmp_path / "workprecision.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    result = json.loads((tmp_path / "workprecision.json").read_text())
    (scene,) = result["scenes"]
    # the exact method is RK4 with located impacts: order 4; the naive one is first order at impacts
    # (its errors scatter with where the impacts fall in a step, hence the wide band)
    exact, naive = scene["orders"]["exact"], scene["orders"]["naive"]
    assert len(exact["dt"]) >= 3 and 3.0 < exact["order"] < 5.0, exact
    assert len(naive["dt"]) >= 3 and 0.5 < naive["order"] < 1.6, naive
    # the reference agrees with scipy's event-located solution far below the errors fitted
    assert scene["same_scipy"] and scene["diff_scipy"] < 1e-9
    assert scene["floor"] * 30 <= min(exact["error"])
    md = (tmp_path / "workprecision.md").read_text()
    assert "## Observed order" in md and "## Speed-up of the exact kernel at equal error" in md
