"""The projector's dynamic lamp mode (the stage :data:`DYNAMIC_LAMP`): the lamp's power follows
the content of each frame, dimming for dark frames, which deepens the black of a dark frame
(the full-on/full-off contrast grows by ``1 / (1 - depth)``) at the price of a per-pixel output
that depends on the whole frame.

Per frame the lamp's power is ``1 - depth (1 - s)``, ``s`` the frame's mean or peak linear
luminance after the response (:func:`dynamic_gain`): 1 for a frame whose statistic is white,
``1 - depth`` for an all-black frame. The power scales the whole emitted light, the black level's
included. The controller follows the video signal, so ``s`` is read from the panel's frame after
the response (``x**gamma``, without the black-level floor, the white segment and the mixing): the
stage sits in the fused group :data:`sim.projector.photometry.PHOTOMETRY`, which has that frame at
hand, after the mixing and before the lens. Being one number per frame it commutes with the
linear lens stages, so the light is the same as if it acted after them; but read after the lens,
the statistic would be of the light blurred and padded with black on the lens's grid, not of the
frame the controller sees.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.options import Range, choice, number
from sim.stages import Stage

LUMINANCE = (0.2126, 0.7152, 0.0722)
"""Weights of the linear luminance of the red, green and blue primaries (Rec. 709: the projector's
input taken as video of that standard)."""
STATISTICS = ("mean", "peak")
"""Values of ``projector.dynamic_lamp_statistic``."""


def dynamic_gain(primaries: np.ndarray, depth: float, statistic: str) -> float:
    """The lamp's relative power for one frame: ``1 - depth (1 - s)``.

    Parameters
    ----------
    primaries : numpy.ndarray
        (H, W, 3) linear primaries of the panel's frame after the response (``x**gamma``), in
        [0, 1].
    depth : float
        The fraction by which the lamp dims for an all-black frame, in [0, 1].
    statistic : str
        ``"mean"``: ``s`` is the mean over the panel of the luminance (:data:`LUMINANCE`);
        ``"peak"``: its maximum.

    Returns
    -------
    float
        The multiplier of the frame's emitted light, in [1 - depth, 1].

    Raises
    ------
    ValueError
        If ``statistic`` is not one of :data:`STATISTICS`.

    Examples
    --------
    >>> black, white = np.zeros((2, 2, 3)), np.ones((2, 2, 3))
    >>> round(dynamic_gain(black, 0.55, "mean"), 12), round(dynamic_gain(white, 0.55, "mean"), 12)
    (0.45, 1.0)
    >>> half = np.concatenate([black, white])  # half the panel white
    >>> round(dynamic_gain(half, 0.5, "mean"), 12), round(dynamic_gain(half, 0.5, "peak"), 12)
    (0.75, 1.0)
    """
    if statistic not in STATISTICS:
        raise ValueError(f"projector dynamic_lamp_statistic = {statistic!r}: expected one of "
                         f"{', '.join(STATISTICS)}")
    y = np.asarray(primaries, np.float64).reshape(-1, 3) @ np.asarray(LUMINANCE)
    s = float(y.mean() if statistic == "mean" else y.max())
    return 1.0 - depth * (1.0 - min(max(s, 0.0), 1.0))


@dataclass(frozen=True)
class DynamicLampOptions:
    """The keys of the projector's dynamic lamp mode."""

    dynamic_lamp: float = number(0.0, Range(0, 0.9), "(fraction the lamp dims for a black frame)")
    """Depth of the dynamic lamp mode, in [0, 0.9]: the fraction by which the lamp dims for an
    all-black frame. Each frame's whole emitted light (its black level's too) is scaled by
    ``1 - dynamic_lamp * (1 - s)``, ``s`` the statistic ``dynamic_lamp_statistic`` of the frame's
    linear luminance after the response; 0 is off."""
    dynamic_lamp_statistic: str = choice("mean", STATISTICS)
    """What the lamp follows: ``"mean"``, the frame's mean linear luminance (Rec. 709 weights of
    the response's output ``x**gamma``, over the whole panel, the scaler's dark bars included), or
    ``"peak"``, its maximum."""


DYNAMIC_LAMP = Stage("dynamic_lamp", DynamicLampOptions, "the lamp's power per frame, following the "
                     "frame's mean or peak linear luminance after the response (dynamic_gain; "
                     "emitted_irradiance)", off={"dynamic_lamp": 0.0})
"""The projector's dynamic lamp stage (applied by the photometry group)."""
