"""Honest member results: an ensemble member that stops before t_end has no final
state (NaN), no samples past where it stopped (NaN), its time reached kept apart,
and every summary counts it; the CLI exits 3.

The members that stop here turn non-finite: shaken with its shaking period T =
1e-310 s puts sin(2 pi t / T) at sin(inf) = NaN in its first steps. (They used
to be the stall of the exact method, a box thrown spinning into a corner; its
fallback now finishes those.)
"""

from __future__ import annotations

import re

import numpy as np
import pytest

import jackbox
from jackbox.ensemble import chaos, ensemble
from jackbox.engine import DONE, NONFINITE

from .conftest import run_cli

T_END = 1.2
SAMPLES = [0.5, 1.15]
#: shaken's period from 1e-310 s (non-finite at once) to 3 s (completes)
SWEEP = {"T": (1e-310, 3.0)}


@pytest.fixture(scope="module")
def spun():
    scene = jackbox.load_scene("shaken")
    return scene, ensemble(scene, 3, sweep=SWEEP, t_end=T_END, samples=SAMPLES)


def test_a_member_that_stops_early_has_no_final_state_and_no_unreached_samples(spun):
    scene, ens = spun
    lost = ~ens.completed
    assert lost.any() and ens.completed.any(), ens.status     # a mix: the check below bites both ways
    assert set(ens.status[lost]) == {NONFINITE} and set(ens.status[~lost]) == {DONE}
    assert np.all(np.isnan(ens.q[lost])) and np.all(np.isnan(ens.qd[lost])) and np.all(np.isnan(ens.energy[lost]))
    assert np.all(np.isfinite(ens.q[~lost])) and np.all(np.isfinite(ens.energy[~lost]))
    assert np.all(ens.t_reached[lost] < T_END) and np.all(ens.t_reached[~lost] == pytest.approx(T_END))
    reached = ens.sample_times[None, :] <= ens.t_reached[:, None]
    assert np.all(np.isfinite(ens.samples_q[reached])) and np.all(np.isnan(ens.samples_q[~reached]))
    assert (~reached).any()
    # what a member did reach is the run's own: the same numbers as jackbox.simulate up to there
    i = int(np.flatnonzero(lost)[0])
    with pytest.raises(jackbox.NonFiniteStateError, match=re.escape(f"t = {ens.t_reached[i]:.6g} s")):
        ens.trajectory(i)
    j = int(np.flatnonzero(~lost)[0])
    np.testing.assert_array_equal(ens.trajectory(j).q[-1], ens.q[j])
    # a mean that forgets to filter is NaN, not a number that mixes lost members in
    assert np.isnan(ens.q[:, 1].mean()) and np.isfinite(ens.q[ens.completed, 1].mean())


def test_summaries_say_how_many_members_did_not_complete(spun):
    _, ens = spun
    k = int((~ens.completed).sum())
    done = ens.impacts[ens.completed]       # a stopped member's count is partial: left out
    assert (f"impulses per member (completed): median {np.median(done):.0f}, "
            f"range {done.min()}..{done.max()}") in ens.summary()
    assert f"NOT COMPLETED: {k} of 3 members ({k} non-finite)" in ens.summary()
    assert f"NOT COMPLETED: {k} of 3 members ({k} non-finite)" in repr(ens)
    assert repr(ens).startswith("<Ensemble shaken: 3 members over 1.2 s, ")


def test_the_cli_exits_3_when_members_did_not_complete(spun, tmp_path, capsys):
    _, ens = spun
    status, out, err = run_cli(capsys, "ensemble", "shaken", "--n", "3", "--sweep", "T=1e-310:3.0",
                               "--t-end", str(T_END), "--samples", "0.5", "1.15", "--out", str(tmp_path), "-q")
    k = int((~ens.completed).sum())
    assert status == 3
    assert err.strip().splitlines() == [f"jackbox: {k} of 3 members did not complete (exit status 3)"]
    with np.load(tmp_path / "ensemble.npz") as saved:
        np.testing.assert_array_equal(saved["q"], ens.q)              # NaN where the API has NaN
        np.testing.assert_array_equal(saved["samples_q"], ens.samples_q)
        np.testing.assert_array_equal(saved["status"], ens.status)
    status, out, _ = run_cli(capsys, "--help")
    assert "exit status:" in out and "3    ensemble or chaos: some members did not complete" in out


def test_a_chaos_study_counts_its_lost_members():
    # shaken with a period that makes its forces NaN in the first steps
    scene = jackbox.load_scene("shaken", {"T": 1e-310})
    study = chaos(scene, 2, t_end=1.0, renorm=0.1)
    assert not study.completed.any()
    assert np.all(np.isnan(study.ftle))
    assert "NOT COMPLETED: 2 of 2 members (2 non-finite)" in study.summary()
    assert "NOT COMPLETED: 2 of 2 members (2 non-finite)" in repr(study)


def test_threads_take_members_in_an_order_that_spreads_a_sweep():
    # a sweep's members are ordered by the swept value (plastic at one end of a restitution sweep,
    # some 20 times slower a step): Numba's threads take equal runs of consecutive iterations, so
    # each iteration runs member i * s % n, a permutation under which every run of consecutive
    # iterations holds about its share of each end (two threads: 1.94x one, was 1.19x)
    from jackbox.engine.members import spread_stride

    f = spread_stride.py_func          # (the compiled one has no Python wrapper)
    for n in (0, 1, 2, 7, 31, 32, 1000, 1024, 62500, 10**6):
        s = f(n)
        order = np.arange(n, dtype=np.int64) * s % n
        assert np.array_equal(np.sort(order), np.arange(n)), n
        for threads in (2, 3, 4, 16):
            if n >= 32 * threads:
                for run in np.array_split(order, threads):
                    low = np.mean(run < n // 2)
                    assert 0.45 <= low <= 0.55, (n, threads, low)
