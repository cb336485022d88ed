"""A room corner: two flat wings meeting at a vertical edge, lighting each other."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.geometry import Rect
from sim.options import Range, number
from sim.surfaces.base import RectSurface


@dataclass(frozen=True)
class CornerOptions:
    """The options only a corner takes (keys of the ``[surface]`` table)."""

    corner_angle: float = number(90.0, Range(30, 180, lo_open=True, hi_open=True), "degrees")
    """Degrees, opening angle between the two wings, in (30, 180) (90: a room corner)."""


class Corner(RectSurface):
    """Two wings, each ``size`` (width, height), meeting at a vertical edge through the origin
    and opening towards +z by ``options.corner_angle`` degrees (a room corner seen from inside;
    180 would be flat). The left half of the albedo texture covers the left wing (index 0), the
    right half the right wing (index 1).

    Examples
    --------
    >>> corner = Corner((1.0, 1.0), 512, CornerOptions(corner_angle=90.0))
    >>> origin, dirs = np.array([0.0, 0.0, 1.0]), np.array([[-1.0, 0.0, -1.0], [1.0, 0.0, -1.0]])
    >>> t, index = corner.intersect(origin, dirs)
    >>> (origin + t[:, None] * dirs).tolist(), index.tolist()
    ([[-0.5, 0.0, 0.5], [0.5, 0.0, 0.5]], [0, 1])
    """

    name = "corner"
    interreflection = True
    planar = False
    Options = CornerOptions

    @property
    def texture_aspect(self) -> float:
        return 2 * self.size[0] / self.size[1]

    def rects(self) -> list[Rect]:
        w, h = self.size
        ey = np.array([0.0, h / 2, 0.0])
        half = np.radians(self.options.corner_angle) / 2
        s, c = np.sin(half), np.cos(half)
        left = np.array([-s, 0.0, c])  # from the edge outwards
        right = np.array([s, 0.0, c])
        return [Rect(left * w / 2, -left * w / 2, ey, (0.0, 0.5)),
                Rect(right * w / 2, right * w / 2, ey, (0.5, 1.0))]
