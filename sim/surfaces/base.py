"""The :class:`Surface` interface: the shape the projector lights and the camera sees.

A surface is built from the keys of a setup's surface section that shape it (``size``,
``texture_resolution`` and the surface's own options, :attr:`Surface.Options`) and answers every
question the simulator asks about geometry: the Mitsuba shapes with the albedo texture laid out over them,
the first hit of rays (registration, light-transport footprints), the normal at a hit, the depth of
each projector pixel's hit, and whether its parts light each other. :class:`RectSurface` implements
it for surfaces made of flat textured rectangles.

World: metres; the surface's reference point is the origin, its front faces +z (see
:mod:`sim.setup`).
"""
from __future__ import annotations

import abc
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from sim.geometry import Pinhole, Rect, first_hit


@dataclass(frozen=True)
class Surface(abc.ABC):
    """A projection surface.

    Attributes
    ----------
    size : (float, float)
        Metres (width, height) of the surface (``surface.size``; what it measures is the shape's).
    texture_resolution : int
        Pixels along the longest side of the albedo texture (``surface.texture_resolution``).
    options : Options
        The surface's own options (``surface.*`` keys only this shape takes).
    """

    size: tuple[float, float]
    texture_resolution: int
    options: Any

    name: ClassVar[str]
    """Registry name, the value of ``surface.geometry`` in a setup file."""
    interreflection: ClassVar[bool]
    """True when parts of the surface light each other: only path tracing of depth >= 3 renders it,
    and the light transport is dense."""
    planar: ClassVar[bool]
    """True for a single plane: a homography maps projector pixels to camera pixels."""
    Options: ClassVar[type]
    """The frozen dataclass of the surface's own options, each field declared with
    :mod:`sim.options` (unit, range) and documented; a setup file gives them as keys of its
    ``[surface]`` table, and they are refused for any other surface."""

    def __post_init__(self):
        if not isinstance(self.options, self.Options):
            raise TypeError(f"{type(self).__name__}: options {self.options!r}: expected "
                            f"{self.Options.__name__}")

    @property
    @abc.abstractmethod
    def texture_aspect(self) -> float:
        """Width over height of the albedo texture laid over the whole surface."""

    def texture_size(self) -> tuple[int, int]:
        """(width, height) in pixels of the albedo texture: :attr:`texture_resolution` along the
        longest side, the other side keeping :attr:`texture_aspect` (at least 1 pixel)."""
        aspect, longest = self.texture_aspect, self.texture_resolution
        if aspect >= 1:
            return longest, max(1, round(longest / aspect))
        return max(1, round(longest * aspect)), longest

    @abc.abstractmethod
    def shapes(self, albedo: np.ndarray, bsdf: Callable[[np.ndarray], dict]) -> dict:
        """Mitsuba scene entries of the surface.

        Parameters
        ----------
        albedo : numpy.ndarray
            float32 (H, W, 3) albedo texture of the whole surface, row 0 at the top, of
            :meth:`texture_size`.
        bsdf : callable
            Maps the part of ``albedo`` one shape shows (rows top to bottom) to its BSDF dict.

        Returns
        -------
        dict
            Shape dicts by scene key.
        """

    @abc.abstractmethod
    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """First hit of rays ``origin + t dirs`` with the surface.

        Parameters
        ----------
        origin : numpy.ndarray
            (3,) or (..., 3) ray origins (metres), broadcast against ``dirs``.
        dirs : numpy.ndarray
            (..., 3) ray directions.

        Returns
        -------
        t : numpy.ndarray
            (...) ray parameter of the nearest hit (metres for unit ``dirs``), inf on a miss.
        index : numpy.ndarray
            (...) index of the surface part hit, -1 on a miss.
        """

    @abc.abstractmethod
    def normals(self, points: np.ndarray, index: np.ndarray) -> np.ndarray:
        """Unit front-facing normals (..., 3) at hit ``points`` (..., 3) on parts ``index`` (...)
        from :meth:`intersect`; arbitrary where ``index`` is -1."""

    def projector_depth(self, projector: Pinhole) -> np.ndarray:
        """Depth of each projector pixel's first hit: its distance along the optical axis.

        Parameters
        ----------
        projector : Pinhole
            The projector (pose, field of view, pixel grid).

        Returns
        -------
        numpy.ndarray
            float (height, width) metres; inf where the pixel's ray misses the surface.
        """
        rays = projector.pixel_rays()
        t, _ = self.intersect(projector.position, rays)
        return t * (rays @ projector.frame()[:, 2])


class RectSurface(Surface):
    """A surface made of flat textured rectangles (:class:`~sim.geometry.Rect`)."""

    @abc.abstractmethod
    def rects(self) -> list[Rect]:
        """The rectangles, each with the span of the albedo texture it shows."""

    def shapes(self, albedo: np.ndarray, bsdf: Callable[[np.ndarray], dict]) -> dict:
        import mitsuba as mi

        w = albedo.shape[1]
        return {f"surface_{i}": {"type": "rectangle",
                                 "to_world": mi.ScalarTransform4f(rect.to_world().tolist()),
                                 "bsdf": bsdf(albedo[:, round(rect.tex_span[0] * w):round(rect.tex_span[1] * w)])}
                for i, rect in enumerate(self.rects())}

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return first_hit(self.rects(), origin, dirs)

    def normals(self, points: np.ndarray, index: np.ndarray) -> np.ndarray:
        return np.stack([r.normal for r in self.rects()])[np.maximum(index, 0)]
