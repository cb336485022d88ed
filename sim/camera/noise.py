"""Poisson-Gaussian sensor noise: the noisy linear signal and its standard deviation.

:func:`expose` draws the same numbers as a straightforward implementation (``Generator.poisson``
on the float64 means of the whole image, then ``Generator.normal`` read noise), so captures are
reproducible across versions bit for bit; it only finishes the signal in chunks of
:data:`CHUNK` values, so the float64 temporaries stay in cache and a caller can encode each
chunk at once.
"""
from __future__ import annotations

import numpy as np

CHUNK = 3 * 4096
"""Values finished at once by :func:`expose` (the draws do not depend on it)."""


def expose(values: np.ndarray, exposure: float, gains, shot_noise: float, read_noise: float,
           rng: np.random.Generator | None, convert=None, dtype=np.float32) -> np.ndarray:
    """Exposed, noisy and full-well-clipped linear signal.

    ``s = values * exposure * gains`` (gains repeat along the last axis), clipped below at 0;
    ``shot_noise * Poisson(s / shot_noise)`` when ``shot_noise > 0`` (all the Poisson draws
    first, in C order); plus a normal draw of standard deviation ``read_noise`` per value when
    ``read_noise > 0``; clipped to [0, 1] and cast to float32; then ``convert`` (e.g. the 8-bit
    encoder), chunk by chunk. The variance before the clip is ``shot_noise * s + read_noise**2``.

    Parameters
    ----------
    values : numpy.ndarray
        float32 linear values (radiance), any shape.
    exposure : float
        Multiplier, > 0.
    gains : array_like or None
        Per-channel gains (the length of the last axis of ``values``), or None.
    shot_noise, read_noise : float
        As in :func:`sensor_signal`.
    rng : numpy.random.Generator or None
        Needed unless both noise terms are 0.
    convert : callable, optional
        float32 chunk -> chunk of ``dtype``.
    dtype : numpy dtype
        Of the result.

    Returns
    -------
    numpy.ndarray
        The shape of ``values``.
    """
    if rng is None and (shot_noise > 0 or read_noise > 0):
        raise ValueError("camera: a random generator is needed for shot or read noise")
    s = np.asarray(values, np.float32) * np.float32(exposure)
    if gains is not None:
        s *= np.asarray(gains, np.float32)
    np.maximum(s, 0.0, out=s)
    flat = s.ravel()
    counts = rng.poisson(flat.astype(np.float64) / shot_noise) if shot_noise > 0 else None
    out = np.empty(flat.shape, dtype)
    buf64, buf32 = np.empty(min(CHUNK, flat.size)), np.empty(min(CHUNK, flat.size), np.float32)
    for i in range(0, flat.size, CHUNK):
        n = min(CHUNK, flat.size - i)
        x = buf64[:n]
        if counts is None:
            x[...] = flat[i:i + n]
        else:
            np.multiply(counts[i:i + n], shot_noise, out=x)
        if read_noise > 0:
            x += rng.normal(0.0, read_noise, n)
        np.clip(x, 0.0, 1.0, out=x)
        y = buf32[:n]
        y[...] = x
        out[i:i + n] = y if convert is None else convert(y)
    return out.reshape(s.shape)


def sensor_signal(radiance: np.ndarray, exposure: float, white_balance, shot_noise: float = 0.0,
                  read_noise: float = 0.0, rng: np.random.Generator | None = None) -> np.ndarray:
    """Linear sensor signal with Poisson-Gaussian noise, clipped at full well.

    ``s = radiance * exposure * white_balance``; with ``shot_noise = a > 0`` the signal is
    ``a * Poisson(s / a)`` (``s / a`` electrons), then Gaussian read noise
    of standard deviation ``read_noise`` is added and the result clipped to [0, 1]. Before
    clipping the variance is ``a * s + read_noise**2`` (see :func:`noise_sigma`). Without noise
    (the defaults) this is the noiseless signal, ``s`` clipped to [0, 1].

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
    return expose(rad, exposure, wb, shot_noise, read_noise, rng)


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
