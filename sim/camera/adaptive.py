"""The camera's content-adaptive tone (the stage :data:`ADAPTIVE_TONE`): per capture, a curve that
lifts the shadows of a dark frame, the more the darker the frame, as automatic lighting optimisers
of consumer cameras do.

On encoded values ``v`` in [0, 1], with ``m`` the frame's mean luma (:data:`sim.camera.style.LUMA`)
and ``a`` the key ``adaptive_tone``:

``k = a max(0, 1 - 2 m)``, ``v -> v + k v (1 - v)**2`` per channel.

A frame whose mean is mid-grey or brighter is unchanged (``k = 0``); an all-black one is too
(``v = 0`` stays). 0 and 1 stay; the lift is largest at ``v = 1/3`` (``4 k / 27``); the slope is
``1 + k`` at 0 and at least ``1 - k / 3``, so the curve is strictly increasing. Being a function of
the whole frame's mean, a pixel's output depends on every other pixel. Applied by the sensor's
fused group (:mod:`sim.camera.sensor`) on the encoded image, first of the processing stages.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.camera.style import LUMA
from sim.options import Range, number
from sim.stages import Stage


def shadow_lift(encoded: np.ndarray, strength: float) -> np.ndarray:
    """The adaptive tone of one frame: ``v + k v (1 - v)**2``, ``k = a max(0, 1 - 2 m)``.

    Parameters
    ----------
    encoded : numpy.ndarray
        float32 (H, W, 3) encoded values in [0, 1].
    strength : float
        ``a`` in [0, 1]: the curve's strength for a frame of mean luma 0.

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3): ``encoded`` itself where ``k = 0``.

    Examples
    --------
    >>> dark = np.full((2, 2, 3), 0.25, np.float32)  # m = 1/4: k = a / 2
    >>> float(shadow_lift(dark, 1.0)[0, 0, 0])
    0.3203125
    """
    v = np.asarray(encoded, np.float32)
    m = float(v.reshape(-1, 3).mean(axis=0, dtype=np.float64) @ np.asarray(LUMA))
    k = strength * max(0.0, 1.0 - 2.0 * m)
    if k == 0.0:
        return v
    return v + np.float32(k) * v * (1 - v) ** 2


def adaptive_tone(encoded: np.ndarray, cfg) -> np.ndarray:
    """The shadow lift of ``cfg`` (``adaptive_tone``)."""
    return shadow_lift(encoded, cfg.adaptive_tone)


@dataclass(frozen=True)
class AdaptiveToneOptions:
    """The key of the camera's content-adaptive tone."""

    adaptive_tone: float = number(0.0, Range(0, 1), "(shadow-lift strength)")
    """Strength a in [0, 1] of the per-capture shadow lift: a frame of mean encoded luma m gets
    ``v + k v (1 - v)**2`` with ``k = a max(0, 1 - 2 m)`` (none at m >= 1/2); 0 is off."""


ADAPTIVE_TONE = Stage("adaptive_tone", AdaptiveToneOptions, "a shadow-lifting curve per capture, "
                      "stronger the darker the frame's mean encoded luma (shadow_lift)",
                      processing=True, off={"adaptive_tone": 0.0})
"""The camera's adaptive-tone stage (applied by the sensor group)."""
