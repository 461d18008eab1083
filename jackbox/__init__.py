"""jackbox: a compiler from rigid-body collision scenes to fused Numba kernels.

A hollow square box and a jack inside it, 6 coordinates
``q = [x_box, y_box, theta_box, x_jack, y_jack, theta_jack]``, Euler-Lagrange
dynamics between impacts and Newton impacts at the walls (and the ground)::

    import jackbox
    scene = jackbox.load_scene("shaken")
    traj = jackbox.simulate(scene, t_end=2.0)
    traj.save("shaken.npz")

``jackbox.reference.simulate`` runs the same scene through the slow, obviously
right twin (sympy.lambdify and plain Python); it is imported on first use.
"""

__version__ = "0.1.0"

import importlib as _importlib  # noqa: E402

from .errors import (JackboxError, NonFiniteStateError, RunStoppedError, SceneError,  # noqa: E402
                     SimulationError, StalledError)

__all__ = ["JackboxError", "NonFiniteStateError", "RunStoppedError", "Scene", "SceneError", "SimulationError",
           "StalledError", "Trajectory", "builtin_scenes", "load_scene", "simulate", "reference"]

#: what the package gives, imported on first use: ``import jackbox`` itself loads neither NumPy nor
#: Numba, so the ``jackbox`` program sets its collector up before they load (jackbox.cli.console)
_LAZY = {"Scene": "scene", "builtin_scenes": "scene", "load_scene": "scene", "Trajectory": "trajectory",
         "simulate": "api", "reference": None}


def __getattr__(name):
    if name in _LAZY:
        module = _importlib.import_module(f".{_LAZY[name] or name}", __name__)
        value = module if _LAZY[name] is None else getattr(module, name)
        globals()[name] = value
        return value
    if not name.startswith("_"):      # a module of the package (jackbox.api, ...), as after its import
        try:
            return _importlib.import_module(f".{name}", __name__)
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
    raise AttributeError(f"module 'jackbox' has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_LAZY))
