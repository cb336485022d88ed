"""Poisson-Gaussian sensor noise: the noisy linear signal and its standard deviation.

:func:`expose` draws the noise in one of two versions of the streams (:func:`stream_version`,
which gives the camera's :func:`~sim.camera.chain.noise_version` recorded in a dataset's
``render.json`` and ``meta.json``); both are exact Poisson and Gaussian draws, only the numbers
differ:

* **3** (where Dr.Jit's LLVM backend runs, i.e. wherever procam renders on the CPU): the whole
  image in one compiled kernel on all cores (:mod:`sim.camera.kernel`), value i from its own
  generator keyed by one 64-bit draw from the capture's generator;
* **2** (the fallback without a usable LLVM): block by block of :data:`BLOCK` values in C order,
  block k from the k-th child of the capture's generator (``Generator.spawn``), NumPy's Poisson
  draws then float32 standard normals scaled by the read noise, the blocks on the camera's threads.

Either way a capture is the same bit for bit on any number of cores. The module declares the
exposure and noise stages (:data:`EXPOSURE`, :data:`NOISE`), applied by the sensor
(:mod:`sim.camera.sensor`).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import numpy as np

from sim.camera.threads import BLOCK, blockwise, run
from sim.options import NON_NEGATIVE, POSITIVE, choice, number
from sim.stages import Stage


def stream_version() -> int:
    """Version of the noise streams :func:`expose` draws in this process: 3 where Dr.Jit's LLVM
    backend runs, else 2 (see the module; :func:`sim.variant.llvm_usable` memoises the answer).
    Version 1 (no longer drawn): ``Generator.poisson`` then ``Generator.normal`` over the whole
    image from the capture's generator."""
    from sim.variant import llvm_usable

    return 3 if llvm_usable() else 2


def expose(values: np.ndarray, exposure: float, gains, shot_noise: float, read_noise: float,
           rng: np.random.Generator | None, convert=None, dtype=np.float32) -> np.ndarray:
    """Exposed, noisy and full-well-clipped linear signal.

    ``s = values * exposure * gains`` (gains repeat along the last axis), clipped below at 0;
    ``shot_noise * Poisson(s / shot_noise)`` when ``shot_noise > 0``; plus a normal draw of
    standard deviation ``read_noise`` per value when ``read_noise > 0``; clipped to [0, 1] and cast
    to float32; then ``convert`` (e.g. the 8-bit encoder), block by block. The variance
    before the clip is ``shot_noise * s + read_noise**2``. The streams are those of
    :func:`stream_version` (see the module).

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
        float32 block -> block of ``dtype``, elementwise; called from several threads at once
        (version 2).
    dtype : numpy dtype
        Of the result.

    Returns
    -------
    numpy.ndarray
        The shape of ``values``.
    """
    noisy = shot_noise > 0 or read_noise > 0
    if rng is None and noisy:
        raise ValueError("camera: a random generator is needed for shot or read noise")
    s = np.asarray(values, np.float32) * np.float32(exposure)
    if gains is not None:
        s *= np.asarray(gains, np.float32)
    np.maximum(s, 0.0, out=s)
    if noisy and stream_version() == 3:
        from sim.camera.kernel import noisy_signal

        x = noisy_signal(s, shot_noise, read_noise, int(rng.integers(2**64, dtype=np.uint64)))
        return x if convert is None else blockwise(convert, x, dtype)
    flat = s.ravel()
    out = np.empty(flat.shape, dtype)
    starts = range(0, flat.size, BLOCK)
    rngs = rng.spawn(len(starts)) if noisy else [None] * len(starts)

    def finish(i: int, g: np.random.Generator | None) -> None:
        block = flat[i:i + BLOCK]
        if shot_noise > 0:
            x = g.poisson(block.astype(np.float64) / shot_noise) * shot_noise
        else:
            x = block.astype(np.float64)
        if read_noise > 0:
            x += read_noise * g.standard_normal(block.size, np.float32)
        np.clip(x, 0.0, 1.0, out=x)
        y = x.astype(np.float32)
        out[i:i + block.size] = y if convert is None else convert(y)

    run([partial(finish, i, g) for i, g in zip(starts, rngs)])
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


@dataclass(frozen=True)
class ExposureOptions:
    """The keys of the camera's exposure."""

    exposure: float = number(1.0, POSITIVE)
    """Multiplier (> 0) from linear scene radiance to sensor signal; signal 1 is the full well."""
    exposure_mode: str = choice("manual", ("manual", "rule"))
    """``"manual"``: ``exposure`` is used as given; ``"rule"``: set from captures of plain white
    and plain black as the official README tells (plain white slightly over-exposed:
    :data:`sim.camera.WHITE_CLIPPED_FRACTION` of the pixels at code 255), recorded in the
    dataset's ``meta.json``."""


@dataclass(frozen=True)
class NoiseOptions:
    """The keys of the sensor noise."""

    shot_noise: float = number(2e-4, NON_NEGATIVE)
    """Poisson gain a (>= 0): a signal s in [0, 1] has variance a * s (s / a electrons)."""
    read_noise: float = number(2e-3, NON_NEGATIVE, "(linear signal units)")
    """Gaussian read-noise sigma (>= 0), in linear signal units."""


EXPOSURE = Stage("exposure", ExposureOptions, 'radiance to sensor signal (exposure_mode = "rule": '
                 "the exposure set by sim.camera.rule_exposure)", linear=True)
"""The camera's exposure stage."""
NOISE = Stage("noise", NoiseOptions, "Poisson-Gaussian noise (on the mosaic's sites with a Bayer "
              "sensor), then the full-well clip to [0, 1] (expose)", random=True,
              streams=stream_version, off={"shot_noise": 0.0, "read_noise": 0.0})
"""The camera's noise stage."""
