"""The whole camera on linear radiance (:func:`capture`) and the exposure rule
(:func:`rule_exposure`)."""
from __future__ import annotations

import functools

import numpy as np

from sim.camera.noise import expose
from sim.camera.optics import apply_optics
from sim.camera.raw import (demosaic, dequantise_raw, jpeg, mosaic, quantise_raw,
                            white_balance_mosaic)
from sim.camera.response import code_thresholds, codes
from sim.camera.threads import blockwise

WHITE_CLIPPED_FRACTION = 0.02
"""The exposure rule's "slightly over-exposed": the fraction of camera pixels whose noiseless
capture of plain white reaches code 255 in some channel."""


def _key(cfg, name: str, default):
    """A hardware key of ``cfg``; objects without it (older configs, tests) have the effect off."""
    return getattr(cfg, name, default)


@functools.lru_cache(maxsize=16)
def raw_code_table(response: str) -> np.ndarray:
    """The 8-bit code of each 16-bit raw code: ``codes(dequantise_raw(k), response)`` for k in
    0..65535 (read-only), so a demosaiced image is encoded by one table lookup per value.

    Examples
    --------
    >>> table = raw_code_table("gamma:2")
    >>> table.shape, int(table[0]), int(table[16384]), int(table[65535])
    ((65536,), 0, 128, 255)
    """
    table = codes(dequantise_raw(np.arange(65536, dtype=np.uint16)), response)
    table.flags.writeable = False
    return table


def raw_signal(radiance: np.ndarray, cfg, rng: np.random.Generator | None) -> np.ndarray:
    """The white-balanced mosaic of a Bayer camera, before demosaicing.

    The mosaic of ``radiance * exposure`` (one channel per pixel), Poisson-Gaussian noise on each
    site, the full-well clip to [0, 1], then the white-balance gain of each site's channel and a
    clip to [0, 1] again (the digital saturation). Its variance before the clips is
    ``g_c**2 (shot_noise * s + read_noise**2)`` for a site of channel c, gain g_c and signal s.

    Parameters
    ----------
    radiance : numpy.ndarray
        float32 (H, W, 3) linear radiance at the sensor (after the optics).
    cfg : CameraConfig-like
        ``bayer`` (a pattern), ``exposure``, ``white_balance``, ``shot_noise``, ``read_noise``.
    rng : numpy.random.Generator or None
        Source of the noise; needed unless both noise terms are 0.

    Returns
    -------
    numpy.ndarray
        float32 (H, W) mosaic in [0, 1].
    """
    s = expose(mosaic(np.asarray(radiance, np.float32), cfg.bayer), cfg.exposure, None,
               cfg.shot_noise, cfg.read_noise, rng)
    s = white_balance_mosaic(s, cfg.bayer, cfg.white_balance)
    return np.clip(s, 0.0, 1.0, out=s)


def capture(radiance: np.ndarray, cfg, rng: np.random.Generator) -> np.ndarray:
    """The whole camera: the stages of :data:`sim.camera.chain.STAGES` in order, to an 8-bit image.

    Parameters
    ----------
    radiance : numpy.ndarray
        Linear camera radiance (H, W, 3).
    cfg : CameraConfig-like
        Any object with ``exposure``, ``white_balance``, ``shot_noise``, ``read_noise``,
        ``response`` and ``bit_depth`` attributes; the hardware keys ``psf_sigma``,
        ``distortion``, ``vignetting``, ``bayer``, ``demosaic`` and ``jpeg_quality`` are off
        when absent.
    rng : numpy.random.Generator
        Source of the sensor noise (seeded by the caller).

    Returns
    -------
    numpy.ndarray
        uint8 (H, W, 3) image.
    """
    if cfg.bit_depth != 8:
        raise ValueError(f"camera bit_depth = {cfg.bit_depth!r}: only 8 is supported")
    rad = np.asarray(radiance, np.float32)
    if rad.ndim != 3 or rad.shape[-1] != 3:
        raise ValueError(f"radiance: expected shape (H, W, 3), got {rad.shape}")
    rad = apply_optics(rad, cfg)
    pattern = _key(cfg, "bayer", "none")
    if pattern == "none":
        wb = np.asarray(cfg.white_balance, np.float32)
        if wb.shape != (3,):
            raise ValueError(f"white_balance: expected 3 gains, got {cfg.white_balance!r}")
        out = expose(rad, cfg.exposure, wb, cfg.shot_noise, cfg.read_noise, rng,
                     lambda s: codes(s, cfg.response), np.uint8)
    else:
        raw = raw_signal(rad, cfg, rng)
        method = _key(cfg, "demosaic", "bilinear")
        if method == "vng":  # OpenCV's VNG is 8-bit only: demosaic the encoded mosaic
            out = demosaic(blockwise(lambda b: codes(b, cfg.response), raw, np.uint8), pattern, method)
        else:
            out = np.take(raw_code_table(cfg.response), demosaic(quantise_raw(raw), pattern, method))
    quality = _key(cfg, "jpeg_quality", 0)
    return jpeg(out, quality) if quality else out


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
    ValueError
        If plain white is black in the camera (no exposure can over-expose it).
    """
    wb = np.asarray(cfg.white_balance, np.float32)
    full = float(code_thresholds(cfg.response)[-1].view(np.float32))  # where code 255 starts
    white, black = (apply_optics(np.asarray(x, np.float32), cfg) for x in (white, black))
    m = (white * wb).max(axis=-1).ravel()
    n = max(1, int(np.ceil(WHITE_CLIPPED_FRACTION * m.size)))
    level = float(np.partition(m, m.size - n)[m.size - n])  # the n-th brightest pixel
    if not level > 0:
        raise ValueError("camera exposure rule: the capture of plain white is black; "
                         "no exposure over-exposes it")
    exposure = full / level

    def noiseless(x: np.ndarray) -> np.ndarray:
        return expose(x, exposure, wb, 0.0, 0.0, None, lambda s: codes(s, cfg.response), np.uint8)

    return {"mode": "rule", "exposure": exposure,
            "white_clipped_fraction": float(np.mean((noiseless(white) == 255).any(axis=-1))),
            "target_white_clipped_fraction": WHITE_CLIPPED_FRACTION,
            "black_zero_fraction": float(np.mean((noiseless(black) == 0).all(axis=-1)))}
