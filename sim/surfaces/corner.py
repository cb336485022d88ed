"""A room corner: two flat wings meeting at a vertical edge, lighting each other."""
from __future__ import annotations

import numpy as np

from sim.geometry import Rect
from sim.surfaces.base import RectSurface


class Corner(RectSurface):
    """Two wings, each ``config.size`` (width, height), meeting at a vertical edge through the
    origin and opening towards +z by ``config.corner_angle`` degrees (a room corner seen from
    inside; 180 would be flat). The left half of the albedo texture covers the left wing (index 0),
    the right half the right wing (index 1).

    Examples
    --------
    >>> from sim.setup import SurfaceConfig
    >>> corner = Corner(SurfaceConfig(geometry="corner", size=(1.0, 1.0), corner_angle=90.0))
    >>> origin, dirs = np.array([0.0, 0.0, 1.0]), np.array([[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0]])
    >>> t, index = corner.intersect(origin, dirs)
    >>> (origin + t[:, None] * dirs).tolist(), index.tolist()
    ([[-0.5, 0.0, 0.5], [0.5, 0.0, 0.5]], [0, 1])
    """

    name = "corner"
    interreflection = True
    planar = False

    @property
    def texture_aspect(self) -> float:
        return 2 * self.config.size[0] / self.config.size[1]

    def rects(self) -> list[Rect]:
        w, h = self.config.size
        ey = np.array([0.0, h / 2, 0.0])
        half = np.radians(self.config.corner_angle) / 2
        s, c = np.sin(half), np.cos(half)
        left = np.array([-s, 0.0, c])  # from the edge outwards
        right = np.array([s, 0.0, c])
        return [Rect(left * w / 2, -left * w / 2, ey, (0.0, 0.5)),
                Rect(right * w / 2, right * w / 2, ey, (0.5, 1.0))]
