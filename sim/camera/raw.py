"""The raw sensor of a colour-filter-array camera: Bayer mosaic, demosaicing (OpenCV) and the
optional JPEG compression of the 8-bit image.

A Bayer pattern is named by its top-left 2x2 block read row by row (``"RGGB"``: red at pixel
(0, 0), green at (1, 0) and (0, 1), blue at (1, 1)). Demosaicing runs on the white-balanced
mosaic quantised to 16 bits (``bilinear``, ``edgeaware``); OpenCV's ``vng`` takes 8-bit data
only, so for it the mosaic is encoded by the response curve and quantised to 8 bits first. The
module declares the mosaic, white-balance, demosaicing and JPEG stages (:data:`MOSAIC`,
:data:`WHITE_BALANCE`, :data:`DEMOSAIC`, :data:`JPEG`); the first three are applied by the
sensor (:mod:`sim.camera.sensor`).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from sim.options import POSITIVE, Range, choice, integer, vector
from sim.stages import Stage

BAYER_PATTERNS = ("RGGB", "BGGR", "GRBG", "GBRG")
"""Valid ``camera.bayer`` patterns (besides ``"none"``)."""
DEMOSAIC_METHODS = ("bilinear", "vng", "edgeaware")
"""Valid ``camera.demosaic`` methods."""
# OpenCV names a pattern by the second and third pixels of its second row: RGGB is "BayerBG".
_CV_PATTERN = {"RGGB": "BG", "BGGR": "RG", "GRBG": "GB", "GBRG": "GR"}
_CV_SUFFIX = {"bilinear": "", "vng": "_VNG", "edgeaware": "_EA"}
_CHANNEL = {"R": 0, "G": 1, "B": 2}
_RAW_LEVELS = 65535


def _check_pattern(pattern: str) -> None:
    if pattern not in BAYER_PATTERNS:
        raise ValueError(f"camera bayer = {pattern!r}: expected one of {', '.join(BAYER_PATTERNS)}")


def channel_map(pattern: str, width: int, height: int) -> np.ndarray:
    """The colour channel (0 R, 1 G, 2 B) each pixel of a mosaic samples.

    Examples
    --------
    >>> channel_map("RGGB", 4, 2).tolist()
    [[0, 1, 0, 1], [1, 2, 1, 2]]
    """
    _check_pattern(pattern)
    block = np.array([[_CHANNEL[pattern[0]], _CHANNEL[pattern[1]]],
                      [_CHANNEL[pattern[2]], _CHANNEL[pattern[3]]]], np.intp)
    return np.tile(block, ((height + 1) // 2, (width + 1) // 2))[:height, :width]


def mosaic(image: np.ndarray, pattern: str) -> np.ndarray:
    """The mosaic a Bayer sensor records: each pixel keeps only the channel of its filter.

    Parameters
    ----------
    image : numpy.ndarray
        (H, W, 3) linear image.
    pattern : str
        One of :data:`BAYER_PATTERNS`.

    Returns
    -------
    numpy.ndarray
        (H, W) mosaic, the dtype of ``image``.

    Examples
    --------
    >>> mosaic(np.arange(12).reshape(2, 2, 3), "GRBG").tolist()
    [[1, 3], [8, 10]]
    """
    _check_pattern(pattern)
    out = np.empty(image.shape[:2], image.dtype)
    for (dy, dx), colour in zip(((0, 0), (0, 1), (1, 0), (1, 1)), pattern):
        out[dy::2, dx::2] = image[dy::2, dx::2, _CHANNEL[colour]]
    return out


@functools.lru_cache(maxsize=8)
def _gain_map(pattern: str, width: int, height: int, gains: tuple[float, float, float]) -> np.ndarray:
    g = np.asarray(gains, np.float32)[channel_map(pattern, width, height)]
    g.flags.writeable = False
    return g


def white_balance_mosaic(raw: np.ndarray, pattern: str, gains) -> np.ndarray:
    """Multiply each site of a mosaic by the gain of its channel.

    Parameters
    ----------
    raw : numpy.ndarray
        float32 (H, W) mosaic.
    pattern : str
        One of :data:`BAYER_PATTERNS`.
    gains : sequence of 3 floats
        Red, green and blue gains.
    """
    h, w = raw.shape
    return raw * _gain_map(pattern, w, h, tuple(float(g) for g in gains))


def demosaic(raw: np.ndarray, pattern: str, method: str) -> np.ndarray:
    """OpenCV demosaicing of a quantised mosaic.

    Parameters
    ----------
    raw : numpy.ndarray
        (H, W) uint16 (``bilinear``, ``edgeaware``) or uint8 (any method) mosaic.
    pattern : str
        One of :data:`BAYER_PATTERNS`.
    method : str
        One of :data:`DEMOSAIC_METHODS`.

    Returns
    -------
    numpy.ndarray
        (H, W, 3) RGB, the dtype of ``raw``.
    """
    if method not in DEMOSAIC_METHODS:
        raise ValueError(f"camera demosaic = {method!r}: expected one of {', '.join(DEMOSAIC_METHODS)}")
    code = getattr(cv2, f"COLOR_Bayer{_CV_PATTERN[pattern]}2RGB{_CV_SUFFIX[method]}")
    return cv2.cvtColor(np.ascontiguousarray(raw), code)


def quantise_raw(raw: np.ndarray) -> np.ndarray:
    """A linear mosaic in [0, 1] as 16-bit codes, ``rint(65535 x)`` after clipping."""
    return np.rint(np.clip(raw, 0.0, 1.0) * np.float32(_RAW_LEVELS)).astype(np.uint16)


def dequantise_raw(codes: np.ndarray) -> np.ndarray:
    """16-bit codes back to linear float32 values in [0, 1]."""
    return codes.astype(np.float32) * np.float32(1.0 / _RAW_LEVELS)


def jpeg(image: np.ndarray, quality: int) -> np.ndarray:
    """Compress and decompress an 8-bit RGB image with OpenCV's JPEG codec (4:2:0 chroma).

    Parameters
    ----------
    image : numpy.ndarray
        uint8 (H, W, 3) RGB.
    quality : int
        1..100.

    Returns
    -------
    numpy.ndarray
        uint8 (H, W, 3) RGB as decoded.
    """
    ok, data = cv2.imencode(".jpg", np.ascontiguousarray(image[..., ::-1]),
                            [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise RuntimeError(f"OpenCV could not JPEG-encode an image of shape {image.shape}")
    return cv2.imdecode(data, cv2.IMREAD_COLOR)[..., ::-1].copy()


@dataclass(frozen=True)
class MosaicOptions:
    """The key of the colour filter array."""

    bayer: str = choice("none", ("none", *BAYER_PATTERNS))
    """Colour filter array: ``"none"`` (three samples per pixel) or a Bayer pattern ``"RGGB"``,
    ``"BGGR"``, ``"GRBG"``, ``"GBRG"`` (top-left 2x2 block, row by row): one channel per pixel,
    noise drawn on the raw mosaic, white balance applied after the noise, then demosaicing."""


@dataclass(frozen=True)
class WhiteBalanceOptions:
    """The key of the white balance."""

    white_balance: tuple[float, float, float] = vector((1.0, 1.0, 1.0), POSITIVE)
    """Per-channel linear gains, each > 0."""


@dataclass(frozen=True)
class DemosaicOptions:
    """The key of the demosaicing."""

    demosaic: str = choice("bilinear", DEMOSAIC_METHODS)
    """OpenCV demosaicing of a Bayer mosaic: ``"bilinear"``, ``"vng"`` or ``"edgeaware"``
    (used only when ``bayer`` is not ``"none"``)."""


@dataclass(frozen=True)
class JpegOptions:
    """The key of the JPEG compression."""

    jpeg_quality: int = integer(0, Range(0, 100), "(0: no JPEG)")
    """JPEG quality 1..100 of the captures (OpenCV), or 0: no compression (lossless PNG)."""


def _jpeg(image: np.ndarray, cfg, rng) -> np.ndarray:
    return jpeg(image, cfg.jpeg_quality)


MOSAIC = Stage("mosaic", MosaicOptions, "with a Bayer pattern, one colour channel per pixel (mosaic)",
               linear=True, off={"bayer": "none"})
"""The camera's colour filter array stage."""
WHITE_BALANCE = Stage("white_balance", WhiteBalanceOptions, "per-channel gains: with a Bayer sensor "
                      "the digital gain of each site after the noise and the clip (clipped to [0, 1] "
                      "again), without one ahead of the noise", linear=True,
                      off={"white_balance": (1.0, 1.0, 1.0)})
"""The camera's white-balance stage."""
DEMOSAIC = Stage("demosaic", DemosaicOptions, "OpenCV demosaicing of the mosaic quantised to 16 bits "
                 "(vng: of the mosaic encoded to 8 bits, OpenCV's VNG being 8-bit only; demosaic)")
"""The camera's demosaicing stage."""
JPEG = Stage("jpeg", JpegOptions, "JPEG compression and decompression (jpeg)", _jpeg,
             off={"jpeg_quality": 0})
"""The camera's JPEG stage."""
