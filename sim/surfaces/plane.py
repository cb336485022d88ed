"""A flat rectangle: the usual projection screen or wall."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.geometry import Rect
from sim.surfaces.base import RectSurface


@dataclass(frozen=True)
class PlaneOptions:
    """A plane takes no options of its own (its ``size`` is the surface section's)."""


class Plane(RectSurface):
    """One rectangle of ``size`` (width, height) in the z = 0 plane, centred at the origin,
    normal +z, up +y; the albedo texture covers it once.

    Examples
    --------
    >>> plane = Plane((1.2, 1.0), 512, PlaneOptions())
    >>> t, index = plane.intersect(np.array([0.0, 0.0, 2.0]), np.array([[0.0, 0.0, -1.0]]))
    >>> float(t[0]), int(index[0])
    (2.0, 0)
    """

    name = "plane"
    interreflection = False
    planar = True
    Options = PlaneOptions

    @property
    def texture_aspect(self) -> float:
        return self.size[0] / self.size[1]

    def rects(self) -> list[Rect]:
        w, h = self.size
        return [Rect(np.zeros(3), np.array([w / 2, 0.0, 0.0]), np.array([0.0, h / 2, 0.0]))]
