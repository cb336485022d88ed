"""The projector's photometry: response, black level and primaries mixing of an input frame.

Outputs are *relative linear* irradiance: the brightness is the scale of Mitsuba's emitter
(:mod:`sim.scene`), so a white input with identity mixing gives 1.
"""
from __future__ import annotations

import cv2
import numpy as np

from sim.io import to_float


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
