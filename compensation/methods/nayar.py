"""Nayar et al. (2003) colour-mixing model: per pixel, an affine map from linearised projector
output to capture, inverted for compensation.

Model. The projector input x ∈ [0, 1]³ is first linearised by a global per-channel response,
then mixed per pixel by a 3×3 matrix (projector primaries → camera channels, surface reflectance
included) and offset by the light that does not depend on x (ambient, projector black level)::

    p = x^γ   (per channel, γ ∈ R³ global)        c̃ = V p + o   (V 3×3, o ∈ R³ per pixel)

    compensation:  p* = V⁻¹ (y − o),  clipped to [0, 1],   x* = p*^(1/γ)

Response. Nayar et al. calibrate the projector and camera responses first. We keep the simple,
principled part: one exponent per projector channel, from the primary ramps among the plain
colours (frames where the other two channels are 0). Under the model, camera channel k along the
ramp of primary k is ``c̃ₖ(t) = oₖ + Vₖₖ t^γₖ`` whatever the crosstalk, so at every pixel
``(c̃ₖ(t) − c̃ₖ(0)) / (c̃ₖ(1) − c̃ₖ(0)) = t^γₖ``; γₖ is the median of ``log(ratio) / log t``
over the intermediate ramp levels and all pixels whose ramp is unsaturated and spans at least
:data:`MIN_RANGE` (the median shrugs off noisy dark pixels). A median of exact ratios is exact on
noise-free data, unlike a least-squares fit in log space over all 125 colours, which would need
V first. The camera is treated as linear in its encoded values: its own response is not
estimated, and its curvature along the ramps is absorbed into γ as far as a power law can.

Fit. Per pixel and camera channel, (Vₖ, oₖ) by least squares on the 125 plain colours (a 4×4
normal-equation system in float64), leaving out the samples where that channel is clipped at 0
or 255 (the affine model does not hold there) unless fewer than :data:`MIN_SAMPLES` remain.
"""
from __future__ import annotations

import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch

from compensation.data import N_PLAIN
from compensation.methods.base import FitResult, Method, load_arrays, plain_colour_pairs, resolve_device
from compensation.methods.tps import pixel_samples
from compensation.training.config import NoOptions, TrainConfig
from sim.errors import ProcamError

if TYPE_CHECKING:
    from compensation.data import SetupData

STATE_FILE = "nayar.npz"
"""File name of the fitted model in a run directory (NumPy ``.npz``, no pickles)."""
MIN_RANGE = 0.05
"""Least span c̃ₖ(1) − c̃ₖ(0) of a pixel's primary ramp used for γ (encoded units, ≈ 13 codes)."""
CLIP_LOW, CLIP_HIGH = 0.5 / 255, 254.5 / 255
"""Captured values at or beyond these (8-bit codes 0 and 255) count as clipped."""
MIN_SAMPLES = 8
"""Fewest unclipped samples for a per-channel fit that leaves the clipped ones out."""
_FIT_CHUNK = 4096
"""Pixels per batch of normal equations (about 50 MB of float64 at n = 125)."""
CHANNELS = "RGB"


def primary_ramps(levels: np.ndarray) -> tuple[int, list[tuple[int, np.ndarray, np.ndarray]]]:
    """Find the black frame and the ramp of each primary among uniform frame colours.

    Parameters
    ----------
    levels : numpy.ndarray
        (N, 3) colour of each plain frame, in [0, 1].

    Returns
    -------
    black : int
        Index of the black frame.
    ramps : list
        Per channel k: (index of the full-primary frame, indices of the intermediate levels,
        their values t ∈ (0, 1)).

    Raises
    ------
    ProcamError
        If the black frame, a full primary or an intermediate ramp level is missing.

    Examples
    --------
    >>> lv = np.linspace(0, 1, 3)
    >>> black, ramps = primary_ramps(np.array([(r, g, b) for r in lv for g in lv for b in lv]))
    >>> black, ramps[0][0], ramps[0][1].tolist(), ramps[0][2].tolist()
    (0, 18, [9], [0.5])
    """
    tol = 1e-6
    off = levels <= tol
    black = np.flatnonzero(off.all(axis=1))
    if not len(black):
        raise ProcamError("plain colours: no black frame (0, 0, 0); cannot estimate the projector "
                          "response")
    ramps = []
    for k, name in enumerate(CHANNELS):
        on_ramp = off[:, [j for j in range(3) if j != k]].all(axis=1) & ~off[:, k]
        full = np.flatnonzero(on_ramp & (levels[:, k] >= 1 - tol))
        inner = np.flatnonzero(on_ramp & (levels[:, k] < 1 - tol))
        if not len(full) or not len(inner):
            raise ProcamError(f"plain colours: the ramp of primary {name} (other channels 0) needs "
                              f"the full level and at least one level in (0, 1); found levels "
                              f"{sorted(levels[on_ramp, k].round(4).tolist())}")
        ramps.append((int(full[0]), inner, levels[inner, k]))
    return int(black[0]), ramps


def estimate_gamma(captures: torch.Tensor, frames: torch.Tensor) -> np.ndarray:
    """Per-channel projector response exponent γ from the primary ramps of the plain colours.

    Parameters
    ----------
    captures : torch.Tensor
        (N, 3, H, W) captures of the plain colours, encoded, in [0, 1].
    frames : torch.Tensor
        (N, 3, H, W) the uniform projector frames, in [0, 1].

    Returns
    -------
    numpy.ndarray
        float64 (3,) exponents γ (dimensionless).

    Raises
    ------
    ProcamError
        If a ramp is missing (see :func:`primary_ramps`) or no pixel has a usable ramp in a
        channel (every ramp saturated or spanning less than :data:`MIN_RANGE`).
    """
    black, ramps = primary_ramps(frames.double().mean(dim=(2, 3)).numpy())
    caps = captures.double().flatten(2).numpy()  # (N, 3, H·W)
    gamma = np.empty(3)
    for k, (full, inner, t) in enumerate(ramps):
        base, top = caps[black, k], caps[full, k]
        usable = (top - base >= MIN_RANGE) & (top < CLIP_HIGH)
        ratio = (caps[inner, k][:, usable] - base[usable]) / (top - base)[usable]
        valid = (ratio > 0) & (ratio < 1)
        if not valid.any():
            raise ProcamError(f"plain colours: no pixel has an unsaturated ramp of primary {CHANNELS[k]} "
                              f"spanning at least {MIN_RANGE} (encoded); cannot estimate its response")
        exponents = np.log(np.where(valid, ratio, 0.5)) / np.log(t)[:, None]
        gamma[k] = np.median(exponents[valid])
    return gamma


def fit_mixing(linear: torch.Tensor, captures: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-pixel colour mixing ``c̃ = V p + o`` by least squares, clipped samples left out.

    Parameters
    ----------
    linear : torch.Tensor
        (P, n, 3) linearised projector output p = x^γ per pixel and sample.
    captures : torch.Tensor
        (P, n, 3) captured colours c̃ (encoded, [0, 1]).

    Returns
    -------
    matrix : torch.Tensor
        float64 (P, 3, 3) V, rows = camera channels, columns = projector primaries.
    offset : torch.Tensor
        float64 (P, 3) o.

    Raises
    ------
    ProcamError
        If the samples do not span the colour space (fewer than 4 affinely independent colours).
    """
    solution = torch.empty((linear.shape[0], 3, 4), dtype=torch.float64)
    for s in range(0, linear.shape[0], _FIT_CHUNK):
        lin, c = linear[s:s + _FIT_CHUNK].double(), captures[s:s + _FIT_CHUNK].double()
        x = torch.cat([lin, torch.ones_like(lin[..., :1])], dim=-1)  # (p, n, 4)
        weight = ((c > CLIP_LOW) & (c < CLIP_HIGH)).double()  # (p, n, 3): one set per camera channel
        weight[(weight.sum(dim=1) < MIN_SAMPLES).unsqueeze(1).expand_as(weight)] = 1.0
        xw = x.unsqueeze(1) * weight.transpose(1, 2).unsqueeze(-1)  # (p, 3, n, 4)
        gram = xw.transpose(-1, -2) @ x.unsqueeze(1)  # (p, 3, 4, 4)
        rhs = xw.transpose(-1, -2) @ c.transpose(1, 2).unsqueeze(-1)  # (p, 3, 4, 1)
        part, info = torch.linalg.solve_ex(gram, rhs)
        if (info != 0).any() or not torch.isfinite(part).all():
            raise ProcamError("colour mixing: the projector colours do not span the colour space "
                              "(need at least 4 affinely independent plain colours)")
        solution[s:s + _FIT_CHUNK] = part.squeeze(-1)
    return solution[..., :3], solution[..., 3]


def invert_mixing(targets: torch.Tensor, matrix: torch.Tensor, offset: torch.Tensor,
                  gamma: torch.Tensor) -> torch.Tensor:
    """Projector inputs that make each pixel show ``targets``: ``(V⁻¹(y − o)).clip(0, 1)^(1/γ)``.

    Parameters
    ----------
    targets : torch.Tensor
        (P, m, 3) desired captured colours y per pixel.
    matrix : torch.Tensor
        (P, 3, 3) inverse mixing matrices V⁻¹ (pseudo-inverse where V is singular).
    offset : torch.Tensor
        (P, 3) offsets o.
    gamma : torch.Tensor
        (3,) projector response exponents.

    Returns
    -------
    torch.Tensor
        (P, m, 3) projector inputs in [0, 1], dtype of ``matrix``.

    Examples
    --------
    One pixel with V = I / 2, o = 0.1 and γ = 2: y = 0.35 needs p = 0.5, x = √0.5; y = 0.1 needs
    nothing; y = 1 is out of gamut (p = 1.8 is clipped to 1):

    >>> inverse = 2 * torch.eye(3, dtype=torch.float64)[None]
    >>> y = torch.tensor([[[0.35, 0.1, 1.0]]], dtype=torch.float64)
    >>> invert_mixing(y, inverse, torch.full((1, 3), 0.1, dtype=torch.float64),
    ...               torch.tensor([2.0, 2.0, 2.0], dtype=torch.float64)).tolist()
    [[[0.7071067811865475, 0.0, 1.0]]]
    """
    linear = (targets.to(matrix.dtype) - offset.unsqueeze(1)) @ matrix.transpose(1, 2)
    return linear.clamp_(0.0, 1.0).pow_(1.0 / gamma)


class NayarMethod(Method):
    """Nayar et al. (2003) per-pixel colour mixing with a global projector gamma, fitted on the
    125 plain-colour pairs.

    Parameters
    ----------
    device : str
        Torch device for prediction (``"auto"``: CUDA if available); ``fit`` uses the config's.
    """

    name = "nayar"
    official_name = "Nayar"
    options = NoOptions
    state_file = STATE_FILE
    plain_colours = True

    @classmethod
    def seeded(cls, cfg: TrainConfig) -> bool:
        """A least-squares fit on the plain colours: no seed."""
        return False

    def __init__(self, device: str = "auto"):
        self.device = resolve_device(device)
        self.size: tuple[int, int] | None = None
        self.gamma: torch.Tensor | None = None
        self.matrix: torch.Tensor | None = None
        self.offset: torch.Tensor | None = None
        self._inverse: torch.Tensor | None = None

    def fit(self, data: SetupData, cfg: TrainConfig, progress: bool = True,
            checkpoint: Path | None = None) -> FitResult:
        """Estimate γ, then every pixel's V and o.

        Returns
        -------
        FitResult
            ``final_loss`` is the mean |π†(c̃ᵢ) − xᵢ| over the plain colours (projector input
            units), ``batch`` 125, ``extra["gamma"]`` the three exponents.
        """
        self.device = resolve_device(cfg.device)
        pairs = plain_colour_pairs(data, self.name)
        captures, frames = pairs.captures, pairs.frames
        start = time.perf_counter()
        gamma = estimate_gamma(captures, frames)
        linear = torch.from_numpy(pixel_samples(frames)).double().pow(torch.from_numpy(gamma))
        matrix, offset = fit_mixing(linear, torch.from_numpy(pixel_samples(captures)))
        self._set_state(tuple(captures.shape[-2:]), torch.from_numpy(gamma), matrix, offset)
        seconds = time.perf_counter() - start
        residual = (self.predict(captures, data.surface) - frames).abs().mean().item()
        return FitResult(seconds, N_PLAIN / seconds, residual, N_PLAIN, [(1, residual, 0.0)],
                         {"gamma": gamma.tolist()})

    def _set_state(self, size: tuple[int, int], gamma: torch.Tensor, matrix: torch.Tensor,
                   offset: torch.Tensor) -> None:
        self.size = size
        self.gamma = gamma.to(self.device, torch.float64)
        self.matrix = matrix.to(self.device, torch.float64)
        self.offset = offset.to(self.device, torch.float64)
        self._inverse = torch.linalg.pinv(self.matrix)

    @torch.no_grad()
    def predict(self, captures: torch.Tensor, surface: torch.Tensor, batch_size: int = 64) -> torch.Tensor:
        if self.matrix is None:
            raise ProcamError(f"{self.name}: predict called before fit or load")
        if captures.ndim != 4 or captures.shape[1] != 3 or tuple(captures.shape[-2:]) != self.size:
            raise ProcamError(f"{self.name}: captures of shape {tuple(captures.shape)}; the model was "
                              f"fitted for (N, 3, {self.size[0]}, {self.size[1]})")
        h, w = self.size
        out = []
        for i in range(0, captures.shape[0], batch_size):
            batch = captures[i:i + batch_size].to(self.device)
            targets = batch.permute(2, 3, 0, 1).reshape(h * w, batch.shape[0], 3)
            frames = invert_mixing(targets, self._inverse, self.offset, self.gamma)
            out.append(frames.reshape(h, w, -1, 3).permute(2, 3, 0, 1).float().cpu())
        return torch.cat(out).contiguous()

    def save(self, run_dir: Path) -> None:
        if self.matrix is None:
            raise ProcamError(f"{self.name}: nothing to save before fit or load")
        np.savez(Path(run_dir) / STATE_FILE, gamma=self.gamma.cpu().numpy(),
                 matrix=self.matrix.cpu().numpy(), offset=self.offset.cpu().numpy(),
                 size=np.array(self.size, np.int64))

    @classmethod
    def load(cls, run_dir: Path, device: str = "auto") -> NayarMethod:
        """Restore a fitted model from ``run_dir/nayar.npz``.

        Raises
        ------
        ProcamError
            If the file is missing, unreadable, holds pickled objects, or its arrays are missing
            or of inconsistent shapes.
        """
        path = Path(run_dir) / STATE_FILE
        state = load_arrays(path, ("gamma", "matrix", "offset", "size"), "colour-mixing model")
        gamma, matrix, offset, size = (state[k] for k in ("gamma", "matrix", "offset", "size"))
        pixels = int(np.prod(size)) if size.shape == (2,) else -1
        if gamma.shape != (3,) or matrix.shape != (pixels, 3, 3) or offset.shape != (pixels, 3):
            raise ProcamError(f"{path}: inconsistent shapes: gamma {gamma.shape}, matrix {matrix.shape}, "
                              f"offset {offset.shape}, size {size.tolist()}; expected (3,), (H·W, 3, 3), "
                              "(H·W, 3), [H, W]")
        method = cls(device)
        method._set_state((int(size[0]), int(size[1])), torch.from_numpy(gamma), torch.from_numpy(matrix),
                          torch.from_numpy(offset))
        return method
