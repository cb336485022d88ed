"""Paired comparisons of two methods (compensation.reports.paired) against independent references:
SciPy's permutation test, the exact bootstrap distribution of a tiny case enumerated by hand, and
known answers (a clear winner, identical methods)."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy import stats

from compensation.reports.paired import (hierarchical_bootstrap_interval, paired_comparison,
                                         paired_differences, sign_flip_p_value)
from compensation.reports.summary import bootstrap_interval


@pytest.mark.parametrize("n", [2, 5, 9, 12])
def test_sign_flip_p_value_is_scipys_exact_permutation_test(n):
    values = np.random.default_rng(n).normal(0.4, 1.0, n)
    scipy_p = stats.permutation_test((values,), np.mean, permutation_type="samples", n_resamples=np.inf,
                                     alternative="two-sided").pvalue
    assert sign_flip_p_value(values) == pytest.approx(scipy_p, abs=1e-12)
    assert sign_flip_p_value([5.0]) == 1.0  # one setup: + and − are equally far from 0 (SciPy needs two)


def test_random_sign_flips_approach_the_exact_p_value():
    """Beyond 16 setups: 10000 random patterns, seeded, within Monte Carlo error of all 2^18."""
    values = np.random.default_rng(3).normal(0.3, 1.0, 18)
    exact = sign_flip_p_value(values, exact_setups=18)
    sampled = sign_flip_p_value(values)
    assert 0.05 < exact < 0.95
    assert sampled == pytest.approx(exact, abs=4 * np.sqrt(exact * (1 - exact) / 10000))
    assert sign_flip_p_value(values) == sampled  # a fixed seed: reproducible


def _exact_bootstrap_quantiles(groups, confidence=0.95):
    """The percentiles of the pooled mean over every hierarchical resample, each with its probability:
    every ordered draw of the setups, then every ordered draw of the images within each."""
    outcomes: dict[float, float] = {}
    g = len(groups)
    for setups in itertools.product(range(g), repeat=g):
        choices = [list(itertools.product(groups[s], repeat=len(groups[s]))) for s in setups]
        weight = g ** -g * np.prod([1 / len(c) for c in choices])
        for draw in itertools.product(*choices):
            values = [v for part in draw for v in part]
            mean = round(sum(values) / len(values), 9)
            outcomes[mean] = outcomes.get(mean, 0.0) + weight
    atoms = np.array(sorted(outcomes))
    cdf = np.cumsum([outcomes[a] for a in atoms])
    quantiles = []
    for q in ((1 - confidence) / 2, (1 + confidence) / 2):
        i = int(np.searchsorted(cdf, q))
        assert min(abs(cdf[i] - q), abs(cdf[i - 1] - q) if i else 1.0) > 0.005  # no atom on the edge
        quantiles.append(float(atoms[i]))
    return tuple(quantiles)


def test_hierarchical_bootstrap_matches_the_enumerated_distribution():
    groups = [[0.0, 1.0], [3.0, 5.0, 9.0]]  # setups of unequal size: the mean pools the images
    exact = _exact_bootstrap_quantiles(groups)
    assert exact == (0.25, 7.0)
    assert hierarchical_bootstrap_interval(groups, samples=40000) == pytest.approx(exact)
    assert hierarchical_bootstrap_interval(groups) == hierarchical_bootstrap_interval(groups)  # seeded


def test_hierarchical_interval_holds_the_spread_between_setups():
    """Setups far apart with little spread within: resampling images alone (the flat bootstrap of
    every pair) misses the setups' spread, resampling setups first does not."""
    rng = np.random.default_rng(0)
    groups = [list(level + rng.normal(0, 0.1, 30)) for level in (0.0, 2.0, 4.0, 6.0)]
    lo, hi = hierarchical_bootstrap_interval(groups)
    flat_lo, flat_hi = bootstrap_interval([v for g in groups for v in g])
    assert lo < 3.0 < hi and hi - lo > 3 * (flat_hi - flat_lo)


def test_a_clearly_better_method():
    """A is 1 dB above B on every setup (±0.5 dB per image, ±0.3 dB per setup): 8 setups of 20 images."""
    rng = np.random.default_rng(1)
    b = {f"s{i}": list(rng.uniform(15, 25, 20)) for i in range(8)}
    a = {s: list(np.array(v) + 1.0 + rng.normal(0, 0.3) + rng.normal(0, 0.5, 20)) for s, v in b.items()}
    c = paired_comparison(paired_differences(a, b))
    assert 0 < c["lo"] < c["mean"] < c["hi"] and c["mean"] == pytest.approx(1.0, abs=0.3)
    assert c["p"] == 2 / 2 ** 8  # every setup's mean favours A: only +…+ and −…− are as extreme
    assert c["share"] > 0.9 and (c["setups"], c["images"]) == (8, 160)
    reverse = paired_comparison(paired_differences(b, a))
    assert reverse["mean"] == pytest.approx(-c["mean"]) and reverse["hi"] < 0 and reverse["p"] == c["p"]


def test_identical_methods():
    scores = {f"s{i}": list(np.random.default_rng(i).uniform(15, 25, 10)) for i in range(20)}
    c = paired_comparison(paired_differences(scores, scores))
    assert (c["mean"], c["lo"], c["hi"], c["share"], c["p"]) == (0.0, 0.0, 0.0, 0.0, 1.0)


def test_pairs_are_the_same_setup_and_image():
    nan = float("nan")
    a = {"s1": [20.0, 21.0, nan], "s2": [18.0], "only_a": [30.0]}
    b = {"s2": [17.0, 16.0], "s1": [19.0, 22.0, 25.0]}
    assert paired_differences(a, b) == [[1.0, -1.0], [1.0]]
    c = paired_comparison(paired_differences(a, b))
    assert (c["mean"], c["share"], c["setups"], c["images"]) == (pytest.approx(1 / 3), 2 / 3, 2, 3)
