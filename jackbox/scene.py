"""Scene files: read, check and describe a simulation (the static half of the pipeline).

A scene is one TOML file with the schema of ``SCENES.md`` (documented in
``docs/scenes.md``). :func:`load_scene` reads a built-in scene by name or a file by
path, applies ``--set`` style overrides, and checks everything before anything
runs: every refusal is a :class:`~jackbox.errors.SceneError` naming the file, the
key and the problem.

The result, :class:`Scene`, splits what a scene says into

* its *structure* (jack shape and point count, free or prescribed box, ground,
  formulas of forces, potential and motion, the names of the parameters): what
  the compiler compiles in, summarised by :meth:`Scene.structure`;
* its *parameters* (masses, sizes, inertias, g, restitutions, ``[params]``): one
  float array, :attr:`Scene.param_values`, that the generated code reads at run
  time, so changing a value never regenerates or recompiles anything;
* its start state and run settings.

The model's vocabulary (coordinates, walls, parameter slots) and the formula
language are the compiler's (:mod:`codegen`); :meth:`Scene.model_spec` is the
structure as the compiler takes it. This module never imports sympy: checking a
scene and running a compiled one is cheap.
"""

from __future__ import annotations

import math
import re
import tomllib
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

# the model's vocabulary and the formula language are the compiler's; the runtime's
# other modules take the vocabulary from here
from codegen import (BASE_PARAMS, BASE_SYMBOLS, BOX_COORDS, COORDS, CORNER_SIGNS, FORMULA_FUNCTIONS, JACK_COORDS,
                     JACK_SHAPES, RATES, WALL_NORMALS, Expr, ExprError, ModelSpec, constraint_names, parse_formula)
from codegen import WALLS  # noqa: F401  (for geometry and plots)

from .errors import SceneError

RESERVED = frozenset(
    {"t", "pi", "a_jack", *BASE_PARAMS, *COORDS, *RATES, *FORMULA_FUNCTIONS}
)

#: Defaults for optional keys; everything else is required.
DEFAULTS: dict[str, dict[str, Any]] = {
    "box": {"motion": "free", "x": "0", "y": "0", "theta": "0"},
    "world": {"gravity": 9.81, "ground": False},
    "impact": {"restitution": 1.0},
    "initial": {"qd": [0.0] * 6},
    "run": {"t_end": 10.0, "dt": 1e-3},
}
SCHEMA: dict[str, tuple[str, ...]] = {
    "": ("name", "description", "params", "box", "jack", "world", "potential", "forces",
         "impact", "initial", "run"),
    "box": ("inner_half_width", "wall_thickness", "mass", "inertia", "motion", "x", "y", "theta"),
    "jack": ("shape", "half_size", "mass", "inertia", "vertices"),
    "world": ("gravity", "ground"),
    "impact": ("restitution", "ground_restitution"),
    "initial": ("q", "qd"),
    "run": ("t_end", "dt"),
}
#: Sections whose keys are the user's own names.
FREE_SECTIONS = ("params", "potential", "forces")
NAME_RE = re.compile(r"^[a-z0-9_-]+$")
VERTEX_SLOT_RE = re.compile(r"^jack_[xy][0-9]+$")   # a polygon jack's vertex parameters
IDENT_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def builtin_scenes() -> dict[str, Path]:
    """Names and paths of the scenes shipped with jackbox."""
    folder = resources.files("jackbox.scenes")
    return {Path(p.name).stem: Path(str(p)) for p in sorted(folder.iterdir(), key=lambda p: p.name)
            if p.name.endswith(".toml")}


@dataclass(frozen=True)
class Scene:
    """A checked scene. Build one with :func:`load_scene`."""

    name: str
    description: str
    source: str                     #: where it came from: a path or ``builtin:<name>``
    text: str                       #: the scene file's text (stored in every .npz)
    builtin: bool
    raw: dict = field(repr=False)   #: the TOML tables after overrides, for re-checking

    prescribed: bool                #: box moved by ``motion`` formulas instead of DOFs
    motion: tuple[str, str, str]    #: x, y, theta formulas of a prescribed box
    shape: str
    points: np.ndarray              #: (P, 2) the jack's contact points in its frame
    ground: bool
    potential: dict[str, str]
    forces: dict[str, str]          #: non-zero generalized forces only
    user_params: dict[str, float]
    param_names: tuple[str, ...]
    param_values: np.ndarray
    q0: np.ndarray                  #: (6,) start coordinates
    qd0: np.ndarray                 #: (6,) start rates
    t_end: float
    dt: float

    @property
    def dof_names(self) -> tuple[str, ...]:
        """The coordinates the kernel integrates (3 for a prescribed box, else 6)."""
        return JACK_COORDS if self.prescribed else COORDS

    @property
    def constraint_names(self) -> tuple[str, ...]:
        return constraint_names(len(self.points), self.has_ground_contacts)

    @property
    def has_ground_contacts(self) -> bool:
        # a prescribed box is held by its motion whatever the ground does
        return self.ground and not self.prescribed

    def params(self) -> dict[str, float]:
        return dict(zip(self.param_names, self.param_values.tolist()))

    def model_spec(self) -> ModelSpec:
        """The scene's structure as the compiler takes it (:class:`codegen.ModelSpec`)."""
        return ModelSpec(
            name=self.name, command=f"jackbox build {self.name if self.builtin else self.source}",
            param_names=self.param_names, user_params=tuple(self.user_params), prescribed=self.prescribed,
            motion=self.motion, shape=self.shape, n_points=len(self.points), ground=self.has_ground_contacts,
            potential=self.potential, forces=self.forces,
        )

    def structure(self) -> dict:
        """What the compiler compiles in: equal structures give equal generated code."""
        return self.model_spec().structure()

    def with_overrides(self, overrides: dict[str, Any]) -> "Scene":
        """A copy with ``name=value`` settings applied (see :func:`apply_overrides`)."""
        raw = apply_overrides(self.raw, overrides, self.source)
        return _build(raw, self.source, self.text, self.builtin)


def load_scene(scene: "str | Path | Scene", overrides: dict[str, Any] | None = None) -> Scene:
    """Read a scene: a built-in name (``"shaken"``), a path to a ``.toml``, or a Scene.

    ``overrides`` maps ``name`` to a value, as ``jackbox run --set name=value``:
    a ``[params]`` name, a dotted key (``impact.restitution``) or a key that is
    unique in the schema (``restitution``, ``gravity``, ``dt`` ...).
    """
    if overrides is not None and not isinstance(overrides, dict):
        raise SceneError(str(scene), "", f"overrides must be a dict of keys and values, got {overrides!r}")
    if isinstance(scene, Scene):
        return scene.with_overrides(overrides) if overrides else scene
    if not isinstance(scene, (str, Path)) or not str(scene):
        raise SceneError(repr(scene), "", "a scene is a built-in name, a path to a .toml file or a Scene")
    builtins = builtin_scenes()
    path = Path(scene)
    if str(scene) in builtins and not path.exists():
        path, source, builtin = builtins[str(scene)], f"builtin:{scene}", True
    elif path.exists() or str(scene).endswith(".toml"):
        source, builtin = str(scene), False
        if path.is_dir():
            raise SceneError(source, "", "is a folder, not a scene file")
        if not path.is_file():
            raise SceneError(source, "", "no such scene file")
    else:
        raise SceneError(str(scene), "", f"no such scene file, nor a built-in scene "
                         f"(built-in: {', '.join(builtins)})")
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SceneError(source, "", f"cannot be read ({exc})") from None
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(source, "", f"not valid TOML: {exc}") from None
    if overrides:
        raw = apply_overrides(raw, overrides, source)
    return _build(raw, source, text, builtin)


def scene_from_tables(tables: dict, source: str = "<tables>", text: str = "") -> Scene:
    """A checked Scene from TOML tables (as ``tomllib.loads`` gives, or ``Scene.raw``)."""
    return _build(tables, source, text, False)


def apply_overrides(raw: dict, overrides: dict[str, Any], source: str) -> dict:
    """Return a copy of the TOML tables with ``name=value`` settings applied.

    String values are read as TOML values when they parse as one (``0.6``,
    ``true``, ``[0, 1]``), else kept as strings (formulas).
    """
    raw = {k: dict(v) if isinstance(v, dict) else v for k, v in raw.items()}
    for name, value in overrides.items():
        if isinstance(value, str):
            try:
                value = tomllib.loads(f"v = {value}")["v"]
            except tomllib.TOMLDecodeError:
                pass
        section, key = _resolve_override(raw, name, source)
        if section:
            raw.setdefault(section, {})
            if not isinstance(raw[section], dict):
                raise SceneError(source, section, "must be a table")
            raw[section][key] = value
        else:
            raw[key] = value
    return raw


def _resolve_override(raw: dict, name: str, source: str) -> tuple[str, str]:
    if "." in name:
        section, _, key = name.partition(".")
        if section not in SCHEMA and section not in FREE_SECTIONS:
            raise SceneError(source, f"--set {name}", f"unknown section {section!r}")
        return section, key
    if name in raw.get("params", {}):
        return "params", name
    owners = [s for s, keys in SCHEMA.items() if s and name in keys]
    if name in ("name", "description"):
        return "", name
    if len(owners) == 1:
        return owners[0], name
    slot = SLOT_RULES[name][0] if name in SLOT_RULES else None
    raise SceneError(source, f"--set {name}",
                     "not a [params] name nor a scene key (use section.key, e.g. impact.restitution)"
                     + (f"; the parameter {name} is the scene key {slot}" if slot else ""))


# --- checking -------------------------------------------------------------------------

class _Checker:
    """Reads typed values out of the TOML tables, raising SceneError on the first problem."""

    def __init__(self, raw: dict, source: str):
        self.raw, self.source = raw, source

    def fail(self, key: str, problem: str):
        raise SceneError(self.source, key, problem)

    def table(self, section: str) -> dict:
        value = self.raw.get(section, {})
        if not isinstance(value, dict):
            self.fail(section, f"must be a table [{section}], got {_kind(value)}")
        return value

    def get(self, section: str, key: str, required: bool = True):
        table = self.table(section) if section else self.raw
        if key in table:
            return table[key]
        if key in DEFAULTS.get(section, {}):
            return DEFAULTS[section][key]
        if required:
            self.fail(_dotted(section, key), "is required")
        return None

    def number(self, section: str, key: str, *, positive=False, low=None, high=None,
               required=True) -> float | None:
        value = self.get(section, key, required)
        if value is None:
            return None
        name = _dotted(section, key)
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(name, f"must be a number, got {_kind(value)}")
        value = float(value)
        problem = (_range_problem(value, 0.0, math.inf, True) if positive else
                   _range_problem(value, -math.inf if low is None else low,
                                  math.inf if high is None else high, False))
        if problem:
            self.fail(name, problem)
        return value

    def string(self, section: str, key: str, choices=None) -> str:
        value = self.get(section, key)
        name = _dotted(section, key)
        if not isinstance(value, str):
            self.fail(name, f"must be a string, got {_kind(value)}")
        if choices and value not in choices:
            self.fail(name, f"must be one of {', '.join(map(repr, choices))}, got {value!r}")
        return value

    def vector(self, section: str, key: str, n: int) -> np.ndarray:
        value = self.get(section, key)
        name = _dotted(section, key)
        if not isinstance(value, list) or len(value) != n:
            self.fail(name, f"must be a list of {n} numbers, got {_kind(value)}")
        for i, item in enumerate(value):
            if isinstance(item, bool) or not isinstance(item, (int, float)) or not math.isfinite(item):
                self.fail(f"{name}[{i}]", f"must be a finite number, got {item!r}")
        return np.array(value, dtype=float)

    def value_of(self, key: str, formula: Expr, values: dict[str, float]) -> float:
        try:
            return formula.evaluate(values)
        except ExprError as exc:
            self.fail(key, f"{exc} at t = 0" if "t" in values else str(exc))

    def formula(self, key: str, value, allowed) -> Expr:
        try:
            return parse_formula(value, allowed)
        except ExprError as exc:
            self.fail(key, str(exc))


def _dotted(section: str, key: str) -> str:
    return f"{section}.{key}" if section else key


def _kind(value) -> str:
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, (int, float)):
        return f"a number ({value})"
    if isinstance(value, str):
        return f"a string ({value!r})"
    if isinstance(value, list):
        return f"a list of {len(value)}"
    if isinstance(value, dict):
        return "a table"
    return type(value).__name__


def _build(raw: dict, source: str, text: str, builtin: bool) -> Scene:
    c = _Checker(raw, source)
    for key in raw:
        if key not in SCHEMA[""]:
            c.fail(key, f"unknown key (known: {', '.join(SCHEMA[''])})")
    for section, keys in SCHEMA.items():
        if section:
            for key in c.table(section):
                if key not in keys:
                    c.fail(_dotted(section, key), f"unknown key (known in [{section}]: {', '.join(keys)})")

    name = c.string("", "name")
    if not NAME_RE.match(name):
        c.fail("name", f"must match [a-z0-9_-]+, got {name!r}")
    description = raw.get("description", "")
    if not isinstance(description, str):
        c.fail("description", f"must be a string, got {_kind(description)}")

    user_params: dict[str, float] = {}
    for key in c.table("params"):
        reserved = key in RESERVED or VERTEX_SLOT_RE.match(key)
        if not IDENT_RE.match(key) or reserved:
            c.fail(f"params.{key}", "is not a usable parameter name"
                   + (" (reserved)" if reserved else " (use letters, digits, _)"))
        user_params[key] = c.number("params", key)

    L = c.number("box", "inner_half_width", positive=True)
    w = c.number("box", "wall_thickness", positive=True)
    m_box = c.number("box", "mass", positive=True)
    J_box = c.number("box", "inertia", positive=True, required=False)
    if J_box is None:
        J_box = frame_inertia(m_box, L, w)
    motion_kind = c.string("box", "motion", ("free", "prescribed"))
    prescribed = motion_kind == "prescribed"

    shape = c.string("jack", "shape", JACK_SHAPES)
    m_jack = c.number("jack", "mass", positive=True)
    jack = c.table("jack")
    if shape == "polygon":
        if "half_size" in jack:
            c.fail("jack.half_size", "is not used by a polygon jack (give jack.vertices)")
        points = _polygon(c)
        J_default = polygon_inertia(m_jack, points)
        a = None
    else:
        if "vertices" in jack:
            c.fail("jack.vertices", f"is only for shape = 'polygon', not {shape!r}")
        a = c.number("jack", "half_size", positive=True)
        if shape == "cross":
            points = a * np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])
        else:
            points = a * np.array(CORNER_SIGNS)
        J_default = jack_inertia(shape, m_jack, a)
    J_jack = c.number("jack", "inertia", positive=True, required=False) or J_default

    g = c.number("world", "gravity", low=0.0, high=math.inf)
    ground = c.get("world", "ground")
    if not isinstance(ground, bool):
        c.fail("world.ground", f"must be true or false, got {_kind(ground)}")
    e = c.number("impact", "restitution", low=0.0, high=1.0)
    e_ground = c.number("impact", "ground_restitution", low=0.0, high=1.0, required=False)
    e_ground = e if e_ground is None else e_ground

    constants = set(BASE_SYMBOLS) | set(user_params) | {"t"}
    state = set(COORDS) | set(RATES)
    box_table = c.table("box")
    motion = ("0", "0", "0")
    if prescribed:
        motion_formulas = []
        for coord in ("x", "y", "theta"):
            f = c.formula(f"box.{coord}", c.get("box", coord), constants | state)
            used_state = sorted(f.names & state)
            if used_state:
                c.fail(f"box.{coord}", f"a prescribed motion may not use the state ({', '.join(used_state)}): "
                       "it moves the box whatever the jack does")
            motion_formulas.append(f.text)
        motion = tuple(motion_formulas)
    else:
        for coord in ("x", "y", "theta"):
            if coord in box_table:
                c.fail(f"box.{coord}", "is only used with box.motion = 'prescribed'")

    potential = {}
    for key, value in c.table("potential").items():
        f = c.formula(f"potential.{key}", value, constants | set(COORDS) | set(RATES))
        rates = sorted(f.names & set(RATES))
        if rates:
            c.fail(f"potential.{key}", f"a potential depends on coordinates and t only, not on {', '.join(rates)}")
        potential[key] = f.text
    forces = {}
    for key, value in c.table("forces").items():
        if key not in COORDS:
            c.fail(f"forces.{key}", f"unknown coordinate (known: {', '.join(COORDS)})")
        if prescribed and key in BOX_COORDS:
            c.fail(f"forces.{key}", "a prescribed box takes no forces: its motion is given")
        f = c.formula(f"forces.{key}", value, constants | state)
        if not f.names and c.value_of(f"forces.{key}", f, {}) == 0.0:
            continue  # a zero force emits nothing
        forces[key] = f.text

    q0 = c.vector("initial", "q", 6)
    qd0 = c.vector("initial", "qd", 6)
    t_end = c.number("run", "t_end", positive=True)
    dt = c.number("run", "dt", positive=True)
    if dt > t_end:
        c.fail("run.dt", f"is larger than run.t_end ({dt:g} > {t_end:g})")

    param_names = list(BASE_PARAMS)
    param_values = [m_box, J_box, L, w, m_jack, J_jack, g, e, e_ground]
    if a is not None:
        param_names.append("a_jack")
        param_values.append(a)
    else:
        for i, (x, y) in enumerate(points):
            param_names += [f"jack_x{i}", f"jack_y{i}"]
            param_values += [float(x), float(y)]
    param_names += list(user_params)
    param_values += list(user_params.values())

    values = dict(zip(param_names, param_values)) | {"t": 0.0}
    if prescribed:
        for i, (coord, formula) in enumerate(zip(("x", "y", "theta"), motion)):
            q0[i] = c.value_of(f"box.{coord}", parse_formula(formula, constants), values)
    _check_start(c, q0, points, L, w, ground and not prescribed)

    return Scene(
        name=name, description=description, source=source, text=text, builtin=builtin, raw=raw,
        prescribed=prescribed, motion=motion, shape=shape, points=points, ground=bool(ground),
        potential=potential, forces=forces, user_params=user_params,
        param_names=tuple(param_names), param_values=np.array(param_values, dtype=float),
        q0=q0, qd0=qd0, t_end=t_end, dt=dt,
    )


def _polygon(c: _Checker) -> np.ndarray:
    value = c.get("jack", "vertices")
    if (not isinstance(value, list) or len(value) < 3
            or not all(isinstance(v, list) and len(v) == 2 for v in value)):
        c.fail("jack.vertices", "must be a list of at least 3 [x, y] pairs")
    for i, v in enumerate(value):
        for x in v:
            if isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x):
                c.fail(f"jack.vertices[{i}]", f"must be two finite numbers, got {v!r}")
    pts = np.array(value, dtype=float)
    nxt = np.roll(pts, -1, axis=0)
    cross = pts[:, 0] * nxt[:, 1] - nxt[:, 0] * pts[:, 1]
    area = 0.5 * cross.sum()
    size = np.abs(pts).max()
    if area <= 0:
        c.fail("jack.vertices", "the polygon is clockwise or degenerate (give the vertices counter-clockwise)")
    edges = nxt - pts
    turn = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    if np.any(turn <= 1e-12 * size * size):
        bad = int(np.argmax(turn <= 1e-12 * size * size))
        c.fail("jack.vertices", f"the polygon is not strictly convex (at vertex {(bad + 1) % len(pts)})")
    # left turns everywhere and a total turn of one revolution (a star turns twice)
    nxt_edges = np.roll(edges, -1, axis=0)
    dots = (edges * nxt_edges).sum(axis=1)
    if abs(np.arctan2(turn, dots).sum() - 2.0 * np.pi) > 1e-6:
        c.fail("jack.vertices", "the polygon is not convex (its edges cross: it winds around more than once)")
    centroid = ((pts + nxt) * cross[:, None]).sum(axis=0) / (6.0 * area)
    if np.hypot(*centroid) > 1e-9 * size:
        c.fail("jack.vertices", f"must be given about the polygon's centroid, which is at "
               f"({centroid[0]:.6g}, {centroid[1]:.6g}); subtract it from every vertex")
    return pts


def frame_inertia(mass: float, L: float, w: float) -> float:
    """Polar inertia of the uniform square frame: ``m (so^2 + si^2) / 6``.

    The compiler derives the same value from the four wall segments
    (``frame_inertia`` in ``codegen/model.py``); a test checks that they agree.
    """
    so, si = 2.0 * (L + w), 2.0 * L
    return mass * (so * so + si * si) / 6.0


def jack_inertia(shape: str, mass: float, a: float) -> float:
    """Polar inertia of a cross (four point masses at a from its centre) or a uniform square plate of half-size a."""
    return mass * a * a if shape == "cross" else 2.0 * mass * a * a / 3.0


def polygon_inertia(mass: float, points: np.ndarray) -> float:
    """Polar inertia about the centroid of a uniform convex polygon (CCW vertices)."""
    x, y = points[:, 0], points[:, 1]
    xn, yn = np.roll(x, -1), np.roll(y, -1)
    cross = x * yn - xn * y
    area = 0.5 * cross.sum()
    second = (cross * (x * x + x * xn + xn * xn + y * y + y * yn + yn * yn)).sum() / 12.0
    return float(mass * second / area)


def contact_gaps(q: np.ndarray, points: np.ndarray, L: float, w: float, ground: bool) -> np.ndarray:
    """Gap vector ``phi(q)`` in the order of :attr:`Scene.constraint_names`, in plain numpy.

    Used to refuse penetrating start states without compiling anything; the
    compiler derives the same rows symbolically and the tests compare them.
    One state of :func:`contact_gaps_many`.
    """
    return contact_gaps_many(np.asarray(q, float)[None], np.asarray(points, float)[None], np.array([L], float),
                             np.array([w], float), ground)[0]


def contact_gaps_many(Q: np.ndarray, points: np.ndarray, L: np.ndarray, w: np.ndarray, ground: bool) -> np.ndarray:
    """:func:`contact_gaps` of n states at once: Q (n, 6), points (n, P, 2), L and w (n,); returns (n, C)."""
    xb, yb, tb, xj, yj, tj = (Q[:, k, None] for k in range(6))
    cj, sj, cb, sb = np.cos(tj), np.sin(tj), np.cos(tb), np.sin(tb)
    wx = xj + cj * points[:, :, 0] - sj * points[:, :, 1]
    wy = yj + sj * points[:, :, 0] + cj * points[:, :, 1]
    dx, dy = wx - xb, wy - yb
    lx, ly = cb * dx + sb * dy, -sb * dx + cb * dy
    rows = [L[:, None] - (lx * nx + ly * ny) for nx, ny in WALL_NORMALS]
    if ground:
        h = (L + w)[:, None]
        rows.append(np.concatenate([yb + sb * sx * h + cb * sy * h for sx, sy in CORNER_SIGNS], axis=1))
    return np.concatenate(rows, axis=1)


#: The scene format's rule for each built-in parameter slot (docs/scenes.md): the key
#: its value comes from in a scene file and its range, (low, high, low_open). The same
#: rules hold however a value arrives: the file, --set, simulate(params=...), a sweep.
SLOT_RULES: dict[str, tuple[str, float, float, bool]] = {
    "m_box": ("box.mass", 0.0, math.inf, True),
    "J_box": ("box.inertia", 0.0, math.inf, True),
    "L": ("box.inner_half_width", 0.0, math.inf, True),
    "w_box": ("box.wall_thickness", 0.0, math.inf, True),
    "m_jack": ("jack.mass", 0.0, math.inf, True),
    "J_jack": ("jack.inertia", 0.0, math.inf, True),
    "a_jack": ("jack.half_size", 0.0, math.inf, True),
    "g": ("world.gravity", 0.0, math.inf, False),
    "e": ("impact.restitution", 0.0, 1.0, False),
    "e_ground": ("impact.ground_restitution", 0.0, 1.0, False),
}


def check_param(name: str, value: Any, where: str) -> float:
    """`value` for the parameter slot `name` as a float, or a SceneError naming `where`.

    where: how the value was given (``"simulate(params=...)"``, ``"sweep"``, ...).
    Built-in slots keep their scene-file ranges; ``[params]`` and a polygon's
    vertex slots take any finite number.
    """
    key, low, high, low_open = SLOT_RULES.get(name, (f"params.{name}", -math.inf, math.inf, False))
    what = f"{name} ({key})" if name in SLOT_RULES else name
    if not is_number(value):
        raise SceneError(where, what, f"must be a number, got {_kind(value)}")
    x = float(value)
    problem = _range_problem(x, low, high, low_open)
    if problem:
        raise SceneError(where, what, problem)
    return x


def _range_problem(x: float, low: float, high: float, low_open: bool) -> str | None:
    """What is wrong with the number x for the range (low, high] or [low, high], if anything."""
    if not math.isfinite(x):
        return f"must be finite, got {x}"
    if low_open and not x > low:
        return f"must be > {low:g}, got {x:g}"
    if not low <= x <= high:
        allowed = f">= {low:g}" if high == math.inf else f"in [{low:g}, {high:g}]"
        return f"must be {allowed}, got {x:g}"
    return None


def is_number(value: Any) -> bool:
    """A real number as a value (int, float or numpy's), not a bool or a string."""
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool)


def param_array(scene: "Scene", values: dict[str, Any], where: str) -> np.ndarray:
    """The scene's parameter array with `values` set, each checked as a scene file's would be.

    With new sizes (L, w_box, a_jack or a polygon's vertices) or new values of a
    prescribed box's motion, the start state is checked again: a start that the
    new values put inside a wall is refused, naming `where`.
    """
    p = scene.param_values.copy()
    for name, value in values.items():     # names are the scene's (the caller checked them)
        p[scene.param_names.index(name)] = check_param(name, value, where)
    rederive_inertias(scene, p, values)
    if not np.array_equal(p, scene.param_values):
        check_start(scene, p, where)
    return p


#: the parameter slots each derived inertia is computed from (see derived_inertia_inputs)
BOX_INERTIA_FROM = ("m_box", "L", "w_box")
JACK_INERTIA_FROM = ("m_jack", "a_jack")


def derived_inertia_inputs(scene: "Scene", name: str) -> str | None:
    """The inertia slot (J_box or J_jack) that the scene derives from parameter `name`, if any.

    A scene file that gives no ``box.inertia`` (``jack.inertia``) has it
    computed from the box's mass and sizes (the jack's mass and size or
    vertices); a value set through ``params`` or a sweep must move it the
    same way, as ``--set box.mass=...`` does when the file is read again.
    """
    if name in BOX_INERTIA_FROM and "inertia" not in scene.raw.get("box", {}):
        return "J_box"
    jack_input = name in JACK_INERTIA_FROM or (name.startswith(("jack_x", "jack_y")) and scene.shape == "polygon")
    if jack_input and "inertia" not in scene.raw.get("jack", {}):
        return "J_jack"
    return None


def rederive_inertias(scene: "Scene", p: np.ndarray, given: dict[str, Any]) -> None:
    """The inertias the scene file derived, computed again in p from the masses and sizes in it.

    Only where a value they come from is in `given` and the inertia itself
    is not (an inertia given explicitly, in the file or in `given`, stays).
    """
    P = dict(zip(scene.param_names, p.tolist()))
    for slot in {derived_inertia_inputs(scene, name) for name in given} - {None} - set(given):
        if slot == "J_box":
            value = frame_inertia(P["m_box"], P["L"], P["w_box"])
        elif scene.shape == "polygon":
            value = polygon_inertia(P["m_jack"], np.array([[P[f"jack_x{i}"], P[f"jack_y{i}"]]
                                                           for i in range(len(scene.points))]))
        else:
            value = jack_inertia(scene.shape, P["m_jack"], P["a_jack"])
        p[scene.param_names.index(slot)] = value


def jack_points(scene: "Scene", P: dict) -> np.ndarray:
    """The jack's contact points in its frame for the parameter values P (its size or vertices): (points, 2),
    or (n, points, 2) where P's values are (n,) arrays (one row of parameters a member)."""
    if "a_jack" in P:
        base = scene.param_values[scene.param_names.index("a_jack")]
        return scene.points * (np.asarray(P["a_jack"]) / base)[..., None, None]
    return np.stack([np.stack([P[f"jack_x{i}"], P[f"jack_y{i}"]], axis=-1) for i in range(len(scene.points))],
                    axis=-2)


def check_start(scene: "Scene", p: np.ndarray, where: str) -> None:
    """Refuse a start state that penetrates with the parameter values `p`."""
    P = dict(zip(scene.param_names, p))
    points = jack_points(scene, P)
    q0 = scene.q0.copy()
    if scene.prescribed:
        constants = set(BASE_SYMBOLS) | set(scene.user_params) | {"t"}
        values = P | {"t": 0.0}
        for i, formula in enumerate(scene.motion):
            try:
                q0[i] = parse_formula(formula, constants).evaluate(values)
            except ExprError as exc:
                raise SceneError(where, f"box.{BOX_COORDS[i][:-4]}", f"{exc} at t = 0") from None
    gaps = contact_gaps(q0, points, P["L"], P["w_box"], scene.has_ground_contacts)
    worst = int(np.argmin(gaps))
    if gaps[worst] < -1e-9 * P["L"]:
        raise SceneError(where, "initial.q", f"the start state penetrates with these values: contact "
                         f"{scene.constraint_names[worst]!r} has gap {gaps[worst]:.6g} < 0")


def _check_start(c: _Checker, q0, points, L, w, ground) -> None:
    gaps = contact_gaps(q0, points, L, w, ground)
    tol = 1e-9 * L
    worst = int(np.argmin(gaps))
    if gaps[worst] < -tol:
        name = constraint_names(len(points), ground)[worst]
        c.fail("initial.q", f"the start state penetrates: contact {name!r} has gap {gaps[worst]:.6g} < 0")
