"""Tests of noise version 3 (:mod:`sim.camera.kernel`): its Poisson and Gaussian draws follow the
exact laws (chi-square against the Poisson probabilities, Kolmogorov-Smirnov against the normal
distribution, with a check that the same test refuses a slightly wrong law), its log-factorial, and
its streams (independent values, the same on any number of cores, one key per capture)."""
from __future__ import annotations

import math

import drjit as dr
import numpy as np
import pytest
from scipy import stats

from sim.camera import kernel
from sim.variant import llvm_usable

pytestmark = pytest.mark.skipif(not llvm_usable(), reason="Dr.Jit's LLVM backend is not usable here")

GAIN = 1e-4
"""Signal units per electron in the Poisson tests: means up to 10**4 stay below full well (1)."""


def poisson_counts(mean: float, n: int, key: int) -> tuple[np.ndarray, float]:
    """n Poisson draws of about ``mean`` through :func:`kernel.noisy_signal` (shot noise only), as
    whole counts, and the exact mean the float32 signal gives."""
    signal = np.full(n, mean * GAIN, np.float32)
    counts = np.rint(kernel.noisy_signal(signal, GAIN, 0.0, key).astype(np.float64) / GAIN)
    return counts, float(signal[0]) / GAIN


def chi_square_p(counts: np.ndarray, mean: float) -> float:
    """p-value of the chi-square test of ``counts`` against Poisson(mean), the tail bins pooled so
    that every bin expects at least 20 draws."""
    hi = int(stats.poisson.ppf(1 - 1e-6, mean)) + 1
    edges = np.arange(-0.5, hi + 1.5)
    observed = np.histogram(np.minimum(counts, hi + 1), edges)[0]
    expected = np.diff(stats.poisson.cdf(edges, mean)) * counts.size
    expected[-1] += stats.poisson.sf(hi + 1, mean) * counts.size
    keep = expected >= 20
    o = np.append(observed[keep], observed[~keep].sum())
    e = np.append(expected[keep], expected[~keep].sum())
    if e[-1] < 20:  # fold a small pooled bin into its neighbour
        o, e = np.append(o[:-2], o[-2:].sum()), np.append(e[:-2], e[-2:].sum())
    return float(stats.chi2.sf(((o - e) ** 2 / e).sum(), o.size - 1))


@pytest.mark.parametrize("mean", [0.4, 3.7, 9.99, 10.0, 16.3, 137.0, 2500.5, 9000.0])
def test_poisson_draws_follow_the_poisson_law(mean):
    """Both samplers (multiplication below 10, transformed rejection from 10 on) and the switch:
    the histogram of 200 000 draws against the Poisson probabilities, and the first two moments."""
    counts, exact = poisson_counts(mean, 200_000, key=int(mean * 1000) + 1)
    assert chi_square_p(counts, exact) > 1e-3
    se = math.sqrt(exact / counts.size)
    assert abs(counts.mean() - exact) < 5 * se
    assert counts.var() / exact == pytest.approx(1.0, abs=5 * math.sqrt(2 / counts.size) + 0.01 / exact)


def test_the_chi_square_check_refuses_a_slightly_wrong_law():
    """The test above has teeth: draws of mean 1 % off, or rounded normal draws of the right
    mean and variance, are refused at the same sample size."""
    counts, exact = poisson_counts(137.0, 200_000, key=5)
    assert chi_square_p(counts, exact * 1.01) < 1e-6
    rounded = np.rint(np.random.default_rng(0).normal(16.3, math.sqrt(16.3), 200_000))
    assert chi_square_p(np.maximum(rounded, 0), 16.3) < 1e-6


def test_read_noise_is_standard_normal_in_its_tails():
    """Read noise alone: Kolmogorov-Smirnov against the normal distribution, and the tail mass
    beyond 3 sigma (0.27 %) to within its sampling error."""
    z = (kernel.noisy_signal(np.full(400_000, 0.5, np.float32), 0.0, 0.01, key=3).astype(np.float64)
         - 0.5) / 0.01
    assert stats.kstest(z, "norm").pvalue > 1e-3
    tail = np.mean(np.abs(z) > 3)
    assert tail == pytest.approx(2 * stats.norm.sf(3), abs=5 * math.sqrt(0.0027 / z.size))
    assert abs(z.mean()) < 5 / math.sqrt(z.size) and z.std() == pytest.approx(1.0, abs=0.005)


def test_uniforms_have_53_random_bits():
    """Not Dr.Jit's 32-bit ``next_float64``: its grid would stop the Gaussian tail at 6.7 sigma."""
    u = np.asarray(kernel._uniform(dr.llvm.PCG32(100_000)))
    assert 0 <= u.min() and u.max() < 1
    assert np.mean(u * 2.0**32 == np.floor(u * 2.0**32)) < 0.01
    assert np.all(u * 2.0**53 == np.floor(u * 2.0**53))


def test_log_factorial_matches_lgamma():
    k = np.concatenate([np.arange(0, 200), [1e3, 12345, 1e6, 1e9]])
    got = np.asarray(kernel.log_factorial(dr.llvm.Float64(k)))
    np.testing.assert_allclose(got, [math.lgamma(x + 1) for x in k], rtol=1e-14, atol=1e-14)


def test_streams_are_independent_reproducible_and_the_same_on_any_number_of_cores():
    signal = np.full(300_000, 0.3, np.float32)
    a = kernel.noisy_signal(signal, 1e-3, 1e-2, key=2**64 - 1).astype(np.float64) - 0.3
    before = dr.thread_count()
    try:
        dr.set_thread_count(1)
        one = kernel.noisy_signal(signal, 1e-3, 1e-2, key=2**64 - 1)
    finally:
        dr.set_thread_count(before)
    np.testing.assert_array_equal(one.astype(np.float64) - 0.3, a)
    b = kernel.noisy_signal(signal, 1e-3, 1e-2, key=2**64 - 2).astype(np.float64) - 0.3
    assert a.var() == pytest.approx(0.3e-3 + 1e-4, rel=0.02)
    bound = 5 / math.sqrt(a.size)
    for lag in (1, 2, 3, 960):  # neighbouring values, and the next row of a 960-wide image
        assert abs(np.corrcoef(a[:-lag], a[lag:])[0, 1]) < bound
    assert abs(np.corrcoef(a, b)[0, 1]) < bound  # another key: another capture
    assert kernel.noisy_signal(signal[:0], 1e-3, 1e-2, key=1).shape == (0,)
