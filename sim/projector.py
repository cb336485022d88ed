"""The projector's photometry and optics outside Mitsuba: response, black level, primaries
mixing, and defocus approximated by pre-blurring the frame (design section 2).

All outputs are *relative linear* irradiance: the projector's brightness is not applied here; the
scene applies it as the scale of Mitsuba's ``projector`` emitter.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from sim.io import to_float

_SUPERSAMPLING = 15
"""Sub-samples per pixel side for the disk coverage (odd: one sub-sample sits on the centre)."""


def emitted_irradiance(frame: np.ndarray, gamma: float, black_level: float,
                       mixing) -> np.ndarray:
    """Relative linear irradiance the projector emits for an input frame.

    ``L = (black + (1 - black) * x**gamma) @ mixing.T`` per pixel: every primary follows the
    power-law response with a black-level floor, then the 3x3 mixing matrix spreads each
    primary over the camera channels. Brightness is *not* applied: the scene uses it as the
    emitter scale, so the output is 1 for a white input with identity mixing.

    Parameters
    ----------
    frame : numpy.ndarray
        Projector input x (encoded), (H, W, 3): uint8 (0-255) or float in [0, 1].
    gamma : float
        Projector response exponent (dimensionless, > 0).
    black_level : float
        Fraction of full output emitted for input 0, in [0, 1).
    mixing : array_like
        3x3 primaries-mixing matrix, rows = output (camera) channel, columns = projector primary.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3) relative linear irradiance.

    Raises
    ------
    ValueError
        If the frame is not (H, W, 3), a float frame leaves [0, 1], or ``mixing`` is not 3x3.

    Examples
    --------
    >>> x = np.full((1, 1, 3), 255, np.uint8)
    >>> emitted_irradiance(x, 2.2, 0.01, np.eye(3))[0, 0].tolist()
    [1.0, 1.0, 1.0]
    """
    frame = np.asarray(frame)
    if frame.ndim != 3 or frame.shape[2] != 3:
        raise ValueError(f"projector frame: expected shape (H, W, 3), got {frame.shape}")
    mix = np.asarray(mixing, dtype=np.float32)
    if mix.shape != (3, 3):
        raise ValueError(f"projector mixing: expected a 3x3 matrix, got shape {mix.shape}")
    if frame.dtype == np.uint8:
        x = to_float(frame)
    else:
        x = frame.astype(np.float32)
        if not (x.min() >= 0.0 and x.max() <= 1.0):  # also rejects NaN
            raise ValueError(f"projector frame: float values must lie in [0, 1], got "
                             f"[{x.min():g}, {x.max():g}]")
    primaries = np.float32(black_level) + np.float32(1 - black_level) * x ** np.float32(gamma)
    return (primaries @ mix.T).astype(np.float32)


def projector_irradiance(frame: np.ndarray, cfg) -> np.ndarray:
    """:func:`emitted_irradiance` with the response of a projector configuration.

    Parameters
    ----------
    frame : numpy.ndarray
        Projector input, uint8 or float in [0, 1], (H, W, 3).
    cfg : ProjectorConfig-like
        Any object with ``gamma``, ``black_level`` and ``mixing`` attributes.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3) relative linear irradiance (brightness not applied).
    """
    return emitted_irradiance(frame, cfg.gamma, cfg.black_level, cfg.mixing)


def defocus_blur_diameter_px(aperture: float, focus_distance: float, distance: float,
                             fov: float, width: int) -> float:
    """Diameter of the projector's circle of confusion, in projector pixels.

    A lens of aperture ``A`` focused at ``f`` spreads each pixel over a disk of diameter
    ``c = A * |d - f| / f`` metres on a surface at distance ``d``, where one projector pixel
    measures ``p = 2 * d * tan(fov / 2) / width`` metres; the result is ``c / p``.

    Parameters
    ----------
    aperture : float
        Lens aperture diameter in metres (>= 0; 0 = pinhole, always sharp).
    focus_distance : float
        Distance in metres at which the projector is in focus (> 0).
    distance : float
        Distance in metres from the projector to the surface (> 0).
    fov : float
        Horizontal field of view in degrees, in (0, 180).
    width : int
        Horizontal resolution in pixels (> 0).

    Returns
    -------
    float
        Blur-disk diameter in projector pixels (0 at the focus distance).

    Examples
    --------
    >>> defocus_blur_diameter_px(0.02, 1.0, 1.0, 30.0, 256)
    0.0
    """
    if aperture < 0:
        raise ValueError(f"projector aperture: expected >= 0 metres, got {aperture}")
    if focus_distance <= 0 or distance <= 0:
        raise ValueError(f"projector distances must be > 0 metres, got focus_distance="
                         f"{focus_distance}, distance={distance}")
    if not 0 < fov < 180 or width <= 0:
        raise ValueError(f"projector fov must be in (0, 180) degrees and width > 0 pixels, got "
                         f"fov={fov}, width={width}")
    coc = aperture * abs(distance - focus_distance) / focus_distance
    pitch = 2.0 * distance * math.tan(math.radians(fov) / 2.0) / width
    return coc / pitch


def disk_kernel(diameter_px: float) -> np.ndarray:
    """Normalised anti-aliased disk: each tap is the disk's coverage of that pixel.

    Coverage is estimated with 15x15 sub-samples per pixel (one on the pixel centre, so any
    diameter > 0 covers the centre tap); the kernel is symmetric under flips and transposition,
    sums to 1, and has no empty border rows.

    Parameters
    ----------
    diameter_px : float
        Disk diameter in pixels (>= 0); below 1e-3 the identity kernel ``[[1]]`` is returned.

    Returns
    -------
    numpy.ndarray
        float32 (n, n) kernel, n odd.

    Examples
    --------
    >>> disk_kernel(0.0).tolist()
    [[1.0]]
    >>> round(float(disk_kernel(5.5).sum()), 6)
    1.0
    """
    if not diameter_px >= 0:
        raise ValueError(f"disk diameter: expected >= 0 pixels, got {diameter_px}")
    if diameter_px < 1e-3:
        return np.ones((1, 1), np.float32)
    r = diameter_px / 2.0
    offsets = (np.arange(_SUPERSAMPLING) + 0.5) / _SUPERSAMPLING - 0.5
    m = math.floor(r - offsets[0])  # outermost pixel whose nearest sub-sample is in the disk
    u = (np.arange(-m, m + 1)[:, None] + offsets[None, :]) ** 2  # (n, S) squared coordinates
    coverage = np.zeros((2 * m + 1, 2 * m + 1))
    for uy in u.T:  # one sub-row at a time: memory n * n * S
        coverage += ((uy[:, None, None] + u[None, :, :]) <= r * r).sum(axis=2)
    return (coverage / coverage.sum()).astype(np.float32)


def defocus(irradiance: np.ndarray, diameter_px: float) -> np.ndarray:
    """Blur each channel with the defocus disk (the pre-blur approximation of defocus).

    Exact only for surfaces at the one depth ``diameter_px`` was computed for. Light that
    would come from outside the frame is zero (constant-0 border), so the operation is linear
    and preserves the total energy of content at least a disk radius away from the border.

    Parameters
    ----------
    irradiance : numpy.ndarray
        float (H, W, 3) relative linear irradiance.
    diameter_px : float
        Blur-disk diameter in pixels (see :func:`defocus_blur_diameter_px`).

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3) blurred irradiance (a copy when the kernel is the identity).
    """
    img = np.asarray(irradiance, dtype=np.float32)
    if img.ndim != 3 or img.shape[2] != 3:
        raise ValueError(f"irradiance: expected shape (H, W, 3), got {img.shape}")
    kernel = disk_kernel(diameter_px)
    if kernel.shape == (1, 1):
        return img.copy()
    # The kernel is symmetric, so filter2D's correlation equals the convolution.
    return cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_CONSTANT)
