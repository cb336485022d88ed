"""The camera's picture style: an S-shaped tone curve and a chroma gain (the stage :data:`STYLE`) and
an unsharp mask (the stage :data:`SHARPEN`), on the encoded image.

A camera applies its picture style where this one does: after demosaicing and the response curve,
on output-referred encoded values, before the 8-bit quantisation and the JPEG encoder. The
sensor's fused group (:mod:`sim.camera.sensor`) encodes the signal to floats, applies the
processing stages in order (the adaptive tone of :mod:`sim.camera.adaptive`, then these) and
quantises once, as a camera processes at more than 8 bits.

On encoded values ``v`` in [0, 1], per pixel:

- tone curve of strength ``c``: ``(1 - c) v + c v**2 (3 - 2 v)`` per channel, a blend of the
  identity and the smoothstep; 0, 1/2 and 1 stay, the slope is ``1 + c / 2`` at 1/2 (mid-tones
  steeper) and ``1 - c`` at 0 and 1, and the curve is strictly increasing for ``c < 1``;
- saturation ``s``: ``Y + s (v - Y)`` with ``Y`` the pixel's luma (:data:`LUMA`), so a grey is
  unchanged and the chroma ``v - Y`` is multiplied by ``s``; clipped to [0, 1];
- unsharp mask of radius ``r`` and amount ``a`` on the luma: ``v + a (Y - G_r * Y)`` added to each
  channel, ``G_r`` a Gaussian of ``r`` pixels with mirrored edges (:func:`sim.camera.optics.blur`),
  so a flat field is unchanged and an edge overshoots on both sides; clipped to [0, 1].
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.camera.optics import blur
from sim.options import Range, number
from sim.stages import Stage

LUMA = (0.299, 0.587, 0.114)
"""Weights of the luma of encoded red, green and blue (ITU-R BT.601: the luma of JPEG's YCbCr)."""


def luma(encoded: np.ndarray) -> np.ndarray:
    """The luma of an encoded image: :data:`LUMA` weights of its channels.

    Parameters
    ----------
    encoded : numpy.ndarray
        float32 (H, W, 3) encoded values.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 1).
    """
    return np.asarray(encoded, np.float32) @ np.asarray(LUMA, np.float32)[:, None]


def contrast_curve(encoded: np.ndarray, contrast: float) -> np.ndarray:
    """The picture style's S-shaped tone curve, ``(1 - c) v + c v**2 (3 - 2 v)``.

    Parameters
    ----------
    encoded : numpy.ndarray
        float32 encoded values in [0, 1], any shape.
    contrast : float
        ``c`` in [0, 1]; 0 is the identity.

    Returns
    -------
    numpy.ndarray
        float32, the shape of ``encoded``, in [0, 1].

    Examples
    --------
    >>> contrast_curve(np.array([0.0, 0.25, 0.5, 1.0], np.float32), 1.0).tolist()
    [0.0, 0.15625, 0.5, 1.0]
    """
    v = np.asarray(encoded, np.float32)
    c = np.float32(contrast)
    return (1 - c) * v + c * v * v * (3 - 2 * v)


def saturate(encoded: np.ndarray, saturation: float) -> np.ndarray:
    """The chroma of each pixel about its luma multiplied by ``s``: ``Y + s (v - Y)``, clipped to
    [0, 1].

    Parameters
    ----------
    encoded : numpy.ndarray
        float32 (H, W, 3) encoded values in [0, 1].
    saturation : float
        ``s`` >= 0; 1 is the identity, 0 gives the luma in every channel.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3).

    Examples
    --------
    >>> x = np.array([[[0.5, 0.5, 0.5], [0.6, 0.5, 0.5]]], np.float32)  # luma 0.5 and 0.5299
    >>> saturate(x, 2.0).astype(float).round(4).tolist()
    [[[0.5, 0.5, 0.5], [0.6701, 0.4701, 0.4701]]]
    """
    v = np.asarray(encoded, np.float32)
    y = luma(v)
    return np.clip(y + np.float32(saturation) * (v - y), 0.0, 1.0)


def unsharp_mask(encoded: np.ndarray, radius: float, amount: float) -> np.ndarray:
    """The unsharp mask of the luma added to each channel: ``v + a (Y - G_r * Y)``, clipped to
    [0, 1].

    Parameters
    ----------
    encoded : numpy.ndarray
        float32 (H, W, 3) encoded values in [0, 1].
    radius : float
        Standard deviation ``r`` of the Gaussian, camera pixels (> 0).
    amount : float
        ``a`` >= 0; 0 is the identity.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3).
    """
    v = np.asarray(encoded, np.float32)
    y = luma(v)
    detail = y - blur(y[..., 0], float(radius))[..., None]
    return np.clip(v + np.float32(amount) * detail, 0.0, 1.0)


def picture_style(encoded: np.ndarray, cfg) -> np.ndarray:
    """The tone curve then the saturation of ``cfg`` (``style_contrast``, ``style_saturation``)."""
    return saturate(contrast_curve(encoded, cfg.style_contrast), cfg.style_saturation)


def sharpen(encoded: np.ndarray, cfg) -> np.ndarray:
    """The unsharp mask of ``cfg`` (``sharpen_radius``, ``sharpen_amount``)."""
    return unsharp_mask(encoded, cfg.sharpen_radius, cfg.sharpen_amount)


@dataclass(frozen=True)
class StyleOptions:
    """The keys of the camera's picture style (tone curve and saturation)."""

    style_contrast: float = number(0.0, Range(0, 1), "(tone-curve strength)")
    """Strength c in [0, 1] of the picture style's S-shaped tone curve on encoded values,
    ``(1 - c) v + c v**2 (3 - 2 v)`` per channel: 0, 1/2 and 1 stay, the mid-tones' slope is
    ``1 + c / 2``; 0 is off."""
    style_saturation: float = number(1.0, Range(0, 2), "(chroma multiplier)")
    """Multiplier in [0, 2] of each pixel's chroma about its BT.601 luma Y on encoded values,
    ``Y + s (v - Y)`` (greys unchanged); 1 is off, 0 gives grey."""


@dataclass(frozen=True)
class SharpenOptions:
    """The keys of the camera's sharpening."""

    sharpen_radius: float = number(1.0, Range(0, 5, lo_open=True), "camera pixels")
    """Camera pixels, in (0, 5]: standard deviation of the unsharp mask's Gaussian."""
    sharpen_amount: float = number(0.0, Range(0, 3), "(unsharp-mask amount)")
    """Amount a in [0, 3] of the unsharp mask on the encoded luma Y, ``v + a (Y - G * Y)`` added
    to each channel; 0 is off."""


STYLE = Stage("style", StyleOptions, "picture style: S-shaped tone curve and chroma gain on the "
              "encoded image (contrast_curve, saturate)", processing=True,
              off={"style_contrast": 0.0, "style_saturation": 1.0})
"""The camera's picture-style stage (applied by the sensor group)."""
SHARPEN = Stage("sharpen", SharpenOptions, "unsharp mask of the encoded luma (unsharp_mask)",
                processing=True, off={"sharpen_amount": 0.0})
"""The camera's sharpening stage (applied by the sensor group)."""

