"""The projector outside Mitsuba: its scaler, photometry (response, black level, primaries
mixing), lens (Gaussian point-spread function and depth-dependent defocus) and lamp (flicker and
drift).

A frame goes through the scaler to the native panel (:func:`scale_to_panel`), the response
(:func:`emitted_irradiance`) and the lens (:class:`Lens`); all three but the response are linear,
and everything after the response is linear in the emitted light, so it belongs to the light
transport (the ``transport`` level's operator sees the lens's output). The lens's output is the
panel padded by :attr:`Lens.pad` pixels of each side, so light it blurs past the panel's border is
kept; Mitsuba's emitter is widened to match (:meth:`Lens.fov`).

All outputs are *relative linear* irradiance: the projector's brightness is not applied here; the
scene applies it as the scale of Mitsuba's ``projector`` emitter, and the lamp's per-capture
brightness (:func:`lamp_gain`) multiplies a capture's projector contribution.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import cv2
import numpy as np

from sim import seeds

from sim.io import to_float

_SUPERSAMPLING = 15
"""Sub-samples per pixel side for the disk coverage (odd: one sub-sample sits on the centre)."""
SHARP_DIAMETER = 1e-3
"""Disk diameters (pixels) below this are a point: :func:`disk_kernel` gives the identity."""


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
        x = np.ascontiguousarray(frame, np.float32)
        if not (x.min() >= 0.0 and x.max() <= 1.0):  # also rejects NaN
            raise ValueError(f"projector frame: float values must lie in [0, 1], got "
                             f"[{x.min():g}, {x.max():g}]")
    # OpenCV's pow and 3x4 affine transform: 4-5x less CPU than NumPy's float32 pow and matmul
    # at 800x600, equal to float rounding (the pow to ~2e-6 relative). OpenCV's pow is ~10x
    # slower on zeros (a panel's black bars), so they are lifted to 1e-12 and set to 0 after.
    # The black level is the transform's offset: mixing @ (b + (1 - b) p) = (1 - b) mixing @ p
    # + b mixing @ 1.
    p = cv2.pow(np.maximum(x, np.float32(1e-12)), float(gamma))
    np.copyto(p, 0.0, where=x == 0)
    mix64 = mix.astype(np.float64)
    affine = np.hstack([(1.0 - black_level) * mix64, black_level * mix64.sum(axis=1, keepdims=True)])
    return cv2.transform(p, affine)


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


def frame_area(panel: tuple[int, int], frame: tuple[int, int],
               keep_aspect: bool) -> tuple[float, float, float, float]:
    """Where the scaler puts an input frame on the panel.

    With ``keep_aspect`` the frame is scaled by the largest factor that fits the panel, its size
    rounded to whole pixels keeping the panel's margins equal (so the area stays centred on whole
    pixels), the rest of the panel dark; otherwise it is stretched to the whole panel.

    Parameters
    ----------
    panel : (int, int)
        Native panel (width, height) in pixels.
    frame : (int, int)
        Input frame (width, height) in pixels.
    keep_aspect : bool
        Keep the frame's aspect ratio (``projector.keep_aspect``).

    Returns
    -------
    (float, float, float, float)
        ``(x0, y0, w, h)`` in panel pixels: left and top edge, width and height of the frame's
        image (whole numbers).

    Examples
    --------
    >>> frame_area((800, 600), (256, 256), True)
    (100.0, 0.0, 600.0, 600.0)
    >>> frame_area((800, 600), (256, 256), False)
    (0.0, 0.0, 800.0, 600.0)
    """
    pw, ph = int(panel[0]), int(panel[1])
    fw, fh = int(frame[0]), int(frame[1])
    if min(pw, ph, fw, fh) <= 0:
        raise ValueError(f"frame_area: sizes must be positive pixels, got panel={panel}, frame={frame}")
    if not keep_aspect:
        return 0.0, 0.0, float(pw), float(ph)
    scale = min(pw / fw, ph / fh)
    w = max(pw - 2 * round((pw - fw * scale) / 2), 2 - pw % 2)
    h = max(ph - 2 * round((ph - fh * scale) / 2), 2 - ph % 2)
    return (pw - w) / 2, (ph - h) / 2, float(w), float(h)


def scale_to_panel(frame: np.ndarray, panel: tuple[int, int], keep_aspect: bool) -> np.ndarray:
    """The projector's scaler: an input frame resampled onto the native panel.

    The frame is resized into :func:`frame_area` (area averaging when shrinking, bilinear when
    enlarging) and the rest of the panel set to input 0 (the response then gives it the black
    level). A frame already at the panel's size is returned unchanged.

    Parameters
    ----------
    frame : numpy.ndarray
        float (H, W, 3) encoded input in [0, 1].
    panel : (int, int)
        Native panel (width, height) in pixels.
    keep_aspect : bool
        Keep the frame's aspect ratio (``projector.keep_aspect``).

    Returns
    -------
    numpy.ndarray
        float32 (panel height, panel width, 3).
    """
    x = np.asarray(frame, np.float32)
    pw, ph = int(panel[0]), int(panel[1])
    if x.shape[:2] == (ph, pw):
        return x
    x0, y0, w, h = (int(v) for v in frame_area((pw, ph), (x.shape[1], x.shape[0]), keep_aspect))
    shrink = x.shape[0] > h or x.shape[1] > w
    scaled = cv2.resize(x, (w, h), interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    if (w, h) == (pw, ph):
        return scaled
    out = np.zeros((ph, pw, 3), np.float32)
    out[y0:y0 + h, x0:x0 + w] = scaled
    return out


DEFOCUS_STEP = 0.25
"""Projector pixels between the disk diameters :meth:`Lens.apply` blurs with: a pixel whose
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


def gaussian_radius(sigma: float) -> int:
    """Half-width in pixels of the Gaussian kernel :meth:`Lens.apply` uses (4 sigma, whole
    pixels; 0 for sigma 0)."""
    return int(math.ceil(4.0 * sigma)) if sigma > 0 else 0


def disk_radius(diameter_px: float) -> int:
    """Half-width in pixels of :func:`disk_kernel` for a diameter (its kernel is ``2 r + 1``
    wide)."""
    return (disk_kernel(diameter_px).shape[0] - 1) // 2


@dataclass(frozen=True)
class Lens:
    """The projector's lens: Gaussian point-spread function, then the defocus disk of each pixel.

    Both blurs scatter each pixel's light over a normalised kernel, so the lens is linear and
    keeps all the light: the output grid is the panel plus :attr:`pad` pixels on each side, wide
    enough for the largest blur.

    Attributes
    ----------
    panel : (int, int)
        Native panel (width, height) in pixels.
    pad : int
        Pixels added on each side of the panel (0 when the lens is sharp).
    psf_sigma : float
        Gaussian PSF standard deviation in panel pixels (0: none).
    diameters : numpy.ndarray or None
        float (H + 2 pad, W + 2 pad): defocus disk diameter in pixels of the light leaving each
        pixel of the padded grid (from the depth of the surface it lands on), or None when the
        lens is in focus everywhere (every disk below :data:`SHARP_DIAMETER`).
    """

    panel: tuple[int, int]
    pad: int = 0
    psf_sigma: float = 0.0
    diameters: np.ndarray | None = None

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the output grid in pixels: the panel plus the padding."""
        return self.panel[0] + 2 * self.pad, self.panel[1] + 2 * self.pad

    def fov(self, panel_fov: float) -> float:
        """Horizontal field of view (degrees) of the padded grid for a panel of ``panel_fov``:
        the same pixel pitch, ``pad`` more pixels each side."""
        if self.pad == 0:
            return float(panel_fov)
        t = math.tan(math.radians(panel_fov) / 2) * self.size[0] / self.panel[0]
        return math.degrees(2 * math.atan(t))

    @property
    def sharp(self) -> bool:
        """True when the lens changes nothing (no PSF, no defocus)."""
        return self.psf_sigma == 0 and self.diameters is None

    def apply(self, irradiance: np.ndarray) -> np.ndarray:
        """The light leaving the lens for the panel's irradiance.

        Parameters
        ----------
        irradiance : numpy.ndarray
            float (H, W, 3) panel irradiance.

        Returns
        -------
        numpy.ndarray
            float32 (H + 2 pad, W + 2 pad, 3); the input itself when the lens is :attr:`sharp`.
        """
        img = np.asarray(irradiance, np.float32)
        w, h = self.panel
        if img.shape != (h, w, 3):
            raise ValueError(f"irradiance: expected shape ({h}, {w}, 3), got {img.shape}")
        if self.sharp:
            return img
        p = self.pad
        img = cv2.copyMakeBorder(img, p, p, p, p, cv2.BORDER_CONSTANT, value=(0.0, 0.0, 0.0))
        if self.psf_sigma > 0:
            k = 2 * gaussian_radius(self.psf_sigma) + 1
            img = cv2.GaussianBlur(img, (k, k), self.psf_sigma, borderType=cv2.BORDER_CONSTANT)
        if self.diameters is not None:
            img = varying_defocus(img, self.diameters, self._plan)
        return img

    @cached_property
    def _plan(self) -> list:
        """:func:`defocus_plan` of :attr:`diameters`, made on first use."""
        return defocus_plan(self.diameters)


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


def lamp_gain(cfg, seed: int, stream: int, index: int) -> float:
    """The lamp's relative brightness in one capture.

    ``(1 + drift) * max(0, 1 + flicker * z)`` for a test-time capture
    (:func:`sim.seeds.test_time`), without the ``drift`` factor for a calibration capture; ``z``
    is standard normal, drawn from :func:`sim.seeds.lamp_rng` of the capture.

    Parameters
    ----------
    cfg : ProjectorConfig-like
        ``flicker`` and ``drift``.
    seed, stream, index : int
        The capture (``render.seed``, stream of :mod:`sim.seeds`, index in the stream).

    Returns
    -------
    float
        Multiplier of the capture's projector contribution (1.0 when both are 0).

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> lamp_gain(SimpleNamespace(flicker=0.0, drift=0.1), 0, seeds.TEST, 3)
    1.1
    """
    gain = 1.0
    if cfg.flicker > 0:
        z = float(seeds.lamp_rng(seed, stream, index).standard_normal())
        gain = max(0.0, 1.0 + cfg.flicker * z)
    if cfg.drift != 0 and seeds.test_time(stream):
        gain *= 1.0 + cfg.drift
    return gain
