"""Refusals of SCENES.md ("Validation") and the cases it explicitly allows.

Every test starts from one valid scene and breaks one thing, so that a refusal
can only come from that change. A refusal must be a SceneError whose single
message names the file, the key and the problem.
"""

from __future__ import annotations

import copy
import json
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

import jackbox
from jackbox import SceneError, load_scene

DELETE = object()

# A drop-like scene with a ground and a [params] table; box and jack both centred at
# y = 2, so the box's outer corners (half-size 1.1) are 0.9 above the ground and the
# jack (half-size 0.25) is 0.75 from every wall: far from any contact.
BASE = {
    "name": "probe",
    "description": "a valid scene that each test breaks in one place",
    "params": {"k": 2.0},
    "box": {"inner_half_width": 1.0, "wall_thickness": 0.1, "mass": 10.0, "motion": "free"},
    "jack": {"shape": "square", "half_size": 0.25, "mass": 1.0},
    "world": {"gravity": 9.81, "ground": True},
    "impact": {"restitution": 1.0},
    "initial": {"q": [0.0, 2.0, 0.0, 0.0, 2.0, 0.0], "qd": [0.0] * 6},
    "run": {"t_end": 1.0, "dt": 1e-3},
}
# A prescribed box must start where the jack fits: its y motion keeps it at 2 at t = 0.
PRESCRIBED = {"box.motion": "prescribed", "box.y": "2 + 0.1*sin(2*pi*t)"}
SQUARE = [[0.25, 0.25], [-0.25, 0.25], [-0.25, -0.25], [0.25, -0.25]]   # CCW, centred
#: relative round-off allowed in an inertia computed from a scene (see test_polygon_square_...)
INERTIA_REL = 1e-15


def polygon(vertices) -> dict:
    return {"jack.shape": "polygon", "jack.half_size": DELETE, "jack.vertices": vertices}


# --- writing scene files ----------------------------------------------------------------

def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)          # a JSON string is a valid TOML basic string
    if isinstance(v, list):
        return "[" + ", ".join(map(_toml_value, v)) + "]"
    raise TypeError(f"cannot write {v!r} as TOML")


def to_toml(data: dict) -> str:
    # bare keys must come before the first table, or TOML would put them in it
    lines = [f"{k} = {_toml_value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for section, table in data.items():
        if isinstance(table, dict):
            lines.append(f"\n[{section}]")
            lines += [f"{json.dumps(k)} = {_toml_value(v)}" for k, v in table.items()]
    return "\n".join(lines) + "\n"


def write_scene(tmp_path: Path, changes: dict | None = None, base: dict | str = BASE,
                filename: str = "scene.toml") -> Path:
    """Write `base` with `changes` applied: {"box.mass": -1} sets a key, DELETE removes it."""
    data = tomllib.loads(base) if isinstance(base, str) else copy.deepcopy(base)
    for dotted, value in (changes or {}).items():
        section, _, key = dotted.rpartition(".")
        table = data.setdefault(section, {}) if section else data
        if value is DELETE:
            table.pop(key, None)
        else:
            table[key] = value
    path = tmp_path / filename
    path.write_text(to_toml(data), encoding="utf-8")
    return path


def refused(path: Path, key: str, word: str, overrides=None) -> SceneError:
    """Assert that loading `path` is refused with one line naming the file, `key` and `word`."""
    with pytest.raises(SceneError) as info:
        load_scene(path, overrides)
    msg = str(info.value)
    assert str(path) in msg, msg
    assert key in msg, msg
    assert word.lower() in msg.lower(), msg
    assert "\n" not in msg, msg
    return info.value


# --- the helper itself ------------------------------------------------------------------

def test_to_toml_round_trips_the_base():
    assert tomllib.loads(to_toml(BASE)) == BASE


def test_base_scene_loads(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    assert scene.name == "probe"
    assert scene.params()["k"] == 2.0
    assert len(scene.constraint_names) == 4 * 4 + 4


def test_prescribed_base_loads(tmp_path):
    scene = load_scene(write_scene(tmp_path, PRESCRIBED))
    assert scene.prescribed
    assert scene.q0[1] == 2.0              # 2 + 0.1*sin(0): exact


# --- unknown keys -----------------------------------------------------------------------

@pytest.mark.parametrize("key, value", [("colour", "red"), ("materials", {"steel": 1.0})])
def test_unknown_top_level_key(tmp_path, key, value):
    refused(write_scene(tmp_path, {key: value}), key, "unknown")


@pytest.mark.parametrize("dotted", ["box.friction", "jack.halfsize", "world.wind",
                                    "impact.friction", "initial.q0", "run.steps"])
def test_unknown_key_in_section(tmp_path, dotted):
    refused(write_scene(tmp_path, {dotted: 1.0}), dotted, "unknown")


def test_force_on_unknown_coordinate(tmp_path):
    refused(write_scene(tmp_path, {"forces.z_box": "1"}), "forces.z_box", "unknown coordinate")


def test_missing_section_table_is_refused(tmp_path):
    refused(write_scene(tmp_path, {"box": 3}), "box", "table")


# --- wrong types ------------------------------------------------------------------------

@pytest.mark.parametrize("dotted, value, word", [
    ("box.mass", "10", "number"),                  # string where a number goes
    ("jack.half_size", "0.25", "number"),
    ("impact.restitution", True, "number"),        # a boolean is not a number
    ("params.k", "2", "number"),
    ("jack.shape", 3, "string"),                   # number where a string goes
    ("name", 7, "string"),
    ("box.motion", 1, "string"),
    ("description", 3, "string"),
    ("world.ground", "true", "true or false"),     # ground given as a string
    ("world.ground", 1, "true or false"),
])
def test_wrong_type(tmp_path, dotted, value, word):
    refused(write_scene(tmp_path, {dotted: value}), dotted, word)


@pytest.mark.parametrize("dotted, value", [("jack.shape", "triangle"), ("box.motion", "wobbly")])
def test_unknown_choice(tmp_path, dotted, value):
    refused(write_scene(tmp_path, {dotted: value}), dotted, "one of")


@pytest.mark.parametrize("value", [[0.0, 2.0, 0.0, 0.0, 2.0], [0.0] * 7, [], 0.0])
def test_initial_q_wrong_length(tmp_path, value):
    refused(write_scene(tmp_path, {"initial.q": value}), "initial.q", "6 numbers")


@pytest.mark.parametrize("value", [[0.0, 2.0, "0", 0.0, 2.0, 0.0], [0.0, 2.0, True, 0.0, 2.0, 0.0],
                                   [0.0, 2.0, math.nan, 0.0, 2.0, 0.0]])
def test_initial_q_non_number_entry(tmp_path, value):
    refused(write_scene(tmp_path, {"initial.q": value}), "initial.q[2]", "finite number")


def test_initial_qd_wrong_length(tmp_path):
    refused(write_scene(tmp_path, {"initial.qd": [0.0] * 3}), "initial.qd", "6 numbers")


# --- non-positive sizes and masses, ranges ------------------------------------------------

@pytest.mark.parametrize("value", [0, -1.0])
@pytest.mark.parametrize("dotted", ["box.inner_half_width", "box.wall_thickness", "box.mass",
                                    "box.inertia", "jack.half_size", "jack.mass", "jack.inertia",
                                    "run.t_end", "run.dt"])
def test_non_positive(tmp_path, dotted, value):
    refused(write_scene(tmp_path, {dotted: value}), dotted, "> 0")


@pytest.mark.parametrize("value", [math.inf, math.nan])
def test_non_finite_size(tmp_path, value):
    refused(write_scene(tmp_path, {"box.mass": value}), "box.mass", "finite")


def test_negative_gravity(tmp_path):
    refused(write_scene(tmp_path, {"world.gravity": -9.81}), "world.gravity", "got -9.81")


def test_dt_larger_than_t_end(tmp_path):
    refused(write_scene(tmp_path, {"run.dt": 2.0}), "run.dt", "larger")


@pytest.mark.parametrize("value", [-0.1, 1.1, 2])
@pytest.mark.parametrize("dotted", ["impact.restitution", "impact.ground_restitution"])
def test_restitution_outside_unit_interval(tmp_path, dotted, value):
    refused(write_scene(tmp_path, {dotted: value}), dotted, "[0, 1]")


@pytest.mark.parametrize("dotted, value", [("impact.restitution", 0), ("impact.restitution", 1),
                                           ("impact.ground_restitution", 0.0)])
def test_restitution_bounds_are_allowed(tmp_path, dotted, value):
    load_scene(write_scene(tmp_path, {dotted: value}))


# --- polygons ---------------------------------------------------------------------------

def test_non_convex_polygon(tmp_path):
    dart = [[0.3, 0.0], [-0.2, 0.25], [0.0, 0.0], [-0.2, -0.25]]   # CCW, reflex at (0, 0)
    refused(write_scene(tmp_path, polygon(dart)), "jack.vertices", "convex")


def test_star_polygon_is_not_convex(tmp_path):
    r = 0.3
    star = [[r * math.cos(math.pi / 2 + 4 * math.pi * k / 5),
             r * math.sin(math.pi / 2 + 4 * math.pi * k / 5)] for k in range(5)]
    refused(write_scene(tmp_path, polygon(star)), "jack.vertices", "convex")


def test_clockwise_polygon(tmp_path):
    refused(write_scene(tmp_path, polygon(SQUARE[::-1])), "jack.vertices", "clockwise")


def test_degenerate_polygon(tmp_path):
    line = [[0.2, 0.0], [0.0, 0.0], [-0.2, 0.0]]
    refused(write_scene(tmp_path, polygon(line)), "jack.vertices", "degenerate")


def test_polygon_not_about_its_centroid(tmp_path):
    shifted = [[x + 0.1, y] for x, y in SQUARE]
    refused(write_scene(tmp_path, polygon(shifted)), "jack.vertices", "centroid")


@pytest.mark.parametrize("value", [[[0.2, 0.0], [0.0, 0.2]], "square", [[0.2, 0.0, 1.0]] * 3])
def test_polygon_vertices_malformed(tmp_path, value):
    refused(write_scene(tmp_path, polygon(value)), "jack.vertices", "[x, y] pairs")


def test_polygon_needs_vertices(tmp_path):
    refused(write_scene(tmp_path, polygon(DELETE)), "jack.vertices", "required")


def test_polygon_refuses_half_size(tmp_path):
    changes = polygon(SQUARE) | {"jack.half_size": 0.25}
    refused(write_scene(tmp_path, changes), "jack.half_size", "polygon")


def test_vertices_only_for_polygon(tmp_path):
    refused(write_scene(tmp_path, {"jack.vertices": SQUARE}), "jack.vertices", "polygon")


def test_polygon_square_matches_closed_form(tmp_path):
    a, m = 0.25, 1.0
    scene = load_scene(write_scene(tmp_path, polygon(SQUARE)))
    params = scene.params()
    assert scene.shape == "polygon"
    # Inertias: a handful of float operations on short decimal inputs. Measured: the
    # square and the box exact, the triangle 1.3e-16 relative; INERTIA_REL is ~8x that.
    assert params["J_jack"] == pytest.approx(2.0 * m * a * a / 3.0, rel=INERTIA_REL)
    # the vertices are runtime parameters, in order
    for i, (x, y) in enumerate(SQUARE):
        assert params[f"jack_x{i}"] == x and params[f"jack_y{i}"] == y
    np.testing.assert_array_equal(scene.points, SQUARE)
    assert len(scene.constraint_names) == 4 * 4 + 4
    # the same square as shape = "square" gives the same inertia
    square = load_scene(write_scene(tmp_path, filename="square.toml"))
    assert square.params()["J_jack"] == pytest.approx(params["J_jack"], rel=INERTIA_REL)


def test_polygon_triangle_inertia(tmp_path):
    s, m = 0.4, 2.0
    h = s * math.sqrt(3) / 2
    triangle = [[2 * h / 3, 0.0], [-h / 3, s / 2], [-h / 3, -s / 2]]   # centroid at 0
    scene = load_scene(write_scene(tmp_path, polygon(triangle) | {"jack.mass": m}))
    assert scene.params()["J_jack"] == pytest.approx(m * s * s / 12, rel=INERTIA_REL)
    assert len(scene.constraint_names) == 4 * 3 + 4


def test_default_inertias(tmp_path):
    scene = load_scene(write_scene(tmp_path))
    so, si = 2 * (1.0 + 0.1), 2 * 1.0
    assert scene.params()["J_box"] == pytest.approx(10.0 * (so * so + si * si) / 6, rel=INERTIA_REL)
    assert scene.params()["J_jack"] == pytest.approx(2 * 1.0 * 0.25 ** 2 / 3, rel=INERTIA_REL)
    cross = load_scene(write_scene(tmp_path, {"jack.shape": "cross"}, filename="cross.toml"))
    assert cross.params()["J_jack"] == pytest.approx(1.0 * 0.25 ** 2, rel=INERTIA_REL)


def test_inertia_overrides(tmp_path):
    scene = load_scene(write_scene(tmp_path, {"box.inertia": 3.5, "jack.inertia": 0.5}))
    assert scene.params()["J_box"] == 3.5
    assert scene.params()["J_jack"] == 0.5


# --- start state ------------------------------------------------------------------------

@pytest.mark.parametrize("x_jack, y_jack, wall", [(0.9, 2.0, "right"), (0.0, 2.9, "top"),
                                                   (-0.9, 2.0, "left"), (0.0, 1.1, "bottom")])
def test_start_penetrates_a_wall(tmp_path, x_jack, y_jack, wall):
    q = [0.0, 2.0, 0.0, x_jack, y_jack, 0.0]
    err = refused(write_scene(tmp_path, {"initial.q": q}), "initial.q", "penetrates")
    assert f"'{wall}:" in str(err)


def test_start_penetrates_a_wall_of_a_tilted_box(tmp_path):
    # the jack is at the box centre's height but the tilted floor comes up under its corner
    q = [0.0, 2.0, 0.6, 0.6, 2.0 - 0.6, 0.0]
    refused(write_scene(tmp_path, {"initial.q": q}), "initial.q", "penetrates")


def test_start_box_penetrates_the_ground(tmp_path):
    # tilted by 0.3 rad, the lowest corner is 1.1 (cos 0.3 + sin 0.3) = 1.38 below the centre
    q = [0.0, 1.0, 0.3, 0.0, 1.0, 0.0]
    err = refused(write_scene(tmp_path, {"initial.q": q}), "initial.q", "penetrates")
    assert "'ground:" in str(err)


def test_ground_off_allows_box_below_zero(tmp_path):
    q = [0.0, -5.0, 0.3, 0.0, -5.0, 0.0]
    load_scene(write_scene(tmp_path, {"world.ground": False, "initial.q": q}))


@pytest.mark.parametrize("offset", [0.0, -1e-12])
def test_start_touching_a_wall_is_allowed(tmp_path, offset):
    # "beyond a tiny tolerance": resting exactly on the floor (or a rounding error into it)
    q = [0.0, 2.0, 0.0, 0.0, 2.0 - 1.0 + 0.25 + offset, 0.0]
    load_scene(write_scene(tmp_path, {"initial.q": q}))


def test_wide_cross_fits_when_turned(tmp_path):
    # circumradius 1.2 L > L: it cannot turn freely, but at 45 degrees its tips are at
    # 1.2 / sqrt(2) = 0.85 L from the centre, inside every wall
    changes = {"jack.shape": "cross", "jack.half_size": 1.2,
               "initial.q": [0.0, 2.0, 0.0, 0.0, 2.0, math.pi / 4]}
    scene = load_scene(write_scene(tmp_path, changes))
    assert scene.params()["a_jack"] == 1.2


def test_wide_cross_refused_when_it_does_not_fit(tmp_path):
    changes = {"jack.shape": "cross", "jack.half_size": 1.2,
               "initial.q": [0.0, 2.0, 0.0, 0.0, 2.0, 0.0]}
    refused(write_scene(tmp_path, changes), "initial.q", "penetrates")


def test_prescribed_box_start_comes_from_its_motion(tmp_path):
    # initial.q's box entries are ignored: at y_box = 50 the jack would be outside the box
    changes = PRESCRIBED | {"initial.q": [9.0, 50.0, 1.0, 0.0, 2.0, 0.0]}
    scene = load_scene(write_scene(tmp_path, changes))
    np.testing.assert_array_equal(scene.q0[:3], [0.0, 2.0, 0.0])      # sin(0) = 0 exactly


def test_prescribed_box_start_is_checked(tmp_path):
    changes = PRESCRIBED | {"box.y": "0"}     # the box at 0, the jack at 2: through the lid
    refused(write_scene(tmp_path, changes), "initial.q", "penetrates")


# --- expressions ------------------------------------------------------------------------

@pytest.mark.parametrize("dotted, text", [
    ("forces.x_box", "k*sin(2*pi*t"),
    ("forces.theta_jack", "k *"),
    ("potential.spring", "0.5*k*(y_box - )**2"),
    ("forces.y_jack", ""),
])
def test_expression_does_not_parse(tmp_path, dotted, text):
    word = "empty" if not text else "parse"
    refused(write_scene(tmp_path, {dotted: text}), dotted, word)


def test_prescribed_motion_does_not_parse(tmp_path):
    refused(write_scene(tmp_path, PRESCRIBED | {"box.x": "0.1*sin("}), "box.x", "parse")


@pytest.mark.parametrize("dotted, text, name", [
    ("forces.x_box", "B*sin(t)", "B"),
    ("forces.y_jack", "m_jack*gravity", "gravity"),
    ("potential.spring", "0.5*k*(y_box - y0)**2", "y0"),
    ("forces.x_jack", "x_jack_ddot", "x_jack_ddot"),
])
def test_expression_names_unknown_symbol(tmp_path, dotted, text, name):
    err = refused(write_scene(tmp_path, {dotted: text}), dotted, "unknown symbol")
    assert f"'{name}'" in str(err)


def test_prescribed_motion_names_unknown_symbol(tmp_path):
    refused(write_scene(tmp_path, PRESCRIBED | {"box.x": "amp*t"}), "box.x", "unknown symbol")


@pytest.mark.parametrize("text", ["foo(t)", "sinus(t)", "np.sin(t)", "max(t, 1)"])
def test_expression_unknown_function(tmp_path, text):
    refused(write_scene(tmp_path, {"forces.x_box": text}), "forces.x_box", "unknown function")


@pytest.mark.parametrize("text", ["t if t else 1", "[t]", "'a'", "t < 1", "t % 2"])
def test_expression_outside_the_grammar(tmp_path, text):
    refused(write_scene(tmp_path, {"forces.x_box": text}), "forces.x_box", "allowed")


@pytest.mark.parametrize("coord", ["x", "y", "theta"])
@pytest.mark.parametrize("text", ["x_jack", "0.1*sin(theta_jack)", "y_jack_dot", "x_box"])
def test_prescribed_motion_uses_the_state(tmp_path, coord, text):
    changes = PRESCRIBED | {f"box.{coord}": text}
    refused(write_scene(tmp_path, changes), f"box.{coord}", "state")


@pytest.mark.parametrize("coord", ["x_box", "y_box", "theta_box"])
def test_force_on_prescribed_box(tmp_path, coord):
    refused(write_scene(tmp_path, PRESCRIBED | {f"forces.{coord}": "1"}), f"forces.{coord}", "prescribed")


def test_prescribed_box_allows_jack_forces_and_potential_of_its_coordinates(tmp_path):
    changes = PRESCRIBED | {"forces.x_jack": "k*sin(t)", "potential.tether": "0.5*k*(y_jack - y_box)**2"}
    scene = load_scene(write_scene(tmp_path, changes))
    assert scene.forces == {"x_jack": "k*sin(t)"}
    assert "tether" in scene.potential


def test_motion_keys_need_a_prescribed_box(tmp_path):
    refused(write_scene(tmp_path, {"box.x": "0.1*t"}), "box.x", "prescribed")


@pytest.mark.parametrize("text, rate", [("0.5*k*y_box_dot**2", "y_box_dot"),
                                        ("theta_jack_dot*t", "theta_jack_dot")])
def test_potential_uses_a_rate(tmp_path, text, rate):
    refused(write_scene(tmp_path, {"potential.spring": text}), "potential.spring", rate)


def test_forces_may_use_state_rates_and_params(tmp_path):
    text = "-k*x_box_dot + m_box*g + J_jack*theta_jack + L*t"
    scene = load_scene(write_scene(tmp_path, {"forces.x_box": text}))
    assert scene.forces["x_box"] == text


@pytest.mark.parametrize("text, why", [("1/0", "division by zero"), ("log(0)", "math domain error"),
                                       ("10**1000", "too large")])
def test_constant_force_that_cannot_be_evaluated(tmp_path, text, why):
    # a formula of constants alone is evaluated when the scene loads: refused there, not
    # as a NaN or an exception in the middle of a run
    err = refused(write_scene(tmp_path, {"forces.x_box": text}), "forces.x_box", "cannot be evaluated")
    assert f"'{text}'" in str(err) and why in str(err), err


@pytest.mark.parametrize("text, why", [("1/t", "division by zero"), ("log(t)", "math domain error")])
def test_prescribed_motion_undefined_at_start(tmp_path, text, why):
    # the start state comes from the motion at t = 0, so a motion undefined there is refused
    err = refused(write_scene(tmp_path, PRESCRIBED | {"box.x": text}), "box.x", "cannot be evaluated")
    assert f"'{text}'" in str(err) and why in str(err) and "at t = 0" in str(err), err


# --- names ------------------------------------------------------------------------------

@pytest.mark.parametrize("name", ["Drop", "my scene", "drop.v2", "", "é"])
def test_bad_scene_name(tmp_path, name):
    refused(write_scene(tmp_path, {"name": name}), "name", "[a-z0-9_-]+")


@pytest.mark.parametrize("name", ["g", "t", "pi", "e", "L", "m_box", "x_box", "y_jack_dot", "sin",
                                  "a_jack"])
def test_reserved_param_name(tmp_path, name):
    refused(write_scene(tmp_path, {f"params.{name}": 1.0}), f"params.{name}", "reserved")


@pytest.mark.parametrize("name", ["2k", "k-2"])
def test_param_name_not_an_identifier(tmp_path, name):
    refused(write_scene(tmp_path, {f"params.{name}": 1.0}), f"params.{name}", "usable")


@pytest.mark.parametrize("name", ["jack_x0", "jack_y3", "jack_x7"])
@pytest.mark.parametrize("shape", ["polygon", "square"])
def test_param_name_clashing_with_polygon_slot(tmp_path, shape, name):
    # docs/scenes.md: a [params] name may not shadow the internal slot names jack_x<i>,
    # jack_y<i>: refused for every i and every shape (a square has no such slots, and a
    # four-vertex polygon has no jack_x7, but the names are reserved all the same)
    changes = (polygon(SQUARE) if shape == "polygon" else {}) | {f"params.{name}": 3.0}
    refused(write_scene(tmp_path, changes), f"params.{name}", "reserved")


# --- files ------------------------------------------------------------------------------

def test_invalid_toml(tmp_path):
    path = tmp_path / "broken.toml"
    path.write_text(to_toml(BASE).replace("[jack]", "[jack"), encoding="utf-8")
    refused(path, "", "TOML")


def test_duplicate_toml_key(tmp_path):
    path = tmp_path / "twice.toml"
    path.write_text(to_toml(BASE) + '\n[box]\nmass = 2.0\n', encoding="utf-8")
    refused(path, "", "TOML")


def test_missing_file(tmp_path):
    path = tmp_path / "nowhere.toml"
    refused(path, "", "no such")


def test_missing_name_that_is_not_builtin():
    with pytest.raises(SceneError, match="no such scene file.*built-in"):
        load_scene("no_such_scene_here")


def test_directory_is_not_a_scene_file(tmp_path):
    folder = tmp_path / "dir.toml"
    folder.mkdir()
    refused(folder, "", "is a folder, not a scene file")


@pytest.mark.parametrize("dotted", ["name", "box.inner_half_width", "box.wall_thickness", "box.mass",
                                    "jack.shape", "jack.half_size", "jack.mass", "initial.q"])
def test_missing_required_key(tmp_path, dotted):
    refused(write_scene(tmp_path, {dotted: DELETE}), dotted, "required")


@pytest.mark.parametrize("dotted", ["description", "params.k", "box.motion", "world.gravity",
                                    "world.ground", "impact.restitution", "initial.qd",
                                    "run.t_end", "run.dt"])
def test_optional_key_may_be_left_out(tmp_path, dotted):
    load_scene(write_scene(tmp_path, {dotted: DELETE}))


def test_scene_text_is_kept(tmp_path):
    path = write_scene(tmp_path)
    scene = load_scene(path)
    assert scene.text == path.read_text(encoding="utf-8")
    assert scene.source == str(path)


# --- overrides (jackbox run --set) --------------------------------------------------------

def test_override_restitution_sets_both(tmp_path):
    # ground_restitution defaults to restitution, also when restitution is overridden
    params = load_scene("drop", {"restitution": "0.6"}).params()
    assert params["e"] == 0.6
    assert params["e_ground"] == 0.6


def test_override_param():
    scene = load_scene("shaken", {"A": "400"})
    assert scene.params()["A"] == 400.0
    assert load_scene("shaken").params()["A"] == 300.0


def test_override_dotted_key():
    params = load_scene("drop", {"impact.ground_restitution": "0.3"}).params()
    assert params["e"] == 1.0
    assert params["e_ground"] == 0.3


def test_override_on_a_file(tmp_path):
    scene = load_scene(write_scene(tmp_path), {"gravity": "1.62", "k": "5", "initial.q": "[0, 2, 0, 0.5, 2, 0]"})
    assert scene.params()["g"] == 1.62
    assert scene.params()["k"] == 5.0
    assert scene.q0[3] == 0.5


def test_override_is_validated(tmp_path):
    path = write_scene(tmp_path)
    refused(path, "impact.restitution", "[0, 1]", overrides={"restitution": "1.5"})


@pytest.mark.parametrize("name", ["nosuch", "mass", "foo.bar"])
def test_override_unknown_name(name):
    # "mass" is in both [box] and [jack]: ambiguous, so as unknown as a made-up name
    with pytest.raises(SceneError) as info:
        load_scene("drop", {name: "1"})
    msg = str(info.value)
    assert "builtin:drop" in msg and f"--set {name}" in msg, msg


def test_override_unknown_key_in_known_section():
    with pytest.raises(SceneError, match=r"impact\.friction: unknown key"):
        load_scene("drop", {"impact.friction": "0.3"})


def test_scene_object_with_overrides():
    base = load_scene("drop")
    changed = jackbox.load_scene(base, {"restitution": "0.5"})
    assert changed.params()["e"] == 0.5
    assert base.params()["e"] == 1.0
