"""The physical bound of the closed loop: for each desired image, the projector frame whose capture
comes closest to the target y', found by optimisation through the simulator's own noise-free model.

The model F is the setup's simulator with its random draws switched off
(:meth:`sim.capture.Simulator.noise_free`: light transport, projector response and colour mixing,
camera response, processing and clipping, 8-bit output), each test image always evaluated with the
same Monte-Carlo samples (stream :data:`sim.seeds.OPTIMUM`, index = image). The frame x is kept in
[0, 1] on the projector's 8-bit grid. :func:`optimum` minimises ‖F(x) − y'‖² per image by damped
Gauss–Newton steps (Levenberg–Marquardt), the Jacobian measured on F by finite differences, in two
stages:

1. per pixel (:data:`ROUNDS` rounds): each pixel's 3×3 colour response to a change of its own input
   and its neighbours' alike (:func:`colour_jacobian`, 3 evaluations), the box-constrained step
   solved exactly per pixel (:func:`box_least_squares`);
2. across pixels (:data:`SPATIAL_ROUNDS` rounds): each pixel's response to each input channel of
   every pixel within :data:`RADIUS` (:func:`local_jacobian`, 3·(2·RADIUS + 1)² evaluations: what
   blur, scattering and the camera's resampling couple), the step solved by projected accelerated
   gradient (:func:`local_least_squares`) from the per-pixel one; first on :data:`PILOT_IMAGES`
   images, then on the others only where it paid there.

Each step is tried as it is and kept only at the pixels whose error it lowered; an image takes the
better of the two only where that lowers its error on F, so the result never scores below its
start. The frames found are then projected once more through the real (noisy) setup, as
every method's compensation is: that is the row compared with the methods; the noise-free scores
are kept beside it.
"""
from __future__ import annotations

import itertools
import math

import torch
from tqdm import tqdm

from compensation.data import SetupData
from compensation.experiments.closed_loop import (closed_loop_scores, closed_loop_target, project,
                                                 reachable_mask)
from compensation.experiments.targets import TargetPolicy
from compensation.scores.metrics import mse_per_image
from sim import seeds
from sim.capture import Simulator

ROUNDS = 6
"""Gauss–Newton rounds per pixel, each 5 noise-free evaluations of every test image: the colour
Jacobian at the current frame (3), the step, and the step kept only at the pixels it improved."""
STEP = 24 / 255
"""Finite-difference step of the Jacobian (projector input units): large against the 8-bit
quantisation of the frame and of the capture (1/255 each), small against the response's curvature."""
DAMPING = 1e-2
"""Initial Levenberg–Marquardt damping μ (the system is JᵀJ + μ·I); divided by 3 after a kept step
and multiplied by 4 after a refused one, per image."""
LEVELS = 255
"""Projector input levels (8 bit): the frame is kept on this grid."""
SPATIAL_ROUNDS = 1
"""Rounds of the second stage (the Jacobian across pixels measured once, at its start; 2
evaluations per round besides)."""
RADIUS = 1
"""Neighbourhood (pixels, Chebyshev) of the Jacobian across pixels. A pixel's response to inputs
farther away is attributed to the nearest input of the probe lattice (stride 2·RADIUS + 1)."""
PILOT_IMAGES = 8
"""The stage across pixels runs first on this many images (the first ones), and on the others only
where it lowered the pilot images' error by at least :data:`PILOT_GAIN_DB`: a setup whose pixels
are seen alone, or whose remaining error the neighbourhood cannot reach, is spared its 29
evaluations per image."""
PILOT_GAIN_DB = 0.1
"""Gain (dB, of the pilot images' mean squared error) that makes the stage across pixels run on
every image."""
CHUNK = 16
"""Images the stage across pixels holds at once: its Jacobian takes 81 float64 values per pixel
(680 MB for 16 images at 256²)."""
SOLVER_ITERATIONS = 100
"""Projected accelerated-gradient iterations of each step across pixels."""


def box_least_squares(jac: torch.Tensor, residual: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor,
                      damping: torch.Tensor | float) -> torch.Tensor:
    """Per pixel, the exact minimiser of ‖J·d − r‖² + μ‖d‖² subject to lo ≤ d ≤ hi.

    With three unknowns every active set can be tried: each of the 27 ways to hold every channel
    free, at its lower or at its upper bound gives a linear system; the minimiser is the feasible
    solution of lowest cost (the cost is strictly convex for μ > 0, so its constrained minimum is
    the free minimum of one of these faces).

    Parameters
    ----------
    jac : torch.Tensor
        (..., 3, 3): output channel × input channel.
    residual, lo, hi : torch.Tensor
        (..., 3); lo ≤ 0 ≤ hi.
    damping : torch.Tensor or float
        μ > 0, broadcast against (...).

    Returns
    -------
    torch.Tensor
        d, float64 (..., 3).

    Examples
    --------
    >>> j = torch.eye(3).expand(1, 3, 3)
    >>> r = torch.tensor([[0.5, -2.0, 0.1]])
    >>> box_least_squares(j, r, -torch.ones(1, 3), torch.ones(1, 3), 1e-9).round(decimals=6).tolist()
    [[0.5, -1.0, 0.1]]
    """
    jac, residual, lo, hi = (t.double() for t in (jac, residual, lo, hi))
    mu = torch.as_tensor(damping, dtype=torch.float64)
    if mu.ndim:
        mu = mu.reshape(*mu.shape, *([1] * (jac.ndim - 2 - mu.ndim)))
    a = jac.transpose(-1, -2) @ jac + mu[..., None, None] * torch.eye(3, dtype=torch.float64)
    b = (jac.transpose(-1, -2) @ residual[..., None])[..., 0]
    best = torch.zeros_like(residual)
    best_cost = torch.zeros(residual.shape[:-1], dtype=torch.float64)  # d = 0 is feasible, cost 0
    eye = torch.eye(3, dtype=torch.float64)
    for pattern in itertools.product((0, 1, 2), repeat=3):  # free, at lo, at hi
        fixed = torch.tensor([p != 0 for p in pattern])
        rows = torch.where(fixed[:, None], eye, a)
        value = torch.stack([lo[..., i] if p == 1 else hi[..., i] if p == 2 else b[..., i]
                             for i, p in enumerate(pattern)], dim=-1)
        d = torch.linalg.solve(rows, value)
        ok = ((d >= lo - 1e-12) & (d <= hi + 1e-12)).all(dim=-1)
        cost = 0.5 * (d[..., None, :] @ a @ d[..., :, None])[..., 0, 0] - (b * d).sum(-1)
        better = ok & (cost < best_cost)
        best = torch.where(better[..., None], d, best)
        best_cost = torch.where(better, cost, best_cost)
    return best


def _on_grid(x: torch.Tensor) -> torch.Tensor:
    """x rounded to the projector's 8-bit input levels, in [0, 1]."""
    return (x.clamp(0, 1) * LEVELS).round() / LEVELS


def colour_jacobian(model, x: torch.Tensor, captured: torch.Tensor) -> torch.Tensor:
    """Each pixel's 3×3 colour response of the model F at x, by finite differences.

    Channel c of every pixel moves by :data:`STEP` (down where it would pass 1), one evaluation per
    channel; column c of a pixel's Jacobian is the change of its capture over the change of its
    input (what its neighbours' equal change adds through blur and scattering included).

    Parameters
    ----------
    model : callable
        F: frames (N, 3, H, W) on the 8-bit grid → captures (N, 3, H, W).
    x : torch.Tensor
        Frames on the 8-bit grid, (N, 3, H, W).
    captured : torch.Tensor
        F(x).

    Returns
    -------
    torch.Tensor
        float64 (N, H, W, 3, 3): output channel × input channel.
    """
    step = round(STEP * LEVELS) / LEVELS
    cols = []
    for c in range(3):
        sign = torch.where(x[:, c] + step <= 1, 1.0, -1.0)
        moved = x.clone()
        moved[:, c] = _on_grid(x[:, c] + sign * step)
        change = (model(moved) - captured).double() / (sign * step)[:, None].double()
        cols.append(change.permute(0, 2, 3, 1))
    return torch.stack(cols, dim=-1)


def _offsets(radius: int) -> list[tuple[int, int]]:
    """The neighbourhood's offsets (dy, dx), row by row."""
    return [(dy, dx) for dy in range(-radius, radius + 1) for dx in range(-radius, radius + 1)]


def _shift(t: torch.Tensor, dy: int, dx: int) -> torch.Tensor:
    """``out[..., i, j] = t[..., i + dy, j + dx]``, zero where that is outside (t: (..., H, W)).

    >>> _shift(torch.arange(3.0)[None], 0, 1).tolist()
    [[1.0, 2.0, 0.0]]
    """
    h, w = t.shape[-2:]
    out = torch.zeros_like(t)
    out[..., max(0, -dy):h - max(0, dy), max(0, -dx):w - max(0, dx)] = \
        t[..., max(0, dy):h - max(0, -dy), max(0, dx):w - max(0, -dx)]
    return out


def local_jacobian(model, x: torch.Tensor, captured: torch.Tensor, radius: int = RADIUS) -> torch.Tensor:
    """The model's Jacobian across pixels at x, within ``radius``, by finite differences.

    Channel c of the pixels of one phase of a lattice of stride s = 2·radius + 1 moves by
    :data:`STEP` (down where it would pass 1): each output pixel then has exactly one moved input
    within ``radius``, so one evaluation gives every pixel's response to that neighbour; 3·s²
    evaluations give the whole neighbourhood.

    Returns
    -------
    torch.Tensor
        float64 (N, H, W, 3, K, 3), K = s²: output channel × offset (:func:`_offsets`) × input
        channel; entry [n, i, j, :, k, :] is the response of pixel (i, j) to pixel (i, j) + offset k.
    """
    s = 2 * radius + 1
    step = round(STEP * LEVELS) / LEVELS
    n, _, h, w = x.shape
    offsets = _offsets(radius)
    jac = torch.zeros(n, h, w, 3, len(offsets), 3, dtype=torch.float64)
    rows, cols = torch.arange(h)[:, None], torch.arange(w)[None, :]
    for c in range(3):
        sign = torch.where(x[:, c] + step <= 1, 1.0, -1.0).double()
        for a, b in itertools.product(range(s), repeat=2):
            lattice = (rows % s == a) & (cols % s == b)
            moved = x.clone()
            moved[:, c] = torch.where(lattice, _on_grid(x[:, c] + sign.float() * step), x[:, c])
            change = (model(moved) - captured).double()
            for k, (dy, dx) in enumerate(offsets):
                source = _shift(lattice.double(), dy, dx).bool()  # the input at p + offset moved
                moved_by = torch.where(source, _shift(sign, dy, dx) * step, 1.0)
                jac[..., k, c] += torch.where(source, change / moved_by[:, None], 0.0).permute(0, 2, 3, 1)
    return jac


def _apply(jac: torch.Tensor, d: torch.Tensor, radius: int) -> torch.Tensor:
    """G·d: (N, H, W, 3) → (N, H, W, 3), with G from :func:`local_jacobian`."""
    out = torch.zeros_like(d)
    for k, (dy, dx) in enumerate(_offsets(radius)):
        moved = _shift(d.permute(0, 3, 1, 2), dy, dx).permute(0, 2, 3, 1)
        out += (jac[..., k, :] @ moved[..., None])[..., 0]
    return out


def _apply_transposed(jac: torch.Tensor, u: torch.Tensor, radius: int) -> torch.Tensor:
    """Gᵀ·u: (N, H, W, 3) → (N, H, W, 3)."""
    parts = torch.einsum("nhwckj,nhwc->nkjhw", jac, u)  # every offset's share, in one product
    out = torch.zeros_like(u.permute(0, 3, 1, 2))
    for k, (dy, dx) in enumerate(_offsets(radius)):
        out += _shift(parts[:, k], -dy, -dx)
    return out.permute(0, 2, 3, 1)


def local_least_squares(jac: torch.Tensor, residual: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor,
                        damping: torch.Tensor, start: torch.Tensor, radius: int = RADIUS,
                        iterations: int = SOLVER_ITERATIONS) -> torch.Tensor:
    """Per image, min ½‖G·d − r‖² + ½μ‖d‖² subject to lo ≤ d ≤ hi, by projected accelerated
    gradient (FISTA, step 1/L with L from power iteration) from ``start``; ``start`` itself where
    the iterations end no lower.

    Parameters
    ----------
    jac : torch.Tensor
        G, from :func:`local_jacobian`.
    residual, lo, hi, start : torch.Tensor
        float64 (N, H, W, 3).
    damping : torch.Tensor
        μ per image, (N,).

    Returns
    -------
    torch.Tensor
        d, float64 (N, H, W, 3).
    """
    mu = damping.double().reshape(-1, 1, 1, 1)

    def normal(v: torch.Tensor) -> torch.Tensor:
        return _apply_transposed(jac, _apply(jac, v, radius), radius) + mu * v

    def cost(d: torch.Tensor) -> torch.Tensor:
        return (0.5 * ((_apply(jac, d, radius) - residual) ** 2).sum((1, 2, 3))
                + 0.5 * mu.flatten() * (d ** 2).sum((1, 2, 3)))

    v = torch.ones_like(residual)
    for _ in range(10):
        v = normal(v)
        norm = v.flatten(1).norm(dim=1).clamp_min(1e-30).reshape(-1, 1, 1, 1)
        v = v / norm
    lipschitz = 1.05 * norm
    target = _apply_transposed(jac, residual, radius)
    d, z, t = start.clone(), start.clone(), 1.0
    for _ in range(iterations):
        new = torch.minimum(torch.maximum(z - (normal(z) - target) / lipschitz, lo), hi)
        t_next = (1 + (1 + 4 * t * t) ** 0.5) / 2
        z = new + ((t - 1) / t_next) * (new - d)
        d, t = new, t_next
    return torch.where((cost(d) < cost(start)).reshape(-1, 1, 1, 1), d, start)


def evaluation_count(starts: int = 1, rounds: int = ROUNDS, spatial_rounds: int = SPATIAL_ROUNDS) -> int:
    """Noise-free evaluations of each image by :func:`optimum` at most: y', the further starts, 5 per
    round per pixel, and the Jacobian across pixels and 2 per round across pixels (on the pilot
    images only, where the stage across pixels does not pay: :data:`PILOT_IMAGES`).

    >>> evaluation_count()
    61
    """
    across = 3 * (2 * RADIUS + 1) ** 2 + 2 * spatial_rounds if spatial_rounds else 0
    return 1 + starts + 5 * rounds + across


def optimum(data: SetupData, sim: Simulator, desired: torch.Tensor | None = None,
            policy: TargetPolicy = TargetPolicy(), starts: tuple[torch.Tensor, ...] = (),
            rounds: int = ROUNDS, spatial_rounds: int = SPATIAL_ROUNDS,
            progress: bool = False) -> tuple[dict, torch.Tensor]:
    """The best projector frame for each desired image, and its closed-loop scores.

    Parameters
    ----------
    data : SetupData
        The setup's data (the test frames are the desired images by default; the plain black and
        white captures bound what is reachable).
    sim : Simulator
        The same setup's simulator (:func:`~compensation.experiments.closed_loop.simulator_for`).
    desired : torch.Tensor, optional
        Desired images y (N, 3, H, W).
    policy : TargetPolicy
        How y is mapped to the target y'.
    starts : tuple of torch.Tensor
        Further frames (N, 3, H, W) to start from (a method's compensation, the feedback oracle's
        last frame): each image starts from whichever of y' and these scores best on the model, so
        the optimum is never worse than any of them on it.
    rounds, spatial_rounds : int
        Gauss–Newton rounds per pixel, then across pixels.
    progress : bool
        Show a progress bar of the model's evaluations.

    Returns
    -------
    dict
        The closed-loop scores of the frames projected through ``sim`` (as
        :func:`~compensation.experiments.closed_loop.closed_loop`'s), ``noise_free`` (the same
        scores of their captures on the model), ``evaluations`` (model evaluations per image, the
        mean), ``rounds``, ``spatial_rounds``, ``across_pixels`` (``pilot_images``,
        ``pilot_gain_db``, ``applied``: whether the stage across pixels ran on every image; None
        without it) and ``target`` (the policy and its map).
    torch.Tensor
        The frames, float32 (N, 3, H, W) on the 8-bit grid.
    """
    y, record = closed_loop_target(data, data.test.frames if desired is None else desired, policy)
    noise_free = sim.noise_free()
    n = len(y)
    # the bar counts evaluations of the whole test set, in fractions as batches of images finish
    bar = tqdm(total=evaluation_count(len(starts), rounds, spatial_rounds), desc=f"{data.name} · exact optimum",
               unit="eval", disable=not progress,
               bar_format="{l_bar}{bar}| {n:.1f}/{total_fmt} [{elapsed}<{remaining}, {rate_fmt}]")
    counts = torch.zeros(n)

    def model(frames: torch.Tensor, first: int = 0) -> torch.Tensor:
        """F of images ``first`` … (each always with its own index: its own samples)."""
        counts[first:first + len(frames)] += 1
        bar.update(len(frames) / n)
        return project(noise_free, frames, seeds.OPTIMUM, first)

    x = _on_grid(y)
    captured = model(x)
    err = mse_per_image(captured, y)
    for start in starts:
        s = _on_grid(start)
        c = model(s)
        e = mse_per_image(c, y)
        take = e < err
        x[take], captured[take], err[take] = s[take], c[take], e[take]

    def keep(trial: torch.Tensor, mu: torch.Tensor, part: slice = slice(0, n)) -> torch.Tensor:
        """Evaluate a trial step of the images ``part`` and, per pixel, the step only where it
        lowered that pixel's error; keep for each image the better of the two if it beats its
        current frame. Returns the images' new damping."""
        trial = _on_grid(trial)
        now, target = captured[part], y[part]
        c = model(trial, part.start)
        better = ((c - target) ** 2).sum(1, keepdim=True) < ((now - target) ** 2).sum(1, keepdim=True)
        merged = torch.where(better, trial, x[part])
        cm = model(merged, part.start)
        use = (mse_per_image(cm, target) <= mse_per_image(c, target))[:, None, None, None]
        trial, c = torch.where(use, merged, trial), torch.where(use, cm, c)
        e = mse_per_image(c, target)
        take = e < err[part]
        idx = torch.arange(part.start, part.stop)[take]
        x[idx], captured[idx], err[idx] = trial[take], c[take], e[take]
        return torch.where(take, mu / 3, mu * 4)

    def across_pixels(part: slice) -> None:
        """The second stage on the images ``part``."""
        jac = local_jacobian(lambda frames: model(frames, part.start), x[part], captured[part])
        own = jac.sum(dim=-2)  # each pixel's response to a change uniform over its neighbourhood
        mu = torch.full((part.stop - part.start,), DAMPING, dtype=torch.float64)
        for _ in range(spatial_rounds):
            xp = x[part].permute(0, 2, 3, 1).double()
            residual = (y[part] - captured[part]).permute(0, 2, 3, 1).double()
            start = box_least_squares(own, residual, -xp, 1 - xp, mu)
            d = local_least_squares(jac, residual, -xp, 1 - xp, mu, start)
            mu = keep(x[part] + d.permute(0, 3, 1, 2).float(), mu, part)

    mu = torch.full_like(err, DAMPING)
    for _ in range(rounds):
        jac = colour_jacobian(model, x, captured)
        xp = x.permute(0, 2, 3, 1).double()
        d = box_least_squares(jac, (y - captured).permute(0, 2, 3, 1), -xp, 1 - xp, mu)
        mu = keep(x + d.permute(0, 3, 1, 2).float(), mu)
    across = None
    if spatial_rounds:
        pilot = slice(0, min(PILOT_IMAGES, CHUNK, n))
        before = float(err[pilot].mean())
        across_pixels(pilot)
        after = float(err[pilot].mean())
        gain = 10 * math.log10(before / after) if after > 0 else (0.0 if before == 0 else math.inf)
        applied = gain >= PILOT_GAIN_DB
        for first in range(pilot.stop, n if applied else pilot.stop, CHUNK):
            across_pixels(slice(first, min(first + CHUNK, n)))
        across = {"pilot_images": pilot.stop, "pilot_gain_db": round(gain, 4), "applied": applied}
    bar.close()
    mask = reachable_mask(data, y)
    scores = closed_loop_scores(project(sim, x, seeds.CLOSED_LOOP), y, mask)
    free = closed_loop_scores(captured, y, mask)
    scores.update(noise_free={k: free[k] for k in ("psnr", "rmse", "ssim", "deltaE", "psnr_reachable",
                                                  "psnr_per_image")},
                  evaluations=round(float(counts.mean()), 1), rounds=rounds, spatial_rounds=spatial_rounds,
                  across_pixels=across,
                  projections=int(y.shape[0]), target=record)
    return scores, x
