"""The boundary between the compiler and the runtime (README, Layout).

``codegen/`` knows nothing of the runtime: none of its modules imports ``jackbox``
(or reads its files). ``jackbox/`` reaches the compiler through one declared
interface, the names in ``codegen.__all__``, imported from the package's top
level and never from a stage (``codegen.model``, ``codegen.driver`` ...). So there
is no import cycle, and importing the compiler does not import sympy.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

import codegen
import jackbox

from .conftest import BUILTINS

ROOT = Path(__file__).resolve().parent.parent
RUNTIME = ("jackbox", "generated")


def imports(path: Path):
    """(module, imported names, relative level, line) of every import statement in a file."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, (), 0, node.lineno
        elif isinstance(node, ast.ImportFrom):
            yield node.module or "", tuple(a.name for a in node.names), node.level, node.lineno


def sources(package: str) -> list[Path]:
    files = sorted((ROOT / package).rglob("*.py"))
    assert files, package
    return files


def test_codegen_imports_nothing_of_the_runtime():
    found = []
    for path in sources("codegen"):
        where = f"{path.relative_to(ROOT)}:"
        for module, _, level, line in imports(path):
            if level == 0 and module.split(".")[0] in RUNTIME:
                found.append(f"{where}{line} imports {module}")
            if level > 1:        # from .. import x: out of the package
                found.append(f"{where}{line} imports from outside codegen ({'.' * level}{module})")
        # nor by name (importlib, a path to a runtime file)
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and any(
                    node.value == name or node.value.startswith((f"{name}.", f"{name}/")) for name in RUNTIME):
                found.append(f"{where}{node.lineno} names {node.value!r}")
    assert not found, "codegen/ must know nothing of the runtime:\n" + "\n".join(found)


def test_runtime_reaches_codegen_only_through_its_top_level():
    declared = set(codegen.__all__)
    found, used = [], set()
    for path in sources("jackbox"):
        where = f"{path.relative_to(ROOT)}:"
        for module, names, level, line in imports(path):
            if level or module.split(".")[0] != "codegen":
                continue
            if module != "codegen":
                found.append(f"{where}{line} imports {module} (a stage, not the interface)")
            elif undeclared := sorted(set(names) - declared):
                found.append(f"{where}{line} imports {', '.join(undeclared)}, not in codegen.__all__")
            used |= set(names)
    assert not found, "jackbox/ must import only `from codegen import <name in __all__>`:\n" + "\n".join(found)
    assert {"ModelSpec", "generate", "model_hash"} <= used


def test_every_declared_name_exists():
    for name in codegen.__all__:
        assert getattr(codegen, name) is not None, name


def loaded_after(code: str, packages=("jackbox", "generated", "sympy")) -> list[str]:
    """Which of `packages` a new Python process has imported after running `code`."""
    code += f"\nimport sys; print(sorted({{m.split('.')[0] for m in sys.modules}} & {set(packages)!r}))"
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                          check=False, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    return ast.literal_eval(proc.stdout.strip().splitlines()[-1])


def test_importing_codegen_loads_neither_the_runtime_nor_sympy():
    assert loaded_after("import codegen; codegen.ModelSpec, codegen.generate, codegen.parse_formula") == []


def test_importing_jackbox_or_its_program_loads_neither_numpy_nor_numba():
    # the program turns Python's cyclic collector off before they load (cli.console); what the
    # package gives is imported on first use, under the names it always had
    heavy = ("numpy", "numba", "sympy")
    assert loaded_after("import jackbox, jackbox.cli", heavy) == []
    assert loaded_after("from jackbox import simulate, load_scene, Scene, Trajectory; import jackbox; "
                        "jackbox.api.EVENT_TOL, jackbox.errors.SceneError", heavy) == ["numba", "numpy"]
    assert loaded_after("import jackbox; print(callable(jackbox.simulate), jackbox.load_scene('drop').name)",
                        heavy) == ["numba", "numpy"]


def test_a_run_does_not_import_sympy():
    # the runtime imports the compiler's interface, but sympy only when a module must be generated
    assert loaded_after("import jackbox; jackbox.simulate('drop', t_end=0.01)") == ["jackbox"]


@pytest.mark.parametrize("name", BUILTINS)
def test_scene_and_its_model_spec_agree(name):
    scene = jackbox.load_scene(name)
    spec = scene.model_spec()
    assert spec.name == scene.name and spec.command == f"jackbox build {name}"
    assert spec.dof_names == scene.dof_names
    assert spec.constraint_names == scene.constraint_names
    assert spec.structure() == scene.structure()
    assert spec.n_points == len(scene.points) and spec.ground == scene.has_ground_contacts
    assert spec.user_params == tuple(scene.user_params)
    assert spec.param_names == scene.param_names[:len(scene.param_names) - len(spec.user_params)] + spec.user_params


def test_model_spec_is_plain_data():
    spec = jackbox.load_scene("shaken").model_spec()
    # formulas as sorted (name, formula) pairs, so that equal structures compare equal however given
    again = codegen.ModelSpec(**{**vars(spec), "forces": dict(reversed(spec.forces))})
    assert again == spec and hash(again) == hash(spec)
    assert all(isinstance(v, (str, int, bool, tuple)) for v in vars(spec).values())


def test_a_plain_install_ships_every_package_of_the_checkout():
    # an editable install sees the folders; `pip install .` ships only the packages pyproject names
    # (it once left jackbox.engine out, and `import jackbox` failed on a clean install)
    import fnmatch
    import tomllib

    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["tool"]["setuptools"]
    here = {str(init.parent.relative_to(ROOT)).replace("/", ".")
            for top in ("codegen", "generated", "jackbox") for init in (ROOT / top).rglob("__init__.py")}
    packages = config["packages"]
    if isinstance(packages, list):
        shipped = set(packages)
    else:                  # [tool.setuptools.packages.find]: the packages its include patterns match
        shipped = {name for name in here if any(fnmatch.fnmatchcase(name, pattern)
                                                for pattern in packages["find"]["include"])}
    assert "jackbox.engine" in here and here <= shipped, here - shipped


def test_no_engine_function_is_called_with_a_literal_number_or_truth_value():
    # Numba compiles an njit function again for each literal argument it is
    # called with (f(x, False) and f(x, flag) are two compiles, so are
    # run_segment(..., 0, ...) and (..., 1, ...)): a literal handed to an engine
    # function costs a compile of it and of everything it inlines. Constants go
    # in typed (np.int64(0), np.bool_(False)); calls through the model's and the
    # stages' function values are typed by their signatures and are not looked at.
    # A function inlined at Numba's level (inline="always") is never compiled on its
    # own: its body is typed in each caller, where a literal is a constant on purpose
    # (modes.held_solve's counts, so that its loops unroll)
    engine = Path(jackbox.__file__).parent / "engine"
    trees = {path.name: ast.parse(path.read_text(encoding="utf-8")) for path in sorted(engine.glob("*.py"))}
    jitted = {node.name for tree in trees.values() for node in ast.walk(tree)
              if isinstance(node, ast.FunctionDef) and any("njit" in ast.unparse(d) for d in node.decorator_list)
              and not any("inline='always'" in ast.unparse(d) for d in node.decorator_list)}
    assert {"run_segment", "held_accel", "project_rows", "rk4_rows", "log_event"} <= jitted
    found = [f"{name}:{node.lineno} {node.func.id}({ast.unparse(arg)})"
             for name, tree in trees.items() for node in ast.walk(tree)
             if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id in jitted
             for arg in node.args
             if isinstance(arg, ast.Constant) and isinstance(arg.value, (bool, int))]
    assert not found, "literal arguments to engine functions: " + ", ".join(found)
