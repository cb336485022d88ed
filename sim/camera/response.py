"""Camera response curves, 8-bit quantisation, and the fast encoder of linear signals to codes.

:func:`encode` then :func:`quantise` is the straightforward definition of a capture's 8-bit code;
:func:`codes` gives the same codes from the linear signal by table look-up (see
:func:`code_thresholds`).

Response curves map the linear sensor signal in [0, 1] (1 = full well) to the encoded value in
[0, 1], strictly increasing with an inverse. Two families are offered:

- colour-science CCTFs (:data:`RESPONSE_NAMES`, after ``"linear"``): the names in ``colour.CCTF_ENCODINGS`` whose
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

The module declares the response stage (:data:`RESPONSE`), applied by the sensor
(:mod:`sim.camera.sensor`).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Callable

import numpy as np

from sim.options import integer, string
from sim.stages import Stage

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


RESPONSE_NAMES = ("linear", *_COLOUR_CURVES)
"""Names of the fixed response curves; each resolves to (encode, decode), both float64 [0, 1] ->
[0, 1]. colour-science is imported when a capture first encodes or decodes, not when a setup is
checked (its import takes about a second)."""

_PARAMETRIC = {"gamma": _gamma, "scurve": _scurve}
_PARAMETER_RANGE = (0.1, 10.0)
_LEVELS = 255  # 8-bit code values


def response_names() -> tuple[str, ...]:
    """Names of the fixed response curves (the parametric ``gamma:<g>``/``scurve:<k>`` aside)."""
    return RESPONSE_NAMES


def _valid_forms() -> str:
    lo, hi = _PARAMETER_RANGE
    return (f"one of {', '.join(repr(n) for n in RESPONSE_NAMES)}, or 'gamma:<g>' / "
            f"'scurve:<k>' with a number g or k in ({lo:g}, {hi:g})")


@functools.lru_cache(maxsize=64)
def _resolve(response: str) -> tuple[Callable, Callable]:
    """(encode, decode) of a response name; ValueError naming the valid forms otherwise."""
    if response == "linear":
        return _identity, _identity
    if response in _COLOUR_CURVES:
        import colour

        return colour.CCTF_ENCODINGS[response], colour.CCTF_DECODINGS[response]
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
    if response not in RESPONSE_NAMES:
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


_ONE_BITS = 0x3F800000  # the bit pattern of float32 1.0; non-negative float32 bit patterns are ordered


def _reference_codes(bits: np.ndarray, response: str) -> np.ndarray:
    """8-bit codes of float32 signals given by their bit patterns: ``quantise(encode(x))``."""
    return quantise(encode(bits.astype(np.uint32).view(np.float32), response))


@functools.lru_cache(maxsize=64)
def code_thresholds(response: str) -> np.ndarray:
    """The float32 signal at which each 8-bit code starts: ``t[k - 1]`` is the smallest float32
    ``x`` in [0, 1] with ``quantise(encode(x)) >= k``, k = 1..255.

    Found by bisection over the float32 bit patterns of [0, 1] (ordered like the numbers), with
    :func:`encode` and :func:`quantise` themselves, so the codes of :func:`codes` are theirs bit
    for bit wherever the encoded code does not decrease with the signal.

    Parameters
    ----------
    response : str
        A response name (see :func:`check_response`).

    Returns
    -------
    numpy.ndarray
        uint32 bit patterns of the 255 thresholds (view them as float32 for the values).

    Examples
    --------
    >>> t = code_thresholds("linear").view(np.float32)  # just above the half codes: rint rounds to even
    >>> round(float(t[0]) * 255, 6), round(float(t[-1]) * 255, 4)
    (0.5, 254.5)
    """
    check_response(response)
    k = np.arange(1, _LEVELS + 1)
    lo = np.zeros(_LEVELS, np.int64)  # code(lo) < k
    hi = np.full(_LEVELS, _ONE_BITS, np.int64)  # code(hi) >= k
    while np.any(hi - lo > 1):
        mid = (lo + hi) // 2
        up = _reference_codes(mid, response) >= k
        hi = np.where(up, mid, hi)
        lo = np.where(up, lo, mid)
    return hi.astype(np.uint32)


@functools.lru_cache(maxsize=64)
def _code_table(response: str) -> tuple[int, np.ndarray, np.ndarray, np.ndarray | None]:
    """(shift, base, next, crowded-or-None): cell ``c = bits >> shift`` of the float32 bit
    patterns starts at code ``base[c]``; the code is one more from ``next[c]`` on. The largest
    shift (fewest cells) with at most one threshold per cell is used; where even 2**20 cells leave
    cells with two thresholds, ``crowded`` marks them (their signals are searched)."""
    t = code_thresholds(response).astype(np.int64)
    for shift in range(16, 9, -1):
        starts = np.arange((_ONE_BITS >> shift) + 1, dtype=np.int64) << shift
        base = np.searchsorted(t, starts, side="right")
        after = np.append(t, [2**32 - 1, 2**32 - 1])
        crowded = after[base + 1] < starts + (1 << shift)
        if not crowded.any() or shift == 10:
            break
    nxt = after[base]
    return shift, base.astype(np.uint8), nxt, (crowded if crowded.any() else None)


def codes(signal: np.ndarray, response: str) -> np.ndarray:
    """8-bit codes of a linear float32 signal: ``quantise(encode(signal, response))`` bit for bit,
    by a table on the float32 bit patterns and one comparison with the next threshold.

    Parameters
    ----------
    signal : numpy.ndarray
        float32 linear signal; values outside [0, 1] (and -0.0) are clipped.
    response : str
        A response name (see :func:`check_response`).

    Returns
    -------
    numpy.ndarray
        uint8 codes, the shape of ``signal``.

    Examples
    --------
    >>> codes(np.array([0.25, 2.0, -1.0], np.float32), "gamma:2").tolist()
    [128, 255, 0]
    """
    x = np.ascontiguousarray(signal, dtype=np.float32)
    shift, base, nxt, crowded = _code_table(response)
    bits = np.empty(x.shape, np.intp)  # gathers index with intp: no conversion pass
    np.clip(x.view(np.int32), 0, _ONE_BITS, out=bits)
    cell = bits >> shift
    out = base[cell]
    out += bits >= nxt[cell]
    if crowded is not None:  # a steep curve: cells with two thresholds or more
        many = crowded[cell]
        out[many] = np.searchsorted(code_thresholds(response), bits[many].astype(np.uint32), side="right")
    return out


def _eight_bits(value: int) -> None:
    """Raise ValueError unless ``value`` is 8."""
    if value != 8:
        raise ValueError("expected 8 (captures are 8-bit PNGs)")


@dataclass(frozen=True)
class ResponseOptions:
    """The keys of the camera's response and quantisation."""

    response: str = string("sRGB", check=check_response)
    """Camera response curve, a name accepted by :func:`sim.camera.check_response`."""
    bit_depth: int = integer(8, check=_eight_bits)
    """Bits per channel of the captures; must be 8."""


RESPONSE = Stage("response", ResponseOptions, "response curve and 8-bit quantisation, at once from "
                 "the linear signal (codes); with a processing stage on, the curve (encode) before "
                 "the processing and the quantisation (quantise) after it")
"""The camera's response stage."""
