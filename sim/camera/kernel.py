"""The sensor noise of a whole image as one compiled kernel: :func:`noisy_signal`, exact Poisson and
Gaussian draws by Dr.Jit's LLVM backend on all cores (noise version 3, :mod:`sim.camera.noise`).

Streams
    Value i of a capture draws its uniforms from its own PCG32 generator, whose state and
    increment are the four words of Philox4x32 at key ``key`` and counter i (``key``: one 64-bit
    draw from the capture's NumPy generator), so a capture is the same on any number of cores.
    Every uniform has 53 random bits, as NumPy's ``random()``: a 64-bit output (two PCG32 steps)
    cut to 53 bits. (Dr.Jit's ``next_float64`` has 32, which would stop the Gaussian tail at 6.7
    sigma; the 53 bits cost 3 % of the kernel's time.)
Poisson draws (mean ``m``)
    NumPy's algorithms, run per value in a vectorised loop: below :data:`REJECTION_MIN`,
    multiplication of uniforms until the product falls to ``exp(-m)``; from it on, transformed
    rejection with squeeze (the hat, squeeze, acceptance test and constants of NumPy's
    ``Generator.poisson``), with ``log k!`` by NumPy's Stirling series (k >= 6) and exact
    values below.
Gaussian draws
    Box-Muller's cosine branch, ``sqrt(-2 log(1 - u1)) cos(2 pi u2)``: one standard normal from two
    uniforms; with 53-bit uniforms the radius reaches 8.6 sigma.

All three are exact samplers (up to float64 rounding), so the law is NumPy's; the numbers are not.
The tests compare the law against the Poisson probabilities and the normal distribution.
"""
from __future__ import annotations

import math

import drjit as dr
import numpy as np
from drjit.llvm import Bool, Float32, Float64, PCG32, Philox4x32, UInt32, UInt64

REJECTION_MIN = 10.0
"""Means from which the Poisson draws use transformed rejection (NumPy's threshold)."""

_STIRLING = (8.333333333333333e-02, -2.777777777777778e-03, 7.936507936507937e-04,
             -5.952380952380952e-04, 8.417508417508418e-04, -1.917526917526918e-03,
             6.410256410256410e-03, -2.955065359477124e-02, 1.796443723688307e-01,
             -1.39243221690590e+00)
"""Coefficients of the Stirling series of log Gamma(x) in powers of 1 / x**2 (NumPy's)."""


def log_factorial(k: Float64) -> Float64:
    """``log k!`` of whole numbers k >= 0: exact table values below 6, the Stirling series of
    ``log Gamma(k + 1)`` (10 terms, float64 rounding) from 6 on.

    Examples
    --------
    >>> [round(float(v), 9) for v in log_factorial(Float64([0, 3, 6, 170]))]
    [0.0, 1.791759469, 6.579251212, 706.573062246]
    """
    x = dr.maximum(k + 1.0, 7.0)
    x2 = 1.0 / (x * x)
    series = Float64(_STIRLING[-1])
    for c in reversed(_STIRLING[:-1]):
        series = dr.fma(series, x2, c)
    out = series / x + 0.5 * math.log(2.0 * math.pi) + (x - 0.5) * dr.log(x) - x
    for j in range(6):
        out = dr.select(k == j, math.lgamma(j + 1.0), out)
    return out


def _streams(key: int, n: int) -> PCG32:
    """One PCG32 generator per value, seeded from Philox4x32 (see the module)."""
    w = Philox4x32(dr.opaque(UInt64, key), dr.arange(UInt32, n)).next_uint32x4()
    state = UInt64(w[0]) | (UInt64(w[1]) << 32)
    sequence = UInt64(w[2]) | (UInt64(w[3]) << 32)
    rng = PCG32(n)
    rng.seed(state, sequence)
    return rng


def _uniform(rng: PCG32) -> Float64:
    """A uniform float64 on [0, 1) with 53 random bits (two PCG32 steps)."""
    return Float64(rng.next_uint64() >> 11) * 2.0 ** -53


def _poisson(rng: PCG32, mean: Float64) -> Float64:
    """Exact Poisson draws of ``mean`` (>= 0), advancing ``rng`` (see the module)."""
    slam = dr.sqrt(mean)
    loglam = dr.log(mean)
    b = 0.931 + 2.53 * slam
    a = -0.059 + 0.02483 * b
    log_invalpha = dr.log(1.1239 + 1.1328 / (b - 3.4))
    vr = 0.9277 - 3.6224 / (b - 2.0)
    large = mean >= REJECTION_MIN

    def attempt(rng, k, done):
        u = _uniform(rng) - 0.5
        v = _uniform(rng)
        us = 0.5 - dr.abs(u)
        kk = dr.floor((2.0 * a / us + b) * u + mean + 0.43)
        squeeze = (us >= 0.07) & (v <= vr)
        tested = ~squeeze & (kk >= 0) & ((us >= 0.013) | (v <= us))

        def test(v, us, kk):
            return (dr.log(v) + log_invalpha - dr.log(a / (us * us) + b)
                    <= -mean + kk * loglam - log_factorial(dr.maximum(kk, 0.0)))

        # a branch: packets of values that the squeeze decided skip the logarithms and the series
        passed = dr.if_stmt((v, us, kk), tested, test, lambda v, us, kk: dr.zeros(Bool, dr.width(v)))
        accept = squeeze | (tested & passed)
        return rng, dr.select(accept, kk, k), accept

    rng, k, _ = dr.while_loop((rng, dr.zeros(Float64, dr.width(mean)), ~large),
                              lambda rng, k, done: ~done, attempt)
    limit = dr.exp(-mean)

    def multiply(rng, prod, x, done):
        prod = prod * _uniform(rng)
        more = prod > limit
        return rng, prod, dr.select(more, x + 1.0, x), ~more

    rng, _, x, _ = dr.while_loop(
        (rng, dr.full(Float64, 1.0, dr.width(mean)), dr.zeros(Float64, dr.width(mean)),
         large | (mean == 0.0)),
        lambda rng, prod, x, done: ~done, multiply)
    return dr.select(large, k, x)


def noisy_signal(signal: np.ndarray, shot_noise: float, read_noise: float, key: int) -> np.ndarray:
    """``shot_noise * Poisson(signal / shot_noise) + read_noise * N(0, 1)`` per value (a term
    left out when its level is 0), clipped to [0, 1]: the noisy linear signal.

    Parameters
    ----------
    signal : numpy.ndarray
        float32 exposed signal, >= 0, any shape.
    shot_noise, read_noise : float
        The Poisson gain and the Gaussian standard deviation, in signal units (>= 0).
    key : int
        The capture's stream key, 0 <= key < 2**64 (see the module).

    Returns
    -------
    numpy.ndarray
        float32, the shape of ``signal``.

    Examples
    --------
    >>> x = noisy_signal(np.full(200_000, 0.5, np.float32), 1e-3, 0.0, key=1)
    >>> bool(abs(x.mean() - 0.5) < 2e-4), bool(abs(x.var() / 5e-4 - 1) < 0.02)
    (True, True)
    """
    s = np.ascontiguousarray(signal, np.float32)
    if s.size == 0:
        return s.copy()
    # the key and the noise levels enter as opaque values, not literals: one compiled kernel
    # serves every capture (a literal would compile, and cache on disk, a kernel per capture)
    x = Float64(Float32(s.ravel()))
    rng = _streams(key, s.size)
    if shot_noise > 0:
        gain = dr.opaque(Float64, shot_noise)
        x = _poisson(rng, x / gain) * gain
    if read_noise > 0:
        u1 = 1.0 - _uniform(rng)
        u2 = _uniform(rng)
        x += dr.opaque(Float64, read_noise) * dr.sqrt(-2.0 * dr.log(u1)) * dr.cos(2.0 * math.pi * u2)
    return Float32(dr.clip(x, 0.0, 1.0)).numpy().reshape(s.shape)
