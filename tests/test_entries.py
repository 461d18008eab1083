"""One set of rules at every entry: a value the scene format refuses in a file is
refused the same way through ``--set``, ``simulate(params=...)``, an ensemble's
``sweep`` and the CLI, before anything runs, in one line that names the value,
where it came from and the allowed range (docs/scenes.md, "What is refused").

Each row below is one rule of the format: the parameter slot, the scene key it
comes from, a value the rule refuses and the words of the refusal.
"""

from __future__ import annotations

import math
import re

import pytest

import jackbox
from jackbox.ensemble import chaos, ensemble
from jackbox.errors import JackboxError, SceneError, SimulationError

from .conftest import run_cli

#: (slot, scene key, a refused value, the refusal's words); drop has every slot but a polygon's
RULES = [
    ("m_box", "box.mass", 0.0, "must be > 0"),
    ("m_box", "box.mass", -2.0, "must be > 0"),
    ("J_box", "box.inertia", 0.0, "must be > 0"),
    ("L", "box.inner_half_width", -1.0, "must be > 0"),
    ("w_box", "box.wall_thickness", 0.0, "must be > 0"),
    ("m_jack", "jack.mass", 0.0, "must be > 0"),
    ("J_jack", "jack.inertia", -1.0, "must be > 0"),
    ("a_jack", "jack.half_size", 0.0, "must be > 0"),
    ("g", "world.gravity", -9.81, "must be >= 0"),
    ("e", "impact.restitution", 2.0, "must be in [0, 1]"),
    ("e", "impact.restitution", -0.1, "must be in [0, 1]"),
    ("e_ground", "impact.ground_restitution", 1.5, "must be in [0, 1]"),
    ("e", "impact.restitution", math.nan, "must be finite"),
    ("m_jack", "jack.mass", math.inf, "must be finite"),
]
IDS = [f"{slot}={value}" for slot, _, value, _ in RULES]


@pytest.mark.parametrize("slot, key, value, words", RULES, ids=IDS)
def test_the_scene_file_refuses_it(slot, key, value, words):
    # the reference: the scene loader's own rule (a --set override is a file edit)
    with pytest.raises(SceneError, match=re.escape(f"{key}: {words}")):
        jackbox.load_scene("drop", {key: value})


@pytest.mark.parametrize("slot, key, value, words", RULES, ids=IDS)
def test_simulate_params_refuse_it_before_running(slot, key, value, words, monkeypatch):
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_kernel)
    with pytest.raises(SceneError) as info:
        jackbox.simulate("drop", t_end=0.01, params={slot: value})
    message = str(info.value)
    assert message.startswith("simulate(params=...): ") and key in message and words in message, message
    assert "\n" not in message


@pytest.mark.parametrize("slot, key, value, words", RULES, ids=IDS)
def test_an_ensemble_sweep_or_params_refuse_it_before_running(slot, key, value, words, monkeypatch):
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_kernel)
    good = jackbox.load_scene("drop").params()[slot]
    with pytest.raises(SceneError, match="^" + re.escape(f"sweep {slot}: {slot} ({key}): {words}")):
        ensemble("drop", 4, t_end=0.01, sweep={slot: (good, value)})
    with pytest.raises(SceneError, match="^" + re.escape(f"params: {slot} ({key}): {words}")):
        chaos("drop", 4, t_end=0.01, params={slot: value})


@pytest.mark.parametrize("slot, key, value, words", RULES, ids=IDS)
def test_the_cli_refuses_it_in_one_line(slot, key, value, words, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_kernel)
    status, out, err = run_cli(capsys, "run", "drop", "--set", f"{key}={value}", "-q", "--no-plots")
    assert status == 2 and out == ""
    (line,) = err.strip().splitlines()
    assert line.startswith("jackbox: error: ") and key in line and words in line, line
    status, out, err = run_cli(capsys, "ensemble", "drop", "--n", "4", "--t-end", "0.01",
                               "--sweep", f"{slot}={'1.0' if slot in ('e', 'e_ground') else '0.5'}:{value}")
    assert status == 2
    (line,) = err.strip().splitlines()
    assert line.startswith("jackbox: error: ") and words in line, line
    assert not any(tmp_path.iterdir())          # nothing written


@pytest.mark.parametrize("rng", ["ab", b"ab", {"a": 0.5, "b": 1.0}, 0.5, (0.5,), (0.1, 0.5, 1.0)])
def test_a_sweep_that_is_not_a_pair_of_ends_is_refused_as_such(rng, monkeypatch):
    # a two-letter string or a two-key dict unpacks into two "ends": refused for what it is, not for its letters
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_kernel)
    with pytest.raises(SimulationError) as info:
        ensemble("drop", 4, t_end=0.01, sweep={"restitution": rng})
    assert str(info.value) == f"sweep: restitution needs (first, last), got {rng!r}"


def test_a_size_that_puts_the_start_inside_a_wall_is_refused_everywhere(monkeypatch):
    # drop's jack (a = 0.25) sits in a box of L = 1: a half-size of 3 cannot be inside it
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_kernel)
    with pytest.raises(SceneError, match="initial.q: the start state penetrates"):
        jackbox.load_scene("drop", {"jack.half_size": 3.0})
    with pytest.raises(SceneError, match=r"^simulate\(params=...\): initial.q: the start state penetrates"):
        jackbox.simulate("drop", t_end=0.01, params={"a_jack": 3.0})
    with pytest.raises(SceneError, match=r"^simulate\(params=...\): initial.q: the start state penetrates"):
        jackbox.simulate("drop", t_end=0.01, params={"L": 0.3})


def test_a_prescribed_box_is_checked_where_its_parameters_put_it(prescribed_scene, monkeypatch):
    # the hand holds the box at y = amp sin(2 pi freq t): 0 at t = 0 whatever amp is,
    # but x = 0.1 sin(2 pi t) and theta = 0.2 sin(pi t) too; the tether's parameters are
    # free. A jack (start x 0.2) in a box shrunk to L = 0.3 penetrates.
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_kernel)
    with pytest.raises(SceneError, match="penetrates"):
        jackbox.simulate(prescribed_scene, t_end=0.01, params={"L": 0.3})


@pytest.mark.parametrize("kw, words", [
    ({"params": {"e": "0.5"}}, "must be a number, got a string"),
    ({"params": {"e": True}}, "must be a number, got a boolean"),
    ({"dt": 1e-300}, "steps (dt = 1e-300 s) is more than a run can take"),
    ({"t_end": 1e5, "dt": 1e-9}, "more than the"),          # 1e14 samples: memory, named
])
def test_simulate_refuses_bad_arguments_in_one_line(kw, words, monkeypatch):
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_kernel)
    with pytest.raises(JackboxError) as info:
        jackbox.simulate("drop", **({"t_end": 0.01} | kw))
    assert words in str(info.value), str(info.value)
    assert "\n" not in str(info.value)


def test_a_huge_record_every_keeps_the_first_and_last_state():
    traj = jackbox.simulate("drop", t_end=0.01, record_every=10**30)
    assert list(traj.t) == [0.0, 0.01]


@pytest.mark.parametrize("kw, words", [
    ({"renorm": math.nan}, "renorm must be a time"),
    ({"renorm": "0.1"}, "renorm must be a time"),
    ({"d0": math.inf}, "d0 must be a small positive number"),
    ({"perturb": {"theta_jack": math.nan}}, "perturb: the size for 'theta_jack'"),
    ({"perturb": {"theta_jack": "1e-3"}}, "perturb: the size for 'theta_jack'"),
])
def test_studies_refuse_bad_arguments_in_one_line(kw, words, monkeypatch):
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_kernel)
    with pytest.raises(SimulationError, match=words):
        chaos("drop", 4, t_end=0.5, **kw)


def _no_kernel(*args, **kwargs):
    raise AssertionError("a refused run must not reach the kernel")


@pytest.mark.parametrize("study, kw, words", [
    (ensemble, {"samples": [0.1 * k for k in range(1, 6)]}, "members with 5 samples each needs"),
    (chaos, {"renorm": 0.001}, "twin pairs logging 500 stretches each needs"),
])
def test_a_study_too_large_for_memory_is_refused_before_running(study, kw, words, monkeypatch):
    monkeypatch.setattr(jackbox.loader, "kernel_for", _no_kernel)
    monkeypatch.setattr(jackbox.api, "available_memory", lambda: 10**6)      # 1 MB free
    with pytest.raises(SimulationError, match=re.escape(words)):
        study("drop", 10**5, t_end=0.5, **kw)


def test_an_event_log_that_outgrows_memory_is_refused_in_one_line(monkeypatch):
    # The event log starts with room for LOG_SIZE events (at least 8 per contact: 128 here)
    # and doubles when full; a doubling that would not fit is refused with one line naming
    # the log's size, where the run got to and what to change (it was a bare MemoryError).
    # spring at e = 0.2 logs about 900 contact events in 10 s; "memory" here holds 200.
    monkeypatch.setattr(jackbox.api, "LOG_SIZE", 32)
    monkeypatch.setattr(jackbox.api, "available_memory", lambda: 200 * jackbox.api.EVENT_BYTES)
    scene = jackbox.load_scene("spring", {"restitution": 0.2})
    with pytest.raises(SimulationError, match=r"an event log of 256 contact events \(t = [0-9.]+ s of 10 s\) needs"):
        jackbox.simulate(scene, t_end=10.0, record_every=10**6)
    monkeypatch.setattr(jackbox.api, "available_memory", lambda: 10**9)
    assert len(jackbox.simulate(scene, t_end=10.0, record_every=10**6).impact_t) > 0   # with room, it runs
