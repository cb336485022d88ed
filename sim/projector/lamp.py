"""The projector's lamp: its brightness from one capture to the next (flicker) and between
calibration and test time (drift)."""
from __future__ import annotations

from sim import seeds


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
