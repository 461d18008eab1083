"""The compiler: symbolic pieces, the emitted functions against their lambdified twins,
and the committed generated/ modules against a fresh regeneration."""

from __future__ import annotations

import difflib
import os
import subprocess
import sys
import zlib

import numpy as np
import pytest
import sympy as sp

import jackbox
from codegen import generate
from codegen import model as cg_model
from codegen.emitter import emit_module
from codegen.printer import KernelPrinter, UnknownSymbolError
from jackbox import loader, reference
from jackbox.scene import contact_gaps, frame_inertia

from .conftest import BUILTINS

N_STATES = 300


def test_frame_inertia_from_segments_is_the_closed_form():
    m, L, w = sp.symbols("m L w", positive=True)
    so, si = 2 * (L + w), 2 * L
    assert sp.simplify(cg_model.frame_inertia(m, L, w) - m * (so**2 + si**2) / 6) == 0
    # and the runtime's numeric default is the same number
    value = float(cg_model.frame_inertia(m, L, w).subs({m: 1000, L: 5, w: 0.5}))
    assert value == pytest.approx(frame_inertia(1000.0, 5.0, 0.5), rel=1e-15)


def test_cross_of_point_masses_has_inertia_m_a_squared():
    # SCENES.md: four point masses m/4 at the tips; the scene uses J = m a^2
    scene = jackbox.load_scene("spring")
    m, a = scene.params()["m_jack"], scene.params()["a_jack"]
    assert scene.params()["J_jack"] == pytest.approx(sum(m / 4 * a * a for _ in range(4)))


def random_states(scene, n, seed):
    """Random (t, q, qd, p) around the scene's start: angles anywhere, positions in the box."""
    rng = np.random.default_rng(seed)
    dof = len(scene.dof_names)
    L = scene.params()["L"]
    angles = [i for i, name in enumerate(scene.dof_names) if name.startswith("theta")]
    for _ in range(n):
        q = rng.uniform(-L, L, dof)
        q[angles] = rng.uniform(-np.pi, np.pi, len(angles))
        qd = rng.normal(0.0, 3.0, dof)
        p = scene.param_values * rng.uniform(0.5, 1.5, len(scene.param_values))
        yield rng.uniform(0.0, 10.0), q, qd, p


@pytest.mark.parametrize("name", ["shaken", "spring", "drop", "hand", "float"])
def test_generated_functions_match_lambdified_twins(name, all_scenes):
    scene = all_scenes[name]
    gen = loader.load_kernel(loader.ensure_model(scene))   # with Numba, as the kernel runs them
    ref = reference.functions(scene)
    n, C = gen.N_DOF, gen.N_CONTACT
    for t, q, qd, p in random_states(scene, N_STATES, seed=zlib.crc32(name.encode())):
        pairs = [
            ("mass_matrix", _call(gen.mass_matrix, (n, n), p), ref.mass_matrix(p)),
            ("forcing", _call(gen.forcing, (n,), t, q, qd, p), ref.forcing(t, q, qd, p)),
            ("accel", _call(gen.accel, (n,), t, q, qd, p), ref.accel(t, q, qd, p)),
            ("inverse_mass", _call(gen.inverse_mass, (n,), p), 1.0 / np.diag(ref.mass_matrix(p))),
            ("phi", _call(gen.phi, (C,), t, q, p), ref.phi(t, q, p)),
            ("phi_q", _call(gen.phi_q, (C, n), t, q, p), ref.phi_q(t, q, p)),
            ("energy", gen.energy(t, q, qd, p), ref.energy(t, q, qd, p)),
        ]
        if scene.prescribed:
            pairs += [("phi_t", _call(gen.phi_t, (C,), t, q, p), ref.phi_t(t, q, p)),
                      ("box_motion", _call(gen.box_motion, (6,), t, p), ref.box_motion(t, p))]
        for what, got, want in pairs:
            # rtol 1e-12: cse only reorders the same float operations. Entries that
            # cancel to ~0 get an absolute floor of 1e-12 times the array's scale.
            scale = max(1.0, float(np.abs(want).max()))
            np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * scale,
                                       err_msg=f"{name}.{what} at t={t}, q={q}, qd={qd}")


@pytest.mark.parametrize("name", ["shaken", "drop", "hand", "float"])
def test_contact_rows_are_the_lambdified_rows_of_the_contacts_asked_for(name, all_scenes):
    # contact_rows writes the gap form of each family once (jack point against a wall, box
    # corner against the ground) with the contact's geometry read by its index: each row must be
    # that contact's row of phi_q, gap_bias, phi and gap_rate, and the rows not asked for untouched.
    # And the held steps' rows on floats (contact_row_s, from contact_pose_s's terms of the pose) are
    # contact_rows' to the bit (a prescribed box's pose depends on t: hand)
    scene = all_scenes[name]
    gen = loader.load_kernel(loader.ensure_model(scene))
    rows_of, pose_of, row_of = gen.jit("contact_rows"), gen.jit("contact_pose_s"), gen.jit("contact_row_s")
    ref = reference.functions(scene)
    n, C = gen.N_DOF, gen.N_CONTACT
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    for t, q, qd, p in random_states(scene, 60, seed=zlib.crc32(name.encode()) + 1):
        asked = rng.permutation(C)[:rng.integers(1, C + 1)]
        out = np.full((C, n + 3), np.nan)
        rows_of(t, q, qd, p, asked.astype(np.int64), len(asked), out)
        rate = ref.phi_q(t, q, p) @ qd + (ref.phi_t(t, q, p) if ref.phi_t else 0.0)
        want = np.column_stack([ref.phi_q(t, q, p), ref.gap_bias(t, q, qd, p), ref.phi(t, q, p), rate])
        scale = max(1.0, float(np.abs(want).max()))
        np.testing.assert_allclose(out[asked], want[asked], rtol=1e-12, atol=1e-12 * scale,
                                   err_msg=f"{name} rows {asked} at t={t}, q={q}, qd={qd}")
        assert np.isnan(np.delete(out, asked, axis=0)).all()
        pose = pose_of(t, tuple(q), p)
        for k in asked:
            assert row_of(t, tuple(q), tuple(qd), p, pose, k) == tuple(out[k]), (name, k, t, q, qd)


def _call(fn, shape, *args):
    out = np.full(shape, np.nan)
    fn(*args, out)
    return out


@pytest.mark.parametrize("name", ["drop", "hand"])
def test_symbolic_gaps_match_the_plain_numpy_geometry(name, all_scenes):
    # scene.contact_gaps (used to refuse penetrating starts) is written independently
    scene = all_scenes[name]
    ref = reference.functions(scene)
    for t, q, qd, p in random_states(scene, 50, seed=7):
        q6 = np.concatenate([ref.box_motion(t, p)[:3], q]) if scene.prescribed else q
        pp = dict(zip(scene.param_names, p))
        points = (scene.points / scene.params()["a_jack"] * pp["a_jack"]) if "a_jack" in pp else np.array(
            [[pp[f"jack_x{i}"], pp[f"jack_y{i}"]] for i in range(len(scene.points))])
        want = contact_gaps(q6, points, pp["L"], pp["w_box"], scene.has_ground_contacts)
        np.testing.assert_allclose(ref.phi(t, q, p), want, rtol=1e-12, atol=1e-12)


def test_only_what_the_scene_has_is_emitted(all_scenes):
    shaken = loader.load_kernel(loader.ensure_model(all_scenes["shaken"]))
    drop = loader.load_kernel(loader.ensure_model(all_scenes["drop"]))
    hand = loader.load_kernel(loader.ensure_model(all_scenes["hand"]))
    # no ground: no ground rows; ground: 4 more
    assert (shaken.N_CONTACT, drop.N_CONTACT) == (16, 20)
    # a prescribed box has no DOFs, and brings its motion and phi_t
    assert hand.N_DOF == 3 and hand.PRESCRIBED and {"phi_t", "box_motion"} <= set(hand.FUNCTIONS)
    assert not {"phi_t", "box_motion"} & set(shaken.FUNCTIONS)
    # a hexagon has 6 contact points per wall
    assert hand.N_CONTACT == 24
    # no forces, no potential: drop's forcing is gravity only, with no time dependence
    text = loader.ensure_model(all_scenes["drop"]).read_text()
    forcing = text[text.index("def forcing"):text.index("def accel")]
    assert "math." not in forcing and "q[" not in forcing and "qd[" not in forcing


def test_every_symbol_must_be_declared():
    x, y = sp.symbols("x y")
    printer = KernelPrinter({x: "x"})
    assert printer.doprint(x**2 + 1) == "x*x + 1"
    with pytest.raises(UnknownSymbolError):
        printer.doprint(x + y)


def test_emitter_refuses_a_model_whose_outputs_use_undeclared_symbols():
    scene = jackbox.load_scene("drop")
    m = cg_model.derive(scene.model_spec())
    m.phi = m.phi.col_join(sp.Matrix([sp.Symbol("stray")]))
    m.phi_q = m.phi.jacobian(m.q)
    with pytest.raises(cg_model.CodegenError, match="stray"):
        emit_module(m, "jackbox build drop")


@pytest.mark.parametrize("name", BUILTINS)
def test_committed_generated_module_is_current(name):
    scene = jackbox.load_scene(name)
    fresh, _ = generate(scene.model_spec())
    committed = (loader.GENERATED_DIR / f"{name}.py").read_text()
    if fresh != committed:
        diff = "".join(difflib.unified_diff(committed.splitlines(True), fresh.splitlines(True),
                                            f"generated/{name}.py (committed)", "regenerated"))
        pytest.fail(f"generated/{name}.py is stale: run `jackbox build {name}` and commit.\n{diff[:5000]}")


def test_regeneration_is_byte_identical_across_processes():
    # set iteration order depends on the hash seed; the output must not
    code = "from codegen import generate; import jackbox; print(generate(jackbox.load_scene('spring').model_spec())[0])"
    texts = {subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                            env=os.environ | {"PYTHONHASHSEED": seed}).stdout
             for seed in ("1", "2", "3")}
    assert len(texts) == 1


def test_generated_header():
    text = (loader.GENERATED_DIR / "shaken.py").read_text()
    head = text.splitlines()[:6]
    assert head[1].startswith("# Generated by jackbox-codegen")
    assert "Do NOT modify by hand" in text.split('"""')[0]
    assert any("jackbox build shaken" in line for line in head)
    assert "time" not in text.split('"""')[0].lower()   # no timestamps
    assert f'MODEL_HASH = "{loader.model_hash(jackbox.load_scene("shaken").structure())}"' in text
