"""A flat rectangle, the usual projection screen or wall, or a sheet with relief (:mod:`sim.surfaces.relief`)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from sim.geometry import Rect
from sim.options import Range, integer, number
from sim.seeds import SEED_MAX
from sim.surfaces.base import RectSurface
from sim.surfaces.relief import HeightField, height_field


@dataclass(frozen=True)
class PlaneOptions:
    """The options only a plane takes (keys of the ``[surface]`` table): its relief. All zero (the
    default) is the exact plane."""

    relief: float = number(0.0, Range(0, 50), "millimetres")
    """Millimetres, in [0, 50]: RMS height of the sheet's smooth random relief (cockle of a printed
    sheet, folds of a hung fabric); 0: none."""
    relief_length: float = number(30.0, Range(5, 1000), "millimetres")
    """Millimetres, in [5, 1000]: correlation length of the relief (its correlation is
    exp(-r² / relief_length²))."""
    relief_seed: int = integer(0, Range(0, SEED_MAX))
    """Seed (>= 0) of the random relief."""
    bow: float = number(0.0, Range(-100, 100), "millimetres")
    """Millimetres, in [-100, 100]: height of the sheet's centre over its edges (a board's or a
    mounted sheet's bow; positive towards the viewer); 0: none."""

    @property
    def flat(self) -> bool:
        """True when the sheet has neither relief nor bow."""
        return self.relief == 0 and self.bow == 0


class Plane(RectSurface):
    """One rectangle of ``size`` (width, height) in the z = 0 plane, centred at the origin,
    normal +z, up +y; the albedo texture covers it once. With ``relief`` or ``bow`` the sheet is
    displaced along z by its height field (:func:`sim.surfaces.relief.height_field`) and rendered
    as a triangle mesh; its outline seen from +z stays the rectangle.

    Examples
    --------
    >>> plane = Plane((1.2, 1.0), 512, PlaneOptions())
    >>> t, index = plane.intersect(np.array([0.0, 0.0, 2.0]), np.array([[0.0, 0.0, -1.0]]))
    >>> float(t[0]), int(index[0])
    (2.0, 0)
    >>> bowed = Plane((1.2, 1.0), 512, PlaneOptions(bow=5.0))
    >>> t, index = bowed.intersect(np.array([0.0, 0.0, 2.0]), np.array([[0.0, 0.0, -1.0]]))
    >>> round(float(t[0]), 9), int(index[0])
    (1.995, 0)
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

    @cached_property
    def field(self) -> HeightField | None:
        """The sheet's height field; None for the exact plane."""
        o = self.options
        if o.flat:
            return None
        return height_field(tuple(map(float, self.size)), float(o.relief), float(o.relief_length),
                            int(o.relief_seed), float(o.bow))

    def shapes(self, albedo: np.ndarray, bsdf: Callable[[np.ndarray], dict]) -> dict:
        if self.field is None:
            return super().shapes(albedo, bsdf)
        import mitsuba as mi

        vertices, faces, uv = self.field.mesh()
        props = mi.Properties()
        props["bsdf"] = mi.load_dict(bsdf(albedo))
        mesh = mi.Mesh("surface_0", len(vertices), len(faces), props=props, has_vertex_normals=True,
                       has_vertex_texcoords=True)
        params = mi.traverse(mesh)
        for key, values in (("vertex_positions", vertices), ("faces", faces), ("vertex_texcoords", uv)):
            params[key] = type(params[key])(values.ravel())  # the variant's buffer type
        params.update()
        mesh.recompute_vertex_normals()
        return {"surface_0": mesh}

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if self.field is None:
            return super().intersect(origin, dirs)
        t = self.field.intersect(origin, dirs)
        return t, np.where(np.isfinite(t), 0, -1)

    def normals(self, points: np.ndarray, index: np.ndarray) -> np.ndarray:
        if self.field is None:
            return super().normals(points, index)
        return self.field.normals(points)
