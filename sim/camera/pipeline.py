"""The whole camera on linear radiance (:func:`capture`: the chain of :mod:`sim.camera.chain`),
its optics alone (:func:`apply_optics`) and the exposure rule (:func:`rule_exposure`)."""
from __future__ import annotations

import numpy as np

from sim.camera import chain
from sim.camera.noise import expose
from sim.camera.response import code_thresholds, codes
from sim.errors import SetupError
from sim.stages import run

WHITE_CLIPPED_FRACTION = 0.02
"""The exposure rule's "slightly over-exposed": the fraction of camera pixels whose noiseless
capture of plain white reaches code 255 in some channel."""


def _optical(items: tuple) -> tuple:
    """The items of a camera chain made of optical stages only (those before the sensor)."""
    return tuple(item for item in items if all(s.optical for s in item.stages))


def apply_optics(radiance: np.ndarray, cfg) -> np.ndarray:
    """The optical stages of :data:`sim.camera.chain.CHAIN` (PSF, glare, distortion,
    vignetting), each only when its keys do not switch it off (the input itself is returned when
    all are off).

    Parameters
    ----------
    radiance : numpy.ndarray
        float32 (H, W, 3) linear radiance.
    cfg : CameraConfig-like
        The optical stages' keys (absent: off).
    """
    return run(_optical(chain.CHAIN), radiance, cfg, None)


def capture(radiance: np.ndarray, cfg, rng: np.random.Generator) -> np.ndarray:
    """The whole camera: the stages of :data:`sim.camera.chain.CHAIN` in order, to an 8-bit image.

    Parameters
    ----------
    radiance : numpy.ndarray
        Linear camera radiance (H, W, 3).
    cfg : CameraConfig-like
        Any object with ``exposure``, ``white_balance``, ``shot_noise``, ``read_noise``,
        ``response`` and ``bit_depth`` attributes; the keys of the stages that can be switched
        off (``psf_sigma``, ``distortion``, ``vignetting``, ``bayer``, ``jpeg_quality`` …) are off
        when absent.
    rng : numpy.random.Generator
        Source of the sensor noise (seeded by the caller).

    Returns
    -------
    numpy.ndarray
        uint8 (H, W, 3) image.
    """
    rad = np.asarray(radiance, np.float32)
    if rad.ndim != 3 or rad.shape[-1] != 3:
        raise ValueError(f"radiance: expected shape (H, W, 3), got {rad.shape}")
    return run(chain.CHAIN, rad, cfg, rng)


def rule_exposure(white: np.ndarray, black: np.ndarray, cfg) -> dict:
    """The exposure a user sets by the official rule: plain white slightly over-exposed.

    The exposure is chosen so that :data:`WHITE_CLIPPED_FRACTION` of the camera pixels of the
    noiseless capture of plain white reach code 255 in their brightest white-balanced channel
    (after the optics); where pixels tie (a flat white field), the smallest exposure at which at
    least that fraction does. One exposure cannot also set how much of plain black is under-exposed;
    that fraction (pixels at code 0 in every channel of the noiseless capture of plain black) is
    measured at the chosen exposure and returned.

    Parameters
    ----------
    white, black : numpy.ndarray
        Linear camera radiance (H, W, 3) of the plain white and plain black projector frames.
    cfg : CameraConfig-like
        The camera (its ``exposure`` is ignored).

    Returns
    -------
    dict
        ``mode`` ("rule"), ``exposure``, ``white_clipped_fraction`` (target and measured),
        ``black_zero_fraction``.

    Raises
    ------
    SetupError
        If plain white is black in the camera (no exposure can over-expose it).
    """
    wb = np.asarray(cfg.white_balance, np.float32)
    full = float(code_thresholds(cfg.response)[-1].view(np.float32))  # where code 255 starts
    white, black = (apply_optics(np.asarray(x, np.float32), cfg) for x in (white, black))
    m = (white * wb).max(axis=-1).ravel()
    n = max(1, int(np.ceil(WHITE_CLIPPED_FRACTION * m.size)))
    level = float(np.partition(m, m.size - n)[m.size - n])  # the n-th brightest pixel
    if not level > 0:
        raise SetupError('camera.exposure_mode = "rule": the capture of plain white is black, so no '
                         "exposure over-exposes it; expected light from the projector's white "
                         "(projector.brightness, projector.mixing) or the room (ambient.radiance) "
                         'that camera.white_balance keeps, or exposure_mode = "manual"')
    exposure = full / level

    def noiseless(x: np.ndarray) -> np.ndarray:
        return expose(x, exposure, wb, 0.0, 0.0, None, lambda s: codes(s, cfg.response), np.uint8)

    return {"mode": "rule", "exposure": exposure,
            "white_clipped_fraction": float(np.mean((noiseless(white) == 255).any(axis=-1))),
            "target_white_clipped_fraction": WHITE_CLIPPED_FRACTION,
            "black_zero_fraction": float(np.mean((noiseless(black) == 0).all(axis=-1)))}
