"""The camera's sensor as one fused group of stages (:data:`SENSOR`): exposure, Bayer mosaic,
Poisson-Gaussian noise and the full-well clip, white balance, demosaicing, response curve, the
processing of the encoded image (adaptive tone, picture style, sharpening) and 8-bit quantisation,
applied by :func:`sensor` in as few passes as each case allows (without a Bayer sensor and without
processing: one noise kernel and the encoder on its blocks).

The response stage's curve and quantisation are fused (:func:`sim.camera.response.codes` gives
8-bit codes straight from the linear signal), and a camera processes its image between the two:
with a processing stage on, the signal is encoded to floats, processed (:data:`PROCESSING`, in
order) and quantised once. With OpenCV's VNG demosaicing, which takes 8-bit data only, the
processing acts on the demosaiced 8-bit codes instead.
"""
from __future__ import annotations

import functools

import numpy as np

from sim.camera.adaptive import ADAPTIVE_TONE, adaptive_tone
from sim.camera.noise import EXPOSURE, NOISE, expose
from sim.camera.raw import (DEMOSAIC, MOSAIC, WHITE_BALANCE, demosaic, dequantise_raw, mosaic,
                            quantise_raw, white_balance_mosaic)
from sim.camera.response import RESPONSE, codes, encode, quantise
from sim.camera.style import SHARPEN, STYLE, picture_style, sharpen
from sim.camera.threads import blockwise
from sim.stages import Fused

PROCESSING = ((ADAPTIVE_TONE, adaptive_tone), (STYLE, picture_style), (SHARPEN, sharpen))
"""The processing stages of the encoded image, in order, each with its function
``(encoded, cfg) -> encoded`` (float32 (H, W, 3) in [0, 1])."""


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


@functools.lru_cache(maxsize=16)
def raw_encoded_table(response: str) -> np.ndarray:
    """The encoded value of each 16-bit raw code: ``encode(dequantise_raw(k), response)`` for k in
    0..65535 (float32, read-only), so a demosaiced image is encoded by one table lookup per value.

    Examples
    --------
    >>> table = raw_encoded_table("gamma:2")
    >>> float(table[0]), round(float(table[16384]), 5), float(table[65535])  # 16384 / 65535
    (0.0, 0.5, 1.0)
    """
    table = encode(dequantise_raw(np.arange(65536, dtype=np.uint16)), response)
    table.flags.writeable = False
    return table


def process(encoded: np.ndarray, cfg) -> np.ndarray:
    """The processing stages :data:`PROCESSING` that ``cfg`` switches on, in order.

    Parameters
    ----------
    encoded : numpy.ndarray
        float32 (H, W, 3) encoded image in [0, 1] (after the response curve).
    cfg : CameraConfig-like
        The processing stages' keys (absent: off).

    Returns
    -------
    numpy.ndarray
        float32 (H, W, 3) encoded image.
    """
    for stage, apply in PROCESSING:
        if not stage.is_off(cfg):
            encoded = apply(encoded, cfg)
    return encoded


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


def sensor(radiance: np.ndarray, cfg, rng: np.random.Generator) -> np.ndarray:
    """The sensor's stages on the radiance after the optics, to an 8-bit image (see the module).

    Parameters
    ----------
    radiance : numpy.ndarray
        float32 (H, W, 3) linear radiance at the sensor.
    cfg : CameraConfig-like
        ``exposure``, ``white_balance``, ``shot_noise``, ``read_noise``, ``response`` and
        ``bit_depth``; ``bayer`` and ``demosaic`` (a sensor without a Bayer pattern when absent);
        the processing stages' keys (off when absent).
    rng : numpy.random.Generator
        Source of the sensor noise (seeded by the caller).

    Returns
    -------
    numpy.ndarray
        uint8 (H, W, 3) image.
    """
    if cfg.bit_depth != 8:
        raise ValueError(f"camera bit_depth = {cfg.bit_depth!r}: only 8 is supported")
    processed = not all(stage.is_off(cfg) for stage, _ in PROCESSING)
    if MOSAIC.is_off(cfg):
        wb = np.asarray(cfg.white_balance, np.float32)
        if wb.shape != (3,):
            raise ValueError(f"white_balance: expected 3 gains, got {cfg.white_balance!r}")
        if processed:
            signal = expose(radiance, cfg.exposure, wb, cfg.shot_noise, cfg.read_noise, rng)
            return quantise(process(encode(signal, cfg.response), cfg))
        return expose(radiance, cfg.exposure, wb, cfg.shot_noise, cfg.read_noise, rng,
                      lambda s: codes(s, cfg.response), np.uint8)
    raw = raw_signal(radiance, cfg, rng)
    method = getattr(cfg, "demosaic", "bilinear")
    if method == "vng":  # OpenCV's VNG is 8-bit only: demosaic the encoded mosaic
        rgb = demosaic(blockwise(lambda b: codes(b, cfg.response), raw, np.uint8), cfg.bayer, method)
        return quantise(process(rgb.astype(np.float32) * np.float32(1 / 255), cfg)) if processed else rgb
    rgb = demosaic(quantise_raw(raw), cfg.bayer, method)
    if processed:
        return quantise(process(np.take(raw_encoded_table(cfg.response), rgb), cfg))
    return np.take(raw_code_table(cfg.response), rgb)


SENSOR = Fused("sensor", (EXPOSURE, MOSAIC, NOISE, WHITE_BALANCE, DEMOSAIC, RESPONSE,
                          *(stage for stage, _ in PROCESSING)), sensor)
"""The sensor's stages, applied by :func:`sensor`: the response's curve, then the processing, then
its quantisation (see the module)."""
