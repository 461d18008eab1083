"""The hand-written C ceiling (benchmarks/ceiling/) integrates the same equations as generated/shaken.py.

Only numbers are checked here; its speed is measured by benchmarks/ceiling.py, never asserted.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import generated.shaken as m

ROOT = Path(__file__).resolve().parent.parent


def load_ceiling():
    spec = importlib.util.spec_from_file_location("ceiling", ROOT / "benchmarks" / "ceiling.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def rk4_reference(q, qd, p, dt, steps):
    """Classical RK4 with the generated accel, plain NumPy; -> (q, qd, min over steps of phi)."""
    q, qd = q.astype(float), qd.astype(float)
    a1, a2, a3, a4 = (np.empty(m.N_DOF) for _ in range(4))
    gap = np.empty(m.N_CONTACT)
    min_gap = np.inf
    for i in range(steps):
        t, h2 = i * dt, 0.5 * dt
        m.accel(t, q, qd, p, a1)
        v2 = qd + h2 * a1
        m.accel(t + h2, q + h2 * qd, v2, p, a2)
        v3 = qd + h2 * a2
        m.accel(t + h2, q + h2 * v2, v3, p, a3)
        vs = qd + dt * a3
        m.accel(t + dt, q + dt * v3, vs, p, a4)
        h6 = dt / 6.0
        q = q + h6 * (qd + 2.0 * v2 + 2.0 * v3 + vs)
        qd = qd + h6 * (a1 + 2.0 * a2 + 2.0 * a3 + a4)
        m.phi(t + dt, q, p, gap)
        min_gap = min(min_gap, gap.min())
    return q, qd, min_gap


def test_c_loop_matches_generated_equations(tmp_path):
    ceiling = load_ceiling()
    try:
        exe = ceiling.compile_c(tmp_path)
    except ceiling.NoCompilerError as exc:
        pytest.skip(str(exc))
    p, q0, qd0, _ = ceiling.shaken_start()
    steps, dt = 200, 1e-3          # 0.2 s: the jack is still in flight (checked below)
    out = ceiling.run_c(exe, steps, dt, p, q0, qd0)
    q, qd, min_gap = rk4_reference(q0, qd0, p, dt, steps)

    assert out["steps"] == steps
    assert min_gap > 0 and out["min_gap"] > 0, "the jack touched a wall: the window is not free flight"
    # Same tableau, same operation order, no FMA contraction: the two agree to round-off.
    # Entries that stay 0 (y_box and its rate) get an absolute floor of 1e-12 of the state's size.
    scale = np.abs(np.concatenate([q, qd])).max()
    for name, c, ref in (("q", out["q"], q), ("qd", out["qd"], qd)):
        np.testing.assert_allclose(c, ref, rtol=1e-12, atol=1e-12 * scale,
                                   err_msg=f"{name} after {steps} steps of dt={dt} (t={steps * dt})")
    # The gaps are written by hand in C, not copied from the cse'd text: a few ulp of L apart.
    L = p[m.PARAM_NAMES.index("L")]
    assert abs(out["min_gap"] - min_gap) <= 1e-12 * L, (out["min_gap"], min_gap)
