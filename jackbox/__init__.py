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

from .errors import (JackboxError, NonFiniteStateError, RunStoppedError, SceneError,  # noqa: E402
                     SimulationError, StalledError)
from .scene import Scene, builtin_scenes, load_scene  # noqa: E402
from .trajectory import Trajectory  # noqa: E402
from .api import simulate  # noqa: E402

__all__ = ["JackboxError", "NonFiniteStateError", "RunStoppedError", "Scene", "SceneError", "SimulationError",
           "StalledError", "Trajectory", "builtin_scenes", "load_scene", "simulate", "reference"]


def __getattr__(name):
    if name == "reference":   # imports sympy: only when asked for
        import importlib

        return importlib.import_module(".reference", __name__)
    raise AttributeError(f"module 'jackbox' has no attribute {name!r}")
