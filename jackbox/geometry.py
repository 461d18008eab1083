"""Where the bodies are: outlines and gaps of a whole trajectory, in plain numpy.

The pictures (:mod:`jackbox.plots`, :mod:`jackbox.animate`) draw what a
trajectory file says. :class:`Geometry` reads the shapes from the file itself:
the jack's shape and the ground from its scene text, the sizes (``L``,
``w_box``, ``a_jack`` or the polygon's ``jack_x<i>``, ``jack_y<i>``) from the
parameters the run used (``meta["params"]``), so a run with changed sizes is
drawn as it ran. Everything here works on all samples at once: ``q`` is
``(N, 6)`` and the results have a leading ``N`` axis.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass

import numpy as np

from .errors import JackboxError
from .scene import CORNER_SIGNS, WALL_NORMALS, WALLS, Scene

#: the box's corners (+,+), (-,+), (-,-), (+,-) as multiples of a half side: counter-clockwise
CORNERS = np.array(CORNER_SIGNS)


@dataclass(frozen=True)
class Geometry:
    """The shapes of a scene, as a run used them."""

    shape: str              #: "cross", "square" or "polygon"
    points: np.ndarray      #: (P, 2) the jack's contact points (tips, corners, vertices) in its frame
    L: float                #: half the inner side of the box
    w: float                #: the box's wall thickness
    ground: bool            #: the scene has the ground line y = 0 (drawn)
    ground_contacts: bool   #: ... and the box's corners are held above it (a free box)

    @classmethod
    def from_scene(cls, scene: Scene, params: dict[str, float] | None = None) -> Geometry:
        """The scene's shapes, with sizes from ``params`` (slot name -> value) where given."""
        p = scene.params() | dict(params or {})
        if scene.shape == "polygon":
            points = np.array([[p[f"jack_x{i}"], p[f"jack_y{i}"]] for i in range(len(scene.points))])
        else:
            points = scene.points / np.abs(scene.points).max() * p["a_jack"]
        return cls(scene.shape, points, float(p["L"]), float(p["w_box"]), scene.ground,
                   scene.has_ground_contacts)

    @classmethod
    def from_trajectory(cls, traj) -> Geometry:
        """The shapes of the run that made ``traj``: its scene tables after overrides
        (``meta["scene_tables"]``, else the scene text) and ``meta["params"]``."""
        from .scene import scene_from_tables

        try:
            raw = traj.meta.get("scene_tables") or tomllib.loads(traj.scene)
            scene = scene_from_tables(raw, str(traj.meta.get("scene", "trajectory")), traj.scene)
        except (tomllib.TOMLDecodeError, JackboxError) as exc:
            raise JackboxError(f"the trajectory's scene text cannot be read: {exc}") from None
        params = {k: v for k, v in traj.meta.get("params", {}).items() if k in scene.param_names}
        geometry = cls.from_scene(scene, params)
        names = tuple(traj.constraint_names)
        if names and names != scene.constraint_names:
            raise JackboxError("the trajectory's contacts do not match its scene "
                               f"({len(names)} contacts, the scene has {len(scene.constraint_names)})")
        return geometry

    @property
    def constraint_names(self) -> tuple[str, ...]:
        from .scene import constraint_names

        return constraint_names(len(self.points), self.ground_contacts)

    # --- world coordinates of every sample ------------------------------------------------

    def jack_points(self, q: np.ndarray) -> np.ndarray:
        """(N, P, 2) the jack's contact points in the world frame."""
        q = np.atleast_2d(q)
        return _place(self.points, q[:, 3], q[:, 4], q[:, 5])

    def box_corners(self, q: np.ndarray, inner: bool) -> np.ndarray:
        """(N, 4, 2) the box's inner (side 2L) or outer (side 2(L + w)) corners, counter-clockwise."""
        q = np.atleast_2d(q)
        half = self.L if inner else self.L + self.w
        return _place(CORNERS * half, q[:, 0], q[:, 1], q[:, 2])

    def jack_outline(self, q: np.ndarray) -> np.ndarray:
        """(N, M, 2) a path that draws the jack's true shape.

        A cross is its two arms as one stroke (tip 0 to tip 2 through the
        centre, back to the centre, tip 1 to tip 3); a square or a polygon is
        its closed boundary.
        """
        q = np.atleast_2d(q)
        if self.shape == "cross":
            p = self.points
            local = np.array([p[0], p[2], [0.0, 0.0], p[1], p[3]])
        else:
            local = np.vstack([self.points, self.points[:1]])
        return _place(local, q[:, 3], q[:, 4], q[:, 5])

    def gaps(self, q: np.ndarray) -> np.ndarray:
        """(N, C) the gap of every contact, in the order of :attr:`constraint_names`.

        The same rows as :func:`jackbox.scene.contact_gaps`, for every sample at once.
        """
        q = np.atleast_2d(q)
        world = self.jack_points(q)                                 # (N, P, 2)
        d = world - q[:, None, 0:2]
        c, s = np.cos(q[:, 2])[:, None], np.sin(q[:, 2])[:, None]
        local = np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1]], axis=-1)
        rows = [self.L - local @ np.array(n) for n in WALL_NORMALS]   # 4 x (N, P), wall-major
        if self.ground_contacts:
            rows.append(self.box_corners(q, inner=False)[..., 1])
        return np.concatenate(rows, axis=1)

    def wall_segment(self, q: np.ndarray, wall: str) -> np.ndarray:
        """(N, 2, 2) the ends of one inner wall (``right``, ``top``, ``left``, ``bottom``)."""
        k = WALLS.index(wall)
        corners = self.box_corners(q, inner=True)
        # wall k runs between corners k-1 and k of the (+,+), (-,+), (-,-), (+,-) loop
        return np.stack([corners[:, (k - 1) % 4], corners[:, k]], axis=1)


def _place(local: np.ndarray, x: np.ndarray, y: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """(N, M, 2): the (M, 2) body-frame points placed at the N poses (x, y, theta)."""
    c, s = np.cos(theta)[:, None], np.sin(theta)[:, None]
    px, py = local[:, 0][None, :], local[:, 1][None, :]
    return np.stack([x[:, None] + c * px - s * py, y[:, None] + s * px + c * py], axis=-1)
