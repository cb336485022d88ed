"""A flat rectangle: the usual projection screen or wall."""
from __future__ import annotations

import numpy as np

from sim.geometry import Rect
from sim.surfaces.base import RectSurface


class Plane(RectSurface):
    """One rectangle of ``config.size`` (width, height) in the z = 0 plane, centred at the origin,
    normal +z, up +y; the albedo texture covers it once.

    Examples
    --------
    >>> from sim.setup import SurfaceConfig
    >>> plane = Plane(SurfaceConfig(geometry="plane", size=(1.2, 1.0)))
    >>> t, index = plane.intersect(np.array([0.0, 0.0, 2.0]), np.array([[0.0, 0.0, -1.0]]))
    >>> float(t[0]), int(index[0])
    (2.0, 0)
    """

    name = "plane"
    interreflection = False
    planar = True

    @property
    def texture_aspect(self) -> float:
        return self.config.size[0] / self.config.size[1]

    def rects(self) -> list[Rect]:
        w, h = self.config.size
        return [Rect(np.zeros(3), np.array([w / 2, 0.0, 0.0]), np.array([0.0, h / 2, 0.0]))]
