"""Translucency of the surface (paper, fabric): light entering it re-emerges nearby (the stage
:data:`TRANSLUCENCY`).

A fraction ``f`` (``translucency_fraction``) of the light reaching a surface point travels inside
the material and re-emerges around it with the radial exponential kernel ``K(r) ~ exp(-r / mfp)``
(``translucency_mfp``, millimetres on the surface), the rest where it entered:
``(1 - f) x + f (K * x)`` (:func:`translucent`). ``K`` is normalised to sum 1, so the light is kept
(but for what spreads past the padded grid's edge, which is lost); its 2-D second moment is
``mean r**2 = 6 mfp**2``.

The stage acts on the projector's emitted light, on the lens's padded grid, before the light
transport: the kernel's length is converted from surface millimetres to projector pixels with the
width of one panel pixel where the optical axis meets the surface (:attr:`Lens.surface_pitch
<sim.projector.Lens.surface_pitch>`). This approximation ignores obliquity: on a tilted or curved
surface a projector pixel covers more or less of the surface away from the axis (and an elongated
patch), while the kernel stays round and of one size in pixels. The surface's albedo applies once,
at the point where the light leaves.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from sim.errors import ProcamError
from sim.options import UNIT, Range, number
from sim.stages import Stage

REACH = 12.0
"""Kernel half-width in mean free paths (the exponential's tail beyond holds 0.2 % of its second
moment)."""
SUBSAMPLES = 16
"""Most samples per pixel side used to integrate the kernel over each pixel (for a kernel much
narrower than a pixel)."""


@functools.lru_cache(maxsize=8)
def exponential_kernel(mfp: float) -> np.ndarray:
    """The radial exponential kernel ``exp(-r / mfp)`` integrated over each pixel, normalised to
    sum 1.

    Parameters
    ----------
    mfp : float
        Mean free path in pixels, > 0.

    Returns
    -------
    numpy.ndarray
        float32 (2 n + 1, 2 n + 1), ``n = ceil(REACH mfp)``, centred. Read-only, cached.

    Examples
    --------
    >>> k = exponential_kernel(0.2)
    >>> k.shape, round(float(k.sum()), 6), round(float(k[3, 3]), 2)
    ((7, 7), 1.0, 0.77)
    """
    n = int(math.ceil(REACH * mfp))
    sub = int(min(SUBSAMPLES, max(1, math.ceil(4.0 / mfp))))
    offsets = (np.arange(sub) + 0.5) / sub - 0.5
    c = np.arange(-n, n + 1, dtype=np.float64)
    x = (c[:, None] + offsets[None, :]).ravel()
    r = np.hypot(x[:, None], x[None, :])
    k = np.exp(-r / mfp).reshape(2 * n + 1, sub, 2 * n + 1, sub).sum(axis=(1, 3))
    k = (k / k.sum()).astype(np.float32)
    k.flags.writeable = False
    return k


def mfp_pixels(mfp_mm: float, lens) -> float:
    """The mean free path ``mfp_mm`` (millimetres on the surface) in projector pixels, at the
    optical axis (:attr:`Lens.surface_pitch <sim.projector.Lens.surface_pitch>`).

    Raises
    ------
    ProcamError
        If the lens does not know its pixel's size on the surface.
    """
    if not lens.surface_pitch > 0:
        raise ProcamError("projector.translucency_mfp: the lens does not know the size of a "
                          "projector pixel on the surface (make it with sim.projector.lens_for)")
    return mfp_mm * 1e-3 / lens.surface_pitch


def translucent(light: np.ndarray, lens, mfp_mm: float, fraction: float) -> np.ndarray:
    """``(1 - fraction) light + fraction (K * light)`` (see the module docstring).

    Parameters
    ----------
    light : numpy.ndarray
        float32 (H + 2 pad, W + 2 pad, 3): the projector's light on the lens's padded grid.
    lens : sim.projector.Lens
        The setup's lens (its pixel's size on the surface).
    mfp_mm : float
        Mean free path, millimetres on the surface, > 0.
    fraction : float
        Fraction re-emerging through the kernel, in [0, 1].

    Returns
    -------
    numpy.ndarray
        float32, the same shape.
    """
    img = np.ascontiguousarray(light, np.float32)
    spread = cv2.filter2D(img, -1, exponential_kernel(mfp_pixels(mfp_mm, lens)),
                          borderType=cv2.BORDER_CONSTANT)
    return (1.0 - fraction) * img + np.float32(fraction) * spread


@dataclass(frozen=True)
class TranslucencyOptions:
    """The keys of the surface's translucency."""

    translucency_mfp: float = number(0.0, Range(0, 10), "millimetres")
    """Millimetres on the surface, in [0, 10]: the length ``mfp`` of the radial kernel
    ``exp(-r / mfp)`` with which light entering the surface re-emerges nearby (mean r² = 6 mfp²);
    0 is off."""
    translucency_fraction: float = number(1.0, UNIT, "(fraction of the light)")
    """Fraction in [0, 1] of the light reaching the surface that re-emerges through the kernel
    rather than where it entered."""


def _translucency(light: np.ndarray, cfg, lens) -> np.ndarray:
    return translucent(light, lens, cfg.translucency_mfp, cfg.translucency_fraction)


TRANSLUCENCY = Stage("translucency", TranslucencyOptions, "light re-emerging from inside the "
                     "surface around where it entered, a radial exponential kernel (translucent)",
                     _translucency, optical=True, linear=True, off={"translucency_mfp": 0.0})
"""The surface's translucency stage."""
