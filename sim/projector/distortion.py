"""The projection lens's radial distortion about its offset axis (the stage :data:`DISTORTION`).

Geometry, in panel pixels (x right, y down; pixel ``(i, j)`` has its centre at
``(i + 0.5, j + 0.5)``): real projectors throw their image above the lens axis, so the axis meets
the panel's plane at ``a = (W / 2, H / 2 + lens_offset H)``, below the image centre; radii are
normalised by the panel's half-diagonal ``R = sqrt(W**2 + H**2) / 2`` (as the camera's in
:mod:`sim.camera.optics`).

Brown's radial model: the panel point ``x`` at normalised radius ``rho = |x - a| / R`` leaves along
the ray of the ideal (pinhole) grid point ``u = a + (x - a) g(rho)``, ``g = 1 + k1 rho**2 + k2 rho**4``
(:func:`distort_points`); ``k1 < 0`` is barrel, ``k1 > 0`` pincushion. The stage resamples the
lens's output, on its padded grid (:class:`~sim.projector.Lens`), accordingly: the emitted light at
``u`` is the light of ``x = distort^-1(u)`` (bilinear, ``cv2.remap`` with maps made once per
configuration, :func:`distortion_maps`) times the Jacobian ``|det dx/du| = 1 / (g f')`` with
``f(rho) = rho g(rho)`` the radial map, so the total flux is kept: exactly for light smooth over a
few pixels, and up to the moiré of bilinear resampling for detail at the pixel's scale (about 1 %
of the flux of a spot a few pixels wide). Light distorted past the padded grid's edge is lost (the
emitter covers that grid only).

Only the distortion's centre moves with ``lens_offset``: the projector's pinhole geometry (its
axis aimed at ``look_at``) is unchanged, because on a plane a shifted principal point changes the
image by a homography alone, which registration absorbs.
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from sim.errors import ProcamError
from sim.options import Range, number
from sim.stages import Stage

TABLE_SIZE = 65537
"""Samples of the radial map the inverse is interpolated from (over the padded grid's radii)."""


def _axis_and_radius(panel: tuple[int, int], lens_offset: float) -> tuple[np.ndarray, float]:
    w, h = panel
    return np.array([w / 2.0, h / 2.0 + lens_offset * h]), float(np.hypot(w, h) / 2.0)


def distort_points(xy, panel: tuple[int, int], k1: float, k2: float,
                   lens_offset: float) -> np.ndarray:
    """Where panel points leave the lens: their ideal (pinhole) grid coordinates.

    Parameters
    ----------
    xy : array_like
        (..., 2) panel coordinates in pixels (x right, y down; pixel centres at +0.5).
    panel : (int, int)
        Panel (width, height) in pixels.
    k1, k2 : float
        Brown's radial coefficients (radius normalised by the panel's half-diagonal).
    lens_offset : float
        The lens axis lies this fraction of the panel height below the image centre.

    Returns
    -------
    numpy.ndarray
        float64 (..., 2) ideal grid coordinates, in panel pixels.

    Examples
    --------
    >>> distort_points([[50.0, 0.0], [50.0, 50.0], [50.0, 100.0]], (100, 100), 0.1, 0.0, 0.5).tolist()
    [[50.0, -20.0], [50.0, 47.5], [50.0, 100.0]]
    """
    p = np.asarray(xy, np.float64)
    a, r = _axis_and_radius(panel, lens_offset)
    rho2 = np.sum(((p - a) / r) ** 2, axis=-1, keepdims=True)
    return a + (p - a) * (1.0 + k1 * rho2 + k2 * rho2 * rho2)


def outward_reach(panel: tuple[int, int], k1: float, k2: float, lens_offset: float) -> int:
    """Whole pixels by which the distorted panel reaches beyond the panel's rectangle (0 for barrel
    distortion, which draws the image in): the padding the lens's grid needs so that the light of
    the panel's edges is not lost (:func:`sim.projector.lens_for`).

    Examples
    --------
    >>> outward_reach((100, 100), -0.05, 0.0, 0.0), outward_reach((100, 100), 0.05, 0.0, 0.0)
    (0, 3)
    """
    if k1 == 0 and k2 == 0:
        return 0
    w, h = panel
    t = np.linspace(0.0, 1.0, 257)
    border = np.concatenate([np.stack([t * w, np.zeros_like(t)], -1), np.stack([t * w, np.full_like(t, h)], -1),
                             np.stack([np.zeros_like(t), t * h], -1), np.stack([np.full_like(t, w), t * h], -1)])
    u = distort_points(border, panel, k1, k2, lens_offset)
    beyond = np.maximum.reduce([-u[:, 0], u[:, 0] - w, -u[:, 1], u[:, 1] - h, np.zeros(len(u))])
    return int(np.ceil(beyond.max() - 1e-9))


@functools.lru_cache(maxsize=8)
def distortion_maps(panel: tuple[int, int], pad: int, k1: float, k2: float,
                    lens_offset: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The resampling of the stage on the padded grid (see the module docstring).

    Parameters
    ----------
    panel : (int, int)
        Panel (width, height) in pixels.
    pad : int
        The lens's padding (pixels each side).
    k1, k2, lens_offset : float
        The stage's keys.

    Returns
    -------
    mx, my : numpy.ndarray
        float32 (H + 2 pad, W + 2 pad): for each grid pixel, the padded-grid position whose light
        it receives (``cv2.remap``'s convention: pixel centres at integers). Read-only, cached.
    jacobian : numpy.ndarray
        float32 (H + 2 pad, W + 2 pad, 1): ``|det dx/du|``; 0 where the light would come from
        beyond the padded grid's farthest radius. Read-only, cached.

    Raises
    ------
    ProcamError
        If the radial map folds over within the padded grid (``f' <= 0``: no lens does that).
    """
    w, h = panel
    a, r = _axis_and_radius(panel, lens_offset)
    corners = np.array([[-pad, -pad], [w + pad, -pad], [-pad, h + pad], [w + pad, h + pad]], float)
    rho_max = float(np.max(np.linalg.norm(corners - a, axis=1)) / r)
    rho = np.linspace(0.0, rho_max, TABLE_SIZE)
    s = rho * rho
    slope = 1.0 + 3.0 * k1 * s + 5.0 * k2 * s * s  # f'(rho)
    if slope.min() <= 0:
        fold = float(rho[np.argmax(slope <= 0)])
        raise ProcamError(
            f"projector.distortion_k1 = {k1:g}, distortion_k2 = {k2:g} with lens_offset = "
            f"{lens_offset:g}: the lens distortion folds the image over {fold:.2f} half-diagonals "
            f"from the lens axis, within the projector's image (which reaches {rho_max:.2f}); "
            "expected smaller coefficients")
    f = rho * (1.0 + k1 * s + k2 * s * s)
    x, y = np.meshgrid(np.arange(w + 2 * pad) + 0.5 - pad, np.arange(h + 2 * pad) + 0.5 - pad)
    dx, dy = (x - a[0]) / r, (y - a[1]) / r
    rho_u = np.hypot(dx, dy)
    rho_x = np.interp(rho_u, f, rho)
    scale = np.where(rho_u > 0, rho_x / np.maximum(rho_u, 1e-300), 1.0)
    s = rho_x * rho_x
    jacobian = 1.0 / ((1.0 + k1 * s + k2 * s * s) * (1.0 + 3.0 * k1 * s + 5.0 * k2 * s * s))
    jacobian = np.where(rho_u <= f[-1], jacobian, 0.0)
    mx = (a[0] + dx * scale * r + pad - 0.5).astype(np.float32)
    my = (a[1] + dy * scale * r + pad - 0.5).astype(np.float32)
    jac = jacobian.astype(np.float32)[..., None]
    for m in (mx, my, jac):
        m.flags.writeable = False
    return mx, my, jac


def distort(light: np.ndarray, lens, k1: float, k2: float, lens_offset: float) -> np.ndarray:
    """The lens's output as it leaves through the distortion (see the module docstring).

    Parameters
    ----------
    light : numpy.ndarray
        float32 (H + 2 pad, W + 2 pad, 3): the lens's output on its padded grid, or the panel's
        (H, W, 3) light when the lens's blur stages are off (padded here: the grid's padding may
        be the distortion's own, :func:`outward_reach`).
    lens : sim.projector.Lens
        The setup's lens (panel and padding).
    k1, k2, lens_offset : float
        The stage's keys.

    Returns
    -------
    numpy.ndarray
        float32, the same shape.
    """
    mx, my, jac = distortion_maps(tuple(lens.panel), int(lens.pad), float(k1), float(k2),
                                  float(lens_offset))
    if light.shape[:2] != mx.shape:
        p = int(lens.pad)
        light = cv2.copyMakeBorder(np.asarray(light, np.float32), p, p, p, p, cv2.BORDER_CONSTANT,
                                   value=(0.0, 0.0, 0.0))
    out = cv2.remap(np.ascontiguousarray(light, np.float32), mx, my, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_CONSTANT, borderValue=(0.0, 0.0, 0.0))
    return out * jac


@dataclass(frozen=True)
class DistortionOptions:
    """The keys of the projection lens's distortion."""

    distortion_k1: float = number(0.0, Range(-0.1, 0.1),
                                  "(radial k1, normalised by the panel's half-diagonal)")
    """Brown's first radial coefficient of the projection lens, in [-0.1, 0.1] (radius normalised
    by the panel's half-diagonal, about the lens axis): the panel point at radius rho leaves along
    the ray of radius ``rho (1 + k1 rho**2 + k2 rho**4)``; negative is barrel, 0 with
    ``distortion_k2 = 0`` is off."""
    distortion_k2: float = number(0.0, Range(-0.05, 0.05),
                                  "(radial k2, normalised by the panel's half-diagonal)")
    """Brown's second radial coefficient of the projection lens, in [-0.05, 0.05] (see
    ``distortion_k1``)."""
    lens_offset: float = number(0.0, Range(-1, 1), "(fraction of the panel height)")
    """Fraction of the panel height, in [-1, 1], by which the lens axis (the distortion's centre)
    lies below the image centre: real projectors throw the image above the axis (0.5: the axis at
    the image's bottom edge); 0 is centred. Without distortion it changes nothing."""


def _distortion(light: np.ndarray, cfg, lens) -> np.ndarray:
    return distort(light, lens, cfg.distortion_k1, cfg.distortion_k2, cfg.lens_offset)


DISTORTION = Stage("distortion", DistortionOptions, "radial distortion of the projection lens, "
                   "Brown's k1 and k2 about its offset axis, flux kept (distort)", _distortion,
                   optical=True, linear=True, off={"distortion_k1": 0.0, "distortion_k2": 0.0})
"""The projection lens's distortion stage."""
