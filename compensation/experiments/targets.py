"""Target policies: what the closed loop asks a setup to show instead of a desired image it cannot.

A projector adds light to what the surface already reflects, so at each pixel and channel the
camera can only see values between the capture of a black frame ``L`` and of a white frame ``U``
(the plain frames 0001 and 0125 of the dataset's ``ref`` captures). Real systems map the desired
image into that range before compensating it (global or content-dependent target scaling); a
*target policy* chooses the map, and the closed loop then scores the capture against the mapped
target y' instead of y:

``none``
    y' = y, the desired image as is.
``global``
    one map y' = a·y + b per setup, the same for every image: at a pixel every value of y in
    [0, 1] must map into reach, so the map must satisfy ``b ≥ L`` and ``a + b ≤ U`` there.
``image``
    the same map chosen per desired image: a pixel is in reach when its own values map into
    reach, ``L ≤ a·y + b ≤ U`` in every channel.

Choice of map: luminance-preserving, one (a, b) for the three channels, so that the target keeps
the desired image's hue and only its contrast and brightness change (a per-channel map would tint
the target by the surface's colour). A pixel is *in reach* when all three channels are; the tight
bounds ``L`` and ``U`` are used (no allowance for camera noise), so the reachable mask of
:mod:`~compensation.experiments.closed_loop`, which allows two 8-bit levels, counts at least as
many pixels in reach.

The maximisation: the contrast ``a`` is maximised subject to at most ``out_of_reach`` of the
pixels out of reach (``a`` is capped at 1: a target never has more contrast than the desired
image). Where no map of positive contrast leaves so few pixels out (a textured surface under room
light: the black capture of its bright parts above the white capture of its dark parts), the share
is raised to the smallest that admits one, found by bisection (more allowed pixels never make a map
infeasible), and recorded as ``out_of_reach_used``.

- ``global`` is solved exactly (:func:`global_map`). With ``Lp`` the largest black and ``Up`` the
  smallest white channel of pixel p, a pixel is in reach when ``b ≥ Lp`` and ``a + b ≤ Up``. If
  the optimum leaves out ``k`` pixels by its ``b``, its ``b`` is the (k + 1)-th largest ``Lp``
  (any larger b only shrinks a), and its ``a + b`` is then the (m − k + 1)-th smallest ``Up`` of
  the pixels that ``b`` keeps (m: the allowed count). Trying every ``k`` from 0 to m is exact; equal
  ``Lp`` give one candidate, and that ``Up`` is among the m + 1 smallest of all pixels, so a
  256² view of 8-bit captures is solved in a fraction of a second.
- ``image`` is solved to a certified tolerance (:func:`image_map`). For a fixed ``a`` each pixel
  allows an interval of ``b``, ``[max_c (L − a·y), min_c (U − a·y)]``, and the best ``b`` is the
  point covered by most intervals (exact, by sorting the endpoints). The feasible values of ``a``
  need not form one interval, so ``a`` is searched by branch and bound: both endpoints decrease
  with ``a`` (y ≥ 0), so over ``[a0, a1]`` a pixel's interval lies inside ``[lo(a1), hi(a0)]``,
  and the most-covered point of these wider intervals bounds the count from above. Intervals are
  split from the top down to a width of ``tol``; the first leaf whose exact count suffices gives
  ``a``, every interval above it having been proved infeasible. The returned map is feasible and
  the optimum lies in ``[a, a + gap]`` (``gap`` recorded: ``tol`` when the first leaf's lower end
  is feasible, a few ``tol`` otherwise).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.errors import ProcamError

POLICIES = ("none", "global", "image")
"""Target policies (see the module docstring)."""
DEFAULT_OUT_OF_REACH = 0.01
"""Share of pixels a ``global`` or ``image`` map may leave out of reach by default."""
IMAGE_TOLERANCE = 1e-4
"""Width of the search's last intervals of ``a`` for the ``image`` policy."""


@dataclass(frozen=True)
class TargetPolicy:
    """How the closed loop maps a desired image y to the target y' it scores against."""

    name: str = "global"
    """``none``, ``global`` or ``image`` (:data:`POLICIES`)."""
    out_of_reach: float = DEFAULT_OUT_OF_REACH
    """Largest share of pixels a map may leave out of reach, in [0, 1) (unused by ``none``)."""

    def __post_init__(self):
        if self.name not in POLICIES:
            raise ProcamError(f"target policy {self.name!r}: expected one of {', '.join(POLICIES)}")
        if not (isinstance(self.out_of_reach, (int, float)) and 0 <= self.out_of_reach < 1):
            raise ProcamError(f"out of reach {self.out_of_reach!r}: expected a fraction in [0, 1)")

    def record(self) -> dict:
        """The policy as recorded beside scores (``policy``, ``out_of_reach``).

        >>> TargetPolicy("image", 0.05).record()
        {'policy': 'image', 'out_of_reach': 0.05}
        """
        return {"policy": self.name, "out_of_reach": float(self.out_of_reach)}


@dataclass(frozen=True)
class TargetMap:
    """A map y' = clip(a·y + b, 0, 1), the same for the three channels."""

    a: float
    """Contrast, in (0, 1]."""
    b: float
    """Offset (encoded camera units)."""
    gap: float = 0.0
    """How far below the largest feasible contrast ``a`` may lie (0: exact)."""
    out_of_reach: float = 0.0
    """Share of pixels the map was allowed to leave out of reach: the policy's, or the smallest
    share admitting a positive contrast where the policy's admits none."""

    def apply(self, y: np.ndarray) -> np.ndarray:
        """The target of ``y`` (any shape, values in [0, 1]).

        >>> TargetMap(0.5, 0.25).apply(np.array([0.0, 1.0])).tolist()
        [0.25, 0.75]
        """
        return np.clip(self.a * y + self.b, 0.0, 1.0)


IDENTITY = TargetMap(1.0, 0.0)
"""The map of the ``none`` policy."""


def _allowed(n: int, out_of_reach: float) -> int:
    """Pixels a map may leave out of reach among ``n``.

    >>> _allowed(4096, 0.01), _allowed(100, 0.0)
    (40, 0)
    """
    return int(math.floor(out_of_reach * n + 1e-9))


def _relaxed(solve, n: int, out_of_reach: float, what: str) -> TargetMap:
    """``solve(allowed)`` (a map leaving at most ``allowed`` of ``n`` pixels out of reach, or None)
    at the policy's share, else at the smallest count that admits a map (feasibility only grows
    with the count: bisection), with that share recorded in the map.

    Raises
    ------
    ProcamError
        If no map of positive contrast exists even leaving all but one pixel out.
    """
    allowed = _allowed(n, out_of_reach)
    found = solve(allowed)
    if found is not None:
        return TargetMap(found.a, found.b, found.gap, allowed / n)
    top = solve(n - 1)
    if top is None:
        raise ProcamError(f"no map y' = a·y + b of positive contrast keeps any pixel of {what} within "
                          "reach; use the target policy none")
    low, high = allowed, n - 1
    while high - low > 1:
        mid = (low + high) // 2
        found = solve(mid)
        low, high, top = (low, mid, found) if found is not None else (mid, high, top)
    return TargetMap(top.a, top.b, top.gap, high / n)


def global_map(black: np.ndarray, white: np.ndarray, out_of_reach: float = DEFAULT_OUT_OF_REACH) -> TargetMap:
    """The ``global`` map of a setup: the largest ``a`` such that at most ``out_of_reach`` of the
    pixels have ``b < Lp`` or ``a + b > Up`` (exact; see the module docstring).

    Parameters
    ----------
    black, white : numpy.ndarray
        Captures of the black and white frames, (3, H, W) in [0, 1].
    out_of_reach : float
        Largest share of pixels left out of reach; where no map of positive contrast leaves so few,
        the smallest share that admits one (recorded in the map).

    Returns
    -------
    TargetMap
        ``gap`` 0. Among maps of equal contrast, the one leaving out the fewest pixels by ``b``.

    Raises
    ------
    ProcamError
        If no map of positive contrast keeps any pixel in reach.

    >>> black = np.array([0.0, 0.1, 0.5]).reshape(1, 1, 3).repeat(3, 0)
    >>> white = np.array([1.0, 0.9, 0.6]).reshape(1, 1, 3).repeat(3, 0)
    >>> m = global_map(black, white, 0.34)   # one of three pixels may be left out: the third
    >>> round(m.a, 6), round(m.b, 6), round(m.out_of_reach, 3)
    (0.8, 0.1, 0.333)
    >>> m = global_map(black, white, 0.0)    # all three: 0.5 ≤ b, a + b ≤ 0.6
    >>> round(m.a, 6), round(m.b, 6), round(m.out_of_reach, 3)
    (0.1, 0.5, 0.0)
    >>> white[:, 0, 2] = 0.45                # the third pixel's white is below its black
    >>> m = global_map(black, white, 0.0)    # no map keeps all: one pixel is left out
    >>> round(m.a, 6), round(m.b, 6), round(m.out_of_reach, 3)
    (0.8, 0.1, 0.333)
    """
    lo = np.asarray(black, np.float64).max(axis=0).ravel()
    hi = np.asarray(white, np.float64).min(axis=0).ravel()
    n = lo.size
    order = np.argsort(-lo, kind="stable")
    desc = lo[order]
    rank = np.empty(n, np.intp)
    rank[order] = np.arange(n)  # a pixel's place in the descending order of Lp
    by_hi = np.argsort(hi, kind="stable")

    def solve(allowed: int) -> TargetMap | None:
        # the candidates b: the allowed + 1 largest Lp, largest first, once per distinct value (the
        # same b leaves out the same pixels); ``above``: how many pixels each leaves out by its b
        values = np.unique(desc[:min(allowed, n - 1) + 1])[::-1]
        above = np.searchsorted(-desc, -values, side="left")
        # the (spare + 1)-th smallest Up of the pixels a b keeps is among the allowed + 1 smallest
        # Up overall, as b leaves out at most ``allowed - spare`` pixels
        cand = by_hi[:min(allowed + 1, n)]
        cand_rank, cand_hi = rank[cand], hi[cand]
        best = None
        for b, j in zip(values, above):
            spare = allowed - j
            if spare < 0 or spare >= n - j:
                continue
            top = cand_hi[cand_rank >= j][spare]
            if best is None or top - b > best[0] - best[1]:
                best = (top, b)
        if best is None or best[0] - best[1] <= 0:
            return None
        return TargetMap(float(min(best[0] - best[1], 1.0)), float(best[1]))

    return _relaxed(solve, lo.size, out_of_reach, "this setup")


def max_coverage(lo: np.ndarray, hi: np.ndarray) -> int:
    """The largest number of closed intervals ``[lo, hi]`` sharing a point (empty ones ignored).

    >>> max_coverage(np.array([0.0, 0.5, 1.0, 2.0]), np.array([1.0, 1.5, 1.2, 3.0]))
    3
    """
    count = _coverage(lo, hi)[0]
    return int(count.max()) if count.size else 0


def _coverage(lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Coverage of closed intervals on the segments between consecutive endpoints: for each point
    where the count changes, the count just after opening there and the segment it holds on."""
    ok = lo <= hi
    lo, hi = lo[ok], hi[ok]
    points = np.concatenate([lo, hi])
    # at equal values an interval opens before another closes (closed intervals touch)
    kind = np.concatenate([np.zeros(lo.size), np.ones(hi.size)])
    order = np.lexsort((kind, points))
    steps = np.where(kind[order] == 0, 1, -1)
    count = np.cumsum(steps)
    at = points[order]
    opening = steps == 1
    # the segment after an opening event runs to the next event's value
    nxt = np.append(at[1:], at[-1:]) if at.size else at
    return count[opening], at[opening], nxt[opening]


def _bounds(y: np.ndarray, black: np.ndarray, white: np.ndarray, a: float) -> tuple[np.ndarray, np.ndarray]:
    """Each pixel's interval of ``b`` at contrast ``a``: ``[max_c (L − a·y), min_c (U − a·y)]``."""
    return (black - a * y).max(axis=0), (white - a * y).min(axis=0)


def _feasible_b(y, black, white, a: float, need: int) -> float | None:
    """The ``b`` nearest 0 that keeps at least ``need`` pixels in reach at contrast ``a``, or None."""
    count, starts, ends = _coverage(*_bounds(y, black, white, a))
    ok = count >= need
    if not ok.any():
        return None
    nearest = np.clip(0.0, starts[ok], ends[ok])
    return float(nearest[np.argmin(np.abs(nearest))])


def image_map(y: np.ndarray, black: np.ndarray, white: np.ndarray,
              out_of_reach: float = DEFAULT_OUT_OF_REACH, tol: float = IMAGE_TOLERANCE) -> TargetMap:
    """The ``image`` map of one desired image: the largest ``a`` in (0, 1] such that some ``b``
    keeps all but ``out_of_reach`` of the pixels in reach in every channel (branch and bound to
    ``tol``; see the module docstring), or where none does, the smallest share that admits one.

    Parameters
    ----------
    y : numpy.ndarray
        The desired image, (3, H, W) in [0, 1].
    black, white : numpy.ndarray
        Captures of the black and white frames, (3, H, W) in [0, 1].

    Returns
    -------
    TargetMap
        With the ``b`` nearest 0 among those that work, and ``gap``: the optimum lies in
        ``[a, a + gap]``.

    Raises
    ------
    ProcamError
        If no map of positive contrast keeps any pixel in reach.

    >>> y = np.array([0.0, 1.0]).reshape(1, 1, 2).repeat(3, 0)   # a black and a white pixel
    >>> m = image_map(y, np.full((3, 1, 2), 0.2), np.full((3, 1, 2), 0.7))
    >>> round(m.a, 3), round(m.b, 3)
    (0.5, 0.2)
    """
    y, black, white = (np.asarray(v, np.float64).reshape(3, -1) for v in (y, black, white))

    def solve(allowed: int) -> TargetMap | None:
        need = y.shape[1] - allowed
        b = _feasible_b(y, black, white, 1.0, need)
        if b is not None:
            return TargetMap(1.0, b)
        stack, upper = [(0.0, 1.0)], None
        while stack:
            a0, a1 = stack.pop()
            if max_coverage((black - a1 * y).max(axis=0), (white - a0 * y).min(axis=0)) < need:
                continue
            if a1 - a0 > tol:
                mid = 0.5 * (a0 + a1)
                stack += [(a0, mid), (mid, a1)]
                continue
            upper = a1 if upper is None else upper
            b = _feasible_b(y, black, white, a0, need)
            if b is not None and a0 > 0:
                return TargetMap(a0, b, upper - a0)
        return None

    return _relaxed(solve, y.shape[1], out_of_reach, "this image")


def target_maps(policy: TargetPolicy, desired: np.ndarray, black: np.ndarray,
                white: np.ndarray) -> list[TargetMap]:
    """One map per desired image under ``policy``.

    Parameters
    ----------
    desired : numpy.ndarray
        (N, 3, H, W) in [0, 1].
    black, white : numpy.ndarray
        Captures of the black and white frames, (3, H, W).

    >>> y = np.zeros((2, 3, 1, 1))
    >>> [m.a for m in target_maps(TargetPolicy("none"), y, y[0], y[0] + 1)]
    [1.0, 1.0]
    """
    if policy.name == "none":
        return [IDENTITY] * len(desired)
    if policy.name == "global":
        return [global_map(black, white, policy.out_of_reach)] * len(desired)
    return [image_map(img, black, white, policy.out_of_reach) for img in desired]


def map_targets(policy: TargetPolicy, desired: np.ndarray, black: np.ndarray,
                white: np.ndarray) -> tuple[np.ndarray, dict]:
    """The targets y' of desired images under ``policy`` (:func:`target_maps` applied) and their
    record (:func:`map_record`).

    >>> y = np.full((1, 3, 1, 2), 0.5)
    >>> t, r = map_targets(TargetPolicy("global"), y, np.full((3, 1, 2), 0.2), np.full((3, 1, 2), 0.6))
    >>> t.ravel().round(3).tolist(), round(r["a"], 3)
    ([0.4, 0.4, 0.4, 0.4, 0.4, 0.4], 0.4)
    """
    maps = target_maps(policy, desired, black, white)
    return np.stack([m.apply(y) for m, y in zip(maps, desired)]), map_record(policy, maps)


def map_record(policy: TargetPolicy, maps: list[TargetMap]) -> dict:
    """What scores record of their target: the policy, ``a`` and ``b`` (their means over the images
    for ``image``, with ``a_per_image`` and ``b_per_image``), the largest ``gap`` and the largest
    share of pixels a map was allowed to leave out of reach (``out_of_reach_used``).

    >>> map_record(TargetPolicy("global"), [TargetMap(0.5, 0.1, 0.0, 0.01)] * 2)
    {'policy': 'global', 'out_of_reach': 0.01, 'a': 0.5, 'b': 0.1, 'gap': 0.0, 'out_of_reach_used': 0.01}
    """
    a, b = [m.a for m in maps], [m.b for m in maps]
    record = {**policy.record(), "a": float(np.mean(a)), "b": float(np.mean(b)),
              "gap": max((m.gap for m in maps), default=0.0),
              "out_of_reach_used": max((m.out_of_reach for m in maps), default=0.0)}
    if policy.name == "image":
        record.update(a_per_image=a, b_per_image=b)
    return record
