"""Poses, pinhole rays and textured rectangles: the geometry every surface and view shares.

Conventions match Mitsuba 3: ``look_at`` gives a frame whose local +x is ``cross(up, dir)`` (the
image's *left*), +y the image's up and +z the viewing direction. A pinhole with horizontal field of
view ``fov`` maps local direction (x, y, z) to normalised image coordinates
``u = 0.5 - 0.5 x / (z t)`` and ``v = 0.5 - 0.5 y a / (z t)`` with ``t = tan(fov / 2)`` and aspect
``a = width / height`` of the device's own resolution; pixel (column, row) = (u W, v H), row 0 at
the top. Mitsuba's projector emitter uses the same mapping for its irradiance texture. A pinhole
resampled to another pixel grid (the canonical view of a projector) keeps the device's aspect:
its pixels are then not square.

All lengths are in metres, angles in degrees.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Pinhole:
    """A pinhole camera or projector.

    Attributes
    ----------
    position, look_at, up : numpy.ndarray
        Pose in world coordinates (metres).
    fov : float
        Horizontal field of view (degrees).
    width, height : int
        Pixel grid size in pixels.
    aspect : float or None
        Width / height of the image area (the field of view's shape); None: ``width / height``
        (square pixels).
    """

    position: np.ndarray
    look_at: np.ndarray
    up: np.ndarray
    fov: float
    width: int
    height: int
    aspect: float | None = None

    @classmethod
    def from_config(cls, cfg, resolution: tuple[int, int] | None = None) -> "Pinhole":
        """Build from a projector or camera config (``position``, ``look_at``, ``up``, ``fov``,
        ``resolution``). ``resolution`` (width, height) resamples the same image area on another
        pixel grid: the field of view keeps the aspect of the config's resolution."""
        cw, ch = cfg.resolution
        w, h = resolution if resolution is not None else (cw, ch)
        return cls(np.asarray(cfg.position, float), np.asarray(cfg.look_at, float),
                   np.asarray(cfg.up, float), float(cfg.fov), int(w), int(h), float(cw) / float(ch))

    def frame(self) -> np.ndarray:
        """3×3 matrix whose columns are the local x (left), y (up) and z (forward) axes."""
        z = self.look_at - self.position
        z = z / np.linalg.norm(z)
        x = np.cross(self.up, z)
        x = x / np.linalg.norm(x)
        return np.stack([x, np.cross(z, x), z], axis=1)

    @property
    def tan_half(self) -> float:
        return float(np.tan(np.radians(self.fov) / 2))

    @property
    def image_aspect(self) -> float:
        """Width / height of the image area (:attr:`aspect`, or of the pixel grid)."""
        return float(self.aspect) if self.aspect is not None else self.width / self.height

    def pixel_rays(self) -> np.ndarray:
        """Unit world directions through every pixel centre, shape (height, width, 3)."""
        uu, vv = np.meshgrid(np.arange(self.width) + 0.5, np.arange(self.height) + 0.5)
        return self.rays(np.stack([uu, vv], axis=-1))

    def rays(self, pixels: np.ndarray) -> np.ndarray:
        """Unit world directions through continuous pixel coordinates.

        Parameters
        ----------
        pixels : numpy.ndarray
            (..., 2) (column, row) coordinates; pixel centres at integer + 0.5 (the inverse of
            :meth:`project`).

        Returns
        -------
        numpy.ndarray
            (..., 3) unit directions.
        """
        pixels = np.asarray(pixels, float)
        uu, vv = pixels[..., 0] / self.width, pixels[..., 1] / self.height
        t, a = self.tan_half, self.image_aspect
        local = np.stack([-(2 * uu - 1) * t, -(2 * vv - 1) * t / a, np.ones_like(uu)], axis=-1)
        d = local @ self.frame().T
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (..., 3) to pixel coordinates.

        Returns
        -------
        pixels : numpy.ndarray
            (..., 2) continuous (column, row) coordinates; pixel centres at integer + 0.5.
        in_front : numpy.ndarray
            (...) bool, True where the point lies in front of the pinhole.
        """
        local = (points - self.position) @ self.frame()
        z = local[..., 2]
        safe = np.where(z > 1e-9, z, 1e-9)
        t, a = self.tan_half, self.image_aspect
        u = 0.5 - 0.5 * local[..., 0] / (safe * t)
        v = 0.5 - 0.5 * local[..., 1] * a / (safe * t)
        return np.stack([u * self.width, v * self.height], axis=-1), z > 1e-9


@dataclass(frozen=True)
class Rect:
    """A textured rectangle: centre plus two half-axes (metres); normal = cross(ex, ey).

    Texture coordinate s runs 0 → 1 along +ex, t runs 0 → 1 along −ey (row 0 at the top);
    ``tex_span`` is the [s0, s1] part of the surface's albedo texture this rectangle shows.
    """

    center: np.ndarray
    ex: np.ndarray
    ey: np.ndarray
    tex_span: tuple[float, float] = (0.0, 1.0)

    @property
    def normal(self) -> np.ndarray:
        n = np.cross(self.ex, self.ey)
        return n / np.linalg.norm(n)

    def to_world(self) -> np.ndarray:
        """4×4 matrix mapping Mitsuba's rectangle [-1, 1]² (normal +z) onto this rectangle."""
        m = np.eye(4)
        m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = self.ex, self.ey, self.normal, self.center
        return m

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Ray parameter of the hit of rays ``origin + t dirs`` (dirs (..., 3)); inf on a miss."""
        n = self.normal
        denom = dirs @ n
        with np.errstate(divide="ignore", invalid="ignore"):  # rays parallel to the rectangle
            t = ((self.center - origin) @ n) / denom
            hit = origin + t[..., None] * dirs
        rel = hit - self.center
        a = rel @ self.ex / (self.ex @ self.ex)
        b = rel @ self.ey / (self.ey @ self.ey)
        ok = (np.abs(denom) > 1e-12) & (t > 1e-6) & (np.abs(a) <= 1) & (np.abs(b) <= 1)
        return np.where(ok, t, np.inf)


def first_hit(rects: list[Rect], origin: np.ndarray, dirs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nearest hit of rays over several rectangles.

    Returns
    -------
    t : numpy.ndarray
        (...) ray parameter (metres for unit ``dirs``), inf on a miss.
    index : numpy.ndarray
        (...) index of the rectangle hit, -1 on a miss.
    """
    ts = np.stack([r.intersect(origin, dirs) for r in rects], axis=0)
    idx = np.argmin(ts, axis=0)
    t = np.take_along_axis(ts, idx[None], axis=0)[0]
    return t, np.where(np.isfinite(t), idx, -1)
