"""Target policies: the global map is the exact optimum and the image map brackets it, against brute
force on small random setups."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from compensation.experiments.targets import (TargetMap, TargetPolicy, global_map, image_map,
                                              map_record, target_maps)
from sim.errors import ProcamError


def _setup(rng, n: int):
    """A small random surface: black captures in [0, 0.3], white ones 0.2 … 0.9 above them (≤ 1)."""
    black = rng.uniform(0, 0.3, (3, 1, n))
    white = np.minimum(black + rng.uniform(0.2, 0.9, (3, 1, n)), 1.0)
    return black, white


def _in_reach(y, black, white, a, b, eps=1e-9):
    """Pixels (flattened) where every channel of a·y + b lies in [black, white]."""
    t = a * y + b
    return ((t >= black - eps) & (t <= white + eps)).all(axis=0).ravel()


def _brute_global(black, white, allowed, with_b=False):
    """Largest a over every pair (b, t) of candidate values (pixel bounds) with ≤ allowed pixels
    where b < max L or t > min U (with ``with_b``, also the largest b of the pairs that reach it)."""
    lo, hi = black.max(0).ravel(), white.min(0).ravel()
    best, best_b = -np.inf, -np.inf
    for b, t in itertools.product(lo, hi):
        if ((lo > b) | (hi < t)).sum() <= allowed:
            if t - b > best or (t - b == best and b > best_b):
                best, best_b = t - b, b
    return (best, best_b) if with_b else best


@pytest.mark.parametrize("seed", range(30))
def test_global_map_is_the_brute_force_optimum(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(3, 12))
    black, white = _setup(rng, n)
    if seed % 2:  # 8-bit-like captures: equal bounds at many pixels
        black, white = np.round(black * 8) / 8, np.round(white * 8) / 8
    fraction = float(rng.choice([0.0, 0.1, 0.25, 0.4]))
    allowed = int(np.floor(fraction * n + 1e-9))
    m = global_map(black, white, fraction)
    # where the share admits no positive contrast, the smallest count that does is taken
    used = round(m.out_of_reach * n)
    assert used == allowed or (used > allowed and _brute_global(black, white, used - 1) <= 0)
    allowed = used
    brute, brute_b = _brute_global(black, white, allowed, with_b=True)
    assert m.a == pytest.approx(min(brute, 1.0), abs=1e-12)
    assert m.b == brute_b  # of equal contrasts, the map leaving out the fewest pixels by its b
    # the map is feasible: every y in [0, 1] maps into reach at all but the allowed pixels
    out = ~(_in_reach(np.zeros((3, 1, n)), black, white, m.a, m.b)
            & _in_reach(np.ones((3, 1, n)), black, white, m.a, m.b))
    assert out.sum() <= allowed


def test_of_equal_contrasts_the_global_map_takes_the_largest_b():
    # one pixel may be left out: leaving out the second by b (b = 0, a + b = 0.5) or the first by
    # a + b (b = 0.1, a + b = 0.6) both give a = 0.5; the larger b leaves out no pixel by its b
    black = np.array([0.0, 0.1]).reshape(1, 1, 2).repeat(3, 0)
    white = np.array([0.5, 0.6]).reshape(1, 1, 2).repeat(3, 0)
    m = global_map(black, white, 0.5)
    assert (round(m.a, 12), m.b) == (0.5, 0.1)


def _brute_image(y, black, white, allowed):
    """Largest a in [0, 1] with a b keeping all but ``allowed`` pixels in reach: the optimum is a
    crossing of two constraint lines b = bound − a·y (or a = 1), and at a given a a best b is one
    of the lines' values."""
    lines = [(float(v), float(s)) for bound in (black, white) for v, s in zip(bound.ravel(), y.ravel())]
    candidates = {0.0, 1.0}
    for (v1, s1), (v2, s2) in itertools.combinations(lines, 2):
        if s1 != s2:
            a = (v1 - v2) / (s1 - s2)
            if 0 <= a <= 1:
                candidates.add(a)
    need = y.shape[-1] - allowed
    best = None
    for a in sorted(candidates, reverse=True):
        if any(_in_reach(y, black, white, a, v - a * s).sum() >= need for v, s in lines):
            best = a
            break
    return best


@pytest.mark.parametrize("seed", range(30))
def test_image_map_brackets_the_brute_force_optimum(seed):
    rng = np.random.default_rng(100 + seed)
    n = int(rng.integers(3, 8))
    black, white = _setup(rng, n)
    y = rng.uniform(0, 1, (3, 1, n))
    fraction = float(rng.choice([0.0, 0.2, 0.34]))
    allowed = int(np.floor(fraction * n + 1e-9))
    m = image_map(y, black, white, fraction, tol=1e-6)
    used = round(m.out_of_reach * n)
    if used > allowed:  # no positive contrast at the policy's share, nor with one pixel fewer
        assert (_brute_image(y, black, white, used - 1) or 0.0) < 1e-6
    allowed = used
    brute = _brute_image(y, black, white, allowed)
    assert _in_reach(y, black, white, m.a, m.b, eps=1e-9).sum() >= n - allowed
    assert m.a - 1e-12 <= brute <= m.a + m.gap + 1e-9
    assert m.gap <= 10e-6  # a few leaves: the first leaves' lower ends may be out of reach


def test_image_map_beats_the_global_map_on_a_dim_image():
    """An image using a quarter of the range gets more contrast than the map for every image."""
    rng = np.random.default_rng(7)
    black = rng.uniform(0, 0.2, (1, 1, 64)) + rng.uniform(0, 0.02, (3, 1, 64))
    white = black + rng.uniform(0.4, 0.7, (1, 1, 64))
    y = rng.uniform(0, 0.25, (3, 1, 64))
    g, i = global_map(black, white, 0.05), image_map(y, black, white, 0.05)
    assert i.a > 1.5 * g.a


def test_an_unreachable_setup_is_refused_and_a_textured_one_relaxed():
    black, white = np.full((3, 1, 4), 0.6), np.full((3, 1, 4), 0.5)
    with pytest.raises(ProcamError, match="positive contrast"):
        global_map(black, white)
    with pytest.raises(ProcamError, match="positive contrast"):
        image_map(np.full((3, 1, 4), 0.5), black, white)
    # a bright half whose black is above the dark half's white: no grey reaches both halves
    black = np.array([0.3] * 50 + [0.02] * 50).reshape(1, 1, 100).repeat(3, 0)
    white = black + 0.2
    m = global_map(black, white, 0.01)
    assert m.out_of_reach == 0.5 and m.a == pytest.approx(0.2)


def test_policies_and_records():
    black, white = np.zeros((3, 2, 2)), np.ones((3, 2, 2))
    y = np.random.default_rng(0).uniform(0, 1, (2, 3, 2, 2))
    # a perfect projector: every policy is the identity
    for name in ("none", "global", "image"):
        maps = target_maps(TargetPolicy(name), y, black, white)
        assert all((m.a, m.b) == (1.0, 0.0) for m in maps)
    record = map_record(TargetPolicy("image", 0.02), [TargetMap(0.5, 0.1), TargetMap(0.7, 0.3)])
    assert record["a"] == pytest.approx(0.6) and record["a_per_image"] == [0.5, 0.7]
    with pytest.raises(ProcamError, match="target policy"):
        TargetPolicy("clip")
    with pytest.raises(ProcamError, match="fraction"):
        TargetPolicy("global", 1.0)
