"""The camera's optical stages on linear radiance: a Gaussian PSF (lens and anti-alias filter),
radial lens distortion and vignetting (:data:`PSF`, :data:`DISTORTION`, :data:`VIGNETTING`, each
with its options).

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
from dataclasses import dataclass

import cv2
import numpy as np

from sim.options import Range, number
from sim.stages import Stage


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


@dataclass(frozen=True)
class PsfOptions:
    """The key of the camera's PSF."""

    psf_sigma: float = number(0.0, Range(0, 16), "camera pixels")
    """Camera pixels (>= 0, at most 16): standard deviation of the Gaussian optical PSF /
    anti-alias filter applied to the linear radiance; 0 is off."""


@dataclass(frozen=True)
class DistortionOptions:
    """The key of the camera's lens distortion."""

    distortion: float = number(0.0, Range(-0.14, 1), "(radial k1, normalised by the half-diagonal)")
    """Radial lens distortion k1 (Brown model, radius normalised by the half-diagonal), in
    [-0.14, 1]: a point at radius rho is seen at ``rho (1 + k1 rho**2)``; negative is barrel,
    0 is off."""


@dataclass(frozen=True)
class VignettingOptions:
    """The key of the camera's vignetting."""

    vignetting: float = number(0.0, Range(0, 1, hi_open=True), "(fraction lost at the corners)")
    """Fraction in [0, 1) of the light lost at the frame corners (cos^4-like falloff
    ``(1 + c rho**2)**-2`` of the normalised radius rho, see the module); 0 is off."""


def _psf(radiance: np.ndarray, cfg, rng) -> np.ndarray:
    return blur(radiance, float(cfg.psf_sigma))


def _distortion(radiance: np.ndarray, cfg, rng) -> np.ndarray:
    return distort_image(radiance, float(cfg.distortion))


def _vignetting(radiance: np.ndarray, cfg, rng) -> np.ndarray:
    return radiance * vignetting_profile(radiance.shape[1], radiance.shape[0], float(cfg.vignetting))


PSF = Stage("psf", PsfOptions, "Gaussian optical PSF / anti-alias filter of psf_sigma camera pixels "
            "(blur)", _psf, optical=True, linear=True, off={"psf_sigma": 0.0})
"""The camera's PSF stage."""
DISTORTION = Stage("distortion", DistortionOptions, "radial lens distortion, Brown's k1 "
                   "(distort_image)", _distortion, optical=True, linear=True, off={"distortion": 0.0})
"""The camera's lens distortion stage."""
VIGNETTING = Stage("vignetting", VignettingOptions, "cos^4-like falloff towards the corners "
                   "(vignetting_profile)", _vignetting, optical=True, linear=True,
                   off={"vignetting": 0.0})
"""The camera's vignetting stage."""
