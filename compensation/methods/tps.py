"""Per-pixel thin-plate splines in RGB (Grundhöfer & Iwai 2015): captured colour → projector input.

For every pixel, a 3-D → 3-D spline maps the colour the camera saw, c̃ ∈ [0, 1]³ (encoded), to the
projector input x ∈ [0, 1]³ that produced it, fitted on n sample pairs (c̃ᵢ, xᵢ) of that pixel::

    f(c) = Σᵢ wᵢ φ(‖c − c̃ᵢ‖) + A c + b,     φ(r) = r² log r  (φ(0) = 0)

    [ K + λI   P ] [w]   [x]      K_ij = φ(‖c̃ᵢ − c̃ⱼ‖), P = [c̃ᵢᵀ 1] (n × 4),
    [ Pᵀ       0 ] [a] = [0]      a = (A | b), three right-hand sides (R, G, B).

Kernel. φ(r) = r² log r, scipy's ``RBFInterpolator(kernel="thin_plate_spline")``: the fit equals
``RBFInterpolator(c̃, x, kernel="thin_plate_spline", smoothing=λ, degree=1)`` to float64
rounding (tests/test_tps_nayar.py checks this). It is the plane's thin-plate kernel; in three
dimensions the minimiser of the thin-plate bending energy (Duchon 1977) has the kernel r
(scipy's "linear", −r). Both are conditionally positive definite of an order the affine term
covers, so either system is well posed; we measured both (each at its best λ), and r² log r won:
in the six simulated conditions of :data:`SMOOTHING`, −0.1 … +0.4 dB PSNR on the plain colours
and +0.05 … +1.5 dB on 250 textured samples; on smooth planted colour maps sampled on the 5³
plain colours, 10–45 % less interpolation error. φ = r has a cusp at every sample (the
interpolant is only continuous); r² log r is C¹, which suits dense, noisy samples.

Smoothing. λ (:data:`SMOOTHING`) is added to K's diagonal (scipy's convention). Saturated or
dark pixels capture the same 8-bit colour for different projector inputs; duplicate centres make
the exact system (λ = 0) singular, and λ > 0 turns them into a least-squares compromise. A pixel
whose captured colours are degenerate even then (all on a line, or one channel constant: a pixel
the camera does not see, a surface without blue) has a rank-deficient affine part; LU does not
always notice (no zero pivot, coefficients of 1e16), so a LAPACK condition estimate below
:data:`RCOND_MIN` sends the pixel to minimum-norm least squares, and the fit statistics count
it.

How the CompenNet paper ran TPS. The paper compares with TPS (Grundhöfer & Iwai 2015) fitted on
125 plain colours and "TPS textured" fitted on the textured training images; its authors released
no TPS code (asked on the CompenNet repository's issue tracker, the author points to the public
reimplementation pjessesco/grundhofer2015 as "compatible with CompenNet dataset"). What each
source states, and what none does:

- Samples: the dataset's ``ref/img_0001 … img_0125`` are "plain color training images used by
  TPS-based method" (CompenNet README), black first and white last; a 5³ grid fits, its five
  levels are not stated. TPS textured: no source states the count; the reimplementation uses 500,
  the paper's training-set size (here: all training pairs up to :data:`MAX_SAMPLES`).
- Saturated samples: the README's capture rule makes plain white slightly over- and plain black
  slightly under-expose the camera, so the real data hold clipped, duplicate centres; no source
  states how the paper's fit treated them (the reimplementation does nothing special: its ridge
  keeps the system solvable, as λ > 0 does here).
- Kernel, direction, colour space: the reimplementation fits per pixel captured camera colour →
  projector input with r² log₂ r and an affine part on encoded 8-bit values / 255, no
  linearisation; the paper states none of these (Grundhöfer & Iwai describe a calibration-free
  per-pixel scattered-data interpolation of the colour mapping). procam fits the same.
- Smoothing: the paper states no λ. The reimplementation adds 0.05·α² to the kernel diagonal, α
  the pixel's mean distance between its captured colours (a scale-invariant ridge), i.e.
  :data:`PAPER_SMOOTHING`·α² in procam's kernel: the ``paper`` and ``faithful`` profiles'
  setting (``scale_invariant``). The ``quick`` profile keeps λ tuned on procam's simulated pixels
  (:data:`SMOOTHING`, :data:`SMOOTHING_TEXTURED`). Both are recorded in Table 1's rows and in the
  official tag (``TPS_125_lambda0.0347alpha2``).

Speed. Fit time measured on this project's CPU (2 cores shared with other work, load ≈ 7;
scipy 1.17 with OpenBLAS, torch 2.13 CPU with MKL), n = 125 samples per pixel, λ = 1e-2, best
of 2–3 runs:

    pixels                                                   32 × 32    64 × 64
    scipy RBFInterpolator per pixel, 2 worker processes      0.51 s     2.0 s
    fit_splines: NumPy system + LAPACK dgesv + dgecon per
        pixel, 2 forked workers (pool start included)        0.68 s     2.2 s
    torch batched: (P, n+4, n+4) chunks, linalg.solve,
        1 thread                                             1.0 s      3.2 s
        2 OpenMP threads (torch's default here)              7.2 s      22 s

Batched torch loses on the CPU: building the (P, 129, 129) systems is memory bound, its batched
LU is no faster per matrix than OpenBLAS's dgesv, and its OpenMP threads stall when the cores
are shared (a first 2-thread call took 29 s at 32 × 32). So the fit runs one LAPACK solve per
pixel in a pool of worker processes, the solves RBFInterpolator makes; RBFInterpolator itself
is not used because its coefficients are private (stored after a polynomial rescaling) and it
neither detects collinear centres nor survives singular pixels — the condition estimate that
does costs the 10–30 % above. Evaluation is batched in torch (one distance matrix and two batched products per chunk of
pixels). 256² pixels with 125 samples: centres and coefficients take 0.2 GB in float32; each
worker holds one (n + 4)² system at a time.
"""
from __future__ import annotations

import math
import multiprocessing
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import torch
from scipy.linalg import lapack, lstsq
from scipy.spatial.distance import cdist
from tqdm import tqdm

from compensation.data import PairSet
from compensation.methods.base import FitResult, Method, load_arrays, plain_colour_pairs, resolve_device
from compensation.training.config import Options, TrainConfig
from compensation.training.loop import fit_label
from sim.blas import one_blas_thread
from sim.cores import usable_cores
from sim.errors import ProcamError

if TYPE_CHECKING:
    from compensation.data import SetupData

SMOOTHING = 1e-2
"""Default smoothing λ of ``tps`` (plain colours), added to the kernel diagonal.

Chosen on simulated pixels (sim.projector + sim.camera: γ 2.2 projector with crosstalk and 0.5 %
black, random albedo, ambient light, sRGB or linear camera, 8-bit; 16 × 16 pixels, 100 smooth
random test frames), by the test PSNR of π†(x̃) vs x over λ = 1e-3 … 1, for three sensor-noise
levels (none; shot 2e-4 + read 2e-3; shot 1e-3 + read 5e-3): λ = 1e-2 is within 0.3 dB of the
best λ in all six conditions."""
PAPER_SMOOTHING = 0.05 * math.log(2)
"""λ of the paper profile, applied per pixel as λ·α² (``scale_invariant``): the public
reimplementation the CompenNet paper's author points users to (his own TPS code is unreleased)
adds 0.05·α² to the diagonal of a kernel r² log₂ r; with procam's kernel r² ln r that is
0.05·ln 2·α² ≈ 0.0347·α² (about 0.023 for colours filling the RGB cube, α = 0.81)."""
SMOOTHING_TEXTURED = 3e-3
"""Default smoothing λ of ``tps-textured`` (250 textured samples in the study above): within
0.9 dB of the best λ in all six conditions (λ = 1e-2 loses up to 1.6 dB without noise)."""
RCOND_MIN = 1e-13
"""Systems with a smaller reciprocal condition number (LAPACK dgecon, 1-norm) count as singular.

Measured: regular pixels have 1e-6 … 1e-4 with λ ≥ 1e-3 (4e-7 with λ = 0); captured colours on
a line, or one channel constant, give 0 … 1e-33."""
LSTSQ_DRIVER = "gelsy"
"""LAPACK driver of the minimum-norm least squares a singular pixel falls back to: a complete
orthogonal factorisation (QR with column pivoting), the same minimum-norm solution as the SVD
(gelsd, scipy's default) to 1e-12 on singular spline systems, and 5-7 times faster at 129 × 129 —
at λ = 0 with clipped captures most pixels of a dark print take this path."""
MAX_SAMPLES = 500
"""Most sample pairs per pixel of ``tps-textured`` (the paper's n_train; see its docstring)."""
STATE_FILE = "tps.npz"
"""File name of a fitted spline state in a run directory (NumPy ``.npz``, no pickles)."""
_TASK_SIZE = 1 << 22
"""Pixels per worker task × (n + 4)²: 252 pixels at n = 125, 16 at n = 500 (a fraction of a second
of work each: even progress, little idle time at the end)."""
_EVAL_ELEMENTS = 1 << 24
"""Distance-matrix elements per evaluation chunk (64 MiB in float32)."""


def pixel_samples(images: torch.Tensor) -> np.ndarray:
    """Images (N, 3, H, W) as per-pixel colour samples.

    Parameters
    ----------
    images : torch.Tensor
        (N, 3, H, W) values in [0, 1].

    Returns
    -------
    numpy.ndarray
        float32 (H·W, N, 3), pixel-major (row by row): element [p, i] is the RGB colour of
        pixel p in image i.

    Examples
    --------
    >>> x = torch.arange(24, dtype=torch.float32).reshape(2, 3, 2, 2)
    >>> pixel_samples(x)[1].tolist()  # pixel (0, 1) in both images
    [[1.0, 5.0, 9.0], [13.0, 17.0, 21.0]]
    """
    n, _, h, w = images.shape
    return images.detach().to("cpu", torch.float32).permute(2, 3, 0, 1).reshape(h * w, n, 3).numpy().copy()


def fit_pixel_splines(centres: np.ndarray, values: np.ndarray, smoothing: float = SMOOTHING,
                      scale_invariant: bool = False) -> tuple[np.ndarray, float, int]:
    """Fit one spline per pixel, one LAPACK solve after another, in this process.

    Parameters
    ----------
    centres : numpy.ndarray
        (P, n, 3) sample inputs c̃ᵢ per pixel (captured colours, encoded, [0, 1]); n ≥ 4.
    values : numpy.ndarray
        (P, n, 3) sample outputs xᵢ per pixel (projector inputs, [0, 1]).
    smoothing : float
        λ ≥ 0 added to the kernel diagonal; 0 interpolates exactly (distinct centres only).
    scale_invariant : bool
        Add λ·α² instead, α the pixel's mean distance between its centres (over all n² pairs,
        :func:`pixel_alpha`).

    Returns
    -------
    coeffs : numpy.ndarray
        float64 (P, n + 4, 3): kernel weights w (rows 0 … n−1), then A (rows n … n+2, one row per
        input channel) and b (row n+3).
    residual : float
        Sum over pixels, samples and channels of |f(c̃ᵢ) − xᵢ| (0 for exact interpolation).
    degenerate : int
        Pixels whose system was singular (see :data:`RCOND_MIN`), solved by minimum-norm least
        squares.
    """
    centres = np.asarray(centres, np.float64)
    values = np.asarray(values, np.float64)
    count, n, _ = centres.shape
    coeffs = np.empty((count, n + 4, 3))
    lhs = np.zeros((n + 4, n + 4))
    rhs = np.zeros((n + 4, 3))
    residual, degenerate = 0.0, 0
    for p in range(count):
        c = centres[p]
        r = cdist(c, c)
        lam = smoothing * pixel_alpha(r) ** 2 if scale_invariant else smoothing
        lhs[:n, :n] = r * r * np.log(r, out=np.zeros_like(r), where=r > 0)  # φ(0) = 0
        lhs.flat[:n * (n + 5):n + 5] = lam  # the first n diagonal entries
        lhs[:n, n:n + 3] = c
        lhs[:n, n + 3] = 1.0
        lhs[n:, :n] = lhs[:n, n:].T
        rhs[:n] = values[p]
        # dgesv, not dgetrf + dgetrs: this OpenBLAS's dgetrs takes ~10 ms for three columns.
        lu, _, x, info = lapack.dgesv(lhs, rhs)
        if info == 0 and lapack.dgecon(lu, np.linalg.norm(lhs, 1), norm="1")[0] >= RCOND_MIN:
            residual += lam * float(np.abs(x[:n]).sum())  # f(c̃ᵢ) − xᵢ = −λ wᵢ
        else:
            x = lstsq(lhs, rhs, lapack_driver=LSTSQ_DRIVER)[0]
            residual += float(np.abs(lhs[:n] @ x - lam * x[:n] - values[p]).sum())
            degenerate += 1
        coeffs[p] = x
    return coeffs, residual, degenerate


def pixel_alpha(distances: np.ndarray) -> float:
    """α of the scale-invariant smoothing: the mean of a pixel's (n, n) centre distances, the zero
    diagonal included.

    >>> pixel_alpha(np.array([[0.0, 1.0], [1.0, 0.0]]))
    0.5
    """
    return float(distances.sum()) / distances.size


def _fit_task(task: tuple[np.ndarray, np.ndarray, float, bool]) -> tuple[np.ndarray, float, int]:
    """Worker entry point: :func:`fit_pixel_splines` on one chunk, coefficients as float32."""
    coeffs, residual, degenerate = fit_pixel_splines(*task)
    return coeffs.astype(np.float32), residual, degenerate


def fit_splines(centres: np.ndarray, values: np.ndarray, smoothing: float = SMOOTHING,
                workers: int | None = None, progress: bool = False, desc: str = "fit tps",
                scale_invariant: bool = False) -> tuple[np.ndarray, float, int]:
    """Fit one spline per pixel in a pool of worker processes.

    Pixels are split into tasks (see :data:`_TASK_SIZE`); each worker runs
    :func:`fit_pixel_splines` on one task at a time. Workers are forked on Linux (no re-import
    of torch); one worker runs in this process without a pool. OpenBLAS computes on one thread
    meanwhile (:func:`sim.blas.one_blas_thread`): its threads made a singular pixel's least squares
    4.9× slower on 2 free cores and 20-80× slower with another job beside, and gained nothing on a
    regular pixel (``benchmarks/tps.py``).

    Parameters
    ----------
    centres, values : numpy.ndarray
        (P, n, 3) per-pixel sample inputs (captured colours) and outputs (projector inputs).
    smoothing : float
        λ ≥ 0 added to the kernel diagonal.
    workers : int or None
        Worker processes; None uses one per usable core; never more than there are tasks.
    progress : bool
        Show a progress bar over pixels.
    desc : str
        Progress bar label.
    scale_invariant : bool
        λ·α² per pixel instead of λ (:func:`fit_pixel_splines`).

    Returns
    -------
    coeffs : numpy.ndarray
        float32 (P, n + 4, 3), as in :func:`fit_pixel_splines`.
    residual : float
        Mean |f(c̃ᵢ) − xᵢ| over pixels, samples and channels (projector input units).
    degenerate : int
        Pixels solved by least squares (singular system).

    Raises
    ------
    ValueError
        If the shapes differ or are not (P, n, 3) with n ≥ 4, or ``smoothing`` is negative.
    """
    if centres.shape != values.shape or centres.ndim != 3 or centres.shape[2] != 3 or centres.shape[1] < 4:
        raise ValueError(f"spline samples: expected centres and values of one shape (P, n ≥ 4, 3), "
                         f"got {centres.shape} and {values.shape}")
    if not smoothing >= 0:
        raise ValueError(f"spline smoothing = {smoothing!r}: expected a number >= 0")
    count, n, _ = centres.shape
    chunk = max(1, _TASK_SIZE // (n + 4) ** 2)
    tasks = ((centres[s:s + chunk], values[s:s + chunk], smoothing, scale_invariant)
             for s in range(0, count, chunk))
    workers = min(usable_cores() if workers is None else workers, -(-count // chunk))  # no idle worker
    coeffs = np.empty((count, n + 4, 3), np.float32)
    residual, degenerate, done = 0.0, 0, 0
    # one BLAS thread here and in the workers forked inside: each solve is too small to share
    with one_blas_thread(), tqdm(total=count, desc=desc, unit="px", disable=not progress) as bar:
        if workers <= 1:
            pool, results = None, map(_fit_task, tasks)
        else:
            method = "fork" if sys.platform.startswith("linux") else "spawn"
            pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context(method))
            results = pool.map(_fit_task, tasks)
        try:
            for part, res, deg in results:
                coeffs[done:done + len(part)] = part
                done += len(part)
                residual += res
                degenerate += deg
                bar.update(len(part))
        finally:
            if pool is not None:
                pool.shutdown(cancel_futures=True)
    return coeffs, residual / centres.size, degenerate


def evaluate_splines(points: torch.Tensor, centres: torch.Tensor, coeffs: torch.Tensor) -> torch.Tensor:
    """Evaluate per-pixel splines at per-pixel query colours.

    Parameters
    ----------
    points : torch.Tensor
        (P, m, 3) query colours per pixel.
    centres : torch.Tensor
        (P, n, 3) the spline centres c̃ᵢ of each pixel.
    coeffs : torch.Tensor
        (P, n + 4, 3) coefficients from :func:`fit_splines`; all three of one dtype and device.

    Returns
    -------
    torch.Tensor
        (P, m, 3) f(points), unclipped.
    """
    n = centres.shape[1]
    r = torch.cdist(points, centres, compute_mode="donot_use_mm_for_euclid_dist")
    out = torch.baddbmm(coeffs[:, n + 3:], points, coeffs[:, n:n + 3])
    return out.baddbmm_(torch.xlogy(r * r, r), coeffs[:, :n])


def _pixel_images(values: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """(H·W, N, 3) per-pixel values back to images (N, 3, H, W) (inverse of :func:`pixel_samples`)."""
    h, w = size
    return values.reshape(h, w, -1, 3).permute(2, 3, 0, 1)


@dataclass(frozen=True)
class TPSOptions(Options):
    """Options of ``tps`` (splines on the 125 plain colours)."""

    profiles = {name: dict(smoothing=PAPER_SMOOTHING, scale_invariant=True)
                for name in ("paper", "faithful")}
    """The paper's regularisation in the ``paper`` and ``faithful`` profiles."""

    smoothing: float = SMOOTHING
    """λ >= 0 added to the kernel diagonal (see :data:`SMOOTHING` for how 1e-2 was chosen; the
    paper and faithful profiles: :data:`PAPER_SMOOTHING`, scale-invariant)."""
    scale_invariant: bool = False
    """Multiply λ per pixel by α², α the mean distance between the pixel's captured colours
    (the regularisation of the reimplementation the paper's author points to; paper and faithful
    profiles)."""
    workers: int | None = None
    """Worker processes for the fit (>= 1); None: one per usable CPU core. Does not change results."""

    def check(self) -> None:
        self._number("smoothing", positive=False)
        self._require("scale_invariant", isinstance(self.scale_invariant, bool), "true or false")
        self._positive_ints("workers")

    def label(self) -> str:
        """The smoothing as Table 1 names it: ``λ = 0.01`` or ``λ = 0.0347·α²``."""
        return f"λ = {self.smoothing:.3g}" + ("·α²" if self.scale_invariant else "")

    def tag(self) -> str:
        """The smoothing in the official tag: ``lambda0.01`` or ``lambda0.0347alpha2``."""
        return f"lambda{self.smoothing:.3g}" + ("alpha2" if self.scale_invariant else "")


@dataclass(frozen=True)
class TPSTexturedOptions(TPSOptions):
    """Options of ``tps-textured`` (splines on the textured training pairs)."""

    smoothing: float = SMOOTHING_TEXTURED
    """λ >= 0 added to the kernel diagonal (see :data:`SMOOTHING_TEXTURED`; the paper and faithful
    profiles: :data:`PAPER_SMOOTHING`, scale-invariant)."""
    max_samples: int = MAX_SAMPLES
    """Most sample pairs per pixel (>= 4; the paper's 500 training pairs); more pairs are
    subsampled at random (seeded), the same for every pixel."""

    def check(self) -> None:
        super().check()
        self._require("max_samples", isinstance(self.max_samples, int) and self.max_samples >= 4,
                      "an integer >= 4")


class TPSMethod(Method):
    """Per-pixel RGB thin-plate splines fitted on the 125 plain-colour pairs (``data.ref``).

    Parameters
    ----------
    device : str
        Torch device for prediction (``"auto"``: CUDA if available); ``fit`` uses the config's.
    """

    name = "tps"
    official_name = "TPS"
    options = TPSOptions
    state_file = STATE_FILE
    plain_colours = True

    @classmethod
    def seeded(cls, cfg: TrainConfig) -> bool:
        """Every pixel's spline through the 125 plain colours, solved exactly: no seed."""
        return False

    def __init__(self, device: str = "auto"):
        self.device = resolve_device(device)
        self.smoothing: float | None = None
        self.size: tuple[int, int] | None = None
        self.centres: torch.Tensor | None = None
        self.coeffs: torch.Tensor | None = None

    def training_pairs(self, data: SetupData, cfg: TrainConfig) -> PairSet:
        """The sample pairs of every pixel's spline: the 125 plain colours (not the gray frame)."""
        return plain_colour_pairs(data, self.name)

    def fit(self, data: SetupData, cfg: TrainConfig, progress: bool = True,
            checkpoint: Path | None = None) -> FitResult:
        """Fit every pixel's spline on :meth:`training_pairs`.

        Returns
        -------
        FitResult
            ``final_loss`` is the mean |f(c̃ᵢ) − xᵢ| at the samples (nonzero only through
            smoothing), ``batch`` the samples per pixel, ``extra["degenerate_pixels"]`` the pixels
            whose samples could not determine a spline.
        """
        pairs = self.training_pairs(data, cfg)
        if len(pairs) < 4:
            raise ProcamError(f"{self.name}: {len(pairs)} sample pairs per pixel; a spline with its "
                              "affine part needs at least 4 (use more training pairs)")
        self.device = resolve_device(cfg.device)
        self.smoothing = float(cfg.options.smoothing)
        start = time.perf_counter()
        centres = pixel_samples(pairs.captures)
        coeffs, residual, degenerate = fit_splines(centres, pixel_samples(pairs.frames), self.smoothing,
                                                   cfg.options.workers, progress,
                                                   fit_label(data.name, self.name, cfg.seed, len(pairs)),
                                                   cfg.options.scale_invariant)
        seconds = time.perf_counter() - start
        self._set_state(tuple(pairs.captures.shape[-2:]), torch.from_numpy(centres),
                        torch.from_numpy(coeffs))
        return FitResult(seconds, len(pairs) / seconds, residual, len(pairs), [(1, residual, 0.0)],
                         {"degenerate_pixels": degenerate})

    def _set_state(self, size: tuple[int, int], centres: torch.Tensor, coeffs: torch.Tensor) -> None:
        self.size = size
        self.centres = centres.to(self.device, torch.float32)
        self.coeffs = coeffs.to(self.device, torch.float32)

    @torch.no_grad()
    def predict(self, captures: torch.Tensor, surface: torch.Tensor, batch_size: int = 64) -> torch.Tensor:
        if self.centres is None:
            raise ProcamError(f"{self.name}: predict called before fit or load")
        if captures.ndim != 4 or captures.shape[1] != 3 or tuple(captures.shape[-2:]) != self.size:
            raise ProcamError(f"{self.name}: captures of shape {tuple(captures.shape)}; the splines were "
                              f"fitted for (N, 3, {self.size[0]}, {self.size[1]})")
        count, n = self.centres.shape[:2]
        out = []
        for i in range(0, captures.shape[0], batch_size):
            batch = captures[i:i + batch_size].to(self.device, torch.float32)
            points = batch.permute(2, 3, 0, 1).reshape(count, batch.shape[0], 3)
            chunk = max(1, _EVAL_ELEMENTS // (batch.shape[0] * n))
            frames = torch.cat([
                evaluate_splines(points[s:s + chunk], self.centres[s:s + chunk], self.coeffs[s:s + chunk])
                for s in range(0, count, chunk)])
            out.append(_pixel_images(frames.clamp_(0.0, 1.0), self.size).cpu())
        return torch.cat(out).contiguous()

    def save(self, run_dir: Path) -> None:
        if self.centres is None:
            raise ProcamError(f"{self.name}: nothing to save before fit or load")
        np.savez(Path(run_dir) / STATE_FILE, centres=self.centres.cpu().numpy(),
                 coeffs=self.coeffs.cpu().numpy(), size=np.array(self.size, np.int64),
                 smoothing=np.float64(self.smoothing))

    @classmethod
    def load(cls, run_dir: Path, device: str = "auto") -> TPSMethod:
        """Restore a fitted method from ``run_dir/tps.npz``.

        Raises
        ------
        ProcamError
            If the file is missing, unreadable, holds pickled objects, or its arrays are missing
            or of inconsistent shapes.
        """
        path = Path(run_dir) / STATE_FILE
        state = load_arrays(path, ("centres", "coeffs", "size", "smoothing"), "spline state")
        centres, coeffs, size = state["centres"], state["coeffs"], state["size"]
        if (size.shape != (2,) or centres.ndim != 3 or centres.shape[2] != 3
                or centres.shape[0] != int(np.prod(size))
                or coeffs.shape != (centres.shape[0], centres.shape[1] + 4, 3)):
            raise ProcamError(f"{path}: inconsistent shapes: centres {centres.shape}, coeffs "
                              f"{coeffs.shape}, size {size.tolist()}; expected (H·W, n, 3), "
                              "(H·W, n + 4, 3), [H, W]")
        method = cls(device)
        method.smoothing = float(state["smoothing"])
        method._set_state((int(size[0]), int(size[1])), torch.from_numpy(centres),
                          torch.from_numpy(coeffs))
        return method


class TPSTexturedMethod(TPSMethod):
    """Per-pixel RGB thin-plate splines fitted on the textured training pairs (``data.train``).

    Every pixel's spline takes its n samples from the n training pairs (cfg.n_train as loaded), an
    (n + 4)² system per pixel, so the fit costs O(n³) per pixel. Measured with 2 worker processes on
    2 shared CPU cores: n = 500: 24 s at 64², 113 s at 128² (load ≈ 5, φ = r and no condition
    estimate yet; 51 s and 271 s at load ≈ 8 with both), extrapolated 8–18 min at 256²; n = 250: 5.6
    s / 21 s at 64² / 128² (12 s / 43 s at load ≈ 8). The fitted state (centres and coefficients,
    float32) is 24·n bytes per pixel: 0.8 GB at 256² with n = 500. Slow on 2 cores but not
    prohibitive (the paper profile is meant for a machine with more cores or a GPU; the workers
    scale with the cores), so all pairs up to :data:`MAX_SAMPLES` = 500 are used; with more training
    pairs the spline takes a random subset of ``max_samples`` of them (seeded by cfg.seed), the same
    for every pixel. On simulated pixels (see :data:`SMOOTHING`), 500 instead of 250 samples gained
    0.3 dB PSNR with sensor noise and 1.5 dB without.

    """

    name = "tps-textured"
    official_name = "TPS_textured"
    options = TPSTexturedOptions
    plain_colours = False

    @classmethod
    def seeded(cls, cfg: TrainConfig) -> bool:
        """The seed picks the subset of the pairs only where there are more than ``max_samples``."""
        return cfg.n_train > cfg.options.max_samples

    def training_pairs(self, data: SetupData, cfg: TrainConfig) -> PairSet:
        """All training pairs, or a seeded random subset of ``max_samples`` of them (sorted)."""
        n, most = len(data.train), cfg.options.max_samples
        if n <= most:
            return data.train
        order = torch.randperm(n, generator=torch.Generator().manual_seed(cfg.seed))
        keep = order[:most].sort().values
        return PairSet(data.train.captures[keep], data.train.frames[keep])
