"""Stage 3b: lay out the generated module of a model.

``sympy.cse`` runs once per function, over that function's outputs, and its
intermediate terms are numbered from ``_x0`` in each: a function's text
depends on its own outputs only, so a model edit (a new potential term) leaves
the text of the gap functions as it was, and the runtime, which caches each
function's machine code by its text, compiles only what changed. Every
function body has the same shape::

    def phi(t, q, p, out):
        \"\"\"doc\"\"\"
        # Unpack inputs
        x_box = q[0]
        # Intermediate terms (3)
        _x0 = math.sin(theta_box)
        # Output terms
        out[0] = ...
        # Total ops: 42

Functions fill preallocated arrays in place and use only ``math``: Numba
compiles them in nopython mode, and they run as plain Python too. Before a
function is emitted, every free symbol of its outputs is checked against its
declared inputs.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import sympy as sp

from .model import CodegenError, Model, gap_terms
from .printer import KernelPrinter
from .version import GENERATOR, model_hash, seal

#: Inputs a function can take, in signature order.
_ARG_ORDER = ("t", "q", "qd", "p", "sc")


@dataclass
class Function:
    name: str
    args: tuple[str, ...]           #: from _ARG_ORDER
    outputs: list[sp.Expr]          #: flattened outputs
    shape: tuple[int, ...] | None   #: shape of `out`, or None for a scalar return
    doc: str
    tuple_io: bool = False          #: q, qd are tuples and the outputs are returned as a tuple


#: Functions the fused loop's free-flight path also needs in tuple form
#: (``accel_s`` ...): floats in registers, no arrays between the RK4 stages.
TUPLE_TWINS = ("accel", "phi", "gap_rate", "box_motion")


def functions(model: Model) -> list[Function]:
    """The functions a model emits: only those its structure needs."""
    if not model.mass_is_constant_diagonal:
        raise CodegenError(
            f"model {model.name!r}: the mass matrix is not constant and diagonal; "
            "this compiler emits accel() = f / diag(M) and needs it to be")
    n, C = len(model.q), model.phi.shape[0]
    diag = [model.M[i, i] for i in range(n)]
    fs = [
        Function("mass_matrix", ("p",), list(model.M), (n, n),
                 "M: (n, n) mass matrix, constant for this model."),
        Function("inverse_mass", ("p",), [1 / m for m in diag], (n,),
                 "diag(M^-1): (n,) inverse of the (diagonal) mass matrix."),
        Function("forcing", ("t", "q", "qd", "p"), list(model.f), (n,),
                 "f: (n,) right-hand side of M qdd = f (forces, gravity, potential)."),
        Function("accel", ("t", "q", "qd", "p"), [fi / m for fi, m in zip(model.f, diag)], (n,),
                 "qdd: (n,) accelerations M^-1 f between impacts."),
        Function("phi", ("t", "q", "p"), list(model.phi), (C,),
                 "phi: (C,) contact gaps, >= 0 when apart."),
        Function("phi_q", ("t", "q", "p"), list(model.phi_q), (C, n),
                 "phi_q: (C, n) Jacobian of the gaps with respect to q."),
    ]
    fs += [
        Function("gap_rate", ("t", "q", "qd", "p"), list(model.gap_rate), (C,),
                 "(C,) gap rates d phi/dt = phi_q qd + phi_t."),
        Function("gap_bias", ("t", "q", "qd", "p"), list(model.gap_bias), (C,),
                 "(C,) velocity terms of the gap accelerations: d2 phi/dt2 = phi_q qdd + gap_bias."),
    ]
    if model.phi_t is not None:
        fs.append(Function("phi_t", ("t", "q", "p"), list(model.phi_t), (C,),
                           "phi_t: (C,) explicit time derivative of the gaps (moving box)."))
    if model.box_motion is not None:
        fs.append(Function("box_motion", ("t", "p"), list(model.box_motion), (6,),
                           "(6,) the prescribed box's pose (x, y, theta) and rates."))
    fs.append(Function("energy", ("t", "q", "qd", "p"), [model.energy], None,
                       "Kinetic + gravity + [potential] energy of both bodies (a float)."))
    fs += [Function(f"{fn.name}_s", fn.args, fn.outputs, (len(fn.outputs),),
                    f"{fn.name}() for the free-flight loop: q, qd tuples in, a tuple out.", tuple_io=True)
           for fn in fs if fn.name in TUPLE_TWINS]
    lane = _lane_gaps(model)
    if lane is not None:
        fs.append(Function("clearance_v", ("t", "q", "p", "sc"), [lane], None,
                           "The smallest gap, for the lanes of an ensemble block: q a tuple, and sc the "
                           "sines and cosines of the box's and the jack's angles (the engine's own, "
                           "vectorisable), so that the body has no call.", tuple_io=True))
    return fs


#: the lane functions' angles: their sines and cosines come in as the tuple ``sc``
LANE_ANGLES = ("theta_box", "theta_jack")


def lane_symbols() -> tuple[sp.Symbol, ...]:
    """(sin, cos) of each of LANE_ANGLES, the symbols ``sc`` stands for."""
    return tuple(sp.Symbol(f"{f}_{a}", real=True) for a in LANE_ANGLES for f in ("sin", "cos"))


def _lane_gaps(model: Model) -> sp.Expr | None:
    """The smallest gap with the angles' sines and cosines as symbols, or None where that leaves a call.

    A prescribed box turns by a function of time: its lanes would need that
    function's sine, so it has none (its members step one at a time).
    """
    if model.box_motion is not None:
        return None
    angles = {s.name: s for s in model.q}
    if not all(a in angles for a in LANE_ANGLES):
        return None
    sc = iter(lane_symbols())
    trig = {}
    for a in LANE_ANGLES:
        trig[sp.sin(angles[a])] = next(sc)
        trig[sp.cos(angles[a])] = next(sc)
    gaps = [g.subs(trig) for g in model.phi]
    if any(g.has(sp.sin, sp.cos, sp.tan, *(angles[a] for a in LANE_ANGLES)) for g in gaps):
        return None
    return sp.Min(*gaps, evaluate=False)


def _inputs(model: Model) -> dict[str, dict[sp.Symbol, tuple[str, str]]]:
    """For each argument: symbol -> (local name, slot text)."""
    return {
        "t": {model.t: ("t", "")},
        "q": {s: (s.name, f"q[{i}]") for i, s in enumerate(model.q)},
        "qd": {s: (s.name, f"qd[{i}]") for i, s in enumerate(model.qd)},
        "p": {s: (f"p_{s.name}", f"p[{i}]") for i, s in enumerate(model.p)},
        "sc": {s: (s.name, f"sc[{i}]") for i, s in enumerate(lane_symbols())},
    }


def emit_module(model: Model, command: str) -> str:
    """The full text of the generated module for `model`."""
    fs = functions(model)
    inputs = _inputs(model)
    for fn in fs:  # every free symbol must be a declared input of its function
        declared = set().union(*(inputs[a] for a in fn.args))
        stray = set().union(*(e.free_symbols for e in fn.outputs)) - declared
        if stray:
            raise CodegenError(f"{fn.name}: undeclared symbols {sorted(map(str, stray))}")

    # one cse per function, its terms numbered from _x0: a function's text depends on its own
    # outputs only, so an edit that leaves them alone leaves it alone (its machine code stays cached);
    # a tuple twin reuses its array function's terms
    names = {s: local for arg in inputs.values() for s, (local, _) in arg.items()}
    cses = {}
    twins = {f"{name}_s": name for name in TUPLE_TWINS}
    for fn in fs:
        if fn.name not in twins:
            cses[fn.name] = sp.cse(fn.outputs, symbols=sp.numbered_symbols("_x", real=True), order="canonical")
    bodies = []
    for fn in fs:
        replacements, outs = cses[twins.get(fn.name, fn.name)]
        printer = KernelPrinter(names | {sym: sym.name for sym, _ in replacements})
        position = {sym: i for i, (sym, _) in enumerate(replacements)}
        if fn.name == "accel_s":
            bodies += _accel_split(fn, outs, replacements, position, inputs, printer, {model.t, *model.p})
        elif fn.name == "accel":
            # on arrays, the tuple twin's terms as they are: the held step on tuples (the model's ride), on
            # arrays (the engine's rk4) and free flight give the same numbers, whichever takes a step
            bodies.append(f"def accel(t, q, qd, p, out):\n    \"\"\"{fn.doc}\"\"\"\n"
                          "    a = accel_s(t, q, qd, p, accel_time_s(t, p))\n"
                          + "".join(f"    out[{i}] = a[{i}]\n" for i in range(len(fn.outputs))))
        else:
            bodies.append(_function(fn, outs, replacements, position, inputs, printer))

    digest = model_hash(model.structure)
    header = [
        "# " + "-" * 77,
        f"# Generated by {GENERATOR}",
        f"# Model: {model.name}, hash {digest}",
        "# Do NOT modify by hand: regenerate with",
        f"#     {command}",
        "# " + "-" * 77,
        f'"""Equations of motion, gaps and energy of the scene {model.name!r} (generated).',
        "",
        "Coordinates q and rates qd: " + ", ".join(s.name for s in model.q) + ".",
        '"""',
        "",
        "import math",
        "",
        f'MODEL_HASH = "{digest}"',
        f'NAME = "{model.name}"',
        f"N_DOF = {len(model.q)}",
        f"N_PARAM = {len(model.p)}",
        f"N_CONTACT = {model.phi.shape[0]}",
        f"N_WALL_CONTACT = {model.n_wall_contacts}",
        f"PRESCRIBED = {model.box_motion is not None}",
        f"HAS_GROUND = {model.phi.shape[0] > model.n_wall_contacts}",
        # the accelerations are functions of time alone (free bodies under given forces): the free-flight
        # RK4 step needs no stage states (jackbox.engine.flight.rk4_stages)
        f"ACCEL_OF_TIME = {not any(fi.free_symbols & {*model.q, *model.qd} for fi in model.f)}",
        f"DOF_NAMES = {tuple(s.name for s in model.q)!r}",
        f"PARAM_NAMES = {tuple(s.name for s in model.p)!r}",
        f"CONSTRAINT_NAMES = {tuple(model.constraint_names)!r}",
        f"E_SLOT = {[s.name for s in model.p].index('e')}",
        f"E_GROUND_SLOT = {[s.name for s in model.p].index('e_ground')}",
        f"FUNCTIONS = {tuple(fn.name for fn in fs) + ('accel_time_s', 'time_of', 'contact_rows', 'contact_pose_s', 'contact_row_s') + TUPLE_HELPERS!r}",
    ]
    bodies += _contact_rows(model, inputs, names)
    bodies += _tuple_helpers(len(model.q), len(model.p))
    return seal("\n".join(header) + "\n" + "".join("\n\n" + body for body in bodies))


def _contact_rows(model: Model, inputs, names) -> list[str]:
    """``contact_rows(t, q, qd, p, rows, m, out)``: only the rows of the contacts asked for; and for the held
    steps on floats, ``contact_pose_s(t, q, p)``, the terms every contact shares that depend on the pose alone
    (the angles' sines and cosines: a tuple), and ``contact_row_s(t, q, qd, p, pose, k)``, row k as a tuple
    from them: the same terms, so the same numbers. A held step reads several rows at one pose, and the next
    step's first stage reads them at the pose its projection ended on: the pose's terms are computed once.

    For each contact ``k`` of ``rows[:m]``, ``out[k, :n]`` is row k of
    ``phi_q``, ``out[k, n]`` its ``gap_bias``, ``out[k, n + 1]`` its gap and
    ``out[k, n + 2]`` its rate. A step with held contacts needs these rows of a
    few contacts at every stage: this gives them from one call, with each
    angle's sine and cosine computed once, where ``phi_q``, ``gap_bias``,
    ``phi`` and ``gap_rate`` compute every row, each with its own sines.

    Each family of contacts (:class:`~codegen.model.ContactFamily`: jack points
    against the walls, box corners against the ground) has its gap written
    once, in the symbols of its geometry; one ``cse`` runs over the families'
    rows, and its terms that do not depend on a contact's geometry (the
    bodies' poses, their sines and cosines) are computed once per call,
    before the loop over the contacts. A contact's geometry is read from
    tuples by its index (its point, its wall), so the body of each family is
    emitted once, not once per contact.
    """
    n = len(model.q)
    outputs, spans = [], []
    for family in model.families:
        jac, _, rate, bias = gap_terms(sp.Matrix([family.gap]), model.t, model.q, model.qd,
                                       model.box_motion is not None)
        spans.append((len(outputs), len(outputs) + n + 3))
        outputs += list(jac) + [bias[0], family.gap, rate[0]]
    replacements, outs = sp.cse(outputs, symbols=sp.numbered_symbols("_x", real=True), order="canonical")
    geometry = {sym for family in model.families for sym in family.symbols}
    local = {sym: "_" + sym.name[len("contact_"):].lower() for sym in geometry}
    # the terms of a contact's geometry (transitively) go inside the loop; the others before it
    per_contact: set[sp.Symbol] = set()
    for sym, rhs in replacements:
        if rhs.free_symbols & (geometry | per_contact):
            per_contact.add(sym)
    printer = KernelPrinter(names | local | {sym: sym.name for sym, _ in replacements})
    position = {sym: i for i, (sym, _) in enumerate(replacements)}
    needed = _needed(outs, replacements, position)
    shared = [(sym, rhs) for sym, rhs in needed if sym not in per_contact]
    values = [v for family in model.families for row in family.values for v in row]
    used = set().union(*(e.free_symbols for e in outs), *(rhs.free_symbols for _, rhs in needed),
                       *(v.free_symbols for v in values))
    ops = sum(sp.count_ops(rhs) for _, rhs in needed) + sum(sp.count_ops(e) for e in outs)
    branches = len(model.families) > 1

    def head(signature: str, doc: str, keep=lambda sym, rhs: True, given=(), geometry=True,
             args=("t", "q", "qd", "p")) -> list[str]:
        """The function's first lines: its inputs `args` unpacked, the contacts' geometry tuples (where
        `geometry`), the `given` lines, and the shared terms that `keep`."""
        lines = [f"def {signature}:", f'    """{doc}"""', "    # Unpack inputs"]
        for arg in args:
            for sym, (name, slot) in inputs[arg].items():
                if sym in used and slot:
                    lines.append(f"    {name} = {slot}")
        if geometry:
            lines.append("    # Each contact's geometry, by its index in its family")
            for family in model.families:
                for j, sym in enumerate(family.symbols):
                    entries = [repr(float(v[j])) if v[j].is_Number else printer.doprint(v[j]) for v in family.values]
                    lines.append(f"    {local[sym]}s = ({', '.join(entries)},)")
        lines += given
        terms = [(sym, rhs) for sym, rhs in shared if keep(sym, rhs)]
        lines.append(f"    # Terms shared by every contact ({len(terms)})")
        lines += [f"    {printer.doprint(sym)} = {printer.doprint(rhs)}" for sym, rhs in terms]
        return lines

    def contact(at: str, write) -> list[str]:
        """Contact k's terms, each family's in a branch of its own, indented by `at`; write(pad, outs) its output."""
        lines, first = [], 0
        pad = at + ("    " if branches else "")
        for f, (family, (lo, hi)) in enumerate(zip(model.families, spans)):
            if branches:
                last = f == len(model.families) - 1
                lines.append(f"{at}else:" if last else f"{at}{'elif' if f else 'if'} k < {first + len(family.values)}:")
            lines.append(f"{pad}c = k - {first}" if first else f"{pad}c = k")
            lines += [f"{pad}{local[sym]} = {local[sym]}s[c]" for sym in family.symbols]
            terms = [(sym, rhs) for sym, rhs in _needed(outs[lo:hi], replacements, position) if sym in per_contact]
            lines.append(f"{pad}# Terms of the contact ({len(terms)})")
            lines += [f"{pad}{printer.doprint(sym)} = {printer.doprint(rhs)}" for sym, rhs in terms]
            lines += write(pad, outs[lo:hi])
            first += len(family.values)
        return lines

    rows = head("contact_rows(t, q, qd, p, rows, m, out)",
                f"The rows of the m contacts rows[:m]: out[k, :{n}] phi_q[k], out[k, {n}] gap_bias[k], "
                f"out[k, {n + 1}] phi[k], out[k, {n + 2}] gap_rate[k].")
    rows += ["    for i in range(m):", "        k = rows[i]"]
    rows += contact("        ", lambda pad, es: [f"{pad}out[k, {i}] = {_number(printer, e)}" for i, e in enumerate(es)])
    rows += [f"    # Total ops: {ops}", "    return"]

    # the shared terms of the pose alone (no rate in them, transitively): once per pose on floats
    moving: set[sp.Symbol] = set()
    for sym, rhs in shared:
        if rhs.free_symbols & (set(model.qd) | moving):
            moving.add(sym)
    pose = [sym for sym, _ in shared if sym not in moving]
    names_of = ", ".join(printer.doprint(sym) for sym in pose) + ("," if len(pose) == 1 else "")
    at_pose = head("contact_pose_s(t, q, p)",
                   "The terms of contact_rows() that every contact shares and that depend on the pose alone, as a "
                   "tuple: contact_row_s()'s pose (jackbox.engine.flight.ride).",
                   lambda sym, rhs: sym not in moving, geometry=False, args=("t", "q", "p"))
    at_pose.append(f"    return ({names_of})" if pose else "    return (0.0,)")
    row = head("contact_row_s(t, q, qd, p, pose, k)",
               f"Row k of contact_rows() as a tuple of {n + 3} (q, qd tuples), its shared terms of the pose read "
               "from pose = contact_pose_s(t, q, p): the held step's hot path (jackbox.engine.flight.ride).",
               lambda sym, rhs: sym in moving, [f"    {names_of} = pose"] if pose else [])
    row += contact("    ", lambda pad, es: [f"{pad}return ({', '.join(_number(printer, e) for e in es)})"])
    return ["\n".join(rows) + "\n", "\n".join(at_pose) + "\n", "\n".join(row) + "\n"]


#: Tuple arithmetic of length N_DOF emitted with every model (no sympy involved), and the
#: parameters as a tuple
TUPLE_HELPERS = ("tuple_of", "axpy_s", "wsum_s", "params_of", "wdot_s", "row_dot_s", "respond_s", "respond2_s",
                 "respond4_s")


def _tuple_helpers(n: int, n_param: int) -> list[str]:
    """Unrolled n-tuple helpers for the free-flight hot path's RK4 on floats (its tableau is the runtime's)."""
    def tup(item, size=n) -> str:
        return "(" + ", ".join(item(i) for i in range(size)) + ("," if size == 1 else "") + ")"

    return [
        "def tuple_of(a):\n"
        '    """The first N_DOF entries of an array as a tuple."""\n'
        f"    return {tup(lambda i: f'a[{i}]')}\n",
        "def axpy_s(h, x, y):\n"
        '    """y + h x for N_DOF-tuples."""\n'
        f"    return {tup(lambda i: f'y[{i}] + h * x[{i}]')}\n",
        "def wsum_s(y, h, w, k1, k2, k3, k4):\n"
        '    """y + h (w[0] k1 + w[1] k2 + w[2] k3 + w[3] k4) for N_DOF-tuples (a 4-stage update)."""\n'
        f"    return {tup(lambda i: f'y[{i}] + h * (w[0] * k1[{i}] + w[1] * k2[{i}] + w[2] * k3[{i}] + w[3] * k4[{i}])')}\n",
        "def params_of(p):\n"
        '    """The N_PARAM parameters as a tuple (read once, then held in registers: an ensemble block\'s lanes)."""\n'
        f"    return {tup(lambda i: f'p[{i}]', n_param)}\n",
        # the held step's solve on tuples (jackbox.engine.flight.ride): each the operations of the engine's
        # loop on arrays that it stands for, in their order (a sum starts at 0.0, as the loop's does)
        "def wdot_s(x, w, y):\n"
        '    """x M^-1 y for two contact rows (w = diag M^-1): an entry of impact.contact_matrix."""\n'
        "    return 0.0" + "".join(f" + x[{i}] * w[{i}] * y[{i}]" for i in range(n)) + "\n",
        "def row_dot_s(r, a):\n"
        '    """A contact row\'s gap acceleration at accelerations a: its bias plus its Jacobian times a."""\n'
        f"    return r[{n}]" + "".join(f" + r[{i}] * a[{i}]" for i in range(n)) + "\n",
        "def respond_s(a, w, r, x):\n"
        '    """a + M^-1 J^T x for one contact row r (modes.add_response)."""\n'
        f"    return {tup(lambda i: f'a[{i}] + w[{i}] * (0.0 + r[{i}] * x)')}\n",
        "def respond2_s(a, w, r1, x1, r2, x2):\n"
        '    """a + M^-1 J^T x for two contact rows r1, r2 (modes.add_response)."""\n'
        f"    return {tup(lambda i: f'a[{i}] + w[{i}] * (0.0 + r1[{i}] * x1 + r2[{i}] * x2)')}\n",
        "def respond4_s(a, w, r1, x1, r2, x2, r3, x3, r4, x4):\n"
        '    """a + M^-1 J^T x for four contact rows (modes.add_response)."""\n'
        f"    return {tup(lambda i: f'a[{i}] + w[{i}] * (0.0 + r1[{i}] * x1 + r2[{i}] * x2 + r3[{i}] * x3 + r4[{i}] * x4)')}\n",
    ]


def _needed(outs, replacements, position) -> list[tuple[sp.Symbol, sp.Expr]]:
    """The intermediate terms that `outs` need, transitively, in cse order."""
    needed: set[sp.Symbol] = set()
    stack = [s for e in outs for s in e.free_symbols if s in position]
    while stack:
        sym = stack.pop()
        if sym not in needed:
            needed.add(sym)
            stack.extend(s for s in replacements[position[sym]][1].free_symbols if s in position)
    return [(sym, rhs) for sym, rhs in replacements if sym in needed]


def _accel_split(fn: Function, outs, replacements, position, inputs, printer, time_symbols) -> list[str]:
    """``accel_time_s(t, p)`` and ``accel_s(t, q, qd, p, tt)``: accel's terms of t and p alone apart.

    RK4 evaluates accel at three times a step (t, t + dt/2 twice, t + dt), and
    t + dt is the next step's t: terms that depend on the time and the
    parameters only (a shaking force's sine, 1/m) are computed once per stage
    time by ``accel_time_s`` and passed in as the tuple ``tt``. Sums and
    products are regrouped so that their time-only factors form one term.
    """
    temps = _needed(outs, replacements, position)
    timed: set[sp.Symbol] = set()
    for sym, rhs in temps:
        if rhs.free_symbols <= time_symbols | timed:
            timed.add(sym)
    pool = time_symbols | timed
    new: dict[sp.Expr, sp.Symbol] = {}

    def is_time(e) -> bool:
        return bool(e.free_symbols) and e.free_symbols <= pool

    def hoist(e):
        if e.is_Atom:
            return e
        if is_time(e):
            if e not in new:
                new[e] = sp.Symbol(f"_t{len(new)}", real=True)
                printer.names[new[e]] = new[e].name
            return new[e]
        if isinstance(e, (sp.Add, sp.Mul)):
            fixed = [a for a in e.args if is_time(a) or a.is_number]
            rest = [hoist(a) for a in e.args if not (is_time(a) or a.is_number)]
            if any(not a.is_number for a in fixed):     # one term for the time-only part
                return e.func(hoist(e.func(*fixed)), *rest)
            return e.func(*fixed, *rest)
        return e.func(*(hoist(a) for a in e.args))

    state = [(sym, hoist(rhs)) for sym, rhs in temps if sym not in timed]
    outs = [hoist(e) for e in outs]
    refs = set().union(*(e.free_symbols for e in outs), *(rhs.free_symbols for _, rhs in state))
    frontier = [sym for sym, _ in temps if sym in timed and sym in refs]
    frontier += [sym for sym in new.values() if sym in refs]
    time_fn = Function("accel_time_s", ("t", "p"), [], (len(frontier),),
                       "accel()'s terms of t and the parameters alone, once per stage time.", tuple_io=True)
    time_defs = [(sym, rhs) for sym, rhs in temps if sym in timed] + [(sym, e) for e, sym in new.items()]
    head = _function(time_fn, frontier, time_defs, None, inputs, printer, temps=time_defs)
    unpack = [f"    {printer.doprint(sym)} = tt[{i}]" for i, sym in enumerate(frontier)]
    fn = dataclasses.replace(fn, doc="accel() for the free-flight loop: q, qd tuples and tt = accel_time_s(t, p) "
                                     "in, a tuple out.")
    body = _function(fn, outs, state, None, inputs, printer, temps=state, extra_args=("tt",), unpack=unpack)
    items = ", ".join(f"a[k + {i}]" for i in range(len(frontier))) + ("," if len(frontier) == 1 else "")
    read = ("def time_of(a, k):\n"
            '    """accel_time_s()\'s terms read back from a[k:] (an ensemble\'s table of them: '
            'jackbox.engine.lanes)."""\n'
            f"    return ({items})\n")
    return [head, body, read]


def _function(fn: Function, outs, replacements, position, inputs, printer, *, temps=None,
              extra_args=(), unpack=()) -> str:
    if temps is None:
        temps = _needed(outs, replacements, position)
    else:   # given (already in order): keep only those the outputs need
        defined = {sym: rhs for sym, rhs in temps}
        keep, stack = set(), [s for e in outs for s in e.free_symbols if s in defined]
        while stack:
            sym = stack.pop()
            if sym not in keep:
                keep.add(sym)
                stack.extend(s for s in defined[sym].free_symbols if s in defined)
        temps = [(sym, rhs) for sym, rhs in temps if sym in keep]
    used = set().union(*(e.free_symbols for e in outs), *(rhs.free_symbols for _, rhs in temps))

    args = [a for a in _ARG_ORDER if a in fn.args] + list(extra_args) + (
        ["out"] if fn.shape and not fn.tuple_io else [])
    lines = [f"def {fn.name}({', '.join(args)}):", f'    """{fn.doc}"""', "    # Unpack inputs"]
    for arg in fn.args:
        for sym, (local, slot) in inputs[arg].items():
            if sym in used and slot:
                lines.append(f"    {local} = {slot}")
    lines += list(unpack)
    lines.append(f"    # Intermediate terms ({len(temps)})")
    lines += [f"    {printer.doprint(sym)} = {printer.doprint(rhs)}" for sym, rhs in temps]
    lines.append("    # Output terms")
    if fn.shape is None:
        lines.append(f"    result = {_number(printer, outs[0])}")
    elif fn.tuple_io:
        lines.append("    result = (" if outs else "    result = ()")
        lines += [f"        {_number(printer, e)}," for e in outs]
        lines += ["    )"] if outs else []
    else:
        cols = fn.shape[1] if len(fn.shape) == 2 else None
        for i, e in enumerate(outs):
            target = f"out[{i // cols}, {i % cols}]" if cols else f"out[{i}]"
            lines.append(f"    {target} = {_number(printer, e)}")
    ops = sum(sp.count_ops(rhs) for _, rhs in temps) + sum(sp.count_ops(e) for e in outs)
    lines.append(f"    # Total ops: {ops}")
    lines.append("    return result" if fn.shape is None or fn.tuple_io else "    return")
    return "\n".join(lines) + "\n"


def _number(printer: KernelPrinter, e: sp.Expr) -> str:
    text = printer.doprint(e)
    # outputs are floats: an exact integer or zero prints as a float literal
    return f"{text}.0" if e.is_Integer else text
