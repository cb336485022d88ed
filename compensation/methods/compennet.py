"""CompenNet (Huang & Ling, CVPR 2019) in the official layout, with and without the surface branch.

The network maps a camera-captured image x̃, warped to the canonical projector view, to the projector
input that produced it (the inverse of the projector–camera process). The surface branch encodes the
surface image s̃ (the capture of a plain projector frame) into four feature maps that are added to the
backbone's first four convolutions. Layer names follow the official code, so state dicts are
recognisable: ``conv1``…``conv6``, ``transConv1``/``transConv2``, ``conv1_s``…``conv4_s`` and
``skipConv1``…``skipConv3``. Parameters: 1,124,479 with the surface branch, 736,063 without.

=====================  ==================================================
Layer                  Shape
=====================  ==================================================
conv1 / conv1_s        Conv 3→32, 3×3, stride 2, padding 1
conv2 / conv2_s        Conv 32→64, 3×3, stride 2, padding 1
conv3 / conv3_s        Conv 64→128, 3×3, stride 1, padding 1
conv4 / conv4_s        Conv 128→256, 3×3, stride 1, padding 1
conv5                  Conv 256→128, 3×3, stride 1, padding 1
transConv1             ConvTranspose 128→64, 2×2, stride 2
transConv2             ConvTranspose 64→32, 2×2, stride 2
conv6                  Conv 32→3, 3×3, stride 1, padding 1
skipConv1              3 × [Conv 3→3, 3×3, padding 1; ReLU]
skipConv2              Conv 32→64, 1×1
skipConv3              Conv 64→128, 1×1
=====================  ==================================================

Training is the paper's recipe, :func:`fit_network` (Adam, step decay, ℓ1 + (1 − SSIM) by
default, optional patch windows), run by the generic loop of :mod:`compensation.training.loop`.
"""

from __future__ import annotations

import warnings
from contextlib import nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar, Literal

import torch
from torch import Tensor, nn

from compensation.methods.base import (CHECKPOINT, FitResult, Method, flush_denormals, load_weights,
                                       resolve_device, save_state, weights_file)
from compensation.scores.losses import LOSSES, get_loss
from compensation.training.config import MAX_ITERS, Options, TrainConfig
from compensation.training.conv_grad import faster_backward
from compensation.training.loop import CropSampler, fit_label, train_loop
from sim.errors import ProcamError

if TYPE_CHECKING:
    from compensation.data import SetupData

SurfaceFeatures = tuple[Tensor, Tensor, Tensor, Tensor]
"""The ReLU outputs of ``conv1_s``…``conv4_s`` (res1_s…res4_s), each (B, C, h, w) with B = 1 or N."""


def count_parameters(model: nn.Module) -> int:
    """Number of trainable parameters (weights and biases) of ``model``.

    Examples
    --------
    >>> count_parameters(CompenNet(surface=True)), count_parameters(CompenNet(surface=False))
    (1124479, 736063)
    """
    return sum(p.numel() for p in model.parameters() if p.requires_grad)


SIZE_MULTIPLE = 4
"""Image sides must be multiples of this (conv1 and conv2 halve the image, transConv1 and
transConv2 double it back)."""
LR_STEP_SHARE = 0.8
"""Share of the iterations after which the learning rate steps where ``lr_step`` is not given
(the paper: 800 of 1000)."""
ONE_CYCLE = dict(pct_start=0.3, div_factor=10.0, final_div_factor=100.0)
"""The ``one-cycle`` schedule: the share of the steps spent rising, the start's and the end's
divisors (start ``lr`` / 10, end ``lr`` / 10 / 100), as :class:`torch.optim.lr_scheduler.OneCycleLR`
takes them."""


def _check_images(name: str, t: Tensor) -> None:
    """Raise ``ValueError`` unless ``t`` is an (N, 3, H, W) tensor with H and W divisible by 4."""
    if not isinstance(t, Tensor):
        raise ValueError(f"CompenNet: {name} must be a torch.Tensor, got {type(t).__name__}")
    if t.ndim != 4:
        raise ValueError(f"CompenNet: {name} must have shape (N, 3, H, W), got {tuple(t.shape)} "
                         f"({t.ndim} dimensions)")
    if t.shape[1] != 3:
        raise ValueError(f"CompenNet: {name} must be RGB with 3 channels, got {t.shape[1]} channels "
                         f"in shape {tuple(t.shape)}")
    h, w = t.shape[2:]
    if h % SIZE_MULTIPLE or w % SIZE_MULTIPLE or h == 0 or w == 0:
        raise ValueError(f"CompenNet: {name} height and width must be positive multiples of 4, "
                         f"got {h}x{w} (H x W)")


def sum_over_batch(t: Tensor) -> Tensor:
    """Sum of ``t`` (N, C, H, W) over its batch, (1, C, H, W) in ``t``'s memory layout.

    In the default and the channels-last layout each sample is one contiguous block, so the sum
    is one reduction over N rows of C·H·W values; ``t.sum(0, keepdim=True)`` on a channels-last
    tensor measured 8-11× slower on the CPU. The sums are the same to float rounding.

    Examples
    --------
    >>> t = torch.rand(4, 8, 5, 6).contiguous(memory_format=torch.channels_last)
    >>> s = sum_over_batch(t)
    >>> s.shape, s.is_contiguous(memory_format=torch.channels_last)
    (torch.Size([1, 8, 5, 6]), True)
    >>> torch.allclose(s, t.sum(0, keepdim=True))
    True
    """
    n, c, h, w = t.shape
    if _in_channels_last(t):
        return t.permute(0, 2, 3, 1).reshape(n, -1).sum(0).view(1, h, w, c).permute(0, 3, 1, 2)
    return t.reshape(n, -1).sum(0).view(1, c, h, w)


class _AddSurface(torch.autograd.Function):
    """``t + f`` for a surface feature ``f`` of batch 1 broadcast over ``t``'s batch; ``f``'s
    gradient is :func:`sum_over_batch` of the output's."""

    @staticmethod
    def forward(ctx, t: Tensor, f: Tensor) -> Tensor:
        return t + f

    @staticmethod
    def backward(ctx, grad: Tensor) -> tuple[Tensor, Tensor | None]:
        return grad, sum_over_batch(grad) if ctx.needs_input_grad[1] else None


def _add_surface(t: Tensor, f: Tensor | int) -> Tensor:
    """``t + f``: a backbone convolution's output plus its surface term (0 without the branch)."""
    if isinstance(f, Tensor) and f.shape[0] == 1 < t.shape[0]:
        return _AddSurface.apply(t, f)
    return t + f


class CompenNet(nn.Module):
    """CompenNet, optionally without the surface branch ("CompenNet w/o surf").

    Parameters
    ----------
    surface : bool
        Build the surface branch ``conv1_s``…``conv4_s`` (1,124,479 parameters); without it the
        network has 736,063 parameters and ignores any surface input.

    Notes
    -----
    As in the official code, Conv2d weights get Kaiming-normal initialisation (seed with
    :func:`torch.manual_seed` for a reproducible network); transposed convolutions and all biases
    keep PyTorch's default initialisation. The same seed gives the official network's initial
    weights (the layers are created and initialised in its order).
    """

    def __init__(self, surface: bool = True):
        super().__init__()
        self.surface = surface
        self.relu = nn.ReLU(inplace=True)  # every input is a fresh sum or convolution output

        # The layers are created in the official code's order, so that one seed gives the official
        # network's initial weights (each layer draws its default initialisation when created).
        self.conv1 = nn.Conv2d(3, 32, 3, 2, 1)
        self.conv2 = nn.Conv2d(32, 64, 3, 2, 1)
        self.conv3 = nn.Conv2d(64, 128, 3, 1, 1)
        self.conv4 = nn.Conv2d(128, 256, 3, 1, 1)
        self.conv5 = nn.Conv2d(256, 128, 3, 1, 1)

        if surface:
            self.conv1_s = nn.Conv2d(3, 32, 3, 2, 1)
            self.conv2_s = nn.Conv2d(32, 64, 3, 2, 1)
            self.conv3_s = nn.Conv2d(64, 128, 3, 1, 1)
            self.conv4_s = nn.Conv2d(128, 256, 3, 1, 1)

        self.transConv1 = nn.ConvTranspose2d(128, 64, 2, 2, 0)
        self.transConv2 = nn.ConvTranspose2d(64, 32, 2, 2, 0)
        self.conv6 = nn.Conv2d(32, 3, 3, 1, 1)

        self.skipConv1 = nn.Sequential(
            nn.Conv2d(3, 3, 3, 1, 1), self.relu,
            nn.Conv2d(3, 3, 3, 1, 1), self.relu,
            nn.Conv2d(3, 3, 3, 1, 1), self.relu,
        )
        self.skipConv2 = nn.Conv2d(32, 64, 1, 1, 0)
        self.skipConv3 = nn.Conv2d(64, 128, 1, 1, 0)

        for m in self.modules():
            if type(m) is nn.Conv2d:  # Conv2d only, as the official code (not ConvTranspose2d)
                nn.init.kaiming_normal_(m.weight)

    def surface_features(self, s: Tensor) -> SurfaceFeatures:
        """Encode the surface image(s) s̃ with the surface branch.

        The result depends only on s̃ and the weights: compute it once and pass it to
        :meth:`forward` as ``features`` for every batch (e.g. at inference, under
        :func:`torch.no_grad`). During training, pass ``s`` to :meth:`forward` instead so that the
        surface branch receives gradients.

        Parameters
        ----------
        s : Tensor
            Surface image(s), (1, 3, H, W) or (N, 3, H, W), float in [0, 1]; H and W multiples of 4.

        Returns
        -------
        tuple of 4 Tensor
            res1_s (B, 32, H/2, W/2), res2_s (B, 64, H/4, W/4), res3_s (B, 128, H/4, W/4),
            res4_s (B, 256, H/4, W/4), with B the batch of ``s``.

        Raises
        ------
        ValueError
            If the network has no surface branch or ``s`` has a bad shape.
        """
        if not self.surface:
            raise ValueError("CompenNet(surface=False) has no surface branch; surface_features "
                             "needs CompenNet(surface=True)")
        _check_images("surface s", s)
        res1_s = self.relu(self.conv1_s(s))
        res2_s = self.relu(self.conv2_s(res1_s))
        res3_s = self.relu(self.conv3_s(res2_s))
        res4_s = self.relu(self.conv4_s(res3_s))
        return res1_s, res2_s, res3_s, res4_s

    def forward(self, x: Tensor, s: Tensor | None = None,
                features: SurfaceFeatures | None = None) -> Tensor:
        """Infer the projector input π†(x̃) from camera captures x̃.

        Parameters
        ----------
        x : Tensor
            Camera captures warped to the projector view, (N, 3, H, W), float in [0, 1]; H and W
            must be multiples of 4.
        s : Tensor, optional
            Surface image s̃, (1, 3, H, W) — the same surface for the whole batch, encoded once and
            broadcast — or (N, 3, H, W), one per sample. With ``surface=True`` exactly one of ``s``
            and ``features`` is required; with ``surface=False`` both are ignored, so callers may
            pass the same arguments to either variant.
        features : tuple of 4 Tensor, optional
            The output of :meth:`surface_features` for the same H and W, with batch 1 or N.

        Returns
        -------
        Tensor
            (N, 3, H, W) projector input, in [0, 1] (ReLU below, clamp at 1 above).

        Raises
        ------
        ValueError
            On a bad shape of ``x``, ``s`` or ``features``, a spatial size mismatch between them,
            or a missing / doubly given surface input for ``surface=True``.
        """
        _check_images("input x", x)
        # Without the surface branch the surface terms are zero (adding 0 leaves the values as is).
        res_s = self._surface_terms(x, s, features) if self.surface else (0, 0, 0, 0)
        res1 = self.skipConv1(x)
        x = self.relu(_add_surface(self.conv1(x), res_s[0]))
        res2 = self.skipConv2(x)
        x = self.relu(_add_surface(self.conv2(x), res_s[1]))
        res3 = self.skipConv3(x)
        x = self.relu(_add_surface(self.conv3(x), res_s[2]))
        x = self.relu(_add_surface(self.conv4(x), res_s[3]))
        x = self.relu(self.conv5(x) + res3)
        x = self.relu(self.transConv1(x) + res2)
        x = self.relu(self.transConv2(x))
        return torch.clamp(self.relu(self.conv6(x) + res1), max=1)

    def _surface_terms(self, x: Tensor, s: Tensor | None,
                       features: SurfaceFeatures | None) -> SurfaceFeatures:
        """Surface features for ``forward``: from ``s`` or checked ``features``, batch 1 or N."""
        n, _, h, w = x.shape
        if (s is None) == (features is None):
            raise ValueError("CompenNet(surface=True): pass exactly one of the surface image s "
                             "(1 or N, 3, H, W) and its cached surface_features(s) "
                             f"(got s={'None' if s is None else 'a tensor'}, "
                             f"features={'None' if features is None else 'given'})")
        if s is not None:
            _check_images("surface s", s)
            if s.shape[2:] != x.shape[2:] or s.shape[0] not in (1, n):
                raise ValueError(f"CompenNet: surface s has shape {tuple(s.shape)}; expected "
                                 f"(1, 3, {h}, {w}) or ({n}, 3, {h}, {w}) to match input x "
                                 f"{tuple(x.shape)}")
            return self.surface_features(s)
        expected = [(32, h // 2, w // 2), (64, h // 4, w // 4), (128, h // 4, w // 4),
                    (256, h // 4, w // 4)]
        shapes = [tuple(f.shape) for f in features] if isinstance(features, (tuple, list)) else None
        if (shapes is None or len(shapes) != 4
                or any(len(got) != 4 or got[0] not in (1, n) or got[1:] != want
                       for got, want in zip(shapes, expected))):
            raise ValueError(f"CompenNet: features must be surface_features(s) of a (1 or {n}, 3, "
                             f"{h}, {w}) surface, i.e. 4 tensors of shapes (1 or {n}, C, h, w) "
                             f"with (C, h, w) = {expected}; got {shapes or type(features).__name__}")
        return tuple(features)


@dataclass(frozen=True)
class CompenNetOptions(Options):
    """Training options of CompenNet (with or without the surface branch): the paper's recipe."""

    iters: int = 1000
    """Optimiser steps (1 to :data:`~compensation.training.config.MAX_ITERS`; paper 1000)."""
    batch: int = 64
    """Training pairs per step (>= 1, at most the training pairs are used; paper 64)."""
    lr: float = 1e-3
    """Adam learning rate (> 0; paper 1e-3)."""
    weight_decay: float = 1e-4
    """Adam L2 weight decay (>= 0; paper 1e-4)."""
    lr_schedule: Literal["step", "one-cycle"] = "step"
    """How the learning rate moves: ``step`` (paper), multiplied by ``lr_gamma`` every ``lr_step``
    steps; ``one-cycle``, from ``lr`` / 10 up to ``lr`` over the first 30 % of the steps, then
    down to ``lr`` / 1000 at the last, both along a half cosine (:data:`ONE_CYCLE`; it reaches a
    given PSNR in fewer steps at a higher ``lr``, ``benchmarks/results/patches``)."""
    lr_step: int | None = None
    """With the ``step`` schedule, multiply the learning rate by ``lr_gamma`` every this many steps
    (>= 1; paper 800). Not given: after 80 % of ``iters`` (:data:`LR_STEP_SHARE`, the paper's 800
    of 1000, at any iteration count), resolved when the options are made
    (``dataclasses.replace`` of ``iters`` alone keeps the resolved step). None with
    ``one-cycle``."""
    lr_gamma: float = 0.2
    """With the ``step`` schedule, the learning-rate decay factor (> 0; paper 0.2)."""
    loss: Literal["l1", "l2", "ssim", "l1+ssim", "l1+l2", "l2+ssim", "l1+l2+ssim"] = "l1+ssim"
    """Training loss (paper ``l1+ssim``: ℓ1 + (1 − SSIM); CompenHR ``l1+l2+ssim``)."""
    sampler: Literal["epoch", "random"] = "epoch"
    """Batch order: ``epoch`` (a seeded permutation per epoch, every pair once per epoch) or
    ``random`` (a fresh random batch each iteration, as the official code draws them)."""
    amp: bool = False
    """Mixed precision: the network's forward pass under bf16 autocast (on the CPU, and on CUDA
    where the GPU supports bf16; fp16 with a gradient scaler on older GPUs), weights, optimiser
    and loss in float32 (paper: off). On a CPU with native bf16 (AVX-512 BF16 or AMX) a step
    is about 1.7× as fast (``benchmarks/train.py --amp-ab``). The trained network also predicts
    under it (``benchmarks/predict.py``)."""
    init: str | None = None
    """Run directory, or state dict file (``.pth``, e.g. an official CompenNet checkpoint, with or
    without DataParallel's ``module.`` prefix), whose weights initialise the network (pre-training;
    same architecture)."""
    patch: int = 0
    """Patch training: side in pixels of the random square window that every step cuts out of its
    batch's captures, frames and surface alike (the same window for all three, so the pixel
    correspondence is kept; the network is fully convolutional). 0 trains on the full images
    (paper). Otherwise a multiple of :data:`SIZE_MULTIPLE` (the network halves the image twice
    and doubles it back), at most the image's shorter side; the windows are seeded by the
    training seed."""

    profiles: ClassVar[dict[str, dict]] = {
        "paper": {},
        # CPU-sized: CompenNet trained at 40-54 samples/s at 64² on 2 free cores at batch 8 or
        # 16 when these settings were chosen, ~17 at 128², ~3.7 at 256² (benchmarks/train.py);
        # the current training step: ~146 at 64² (the demo), 50-56 at 128², 13-15 at
        # 256² (benchmarks/results/train). On the default setup at 64² (250 training / 100 test pairs;
        # benchmarks/results/patches/README.md) iterations count more than the batch: mean test
        # PSNR of seeds 0 and 1 after 500 iterations is 23.45 dB at batch 16 (~170 s) and
        # 23.30 dB at batch 8 (~100 s); 250 iterations at batch 16 give 22.51 dB in ~90 s.
        # So 500 iterations of batch 8.
        "quick": dict(iters=500, batch=8),
        # The paper's 256² on 2 CPU cores: training on 64-pixel windows of the 256² images. On
        # the paper suite's light1_pos1_squares at 256² as shipped (125 / 100 pairs;
        # benchmarks/results/patches/README.md) the paper's full-image recipe (1000 iterations
        # of 64, ~2 h on 2 cores) scores 27.78 dB; 64² windows at batch 16 with the paper's step
        # schedule reach 26.29, 27.22 and 27.79 dB after 2000, 4000 and 6000 iterations (4.9,
        # 9.2 and 13.7 min in float32). bf16 autocast learns the same (26.29 dB at 2000, 0.12
        # dB lower at 6000) 1.7× as fast on a CPU with native bf16; one-cycle at lr 2e-3 reaches
        # 27.45 and 27.54 dB after 4400 and 5000 iterations (3e-3: 27.36 and 27.34). So 5000
        # iterations, one-cycle at 2e-3, in bf16: 0.24 dB below the paper's recipe.
        "faithful": dict(patch=64, iters=5000, batch=16, lr=2e-3, lr_schedule="one-cycle", amp=True),
    }

    implied: ClassVar[dict[str, dict]] = {"lr_step": {"lr_schedule": "step"},
                                          "lr_gamma": {"lr_schedule": "step"}}
    """An explicit ``lr_step`` or ``lr_gamma`` selects the step schedule over a profile's."""

    def __post_init__(self):
        if (self.lr_step is None and self.lr_schedule == "step" and isinstance(self.iters, int)
                and self.iters >= 1):
            object.__setattr__(self, "lr_step", max(1, round(LR_STEP_SHARE * self.iters)))
        super().__post_init__()

    def check(self) -> None:
        self._positive_ints("iters", most=MAX_ITERS)
        self._positive_ints("batch", "lr_step")
        for name in ("lr", "lr_gamma"):
            self._number(name, positive=True)
        self._number("weight_decay", positive=False)
        self._require("lr_schedule", self.lr_schedule in ("step", "one-cycle"), "'step' or 'one-cycle'")
        if self.lr_schedule == "one-cycle":
            self._require("lr_step", self.lr_step is None, "none with lr_schedule one-cycle (a "
                          "step of the step schedule)")
            self._require("lr_gamma", self.lr_gamma == CompenNetOptions.lr_gamma, "the default "
                          "with lr_schedule one-cycle (a factor of the step schedule)")
        self._require("loss", self.loss in LOSSES, f"one of {', '.join(LOSSES)}")
        self._require("sampler", self.sampler in ("epoch", "random"), "'epoch' or 'random'")
        self._require("amp", isinstance(self.amp, bool), "true or false")
        self._optional_path("init")
        self._require("patch", isinstance(self.patch, int) and not isinstance(self.patch, bool)
                      and self.patch >= 0 and self.patch % SIZE_MULTIPLE == 0,
                      f"0 (full images) or a positive multiple of {SIZE_MULTIPLE} (pixels)")


class CompenNetMethod(Method):
    """CompenNet (Huang & Ling, CVPR 2019) with the surface branch fed s̃, trained end to end.

    Parameters
    ----------
    device : str
        Torch device for prediction (``"auto"``: CUDA if available); ``fit`` uses the config's.
    """

    name = "compennet"
    official_name = "CompenNet"
    options = CompenNetOptions
    surface = True
    """The network has the surface branch (fed s̃)."""

    def __init__(self, device: str = "auto"):
        self.device = resolve_device(device)
        self.model: CompenNet | None = None
        self.amp = False
        """Predict under autocast, as the network was trained with its ``amp`` option (bf16 on
        the CPU and on GPUs that support it, else fp16: :func:`forward_dtype` of the prediction
        device); ``benchmarks/predict.py`` measures time and scores against float32."""
        self.layout = torch.channels_last
        """The memory layout the network predicts in: channels-last, oneDNN's native layout on the
        CPU and the tensor cores' on CUDA (the values are the default layout's to float rounding;
        ``benchmarks/predict.py`` measures both)."""

    @classmethod
    def check_image_size(cls, options: CompenNetOptions, width: int, height: int) -> None:
        """Raise :class:`ProcamError` if the patch window is wider than the images' shorter side."""
        if options.patch > min(width, height):
            raise ProcamError(f"option patch = {options.patch}: expected at most the images' shorter "
                              f"side, {min(width, height)} pixels ({width}x{height} W x H), or 0 for "
                              "full images")

    def fit(self, data: SetupData, cfg: TrainConfig, progress: bool = True,
            checkpoint: Path | None = None) -> FitResult:
        self.device = resolve_device(cfg.device)
        try:
            self.check_image_size(cfg.options, data.size[1], data.size[0])
        except ProcamError as exc:
            raise ProcamError(f"{data.name}: {exc}") from None
        torch.manual_seed(cfg.seed)  # He init of the new network is seeded
        model = CompenNet(surface=self.surface)
        if cfg.options.init is not None:
            load_weights(model, weights_file(cfg.options.init), self.name)
        self.model = model.to(self.device)
        self.amp = cfg.options.amp
        return fit_network(self.model, data, cfg, self.surface, progress, checkpoint)

    def predict(self, captures: torch.Tensor, surface: torch.Tensor, batch_size: int = 64) -> torch.Tensor:
        """π†(x̃) for ``captures`` given the surface image, in :attr:`layout` under the precision of
        :attr:`amp`; the network is left in the memory layout it had."""
        if self.model is None:
            raise ProcamError(f"{self.name}: predict called before fit or load")
        layout = self.layout
        was_channels_last = _in_channels_last(self.model.conv1.weight)
        before = torch.channels_last if was_channels_last else torch.contiguous_format
        self.model.eval().to(memory_format=layout)
        try:
            with torch.no_grad(), computing_in(forward_dtype(self.device, self.amp, self.name), self.device):
                features = (self.model.surface_features(surface.to(self.device, memory_format=layout))
                            if self.surface else None)
                out = [self.model(captures[i:i + batch_size].to(self.device, memory_format=layout),
                                  features=features).float().cpu()
                       for i in range(0, captures.shape[0], batch_size)]
        finally:
            self.model.to(memory_format=before)
        return torch.cat(out).contiguous()

    def adopt_options(self, recorded: dict) -> None:
        """Predict in the precision the network was trained in (the recorded ``amp``; off when
        not recorded)."""
        amp = recorded.get("amp", False)
        if not isinstance(amp, bool):
            raise ProcamError(f"option amp = {amp!r}: expected true or false")
        self.amp = amp

    def save(self, run_dir: Path) -> None:
        if self.model is None:
            raise ProcamError(f"{self.name}: nothing to save before fit or load")
        save_state(self.model, Path(run_dir) / CHECKPOINT)

    @classmethod
    def load(cls, run_dir: Path, device: str = "auto") -> CompenNetMethod:
        return cls.from_weights(Path(run_dir) / CHECKPOINT, device)

    @classmethod
    def from_weights(cls, path: Path, device: str = "auto") -> CompenNetMethod:
        """A fitted CompenNet from a state dict file (a run's ``model.pt`` or an official ``.pth``).

        Raises
        ------
        ProcamError
            If the file is missing, unreadable or does not fit the architecture.
        """
        method = cls(device)
        model = CompenNet(surface=cls.surface)
        load_weights(model, Path(path), cls.name)
        method.model = model.to(method.device)
        return method


class CompenNetNoSurfMethod(CompenNetMethod):
    """CompenNet without the surface branch ("CompenNet w/o surf" of the paper)."""

    name = "compennet-nosurf"
    official_name = "CompenNet_wo_surf"
    surface = False

def autocast_dtype(device: torch.device) -> torch.dtype:
    """Mixed-precision type on ``device``: bf16 on the CPU and on GPUs that support it (no scaler
    needed), else fp16."""
    if device.type == "cuda" and not torch.cuda.is_bf16_supported():
        return torch.float16
    return torch.bfloat16


def native_bf16() -> bool:
    """Whether this CPU computes bf16 natively (AVX-512 BF16 or AMX), as oneDNN reports it."""
    return torch.ops.mkldnn._is_mkldnn_bf16_supported()


def forward_dtype(device: torch.device, amp: bool, label: str) -> torch.dtype:
    """The type a CompenNet forward pass computes in on ``device``: :func:`autocast_dtype` with
    ``amp`` on the CPU and CUDA, else float32. Warns, naming ``label``, where ``amp`` on this CPU
    would emulate bf16 (no AVX-512 BF16 or AMX), which may run slower than float32.

    >>> forward_dtype(torch.device("cpu"), False, "run"), forward_dtype(torch.device("mps"), True, "run")
    (torch.float32, torch.float32)
    """
    if not amp or device.type not in ("cpu", "cuda"):
        return torch.float32
    if device.type == "cpu" and not native_bf16():
        warnings.warn(f"{label}: amp computes in bf16, for which this CPU has no native support "
                      "(AVX-512 BF16 or AMX): it may train and predict slower than in float32 "
                      "(--no-amp)", stacklevel=3)
    return autocast_dtype(device)


def computing_in(dtype: torch.dtype, device: torch.device) -> torch.autocast:
    """The autocast context of a forward pass computing in ``dtype`` (:func:`forward_dtype`) on
    ``device``; disabled for float32.

    >>> with computing_in(torch.bfloat16, torch.device("cpu")):
    ...     torch.nn.functional.conv2d(torch.ones(1, 1, 2, 2), torch.ones(1, 1, 1, 1)).dtype
    torch.bfloat16
    >>> with computing_in(torch.float32, torch.device("cpu")):
    ...     torch.nn.functional.conv2d(torch.ones(1, 1, 2, 2), torch.ones(1, 1, 1, 1)).dtype
    torch.float32
    """
    return torch.autocast(device.type, dtype=dtype, enabled=dtype != torch.float32)


def fit_network(model: torch.nn.Module, data: SetupData, cfg: TrainConfig, use_surface: bool,
                progress: bool = True, checkpoint: Path | None = None) -> FitResult:
    """Train a CompenNet-style ``model`` (already on its device) on ``data.train``: the paper's recipe.

    Adam(lr, weight_decay), the learning-rate schedule of ``cfg.options.lr_schedule`` (the
    paper's: StepLR(lr_step, lr_gamma)), batches as ``cfg.options.sampler``
    draws them, the loss named by ``cfg.options.loss``; with ``use_surface`` the network's surface
    branch is fed s̃ with batch 1, broadcast over the batch (computed once per batch, not once per
    sample). With ``cfg.options.patch`` > 0 every step trains on one random window of that side cut
    out of the batch's captures, frames and the surface alike (:class:`CropSampler`). With
    ``cfg.options.amp`` the forward pass runs under autocast (:func:`forward_dtype`; a gradient
    scaler for fp16 only).

    The network and the images are kept in the channels-last memory layout while training
    (oneDNN's native layout on the CPU, ``benchmarks/train.py`` measures its effect; the layout of
    CUDA's tensor-core convolutions); the values are those of the default layout to float
    rounding, and the model is returned in the default layout, its subnormal weights set to zero
    (:func:`~compensation.methods.base.flush_denormals`). On the CPU the transposed
    convolutions take their backward pass as the strided convolutions they transpose, and on
    AVX2 CPUs the wide convolutions their weight gradient in the default layout
    (:func:`~compensation.training.conv_grad.faster_backward`).

    Returns
    -------
    FitResult
        The loop's timing, effective batch and loss curve (iteration, loss, learning rate).
    """
    opt = cfg.options
    device = next(model.parameters()).device
    amp_dtype = forward_dtype(device, opt.amp, data.name)
    scaler = torch.amp.GradScaler(device.type, enabled=amp_dtype == torch.float16)
    model.to(memory_format=torch.channels_last)
    optimizer = torch.optim.Adam(model.parameters(), lr=opt.lr, weight_decay=opt.weight_decay)
    scheduler = _scheduler(optimizer, opt)
    loss_fn = get_loss(opt.loss)
    captures = _channels_last(data.train.captures.to(device))
    frames = _channels_last(data.train.frames.to(device))
    surface = _channels_last(data.surface.to(device)) if use_surface else None
    crops = CropSampler(*captures.shape[2:], opt.patch, cfg.seed) if opt.patch else None

    def step(idx: torch.Tensor) -> torch.Tensor:
        x, y, s = captures, frames, surface
        if crops is not None:  # the window first (views), so that only its pixels are gathered
            top, left = next(crops)
            window = (..., slice(top, top + opt.patch), slice(left, left + opt.patch))
            x, y = x[window], y[window]
            s = s if s is None else s[window]
        x, y, s = _channels_last(x[idx]), _channels_last(y[idx]), s if s is None else _channels_last(s)
        with computing_in(amp_dtype, device):
            pred = model(x, s)
        loss = loss_fn(pred.float(), y)
        optimizer.zero_grad(set_to_none=True)
        scaler.scale(loss).backward()
        scaler.step(optimizer)
        scaler.update()
        rate = scheduler.get_last_lr()[0]
        scheduler.step()
        return torch.stack([loss.detach().double(), torch.tensor(rate, dtype=torch.float64, device=device)])

    stateful = {"model": model, "optimizer": optimizer, "scheduler": scheduler}
    if scaler.is_enabled():
        stateful["scaler"] = scaler
    if crops is not None:
        stateful["crops"] = crops
    model.train()
    try:
        with faster_backward(model) if device.type == "cpu" else nullcontext():
            result = train_loop(step, len(data.train), opt.batch, opt.iters, cfg.seed, device,
                                ("loss", "lr"), fit_label(data.name, cfg.method, cfg.seed, len(data.train)), progress,
                                stateful, checkpoint, cfg.checkpoint_every, opt.sampler)
    finally:
        model.to(memory_format=torch.contiguous_format)
    flush_denormals(model)
    return FitResult.of_loop(result)


def _scheduler(optimizer: torch.optim.Optimizer,
               opt: CompenNetOptions) -> torch.optim.lr_scheduler.LRScheduler:
    """The learning-rate schedule ``opt.lr_schedule`` names, over ``opt.iters`` steps.

    >>> opt = CompenNetOptions(iters=10, lr=1e-3, lr_schedule="one-cycle")
    >>> adam = torch.optim.Adam([torch.zeros(1, requires_grad=True)], lr=opt.lr)
    >>> schedule, rates = _scheduler(adam, opt), []
    >>> for _ in range(opt.iters):
    ...     rates.append(schedule.get_last_lr()[0]); adam.step(); schedule.step()
    >>> round(rates[0], 7), round(max(rates), 7), round(rates[-1], 9), rates.index(max(rates))
    (0.0001, 0.001, 1e-06, 2)
    """
    if opt.lr_schedule == "one-cycle":
        return torch.optim.lr_scheduler.OneCycleLR(optimizer, max_lr=opt.lr, total_steps=opt.iters,
                                                   cycle_momentum=False, **ONE_CYCLE)
    return torch.optim.lr_scheduler.StepLR(optimizer, step_size=opt.lr_step, gamma=opt.lr_gamma)


def _channels_last(images: torch.Tensor) -> torch.Tensor:
    """``images`` (N, C, H, W) in the channels-last memory layout (no copy if already so)."""
    return images.contiguous(memory_format=torch.channels_last)


def _in_channels_last(t: torch.Tensor) -> bool:
    """Whether the 4-D ``t`` is laid out channels-last (and not also in the default layout, as a
    tensor of one channel or one pixel is).

    >>> _in_channels_last(_channels_last(torch.zeros(2, 3, 4, 5))), _in_channels_last(torch.zeros(2, 3, 4, 5))
    (True, False)
    """
    return t.is_contiguous(memory_format=torch.channels_last) and not t.is_contiguous()
