"""The projector's photometry: response, black level, the colour wheel's white segment, primaries
mixing and the dynamic lamp of an input frame (the stages :data:`RESPONSE`,
:data:`~sim.projector.wheel.WHITE_BOOST`, :data:`MIXING` and
:data:`~sim.projector.dynamic.DYNAMIC_LAMP`, fused as :data:`PHOTOMETRY`), and its brightness
(:data:`BRIGHTNESS`).

Outputs are *relative linear* irradiance: the brightness is the scale of Mitsuba's emitter
(:mod:`sim.scene`), so a white input with identity mixing gives 1.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sim.io import to_float
from sim.options import NON_NEGATIVE, POSITIVE, Range, matrix, number
from sim.projector.dynamic import DYNAMIC_LAMP, dynamic_gain
from sim.projector.wheel import WHITE_BOOST, white_boosted
from sim.stages import Fused, Stage


def emitted_irradiance(frame: np.ndarray, gamma: float, black_level: float,
                       mixing, white_boost: float = 0.0, dynamic_lamp: float = 0.0,
                       dynamic_lamp_statistic: str = "mean") -> np.ndarray:
    """Relative linear irradiance the projector emits for an input frame.

    ``L = (black + (1 - black) * x**gamma) @ mixing.T`` per pixel: every primary follows the
    power-law response with a black-level floor, then the 3x3 mixing matrix spreads each
    primary over the camera channels. With ``white_boost`` the response's output ``p = x**gamma``
    first takes the white segment's light, ``(p + b min_c p) / (1 + b)``
    (:func:`~sim.projector.wheel.white_boosted`); with ``dynamic_lamp`` the whole is scaled by
    the frame's lamp power (:func:`~sim.projector.dynamic.dynamic_gain` of ``p``). Brightness is
    *not* applied: the scene uses it as the emitter scale, so the output is 1 for a white input
    with identity mixing.

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
    white_boost : float
        The colour wheel's white segment, in [0, 2] (0: none).
    dynamic_lamp : float
        Depth of the dynamic lamp mode, in [0, 0.9] (0: off).
    dynamic_lamp_statistic : str
        ``"mean"`` or ``"peak"``: what the dynamic lamp follows.

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
    # The white segment acts on p before the floor: the floor is the same for each primary, so
    # (q + w min q) / (1 + w) with q = b + (1 - b) p is b + (1 - b) (p + w min p) / (1 + w). The
    # lamp's power scales the whole transform.
    p = cv2.pow(np.maximum(x, np.float32(1e-12)), float(gamma))
    np.copyto(p, 0.0, where=x == 0)
    gain = dynamic_gain(p, dynamic_lamp, dynamic_lamp_statistic) if dynamic_lamp > 0 else 1.0
    if white_boost > 0:
        p = white_boosted(p, white_boost)
    mix64 = mix.astype(np.float64)
    affine = np.hstack([(1.0 - black_level) * mix64, black_level * mix64.sum(axis=1, keepdims=True)])
    return cv2.transform(p, gain * affine)


def projector_irradiance(frame: np.ndarray, cfg) -> np.ndarray:
    """:func:`emitted_irradiance` with the photometry of a projector configuration.

    Parameters
    ----------
    frame : numpy.ndarray
        Projector input, uint8 or float in [0, 1], (H, W, 3).
    cfg : ProjectorConfig-like
        Any object with ``gamma``, ``black_level`` and ``mixing`` attributes; ``white_boost``,
        ``dynamic_lamp`` and ``dynamic_lamp_statistic`` (off when absent).

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3) relative linear irradiance (brightness not applied).
    """
    return emitted_irradiance(frame, cfg.gamma, cfg.black_level, cfg.mixing,
                              getattr(cfg, "white_boost", 0.0), getattr(cfg, "dynamic_lamp", 0.0),
                              getattr(cfg, "dynamic_lamp_statistic", "mean"))


@dataclass(frozen=True)
class ResponseOptions:
    """The keys of the projector's response."""

    gamma: float = number(2.2, Range(0.1, 10, lo_open=True, hi_open=True))
    """Projector response exponent (encoded input -> linear output), in (0.1, 10)."""
    black_level: float = number(0.005, Range(0, 0.2, hi_open=True))
    """Fraction of full output emitted for input 0, in [0, 0.2)."""


@dataclass(frozen=True)
class MixingOptions:
    """The key of the projector's primaries mixing."""

    mixing: tuple[tuple[float, float, float], ...] = matrix(
        ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)), NON_NEGATIVE)
    """3x3 primaries mixing matrix (rows: camera channel, columns: projector primary), entries >= 0."""


@dataclass(frozen=True)
class BrightnessOptions:
    """The key of the projector's brightness."""

    brightness: float = number(1.0, POSITIVE)
    """Emitter scale (> 0): irradiance 1 at 1 m head-on gives an outgoing radiance equal to the albedo."""


def _photometry(frame: np.ndarray, cfg, lens) -> np.ndarray:
    return projector_irradiance(np.clip(frame, 0.0, 1.0), cfg)


RESPONSE = Stage("response", ResponseOptions, "power-law response with a black-level floor "
                 "(emitted_irradiance)")
"""The projector's response stage."""
MIXING = Stage("mixing", MixingOptions, "3x3 mixing of the primaries onto the camera channels "
               "(emitted_irradiance)", linear=True,
               off={"mixing": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))})
"""The projector's primaries mixing stage."""
PHOTOMETRY = Fused("photometry", (RESPONSE, WHITE_BOOST, MIXING, DYNAMIC_LAMP), _photometry)
"""Response, white segment, mixing and dynamic lamp at once (:func:`projector_irradiance` of the
frame clipped to [0, 1]): the white segment needs the response's primaries, the dynamic lamp the
panel's frame after the response (see :mod:`sim.projector.dynamic`)."""
BRIGHTNESS = Stage("brightness", BrightnessOptions, "the scale of Mitsuba's projector emitter, in the "
                   "light transport (sim.scene)", linear=True, off={"brightness": 1.0})
"""The projector's brightness: applied by Mitsuba, in the light transport."""
