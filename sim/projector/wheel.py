"""The DLP colour wheel's white segment (the stage :data:`WHITE_BOOST`): light added to each pixel
in proportion to its white content, so that white is brighter than the sum of the colour segments
could make it and saturated colours are relatively dimmer.

A pixel of linear primaries ``x`` (after the response) becomes ``(x + b min_c x) / (1 + b)``: the
white segment adds ``b`` times the pixel's white content (the least of its primaries) to every
primary, and the whole is normalised so that white stays 1. A grey keeps its value, a saturated
primary drops to ``1 / (1 + b)``: the projector's colour light output is ``1 / (1 + b)`` of its
white light output. The stage acts between the response and the primaries mixing (in the fused
group :data:`sim.projector.photometry.PHOTOMETRY`, by :func:`white_boosted`); since the black level
is the same for each primary, applying it to the response's output before or after the black-level
floor gives the same light.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.options import Range, number
from sim.stages import Stage


def white_boosted(primaries: np.ndarray, boost: float) -> np.ndarray:
    """Each pixel's primaries with the white segment's light: ``(x + b min_c x) / (1 + b)``.

    Parameters
    ----------
    primaries : numpy.ndarray
        float32 (H, W, 3) linear primaries (the response's output), in [0, 1].
    boost : float
        ``b`` (>= 0): the white segment's light per unit of white content, relative to the colour
        segments'.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3).

    Examples
    --------
    >>> x = np.array([[[1.0, 1.0, 1.0], [1.0, 0.0, 0.0], [0.5, 0.5, 0.5]]], np.float32)
    >>> white_boosted(x, 1.0)[0].tolist()
    [[1.0, 1.0, 1.0], [0.5, 0.0, 0.0], [0.5, 0.5, 0.5]]
    """
    x = np.asarray(primaries, np.float32)
    out = x + np.float32(boost) * x.min(axis=2, keepdims=True)
    out *= np.float32(1.0 / (1.0 + boost))
    return out


@dataclass(frozen=True)
class WhiteBoostOptions:
    """The key of the colour wheel's white segment."""

    white_boost: float = number(0.0, Range(0, 2), "(white segment's light per unit of white content)")
    """The white segment's light relative to the colour segments', in [0, 2]: each pixel of linear
    primaries ``x`` becomes ``(x + white_boost * min_c x) / (1 + white_boost)``, so white stays 1
    and a saturated primary gives ``1 / (1 + white_boost)`` of it (colour light output over white
    light output); 0 is off (a wheel of colour segments only)."""


WHITE_BOOST = Stage("white_boost", WhiteBoostOptions, "the colour wheel's white segment: light added "
                    "to each pixel in proportion to its white content, white kept at 1 "
                    "(white_boosted; emitted_irradiance)", off={"white_boost": 0.0})
"""The projector's white-segment stage (applied by the photometry group)."""
