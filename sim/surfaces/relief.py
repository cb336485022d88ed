"""Relief of a nominally flat sheet: a smooth random height field plus a bow, as real geometry.

A printed sheet mounted on a board cockles where the ink wetted it, a hung fabric folds and
billows: neither is the plane the official pipeline's single homography assumes. The relief is the
height ``z = h(x, y)`` (metres, towards the viewer) over the sheet's rectangle of ``size``:

- a Gaussian random field of RMS ``relief`` and correlation length ``relief_length``
  (correlation ``exp(-r² / relief_length²)``), drawn from ``relief_seed``: white noise blurred by
  a Gaussian of standard deviation ``relief_length / 2``, its mean removed and its RMS set to
  exactly ``relief``;
- a bow ``bow · (1 - (2x / w)²)(1 - (2y / h)²)``: zero along the four edges where the sheet is held,
  ``bow`` at its centre (positive: the centre stands out towards the viewer).

The field lives on a regular grid (:func:`grid_spacing`) and is *piecewise linear* over the
grid's triangles (two per cell, split along the diagonal from the cell's lower-left to its upper
right corner): exactly the triangle mesh Mitsuba renders (:meth:`HeightField.mesh`), so the
geometry procam computes itself (registration's exact map, transport footprints, defocus depths;
:meth:`HeightField.intersect`) and the rendered surface agree to float precision.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np
import scipy.ndimage

from sim import seeds

MM = 1e-3
"""Metres per millimetre (the relief's keys are in millimetres)."""
CELLS_PER_LENGTH = 4
"""Grid cells per correlation length: the piecewise-linear field then follows the smooth field to
a fraction of a percent of its amplitude."""
MIN_CELLS = 64
"""Fewest cells along the longer side (a bow alone is a smooth quadratic)."""
MAX_CELLS = 1024
"""Most cells along the longer side (about a million triangles)."""
NEWTON_STEPS = 30
"""Most Newton steps of a ray's intersection with the field (it converges in a few)."""


@dataclass(frozen=True)
class HeightField:
    """A piecewise-linear height field over the rectangle [-w/2, w/2] × [-h/2, h/2] of the z = 0 plane.

    Attributes
    ----------
    size : (float, float)
        Metres (width, height) of the rectangle.
    heights : numpy.ndarray
        float64 (ny + 1, nx + 1) heights (metres) at the grid's vertices; row 0 at y = -h/2,
        column 0 at x = -w/2.
    """

    size: tuple[float, float]
    heights: np.ndarray

    @property
    def cells(self) -> tuple[int, int]:
        """(nx, ny) grid cells."""
        ny, nx = self.heights.shape
        return nx - 1, ny - 1

    def _cell(self, x: np.ndarray, y: np.ndarray):
        """Cell indices and fractional positions (u, v) in [0, 1] of points (clamped to the
        rectangle; NaN coordinates, rays that never reach z = 0, read cell (0, 0))."""
        (w, h), (nx, ny) = self.size, self.cells
        gx = np.clip(np.nan_to_num((x / w + 0.5) * nx), 0, nx)
        gy = np.clip(np.nan_to_num((y / h + 0.5) * ny), 0, ny)
        i = np.minimum(np.floor(gx).astype(np.int64), nx - 1)
        j = np.minimum(np.floor(gy).astype(np.int64), ny - 1)
        return i, j, gx - i, gy - j

    def height_and_slope(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Height (metres) and its slopes dh/dx, dh/dy at points (x, y) (metres), piecewise linear
        over the grid's triangles; points outside the rectangle take its border's values.

        Examples
        --------
        >>> field = HeightField((2.0, 2.0), np.array([[0.0, 1.0], [1.0, 2.0]]))
        >>> [float(a[0]) for a in field.height_and_slope(np.array([0.5]), np.array([-0.5]))]
        [1.0, 0.5, 0.5]
        """
        (w, h), (nx, ny) = self.size, self.cells
        i, j, u, v = self._cell(np.asarray(x, float), np.asarray(y, float))
        z = self.heights
        h00, h10, h01, h11 = z[j, i], z[j, i + 1], z[j + 1, i], z[j + 1, i + 1]
        lower = u >= v  # the triangle (00, 10, 11) below the diagonal, else (00, 11, 01)
        du = np.where(lower, h10 - h00, h11 - h01)
        dv = np.where(lower, h11 - h10, h01 - h00)
        height = h00 + u * du + v * dv
        return height, du * nx / w, dv * ny / h

    def inside(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """True where (x, y) lies on the rectangle."""
        w, h = self.size
        return (np.abs(x) <= w / 2) & (np.abs(y) <= h / 2)

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> np.ndarray:
        """Ray parameter of the first hit of rays ``origin + t dirs`` with the field from its front
        (+z) side; inf on a miss.

        Newton's method on ``f(t) = o_z + t d_z - h(o_xy + t d_xy)`` from the hit of the z = 0
        plane: exact in a few steps on a piecewise-linear field whose slope along the ray is below
        its descent (rays at well under grazing incidence onto a smooth sheet). Rays that do not
        converge count as misses.
        """
        o = np.broadcast_to(np.asarray(origin, float), np.shape(dirs))
        d = np.asarray(dirs, float)
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.where(d[..., 2] < 0, -o[..., 2] / d[..., 2], np.nan)
            for _ in range(NEWTON_STEPS):
                p = o + t[..., None] * d
                height, sx, sy = self.height_and_slope(p[..., 0], p[..., 1])
                f = p[..., 2] - height
                df = d[..., 2] - sx * d[..., 0] - sy * d[..., 1]
                step = f / df
                t = t - step
                if np.nanmax(np.abs(step), initial=0.0) < 1e-12:
                    break
            p = o + t[..., None] * d
            height, _, _ = self.height_and_slope(p[..., 0], p[..., 1])
            ok = ((t > 1e-6) & (np.abs(p[..., 2] - height) < 1e-9) & self.inside(p[..., 0], p[..., 1])
                  & (df < 0))
        return np.where(ok, t, np.inf)

    def normals(self, points: np.ndarray) -> np.ndarray:
        """Unit normals (+z side) of the triangles under ``points`` (..., 3)."""
        _, sx, sy = self.height_and_slope(points[..., 0], points[..., 1])
        n = np.stack([-sx, -sy, np.ones_like(sx)], axis=-1)
        return n / np.linalg.norm(n, axis=-1, keepdims=True)

    def mesh(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The field as a triangle mesh.

        Returns
        -------
        vertices : numpy.ndarray
            float32 (V, 3) positions (metres), row-major over the grid from (-w/2, -h/2).
        faces : numpy.ndarray
            uint32 (F, 3) counter-clockwise seen from +z, two per cell, split as
            :meth:`height_and_slope` splits them.
        uv : numpy.ndarray
            float32 (V, 2) texture coordinates: (x / w + 1/2, y / h + 1/2), as on Mitsuba's
            rectangle (v = 0 at the bottom edge).
        """
        (w, h), (nx, ny) = self.size, self.cells
        u, v = np.meshgrid(np.linspace(0, 1, nx + 1), np.linspace(0, 1, ny + 1))
        vertices = np.stack([(u - 0.5) * w, (v - 0.5) * h, self.heights], axis=-1).reshape(-1, 3)
        a = (np.arange(ny)[:, None] * (nx + 1) + np.arange(nx)[None]).ravel()
        b, c, d = a + 1, a + nx + 1, a + nx + 2  # right, up, up-right neighbours
        faces = np.concatenate([np.stack([a, b, d], -1), np.stack([a, d, c], -1)])
        uv = np.stack([u, v], axis=-1).reshape(-1, 2)
        return vertices.astype(np.float32), faces.astype(np.uint32), uv.astype(np.float32)


def grid_spacing(size: tuple[float, float], relief_length_mm: float) -> float:
    """Metres between grid vertices: a quarter of the correlation length, but at least
    :data:`MIN_CELLS` and at most :data:`MAX_CELLS` cells along the longer side."""
    longest = max(size)
    spacing = relief_length_mm * MM / CELLS_PER_LENGTH
    return min(max(spacing, longest / MAX_CELLS), longest / MIN_CELLS)


@lru_cache(maxsize=8)
def height_field(size: tuple[float, float], relief_mm: float, relief_length_mm: float, seed: int,
                 bow_mm: float) -> HeightField:
    """The height field of a sheet (see the module docstring), built once per process.

    Parameters
    ----------
    size : (float, float)
        Metres (width, height) of the sheet.
    relief_mm : float
        RMS of the random relief, millimetres (0: none).
    relief_length_mm : float
        Its correlation length, millimetres.
    seed : int
        Seed of the random relief.
    bow_mm : float
        Height of the sheet's centre over its edges, millimetres (positive: towards the viewer).

    Examples
    --------
    >>> field = height_field((1.2, 1.0), 1.0, 40.0, 0, 0.0)
    >>> round(float(np.sqrt(np.mean(field.heights ** 2))) * 1e3, 6)
    1.0
    """
    w, h = size
    spacing = grid_spacing(size, relief_length_mm)
    nx, ny = max(1, math.ceil(w / spacing)), max(1, math.ceil(h / spacing))
    x = np.linspace(-w / 2, w / 2, nx + 1)
    y = np.linspace(-h / 2, h / 2, ny + 1)
    heights = np.zeros((ny + 1, nx + 1))
    if relief_mm > 0:
        sigma = relief_length_mm * MM / 2 / (w / nx), relief_length_mm * MM / 2 / (h / ny)
        pad = [math.ceil(4 * s) for s in sigma]  # white noise beyond the edges: no wrap-around
        noise = np.random.default_rng([seeds.RELIEF_TAG, seed]).standard_normal(
            (ny + 1 + 2 * pad[1], nx + 1 + 2 * pad[0]))
        field = scipy.ndimage.gaussian_filter(noise, (sigma[1], sigma[0]), mode="wrap")
        field = field[pad[1]:pad[1] + ny + 1, pad[0]:pad[0] + nx + 1]
        field -= field.mean()
        heights += field * (relief_mm * MM / np.sqrt(np.mean(field ** 2)))
    if bow_mm != 0:
        heights += bow_mm * MM * np.outer(1 - (2 * y / h) ** 2, 1 - (2 * x / w) ** 2)
    heights.flags.writeable = False
    return HeightField((float(w), float(h)), heights)
