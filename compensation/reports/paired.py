"""Paired comparisons of two methods on the same test images: does method A score above method B?

Both methods' runs score the same test images of the same setups, so their per-image PSNRs pair up
(same setup, same image index). The differences A − B, grouped by setup, give:

- the mean difference over every paired image (pooled across setups);
- its percentile interval from a hierarchical bootstrap (:func:`hierarchical_bootstrap_interval`):
  setups are resampled, then the images within each drawn setup, so the interval holds both the
  spread between setups and the spread between images;
- the share of images where A scores higher;
- a two-sided p-value of a paired sign-flip permutation test on the per-setup mean differences
  (:func:`sign_flip_p_value`): under "A and B are exchangeable" each setup's mean difference is
  as likely negative as positive.

The interval shares the confidence, resample count and seed of the break points' intervals
(:mod:`~compensation.reports.summary`): the same results give the same numbers.
"""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from compensation.reports.summary import BOOTSTRAP_SAMPLES, BOOTSTRAP_SEED, CONFIDENCE, is_finite

EXACT_SETUPS = 16
"""Up to this many setups the sign-flip test enumerates every one of the 2^n sign patterns."""
FLIP_SAMPLES = 10000
"""Random sign patterns of the sign-flip test beyond :data:`EXACT_SETUPS` setups."""


def image_differences(a: Sequence[float], b: Sequence[float]) -> list[float]:
    """``a − b`` image by image (test image i of a dataset is the same frame in every run that scored
    it, so the first images both kept are paired), where both scores are finite.

    >>> image_differences([21.0, 20.0, float("nan")], [20.0, 20.5, 17.0, 18.0])
    [1.0, -0.5]
    """
    return [float(x) - float(y) for x, y in zip(a, b) if is_finite(x) and is_finite(y)]


def paired_differences(a: Mapping[str, Sequence[float]],
                       b: Mapping[str, Sequence[float]]) -> list[list[float]]:
    """The per-image differences ``a − b`` grouped by setup: for each setup both hold (in ``a``'s
    order), its :func:`image_differences`; setups left without any are dropped.

    >>> paired_differences({"s1": [21.0, 20.0, 19.0], "s2": [float("nan")], "s3": [18.0]},
    ...                    {"s1": [20.0, 20.5], "s2": [17.0]})
    [[1.0, -0.5]]
    """
    groups = (image_differences(scores, b.get(setup, ())) for setup, scores in a.items())
    return [diffs for diffs in groups if diffs]


def hierarchical_bootstrap_interval(groups: Sequence[Sequence[float]], confidence: float = CONFIDENCE,
                                    samples: int = BOOTSTRAP_SAMPLES,
                                    seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """Percentile interval of the pooled mean of ``groups`` (each a setup's per-image values) by
    a two-stage bootstrap: each of ``samples`` resamples draws as many groups as there are, with
    replacement, then within each drawn group as many values as it holds, with replacement; the
    interval is the central ``confidence`` share of the resamples' pooled means. The generator
    is seeded with ``seed``. NaN without values.

    >>> hierarchical_bootstrap_interval([[2.0, 2.0], [2.0]])
    (2.0, 2.0)
    >>> hierarchical_bootstrap_interval([[0.0], [1.0]])  # means 0, 0.5, 1 with chances 1/4, 1/2, 1/4
    (0.0, 1.0)
    >>> hierarchical_bootstrap_interval([])
    (nan, nan)
    """
    groups = [np.asarray(g, float) for g in groups if len(g)]
    if not groups:
        return float("nan"), float("nan")
    sizes = np.array([g.size for g in groups])
    padded = np.zeros((sizes.size, sizes.max()))
    for row, g in zip(padded, groups):
        row[:g.size] = g
    rng = np.random.default_rng(seed)
    drawn = rng.integers(0, sizes.size, (samples, sizes.size))
    total, count = np.zeros(samples), np.zeros(samples)
    columns = np.arange(sizes.max())
    for group in drawn.T:  # the j-th drawn setup of every resample
        n = sizes[group][:, None]
        images = (rng.random((samples, columns.size)) * n).astype(int)
        total += np.where(columns < n, padded[group[:, None], images], 0.0).sum(axis=1)
        count += n[:, 0]
    lo, hi = np.quantile(total / count, [(1 - confidence) / 2, (1 + confidence) / 2])
    return float(lo), float(hi)


def sign_flip_p_value(values: Sequence[float], exact_setups: int = EXACT_SETUPS,
                      samples: int = FLIP_SAMPLES, seed: int = BOOTSTRAP_SEED) -> float:
    """Two-sided p-value of the paired sign-flip permutation test of ``values`` (one mean
    difference per setup) against a zero mean: the share of sign patterns whose mean is at least
    as far from 0 as the observed mean. Every one of the 2^n patterns up to ``exact_setups``
    values; beyond, ``samples`` random patterns (a generator seeded with ``seed``), counted with
    the observed one: (1 + hits) / (1 + samples). 1 without values.

    >>> sign_flip_p_value([1.0, 2.0, 3.0])  # of the 8 patterns, +++ and --- are as far from 0
    0.25
    >>> sign_flip_p_value([0.0, 0.0])
    1.0
    """
    v = np.asarray(values, float)
    if v.size == 0:
        return 1.0
    observed = abs(v.mean())
    if v.size <= exact_setups:
        signs = 1 - 2 * ((np.arange(2 ** v.size)[:, None] >> np.arange(v.size)) & 1)
    else:
        signs = np.random.default_rng(seed).choice([-1, 1], (samples, v.size))
    hits = int((np.abs(signs @ v / v.size) >= observed * (1 - 1e-12)).sum())
    return hits / len(signs) if v.size <= exact_setups else (1 + hits) / (1 + samples)


def paired_comparison(groups: Sequence[Sequence[float]]) -> dict:
    """The paired comparison of per-setup groups of per-image differences A − B
    (:func:`paired_differences`): ``mean`` (pooled over images), ``lo`` and ``hi``
    (:func:`hierarchical_bootstrap_interval`), ``share`` (of images with A above B), ``setups``,
    ``images`` and ``p`` (:func:`sign_flip_p_value` of the per-setup means). At least one group.

    >>> c = paired_comparison([[1.0, 3.0], [2.0]])
    >>> c["mean"], c["share"], c["setups"], c["images"], c["p"]
    (2.0, 1.0, 2, 3, 0.5)
    """
    pooled = np.concatenate([np.asarray(g, float) for g in groups])
    lo, hi = hierarchical_bootstrap_interval(groups)
    return {"mean": float(pooled.mean()), "lo": lo, "hi": hi, "share": float((pooled > 0).mean()),
            "setups": len(groups), "images": int(pooled.size),
            "p": sign_flip_p_value([float(np.mean(g)) for g in groups])}
