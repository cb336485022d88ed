"""The projector's lamp: its brightness from one capture to the next (flicker) and between
calibration and test time (drift), the stage :data:`LAMP`."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim import seeds
from sim.options import Range, number
from sim.stages import Stage


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


@dataclass(frozen=True)
class LampOptions:
    """The keys of the projector's lamp."""

    flicker: float = number(0.0, Range(0, 0.5), "(relative brightness std)")
    """Relative standard deviation of the lamp brightness from one capture to the next, in
    [0, 0.5] (0: steady)."""
    drift: float = number(0.0, Range(-1, 1, lo_open=True, hi_open=True), "(relative brightness change)")
    """Relative change of the lamp brightness between calibration captures (reference, training,
    registration) and test-time captures (test and closed loop), in (-1, 1) (0: none)."""


def _lamp(radiance: np.ndarray, cfg, seed: int, stream: int, index: int) -> np.ndarray:
    return radiance * np.float32(lamp_gain(cfg, seed, stream, index))


LAMP = Stage("lamp", LampOptions, "each capture's projector contribution scaled by the lamp's "
             "brightness, drawn from sim.seeds.lamp_rng (lamp_gain; never in calibration renders)",
             _lamp, linear=True, random=True, off={"flicker": 0.0, "drift": 0.0})
"""The projector's lamp stage."""
