"""Defocus of the projector's lens: the circle of confusion of a depth, anti-aliased disk kernels,
and the blur of a map of per-pixel disk diameters (:func:`varying_defocus`)."""
from __future__ import annotations

import math

import cv2
import numpy as np

_SUPERSAMPLING = 15
"""Sub-samples per pixel side for the disk coverage (odd: one sub-sample sits on the centre)."""
SHARP_DIAMETER = 1e-3
"""Disk diameters (pixels) below this are a point: :func:`disk_kernel` gives the identity."""


def defocus_blur_diameter_px(aperture: float, focus_distance: float, distance,
                             fov: float, width: int):
    """Diameter of the projector's circle of confusion, in projector pixels.

    A lens of aperture ``A`` focused at depth ``f`` spreads each pixel over a disk of diameter
    ``c = A * |d - f| / f`` metres on the plane at depth ``d`` (along the optical axis), where one
    projector pixel measures ``p = 2 * d * tan(fov / 2) / width`` metres; the result is ``c / p``.
    Both lengths are measured on that plane, so the ratio holds on a tilted surface too (the
    projective map from the plane to the surface scales both alike).

    Parameters
    ----------
    aperture : float
        Lens aperture diameter in metres (>= 0; 0 = pinhole, always sharp).
    focus_distance : float
        Depth in metres at which the projector is in focus (> 0).
    distance : float or numpy.ndarray
        Depth in metres of the surface point(s) (> 0).
    fov : float
        Horizontal field of view in degrees, in (0, 180).
    width : int
        Horizontal resolution in pixels (> 0).

    Returns
    -------
    float or numpy.ndarray
        Blur-disk diameter in projector pixels (0 at the focus distance), shaped like
        ``distance``.

    Examples
    --------
    >>> defocus_blur_diameter_px(0.02, 1.0, 1.0, 30.0, 256)
    0.0
    """
    d = np.asarray(distance, dtype=float)
    if aperture < 0:
        raise ValueError(f"projector aperture: expected >= 0 metres, got {aperture}")
    if focus_distance <= 0 or not np.all(d > 0):
        raise ValueError(f"projector distances must be > 0 metres, got focus_distance="
                         f"{focus_distance}, distance={distance}")
    if not 0 < fov < 180 or width <= 0:
        raise ValueError(f"projector fov must be in (0, 180) degrees and width > 0 pixels, got "
                         f"fov={fov}, width={width}")
    coc = aperture * np.abs(d - focus_distance) / focus_distance
    pitch = 2.0 * d * math.tan(math.radians(fov) / 2.0) / width
    out = coc / pitch
    return float(out) if out.ndim == 0 else out


def disk_kernel(diameter_px: float) -> np.ndarray:
    """Normalised anti-aliased disk: each tap is the disk's coverage of that pixel.

    Coverage is estimated with 15x15 sub-samples per pixel (one on the pixel centre, so any
    diameter > 0 covers the centre tap); the kernel is symmetric under flips and transposition,
    sums to 1, and has no empty border rows.

    Parameters
    ----------
    diameter_px : float
        Disk diameter in pixels (>= 0); below :data:`SHARP_DIAMETER` the identity kernel ``[[1]]``
        is returned.

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
    if diameter_px < SHARP_DIAMETER:
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


DEFOCUS_STEP = 0.25
"""Projector pixels between the disk diameters :meth:`sim.projector.Lens.apply` blurs with: a pixel whose
diameter lies between two of them is split linearly between the two (its blur's variance is then
off by at most ``DEFOCUS_STEP² / 64`` px², the disks' own anti-aliasing error)."""
DEFOCUS_RELATIVE_STEP = 0.05
"""Beyond ``DEFOCUS_STEP / DEFOCUS_RELATIVE_STEP`` pixels the diameters are this fraction apart."""


def defocus_levels(lo: float, hi: float) -> np.ndarray:
    """Disk diameters (pixels) covering ``[lo, hi]``: ``DEFOCUS_STEP`` apart, or
    ``DEFOCUS_RELATIVE_STEP`` of the diameter for large disks; the first is ``lo``, the last
    at least ``hi``.

    Examples
    --------
    >>> defocus_levels(1.0, 1.6).tolist()
    [1.0, 1.25, 1.5, 1.75]
    """
    levels = [float(lo)]
    while levels[-1] < hi:
        levels.append(levels[-1] + max(DEFOCUS_STEP, DEFOCUS_RELATIVE_STEP * levels[-1]))
    return np.asarray(levels)


def disk_radius(diameter_px: float) -> int:
    """Half-width in pixels of :func:`disk_kernel` for a diameter (its kernel is ``2 r + 1``
    wide)."""
    return (disk_kernel(diameter_px).shape[0] - 1) // 2


def defocus_plan(diameters: np.ndarray) -> list[tuple[np.ndarray, tuple[int, int, int, int], np.ndarray]]:
    """How :func:`varying_defocus` blurs with a diameter map: one step per disk of
    :func:`defocus_levels`.

    A pixel of diameter ``d`` between two levels ``d_k <= d <= d_k+1`` sends
    ``(d_k+1 - d) / (d_k+1 - d_k)`` of its light through the disk of ``d_k`` and the rest through
    the disk of ``d_k+1``.

    Parameters
    ----------
    diameters : numpy.ndarray
        float (H, W) disk diameter in pixels of each pixel's light (>= 0).

    Returns
    -------
    list of (kernel, (y0, y1, x0, x1), weight)
        Per disk: its :func:`disk_kernel`, the box of pixels it changes (those sending light
        through it, widened by its radius) and float32 (y1 - y0, x1 - x0) the share of each
        pixel's light in that box that goes through it.
    """
    d = np.asarray(diameters, np.float64)
    h, w = d.shape
    levels = defocus_levels(float(d.min()), float(d.max()))
    if len(levels) == 1:
        return [(disk_kernel(levels[0]), (0, h, 0, w), np.ones((h, w), np.float32))]
    k = np.clip(np.searchsorted(levels, d, side="right") - 1, 0, len(levels) - 2)
    frac = ((d - levels[k]) / (levels[k + 1] - levels[k])).astype(np.float32)
    steps = []
    for i, diameter in enumerate(levels):
        use = (k == i) | (k + 1 == i)
        kernel = disk_kernel(diameter)
        r = (kernel.shape[0] - 1) // 2
        cols = np.flatnonzero(use.any(axis=0))
        # runs of columns more than a disk apart are separate boxes (a corner's two wings)
        for run in np.split(cols, np.flatnonzero(np.diff(cols) > 2 * r + 1) + 1):
            if len(run) == 0:
                continue
            rows = np.flatnonzero(use[:, run[0]:run[-1] + 1].any(axis=1))
            y0, y1 = max(int(rows[0]) - r, 0), min(int(rows[-1]) + r + 1, h)
            x0, x1 = max(int(run[0]) - r, 0), min(int(run[-1]) + r + 1, w)
            kk, ff = k[y0:y1, x0:x1], frac[y0:y1, x0:x1]  # no other run within r of this one
            weight = np.where(kk == i, 1 - ff, 0) + np.where(kk + 1 == i, ff, 0)
            steps.append((kernel, (y0, y1, x0, x1), weight.astype(np.float32)))
    return steps


def varying_defocus(image: np.ndarray, diameters: np.ndarray, plan=None) -> np.ndarray:
    """Scatter each pixel's light over its own defocus disk (linear, keeps all light that stays
    inside the image).

    Parameters
    ----------
    image : numpy.ndarray
        float32 (H, W, 3).
    diameters : numpy.ndarray
        float (H, W) disk diameter in pixels of each pixel's light (>= 0).
    plan : list, optional
        :func:`defocus_plan` of ``diameters`` (computed when not given).

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3).
    """
    out = np.zeros_like(image)
    for kernel, (y0, y1, x0, x1), weight in plan if plan is not None else defocus_plan(diameters):
        part = image[y0:y1, x0:x1] * weight[..., None]
        if kernel.shape != (1, 1):  # symmetric kernel: filter2D's correlation is the convolution
            part = cv2.filter2D(part, -1, kernel, borderType=cv2.BORDER_CONSTANT)
        out[y0:y1, x0:x1] += part
    return out
