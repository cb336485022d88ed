"""The camera outside Mitsuba: exposure, white balance, Poisson-Gaussian sensor noise, clipping at
full well, a response curve and 8-bit quantisation, applied to the rendered linear radiance.

Response curves map the linear sensor signal in [0, 1] (1 = full well) to the encoded value in
[0, 1], strictly increasing with an inverse. Two families are offered:

- colour-science CCTFs (:data:`RESPONSE_CURVES`): the names in ``colour.CCTF_ENCODINGS`` whose
  encoding maps 0 to 0 and 1 to 1, is strictly increasing on [0, 1] and is inverted by the
  ``colour.CCTF_DECODINGS`` entry of the same name. Tested over every name of colour-science
  0.4.7, that leaves the display/video curves (sRGB, gammas, BT.601/709/1886/2020, SMPTE 240M,
  ROMM/ProPhoto) and two log curves that are normalised to [0, 1] (Protune, REDLog). The camera
  log curves (ARRI LogC3/LogC4, S-Log*, Log3G10, Canon Log*, V-Log, Cineon, ACEScc/cct, ...)
  are scene-referred: they code scene values up to 10-60x diffuse white, so 0 maps to a black
  code of 0.06-0.15 (or -inf) and 1 to 0.4-0.7; some also clamp their toe (ITU-T H.273 Log)
  or are not invertible to 1e-5 (F-Log, L-Log, N-Log, ACESproxy). HDR/absolute curves (PQ /
  ST 2084, HLG, ARIB STD-B67, DCDM, DICOM GSDF, ST.428-1) and wide-range ones (RIMM, ERIMM,
  DaVinci Intermediate, Log3G12) leave 1 well below 1. All of these are excluded.
  BT.601/709/2020 and SMPTE 240M have a jump of up to 2.5e-4 at the joint of their linear toe
  (rounded constants of the standards): decoding is exact, and encoding a value inside that gap
  is off by at most its width (0.06 of an 8-bit level).
- Parametric curves of ours: ``"linear"``, ``"gamma:<g>"`` (encode ``x**(1/g)``) and
  ``"scurve:<k>"``, the film-like ``x**k / (x**k + (1 - x)**k)`` (S-shaped for k > 1, exact
  inverse: the same curve with ``1/k``), for g, k in (0.1, 10).
"""
from __future__ import annotations

import functools
import math
from types import MappingProxyType
from typing import Callable

import colour
import numpy as np

_COLOUR_CURVES = (
    "sRGB", "ITU-T H.273 IEC 61966-2", "Gamma 2.2", "Gamma 2.4", "Gamma 2.6", "ITU-R BT.601",
    "ITU-R BT.709", "ITU-R BT.1886", "ITU-R BT.2020", "SMPTE 240M", "ROMM RGB", "ProPhoto RGB",
    "Protune", "REDLog",
)


def _identity(x: np.ndarray) -> np.ndarray:
    return x


def _gamma(x: np.ndarray, exponent: float) -> np.ndarray:
    return x ** exponent


def _scurve(x: np.ndarray, k: float) -> np.ndarray:
    a = x ** k
    return a / (a + (1.0 - x) ** k)


RESPONSE_CURVES: MappingProxyType[str, tuple[Callable, Callable]] = MappingProxyType({
    "linear": (_identity, _identity),
    **{name: (colour.CCTF_ENCODINGS[name], colour.CCTF_DECODINGS[name])
       for name in _COLOUR_CURVES if name in colour.CCTF_ENCODINGS},
})
"""Named response curves: name -> (encode, decode), both float64 [0, 1] -> [0, 1]."""

_PARAMETRIC = {"gamma": _gamma, "scurve": _scurve}
_PARAMETER_RANGE = (0.1, 10.0)
_LEVELS = 255  # 8-bit code values


def response_names() -> tuple[str, ...]:
    """Names of the fixed response curves (the parametric ``gamma:<g>``/``scurve:<k>`` aside)."""
    return tuple(RESPONSE_CURVES)


def _valid_forms() -> str:
    lo, hi = _PARAMETER_RANGE
    return (f"one of {', '.join(repr(n) for n in RESPONSE_CURVES)}, or 'gamma:<g>' / "
            f"'scurve:<k>' with a number g or k in ({lo:g}, {hi:g})")


@functools.lru_cache(maxsize=64)
def _resolve(response: str) -> tuple[Callable, Callable]:
    """(encode, decode) of a response name; ValueError naming the valid forms otherwise."""
    if response in RESPONSE_CURVES:
        return RESPONSE_CURVES[response]
    kind, sep, value = response.partition(":")
    if sep and kind in _PARAMETRIC:
        try:
            p = float(value)
        except ValueError:
            p = math.nan
        lo, hi = _PARAMETER_RANGE
        if not lo < p < hi:
            raise ValueError(f"camera response {response!r}: the parameter must be a number in "
                             f"({lo:g}, {hi:g})")
        f = _PARAMETRIC[kind]
        if kind == "gamma":
            return functools.partial(f, exponent=1.0 / p), functools.partial(f, exponent=p)
        return functools.partial(f, k=p), functools.partial(f, k=1.0 / p)
    raise ValueError(f"unknown camera response {response!r}: expected {_valid_forms()}")


def check_response(response) -> None:
    """Raise ValueError unless ``response`` names a response curve.

    Parameters
    ----------
    response : str
        A name of :func:`response_names`, or ``"gamma:<g>"`` / ``"scurve:<k>"``.

    Raises
    ------
    ValueError
        Naming the value and listing the valid names and forms.
    """
    if not isinstance(response, str):
        raise ValueError(f"camera response {response!r}: expected a string, {_valid_forms()}")
    _resolve(response)


def _apply(values, response, which: int) -> np.ndarray:
    check_response(response)
    x = np.asarray(values)
    dtype = np.result_type(x.dtype, np.float32)
    y = np.asarray(_resolve(response)[which](np.clip(x.astype(np.float64), 0.0, 1.0)))
    return np.clip(y, 0.0, 1.0).astype(dtype)


def encode(signal, response: str) -> np.ndarray:
    """Apply a camera response curve: linear sensor signal -> encoded value.

    Parameters
    ----------
    signal : array_like
        Linear signal in [0, 1] (1 = full well); values outside are clipped first.
    response : str
        A response name (see :func:`check_response`).

    Returns
    -------
    numpy.ndarray
        Encoded values in [0, 1], float32 (float64 for float64 input).

    Examples
    --------
    >>> float(encode(np.array(0.25), "gamma:2"))
    0.5
    """
    return _apply(signal, response, 0)


def decode(encoded, response: str) -> np.ndarray:
    """Invert a camera response curve: encoded value -> linear sensor signal.

    Parameters
    ----------
    encoded : array_like
        Encoded values in [0, 1]; values outside are clipped first.
    response : str
        A response name (see :func:`check_response`).

    Returns
    -------
    numpy.ndarray
        Linear signal in [0, 1], float32 (float64 for float64 input).

    Examples
    --------
    >>> float(decode(np.array(0.5), "scurve:3"))
    0.5
    """
    return _apply(encoded, response, 1)


def sensor_signal(radiance: np.ndarray, exposure: float, white_balance, shot_noise: float = 0.0,
                  read_noise: float = 0.0, rng: np.random.Generator | None = None) -> np.ndarray:
    """Linear sensor signal with Poisson-Gaussian noise, clipped at full well.

    ``s = radiance * exposure * white_balance``; with ``shot_noise = a > 0`` the signal is
    ``a * Poisson(s / a)`` (``s / a`` electrons), then Gaussian read noise of standard deviation
    ``read_noise`` is added and the result clipped to [0, 1]. Before clipping the variance is
    ``a * s + read_noise**2`` (see :func:`noise_sigma`). Without noise (the defaults) this is
    the noiseless signal, ``s`` clipped to [0, 1].

    Parameters
    ----------
    radiance : numpy.ndarray
        Linear camera radiance, (..., 3), >= 0 (negative values count as 0).
    exposure : float
        Multiplier from radiance to signal (1 = full well at radiance 1), > 0.
    white_balance : array_like
        Three per-channel gains, > 0.
    shot_noise : float
        Poisson gain a in signal units (>= 0; 0 = no shot noise).
    read_noise : float
        Gaussian read-noise standard deviation in signal units (>= 0).
    rng : numpy.random.Generator, optional
        Source of the noise (seeded by the caller); needed unless both noise terms are 0.

    Returns
    -------
    numpy.ndarray
        float32 signal in [0, 1], the shape of ``radiance``.

    Examples
    --------
    >>> sensor_signal(np.array([[0.25, 0.5, 2.0]]), 2.0, (1.0, 1.0, 1.0)).tolist()
    [[0.5, 1.0, 1.0]]
    """
    rad = np.asarray(radiance, dtype=np.float32)
    if rad.ndim < 1 or rad.shape[-1] != 3:
        raise ValueError(f"radiance: expected shape (..., 3), got {rad.shape}")
    wb = np.asarray(white_balance, dtype=np.float32)
    if wb.shape != (3,):
        raise ValueError(f"white_balance: expected 3 gains, got {white_balance!r}")
    if exposure <= 0 or shot_noise < 0 or read_noise < 0:
        raise ValueError(f"camera: expected exposure > 0 and noise levels >= 0, got exposure="
                         f"{exposure}, shot_noise={shot_noise}, read_noise={read_noise}")
    if rng is None and (shot_noise > 0 or read_noise > 0):
        raise ValueError("camera: a random generator is needed for shot or read noise")
    s = np.maximum(rad * np.float32(exposure) * wb, 0.0)
    if shot_noise > 0:
        s = shot_noise * rng.poisson(s.astype(np.float64) / shot_noise)
    if read_noise > 0:
        s = s + rng.normal(0.0, read_noise, s.shape)
    return np.clip(s, 0.0, 1.0).astype(np.float32)


def quantise(encoded, bit_depth: int = 8) -> np.ndarray:
    """Round encoded values in [0, 1] to 8-bit codes: ``rint(255 * x)`` after clipping.

    Parameters
    ----------
    encoded : array_like
        Encoded values (clipped to [0, 1]).
    bit_depth : int
        Must be 8.

    Returns
    -------
    numpy.ndarray
        uint8 codes, the shape of ``encoded``.

    Examples
    --------
    >>> quantise(np.array([0.0, 0.5 / 255 - 1e-6, 1.2])).tolist()
    [0, 0, 255]
    """
    if bit_depth != 8:
        raise ValueError(f"camera bit_depth = {bit_depth!r}: only 8 is supported")
    return np.rint(np.clip(np.asarray(encoded, np.float64), 0.0, 1.0) * _LEVELS).astype(np.uint8)


def capture(radiance: np.ndarray, cfg, rng: np.random.Generator) -> np.ndarray:
    """The whole camera: sensor signal, response curve, quantisation.

    Parameters
    ----------
    radiance : numpy.ndarray
        Linear camera radiance (H, W, 3).
    cfg : CameraConfig-like
        Any object with ``exposure``, ``white_balance``, ``shot_noise``, ``read_noise``,
        ``response`` and ``bit_depth`` attributes.
    rng : numpy.random.Generator
        Source of the sensor noise (seeded by the caller).

    Returns
    -------
    numpy.ndarray
        uint8 (H, W, 3) image.
    """
    signal = sensor_signal(radiance, cfg.exposure, cfg.white_balance, cfg.shot_noise,
                           cfg.read_noise, rng)
    return quantise(encode(signal, cfg.response), cfg.bit_depth)


def noise_sigma(signal, shot_noise: float, read_noise: float) -> np.ndarray:
    """Standard deviation of the sensor noise at a linear signal level (before clipping).

    Parameters
    ----------
    signal : array_like
        Linear sensor signal (negative values count as 0).
    shot_noise, read_noise : float
        As in :func:`sensor_signal`.

    Returns
    -------
    numpy.ndarray
        ``sqrt(shot_noise * signal + read_noise**2)`` in signal units (float64).

    Examples
    --------
    >>> float(noise_sigma(0.3, 1e-3, 1e-2)) ** 2
    0.0004
    """
    s = np.maximum(np.asarray(signal, np.float64), 0.0)
    return np.sqrt(shot_noise * s + read_noise ** 2)


def quantisation_sigma(signal, response: str) -> np.ndarray:
    """Standard deviation of 8-bit quantisation, in linear signal units, at a signal level.

    A uniform error over one code, ``(1/255) / sqrt(12)`` encoded, divided by the local slope
    of the response curve. The slope is the secant over the one-code interval around the
    encoded signal (moved inside [0, 1] at the ends), so it stays finite where the derivative
    is 0 or infinite.

    Parameters
    ----------
    signal : array_like
        Linear sensor signal in [0, 1].
    response : str
        A response name (see :func:`check_response`).

    Returns
    -------
    numpy.ndarray
        float64 standard deviation in linear signal units.

    Examples
    --------
    >>> round(float(quantisation_sigma(0.5, "linear")) * 255 * 12 ** 0.5, 9)
    1.0
    """
    y = encode(np.asarray(signal, np.float64), response)
    lo = np.clip(y - 0.5 / _LEVELS, 0.0, 1.0 - 1.0 / _LEVELS)
    width = decode(lo + 1.0 / _LEVELS, response) - decode(lo, response)
    return width / math.sqrt(12.0)
