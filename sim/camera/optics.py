"""The camera's optics on linear radiance: a Gaussian PSF (lens and anti-alias filter), radial
lens distortion and vignetting.

Geometry: pixel ``(i, j)`` (column, row) has its centre at ``(i + 0.5, j + 0.5)``; the optical
centre is the image centre ``c = (W / 2, H / 2)`` and radii are normalised by the half-diagonal
``R = sqrt(W**2 + H**2) / 2``, so ``rho = |x - c| / R`` is 1 at the corners.

- Distortion (Brown's radial model, first coefficient ``k1``): an ideal (pinhole) image point at
  normalised radius ``rho`` is seen at ``rho * (1 + k1 * rho**2)``; ``k1 < 0`` is barrel,
  ``k1 > 0`` pincushion. The image is resampled (bilinear) from the ideal radiance; where a
  barrel-distorted pixel looks beyond the rendered field of view the nearest edge pixel is
  repeated.
- Vignetting: the natural cos^4 falloff of a lens whose corner ray makes the angle ``theta_c``
  with the axis, ``v(rho) = (1 + c rho**2)**-2`` with ``c = tan(theta_c)**2`` chosen so that
  ``v(1) = 1 - vignetting`` (the fraction lost at the corners): ``c = (1 - vignetting)**-0.5 - 1``.
"""
from __future__ import annotations

import functools

import cv2
import numpy as np


def _centre_and_radius(width: int, height: int) -> tuple[np.ndarray, float]:
    return np.array([width / 2.0, height / 2.0]), float(np.hypot(width, height) / 2.0)


def distort_points(xy, cfg) -> np.ndarray:
    """Where ideal (pinhole) camera pixel coordinates are seen through the lens distortion.

    Parameters
    ----------
    xy : array_like
        (..., 2) pixel coordinates (x right, y down; pixel centres at +0.5).
    cfg : CameraConfig-like
        ``resolution`` (width, height) and ``distortion`` (k1; 0 = the identity).

    Returns
    -------
    numpy.ndarray
        float64 (..., 2) distorted coordinates.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> distort_points([[150.0, 50.0]], SimpleNamespace(resolution=(200, 100), distortion=0.1)).tolist()
    [[151.0, 50.0]]
    """
    p = np.asarray(xy, np.float64)
    k1 = float(getattr(cfg, "distortion", 0.0))
    if k1 == 0.0:
        return p.copy()
    c, r = _centre_and_radius(*cfg.resolution)
    d = (p - c) / r
    return c + (p - c) * (1.0 + k1 * np.sum(d * d, axis=-1, keepdims=True))


def undistort_radius(rho_d: np.ndarray, k1: float) -> np.ndarray:
    """The ideal normalised radius seen at distorted radius ``rho_d``: the root of
    ``rho (1 + k1 rho**2) = rho_d`` (Newton's method from ``rho_d``; the mapping is increasing
    on [0, 1.5] for ``k1 > -0.148``)."""
    rho = np.array(rho_d, np.float64)
    for _ in range(30):
        f = rho * (1.0 + k1 * rho * rho) - rho_d
        step = f / (1.0 + 3.0 * k1 * rho * rho)
        rho -= step
        if np.max(np.abs(step)) < 1e-12:
            break
    return rho


@functools.lru_cache(maxsize=8)
def _distortion_maps(width: int, height: int, k1: float) -> tuple[np.ndarray, np.ndarray]:
    """``cv2.remap`` maps: for each distorted pixel, the ideal image position it shows (OpenCV's
    convention: pixel centres at integers)."""
    c, r = _centre_and_radius(width, height)
    x, y = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    dx, dy = (x - c[0]) / r, (y - c[1]) / r
    rho_d = np.hypot(dx, dy)
    scale = np.where(rho_d > 0, undistort_radius(rho_d, k1) / np.maximum(rho_d, 1e-300), 1.0)
    mx = c[0] + dx * scale * r - 0.5
    my = c[1] + dy * scale * r - 0.5
    return mx.astype(np.float32), my.astype(np.float32)


def distort_image(radiance: np.ndarray, k1: float) -> np.ndarray:
    """The radiance image as seen through radial distortion ``k1`` (see :func:`distort_points`),
    resampled bilinearly from the ideal image.

    Parameters
    ----------
    radiance : numpy.ndarray
        float32 (H, W, C) ideal image.
    k1 : float
        Brown's first radial coefficient (normalised by the half-diagonal).

    Returns
    -------
    numpy.ndarray
        float32 (H, W, C).
    """
    h, w = radiance.shape[:2]
    mx, my = _distortion_maps(w, h, float(k1))
    return cv2.remap(np.ascontiguousarray(radiance), mx, my, cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


@functools.lru_cache(maxsize=8)
def vignetting_profile(width: int, height: int, vignetting: float) -> np.ndarray:
    """Relative illumination of each pixel, ``(1 + c rho**2)**-2`` with ``v = 1 - vignetting`` at
    the corners (see the module docstring).

    Parameters
    ----------
    width, height : int
        Image size in pixels.
    vignetting : float
        Fraction of light lost at the corners, in [0, 1).

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 1) factors in (0, 1] (read-only, cached).

    Examples
    --------
    >>> v = vignetting_profile(4, 4, 0.5)
    >>> round(float(v[0, 0, 0]), 4), round(float(v[1, 1, 0]), 4)  # rho = 3/4 and 1/4
    (0.6578, 0.9502)
    """
    c, r = _centre_and_radius(width, height)
    x, y = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    rho2 = ((x - c[0]) ** 2 + (y - c[1]) ** 2) / r**2
    k = (1.0 - vignetting) ** -0.5 - 1.0
    v = ((1.0 + k * rho2) ** -2).astype(np.float32)[..., None]
    v.flags.writeable = False
    return v


def blur(radiance: np.ndarray, sigma: float) -> np.ndarray:
    """A Gaussian PSF of standard deviation ``sigma`` pixels (kernel to 4 sigma, mirrored edges,
    so a flat field stays flat and energy is kept).

    Parameters
    ----------
    radiance : numpy.ndarray
        float32 (H, W, C).
    sigma : float
        Pixels, > 0.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, C).
    """
    k = 2 * int(np.ceil(4.0 * sigma)) + 1
    return cv2.GaussianBlur(np.ascontiguousarray(radiance), (k, k), sigmaX=sigma, sigmaY=sigma,
                            borderType=cv2.BORDER_REFLECT)


def apply_optics(radiance: np.ndarray, cfg) -> np.ndarray:
    """PSF, then distortion, then vignetting, each only when its key is non-zero (the input
    itself is returned when all are off).

    Parameters
    ----------
    radiance : numpy.ndarray
        float32 (H, W, 3) linear radiance.
    cfg : CameraConfig-like
        ``psf_sigma``, ``distortion``, ``vignetting`` (absent = 0).
    """
    out = radiance
    sigma = float(getattr(cfg, "psf_sigma", 0.0))
    k1 = float(getattr(cfg, "distortion", 0.0))
    vig = float(getattr(cfg, "vignetting", 0.0))
    if sigma > 0:
        out = blur(out, sigma)
    if k1 != 0:
        out = distort_image(out, k1)
    if vig > 0:
        out = out * vignetting_profile(out.shape[1], out.shape[0], vig)
    return out
