"""The camera lens's veiling glare: light scattered by the lens elements and the barrel into a wide
veil over the image (the stage :data:`GLARE`).

On the linear radiance, each pixel keeps ``1 - glare`` of its light and scatters ``glare`` of it by
a Gaussian of ``glare_sigma`` image widths: ``(1 - glare) x + glare (G * x)``, computed cheaply on a
coarse grid (:func:`sim.scatter.veil`, whose approximation is described there). The light the veil
spreads past the image's edge is lost, and light from outside the rendered field of view adds no
veil (it is not rendered). A small black patch in a large white field receives about ``glare``
times the white's radiance: the veiling glare index of ISO 9358.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.options import Range, number
from sim.scatter import veil
from sim.stages import Stage


@dataclass(frozen=True)
class GlareOptions:
    """The keys of the camera's veiling glare."""

    glare: float = number(0.0, Range(0, 0.5), "(fraction of the light)")
    """Fraction in [0, 0.5] of each pixel's light the lens scatters into the wide veil (about the
    veiling glare index); 0 is off."""
    glare_sigma: float = number(0.25, Range(0, 2, lo_open=True), "(fraction of the image width)")
    """Standard deviation of the veil's Gaussian as a fraction of the image's width, in (0, 2]."""


def _glare(radiance: np.ndarray, cfg, rng) -> np.ndarray:
    return veil(radiance, float(cfg.glare), float(cfg.glare_sigma) * radiance.shape[1])


GLARE = Stage("glare", GlareOptions, "veiling glare of the lens: a wide Gaussian veil "
              "(sim.scatter.veil)", _glare, optical=True, linear=True, off={"glare": 0.0})
"""The camera's veiling glare stage."""
