"""Stage 1: derive the symbolic model of a :class:`~codegen.spec.ModelSpec`.

From a model's spec (its structure, see :mod:`codegen.spec`) this builds, with sympy:

* the world-from-body SE(2) transforms ``g_wb`` (box) and ``g_wj`` (jack);
* the kinetic energy from the body twists, ``T = 1/2 V^T I V`` with
  ``V = (g^{-1} dg/dt)^vee`` and ``I = diag(m, m, J)``, and the potential
  ``V = g (m_box y_box + m_jack y_jack) + [potential]``;
* the Euler-Lagrange equations

  .. math::

      \\frac{d}{dt}\\frac{\\partial L}{\\partial \\dot q} - \\frac{\\partial L}{\\partial q} = Q
      \\quad\\Longrightarrow\\quad M(q)\\,\\ddot q = f(t, q, \\dot q),

  with ``M = d^2 L / dqd^2`` and ``f = Q + dL/dq - (d^2 L / dqd dq) qd - d^2 L / dqd dt``;
* the gap vector ``phi(t, q)`` (jack points against the inner walls in the box
  frame, ``phi = L - n . (g_wb^{-1} g_wj v)``; box corners against the ground),
  its Jacobian ``phi_q`` and, for a prescribed box, ``phi_t``; the gap rates
  ``phi_q qd + phi_t`` and the velocity terms of the gap accelerations
  (``gap_bias``, with ``d^2 phi/dt^2 = phi_q qdd + gap_bias``);
* the energy ``T + V`` of both bodies.

Masses, sizes, inertias, g, restitutions and the user's parameters stay
symbols (the parameter array); only the structure is compiled in. For a
prescribed box the box coordinates are the motion formulas, functions of t.
"""

from __future__ import annotations

import ast
from dataclasses import dataclass

import sympy as sp

from . import expr as _expr
from .spec import BASE_SYMBOLS, BOX_COORDS, CORNER_SIGNS, COORDS, JACK_COORDS, RATES, WALL_NORMALS, ModelSpec

_FUNCTIONS = {
    "sin": sp.sin, "cos": sp.cos, "tan": sp.tan, "asin": sp.asin, "acos": sp.acos,
    "atan": sp.atan, "atan2": sp.atan2, "sinh": sp.sinh, "cosh": sp.cosh, "tanh": sp.tanh,
    "exp": sp.exp, "log": sp.log, "sqrt": sp.sqrt, "abs": sp.Abs,
}


class CodegenError(Exception):
    """The compiler met a model it cannot emit (a bug or an unsupported structure)."""


@dataclass
class ContactFamily:
    """Contacts of one kind, each a gap of the same form with its own geometry.

    ``gap`` is written once in terms of ``symbols`` (a jack point in the jack's
    frame and the inner normal of a wall in the box's frame; or a box corner's
    signs against the ground); ``values`` has, for each contact of the family
    in the order of ``phi``, what those symbols stand for (numbers, or
    parameter slots: a polygon's vertices). ``phi``'s rows are this gap with
    each contact's values put in, and the generated ``contact_rows`` computes
    any contact's row from it.
    """

    symbols: tuple[sp.Symbol, ...]
    values: list[tuple[sp.Expr, ...]]
    gap: sp.Expr

    def rows(self) -> list[sp.Expr]:
        """The gap of each contact of the family."""
        return [self.gap.subs(dict(zip(self.symbols, v)), simultaneous=True) for v in self.values]


#: the symbols of a wall contact: the jack point (X, Y) in the jack's frame, the wall's inner normal (NX, NY)
WALL_SYMBOLS = tuple(sp.Symbol(name, real=True) for name in ("contact_X", "contact_Y", "contact_NX", "contact_NY"))
#: the symbols of a ground contact: the signs (SX, SY) of a box corner
GROUND_SYMBOLS = tuple(sp.Symbol(name, real=True) for name in ("contact_SX", "contact_SY"))


@dataclass
class Model:
    """The symbolic model of one spec: inputs (symbols) and outputs (expressions)."""

    name: str
    structure: dict
    t: sp.Symbol
    q: list[sp.Symbol]            #: the integrated coordinates (3 or 6)
    qd: list[sp.Symbol]
    p: list[sp.Symbol]            #: parameter slots, in array order
    M: sp.Matrix                  #: (n, n) mass matrix
    f: sp.Matrix                  #: (n,) forcing: Q + dL/dq - ...
    phi: sp.Matrix                #: (C,) gaps
    phi_q: sp.Matrix              #: (C, n)
    phi_t: sp.Matrix | None       #: (C,) explicit time derivative (prescribed box only)
    gap_rate: sp.Matrix           #: (C,) d phi / dt = phi_q qd + phi_t
    gap_bias: sp.Matrix           #: (C,) d^2 phi / dt^2 at qdd = 0 (contact accelerations)
    energy: sp.Expr
    box_motion: sp.Matrix | None  #: (6,) pose and rates of a prescribed box
    constraint_names: tuple[str, ...]
    n_wall_contacts: int
    families: tuple[ContactFamily, ...] = ()   #: the walls', then the ground's (the rows of phi, in order)

    @property
    def mass_is_constant_diagonal(self) -> bool:
        n = self.M.shape[0]
        diagonal = all(self.M[i, j] == 0 for i in range(n) for j in range(n) if i != j)
        constant = not self.M.free_symbols & {self.t, *self.q, *self.qd}
        return diagonal and constant


def se2(x, y, theta) -> sp.Matrix:
    """World-from-body homogeneous transform of a planar rigid body."""
    c, s = sp.cos(theta), sp.sin(theta)
    return sp.Matrix([[c, -s, x], [s, c, y], [0, 0, 1]])


def se2_inverse(g: sp.Matrix) -> sp.Matrix:
    R, p = g[:2, :2], g[:2, 2]
    Rt = R.T
    top = Rt.row_join(-Rt * p)
    return top.col_join(sp.Matrix([[0, 0, 1]]))


def kinetic_energy(rate, m, J) -> sp.Expr:
    """Kinetic energy of a planar rigid body from its world-frame rates ``(x', y', theta')``.

    The body twist is ``(R^T p', theta')`` and ``R`` is a rotation, so
    ``T = m |p'|^2 / 2 + J theta'^2 / 2`` exactly: no simplification needed
    (sympy's ``simplify`` of the twist was most of the compiler's time).
    """
    vx, vy, w = rate
    return sp.Rational(1, 2) * (m * (vx**2 + vy**2) + J * w**2)


def frame_inertia(m, L, w):
    """Polar inertia of the square frame from its four wall segments.

    Top and bottom walls: ``2(L+w)`` by ``w`` at distance ``L + w/2``; left and
    right: ``w`` by ``2L`` at the same distance. Mass is shared by area; each
    segment contributes ``m_i (b^2 + h^2) / 12 + m_i d^2`` (parallel axis).
    """
    so, si, d = 2 * (L + w), 2 * L, L + w / 2
    area = so**2 - si**2
    segments = [(so, w), (so, w), (w, si), (w, si)]   # (width, height), all at distance d
    total = 0
    for b, h in segments:
        m_i = m * b * h / area
        total += m_i * (b**2 + h**2) / 12 + m_i * d**2
    return sp.simplify(total)


def to_sympy(text: str, symbols: dict[str, sp.Expr]) -> sp.Expr:
    """Turn a formula into sympy, walking its checked syntax tree (no eval)."""
    tree = _expr.parse(text, set(symbols)).tree

    def walk(node):
        if isinstance(node, ast.Constant):
            value = node.value
            return sp.Integer(value) if isinstance(value, int) else sp.Float(value)
        if isinstance(node, ast.Name):
            return sp.pi if node.id == "pi" else symbols[node.id]
        if isinstance(node, ast.UnaryOp):
            value = walk(node.operand)
            return -value if isinstance(node.op, ast.USub) else value
        if isinstance(node, ast.BinOp):
            a, b = walk(node.left), walk(node.right)
            return {ast.Add: lambda: a + b, ast.Sub: lambda: a - b, ast.Mult: lambda: a * b,
                    ast.Div: lambda: a / b, ast.Pow: lambda: a**b}[type(node.op)]()
        return _FUNCTIONS[node.func.id](*(walk(arg) for arg in node.args))

    return walk(tree)


def gap_terms(gaps: sp.Matrix, t, q, qd, prescribed: bool):
    """``(phi_q, phi_t, gap_rate, gap_bias)`` of a column of gaps (phi_t None for a free box).

    The rates ``phi_q qd + phi_t`` and the velocity-product part of the gap
    accelerations, ``d^2 phi/dt^2 = phi_q qdd + gap_bias``, which persistent
    contacts need; for every row of ``phi``, and for each family's one gap
    (the generated ``contact_rows``).
    """
    phi_q = gaps.jacobian(q)
    phi_t = gaps.diff(t) if prescribed else None
    gap_rate = phi_q * sp.Matrix(qd) + (phi_t if phi_t is not None else sp.zeros(gaps.shape[0], 1))
    gap_bias = gap_rate.jacobian(q) * sp.Matrix(qd) + (gap_rate.diff(t) if prescribed
                                                      else sp.zeros(gaps.shape[0], 1))
    return phi_q, phi_t, gap_rate, gap_bias


def derive(spec: ModelSpec) -> Model:
    """The symbolic model of `spec` (see the module docstring)."""
    t = sp.Symbol("t", real=True)
    p = [sp.Symbol(name, real=True) for name in spec.param_names]
    P = dict(zip(spec.param_names, p))
    coords = {name: sp.Symbol(name, real=True) for name in COORDS}
    rates = {name: sp.Symbol(name, real=True) for name in RATES}
    q = [coords[name] for name in spec.dof_names]
    qd = [rates[f"{name}_dot"] for name in spec.dof_names]

    # Constants every formula may name; inertias and masses are parameter slots.
    base = {"t": t} | {name: P[name] for name in BASE_SYMBOLS}
    base |= {name: P[name] for name in spec.user_params}

    # Box coordinates: symbols (free) or the motion formulas (prescribed).
    box_pose, box_rate = [coords[c] for c in BOX_COORDS], [rates[f"{c}_dot"] for c in BOX_COORDS]
    if spec.prescribed:
        box_pose = [to_sympy(text, base) for text in spec.motion]
        box_rate = [sp.diff(expr, t) for expr in box_pose]
    jack_pose = [coords[c] for c in JACK_COORDS]
    jack_rate = [rates[f"{c}_dot"] for c in JACK_COORDS]
    state = dict(zip(COORDS, box_pose + jack_pose)) | dict(zip(RATES, box_rate + jack_rate))
    names = base | state

    # Kinetic energy from the world-frame rates (the rates of a prescribed pose are its time derivatives).
    T_box = kinetic_energy(box_rate, P["m_box"], P["J_box"])
    T_jack = kinetic_energy(jack_rate, P["m_jack"], P["J_jack"])
    g_wb, g_wj = se2(*box_pose), se2(*jack_pose)
    V_grav = P["g"] * (P["m_box"] * box_pose[1] + P["m_jack"] * jack_pose[1])
    V_extra = sum((to_sympy(text, names) for _, text in sorted(spec.potential)), sp.Integer(0))
    T = sp.expand(T_box + T_jack)
    V = V_grav + V_extra
    Lag = T - V

    n = len(q)
    dL_dqd = [sp.diff(Lag, v) for v in qd]
    M = sp.Matrix(n, n, lambda i, j: sp.simplify(sp.diff(dL_dqd[i], qd[j])))
    forces = dict(spec.forces)
    Q = [to_sympy(forces[c], names) if c in forces else sp.Integer(0) for c in spec.dof_names]
    f = sp.Matrix([
        Q[i] + sp.diff(Lag, q[i])
        - sum(sp.diff(dL_dqd[i], q[j]) * qd[j] for j in range(n))
        - sp.diff(dL_dqd[i], t)
        for i in range(n)
    ])

    # Gaps: jack points in the box frame against the inner walls, then the ground.
    g_bj = se2_inverse(g_wb) * g_wj
    if spec.shape == "polygon":
        points = [(P[f"jack_x{i}"], P[f"jack_y{i}"]) for i in range(spec.n_points)]
    else:
        a = P["a_jack"]
        signs = [(1, 0), (0, 1), (-1, 0), (0, -1)] if spec.shape == "cross" else CORNER_SIGNS
        points = [(int(sx) * a, int(sy) * a) for sx, sy in signs]
    # Each kind of contact's gap is written once, in the symbols of its geometry.
    X, Y, NX, NY = WALL_SYMBOLS
    local = g_bj * sp.Matrix([X, Y, 1])
    families = [ContactFamily(WALL_SYMBOLS, [(x, y, sp.Integer(int(nx)), sp.Integer(int(ny)))
                                             for nx, ny in WALL_NORMALS for x, y in points],
                              P["L"] - (NX * local[0] + NY * local[1]))]
    if spec.ground:
        SX, SY = GROUND_SYMBOLS
        h = P["L"] + P["w_box"]
        families.append(ContactFamily(GROUND_SYMBOLS, [(sp.Integer(int(sx)), sp.Integer(int(sy)))
                                                       for sx, sy in CORNER_SIGNS],
                                      (g_wb * sp.Matrix([SX * h, SY * h, 1]))[1]))
    rows = [row for family in families for row in family.rows()]
    n_wall = len(families[0].values)
    phi = sp.Matrix(rows)
    phi_q, phi_t, gap_rate, gap_bias = gap_terms(phi, t, q, qd, spec.prescribed)
    box_motion = sp.Matrix(box_pose + box_rate) if spec.prescribed else None

    return Model(
        name=spec.name, structure=spec.structure(), t=t, q=q, qd=qd, p=p,
        M=M, f=f, phi=phi, phi_q=phi_q, phi_t=phi_t, gap_rate=gap_rate, gap_bias=gap_bias, energy=T + V, box_motion=box_motion,
        constraint_names=spec.constraint_names, n_wall_contacts=n_wall, families=tuple(families),
    )
