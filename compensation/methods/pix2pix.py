"""pix2pix (Isola et al., CVPR 2017) as the CompenNet paper's baseline: x̃ → x by a conditional GAN.

The published configuration, written after the official PyTorch code (pytorch-CycleGAN-and-pix2pix,
``--model pix2pix``): a U-Net generator (``unet_256``: 8 levels, ngf 64, BatchNorm, dropout 0.5)
and a 70×70 PatchGAN discriminator (``n_layers=3``, ndf 64, BatchNorm) that sees the condition
and an image concatenated (6 channels); vanilla GAN loss (BCE on logits) plus λ = 100 times the
ℓ1 distance; Adam lr 2e-4, betas (0.5, 0.999); batch 1; N(0, 0.02) initialisation; no cropping,
resizing or flipping. As in the paper's baseline, the generator sees only the capture x̃ (no
surface image) and outputs the projector frame x. Images are mapped [0, 1] → [-1, 1] on the way in
and back on the way out.

Parameters (official code with BatchNorm, where convolutions followed by a norm have no bias):

- U-Net, 8 levels (``unet_256``, 256²): 54,413,955 (the official code logs ``54.414 M``)
- U-Net, 7 levels (``unet_128``, 128²): 41,828,995
- U-Net, 5 levels (32²): 16,659,075
- PatchGAN on 6 channels: 2,768,705 (the official code logs ``2.769 M``)

The number of U-Net levels follows the image size: log2 of the smaller side, at most 8, so that a
2^k × 2^k image shrinks to a 1 × 1 bottleneck as in ``unet_256`` / ``unet_128``, and no more than
both sides' factors of two allow (64 × 48 → 4 levels); width and height must be divisible by
2^levels.

Test-time behaviour follows the paper and the official ``test.py`` without ``--eval``: the
generator runs as in training — BatchNorm normalises with the statistics of the test batch, which
is a single image (instance-norm-like), and dropout stays on. To make π† a deterministic function
of its input, every image is predicted alone with the dropout mask drawn from a fixed seed
(:data:`PREDICT_SEED`), and the stored running statistics are left untouched.
"""
from __future__ import annotations

import re
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from compensation.methods.base import (CHECKPOINT, FitResult, Method, flush_denormals, load_state,
                                       load_weights, resolve_device, save_state, weights_file)
from compensation.training.config import MAX_ITERS, Options, TrainConfig
from compensation.training.loop import fit_label, train_loop
from sim.errors import ProcamError

if TYPE_CHECKING:
    from compensation.data import SetupData

PIX2PIX_PROFILES: dict[str, dict] = {
    # The CompenNet paper's baseline: 10,000 iterations at batch 1 (= 20 epochs of 500 pairs, all
    # within the official code's constant-lr phase), meant for a GPU.
    "paper": dict(iters=10000, batch=1),
    # A few CPU minutes. Measured training speed (G and D steps, fp32, torch 2.13 CPU) on a 2-core
    # machine shared with other jobs: 128² (7 levels) 0.60-0.67 CPU-seconds per iteration, i.e.
    # 1.0 it/s on one thread under load and up to 2.6 it/s on two threads; 64² (6 levels) 0.33
    # CPU-s/it, 2.0 it/s on one thread, up to 6.0 it/s on two. 500 iterations (2 epochs of the
    # quick profile's 250 pairs) take 3-5 min at 128² on two free cores, ~1.5 min at the quick
    # profile's 64².
    "quick": dict(iters=500, batch=1),
    # The paper's 256² (8 levels) on 2 CPU cores: ~0.7 CPU-seconds per iteration on one thread
    # (measured beside other jobs), so 500 iterations take about 6 CPU-minutes (the faithful
    # profile's CompenNet takes ~14 minutes of both cores).
    "faithful": dict(iters=500, batch=1),
}
"""pix2pix's iterations and batch size per training profile (explicit options still win)."""

NGF = 64
"""Generator filters in the outermost level (channels)."""
NDF = 64
"""Discriminator filters in the first layer (channels)."""
MIN_LEVELS = 4
"""Fewest U-Net levels (4: a 64 × 48 view; the published nets have 7 and 8)."""
MIN_SIDE = 32
"""Smallest image side (pixels): the 70×70 PatchGAN's five 4×4 convolutions need it."""
MAX_LEVELS = 8
"""Most U-Net levels (``unet_256``)."""
DROPOUT = 0.5
"""Dropout probability in the decoder of the levels between the fourth and the innermost."""
LAMBDA_L1 = 100.0
"""Weight λ of the ℓ1 term (measured in [-1, 1] units) in the generator's objective."""
LR = 2e-4
"""Adam learning rate of both networks (constant)."""
BETAS = (0.5, 0.999)
"""Adam betas of both networks."""
INIT_STD = 0.02
"""Standard deviation of the normal initialisation of convolution and BatchNorm weights."""
PREDICT_SEED = 0
"""Seed of the dropout mask used for every image at test time."""


def check_size(height: int, width: int, levels: int) -> None:
    """Check that a ``height`` × ``width`` image (pixels) fits a U-Net with ``levels`` levels.

    Raises
    ------
    ProcamError
        If width or height is not a positive multiple of 2^levels.

    Examples
    --------
    >>> check_size(64, 32, 5)
    >>> check_size(48, 48, 5)  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    sim.errors.ProcamError: 48x48 pixels: pix2pix's U-Net with 5 levels needs ... divisible by 2^5 = 32 ...
    """
    step = 2 ** levels
    if height < 1 or width < 1 or height % step or width % step:
        raise ProcamError(f"{width}x{height} pixels: pix2pix's U-Net with {levels} levels needs width "
                          f"and height divisible by 2^{levels} = {step} (a power-of-two size such as "
                          "128 or 256 works)")


def unet_levels(height: int, width: int) -> int:
    """Number of U-Net levels for ``height`` × ``width`` images (pixels).

    As many halvings as both sides allow, at most :data:`MAX_LEVELS`: log2 of the smaller side for
    power-of-two sizes (256² → 8, ``unet_256``; 128² → 7, ``unet_128``; 32² → 5), fewer where a
    side has fewer factors of two (64 × 48 → 4: a 4 × 3 bottleneck).

    Raises
    ------
    ProcamError
        If the sides allow fewer than :data:`MIN_LEVELS` halvings, or one is below :data:`MIN_SIDE`.

    Examples
    --------
    >>> unet_levels(256, 256), unet_levels(128, 128), unet_levels(32, 32), unet_levels(512, 1024)
    (8, 7, 5, 8)
    >>> unet_levels(48, 64)
    4
    """
    def halvings(n: int) -> int:
        return (n & -n).bit_length() - 1 if n > 0 else 0

    levels = min(MAX_LEVELS, int(min(height, width)).bit_length() - 1, halvings(height), halvings(width))
    if levels < MIN_LEVELS:
        raise ProcamError(f"{width}x{height} pixels: pix2pix's U-Net needs width and height divisible "
                          f"by 2^{MIN_LEVELS} = {2 ** MIN_LEVELS} (e.g. 64x48, 128 or 256)")
    if min(height, width) < MIN_SIDE:
        raise ProcamError(f"{width}x{height} pixels: pix2pix's PatchGAN needs width and height of at "
                          f"least {MIN_SIDE} pixels")
    check_size(height, width, levels)
    return levels


class UNetGenerator(nn.Module):
    """pix2pix's U-Net generator (``unet_256`` with 8 levels, ``unet_128`` with 7).

    Level ``i`` halves the resolution with a 4×4 stride-2 convolution to ``ngf·min(2^i, 8)``
    channels (LeakyReLU 0.2 before it except at level 0, BatchNorm after it except at the innermost
    level) and doubles it back with a 4×4 stride-2 transposed convolution (ReLU before it, BatchNorm
    after it, Tanh at level 0), fed with the concatenation of the level's encoder output and the
    decoder output of the level below. Dropout 0.5 follows the decoder of levels 4 … levels−2,
    which are the three levels above the innermost one in ``unet_256`` (two in ``unet_128``, none
    with 5 levels), as in the official code.

    Parameters
    ----------
    levels : int
        Down-sampling levels, :data:`MIN_LEVELS` … :data:`MAX_LEVELS`; inputs must have width and
        height divisible by 2^levels.
    ngf : int
        Filters of the outermost level.

    Raises
    ------
    ProcamError
        If ``levels`` is out of range.
    """

    def __init__(self, levels: int, ngf: int = NGF):
        super().__init__()
        if not MIN_LEVELS <= levels <= MAX_LEVELS:
            raise ProcamError(f"pix2pix U-Net: levels={levels}: expected {MIN_LEVELS} to {MAX_LEVELS}")
        self.levels = levels
        channels = [ngf * min(2 ** i, 8) for i in range(levels)]
        innermost = levels - 1
        self.down = nn.ModuleList([nn.Conv2d(3, channels[0], 4, 2, 1, bias=False)])
        for i in range(1, levels):
            layers = [nn.LeakyReLU(0.2), nn.Conv2d(channels[i - 1], channels[i], 4, 2, 1, bias=False)]
            if i < innermost:
                layers.append(nn.BatchNorm2d(channels[i]))
            self.down.append(nn.Sequential(*layers))
        self.up = nn.ModuleList()
        for i in range(levels):
            inputs = channels[i] if i == innermost else 2 * channels[i]
            if i == 0:
                layers = [nn.ReLU(), nn.ConvTranspose2d(inputs, 3, 4, 2, 1), nn.Tanh()]
            else:
                layers = [nn.ReLU(), nn.ConvTranspose2d(inputs, channels[i - 1], 4, 2, 1, bias=False),
                          nn.BatchNorm2d(channels[i - 1])]
                if 4 <= i < innermost:
                    layers.append(nn.Dropout(DROPOUT))
            self.up.append(nn.Sequential(*layers))

    def forward(self, x: Tensor) -> Tensor:
        """Translate (N, 3, H, W) images in [-1, 1] into (N, 3, H, W) images in (-1, 1).

        Raises
        ------
        ProcamError
            If H or W is not divisible by 2^levels.
        """
        check_size(x.shape[-2], x.shape[-1], self.levels)
        skips = []
        for down in self.down:
            x = down(x)
            skips.append(x)
        x = self.up[-1](skips[-1])
        for i in range(self.levels - 2, -1, -1):
            x = self.up[i](torch.cat([skips[i], x], 1))
        return x


class PatchDiscriminator(nn.Module):
    """pix2pix's PatchGAN discriminator (``basic``: ``n_layers=3``, a 70×70 receptive field).

    Four 4×4 convolutions (stride 2, 2, 2, 1) to ndf·(1, 2, 4, 8) channels with LeakyReLU 0.2 and
    BatchNorm after all but the first, then a 4×4 stride-1 convolution to one logit per patch:
    a 256² input gives 30×30 logits.

    Parameters
    ----------
    in_channels : int
        Input channels: the condition and an image, concatenated (3 + 3).
    ndf : int
        Filters of the first layer.
    """

    def __init__(self, in_channels: int = 6, ndf: int = NDF):
        super().__init__()
        self.model = nn.Sequential(
            nn.Conv2d(in_channels, ndf, 4, 2, 1), nn.LeakyReLU(0.2),
            nn.Conv2d(ndf, 2 * ndf, 4, 2, 1, bias=False), nn.BatchNorm2d(2 * ndf), nn.LeakyReLU(0.2),
            nn.Conv2d(2 * ndf, 4 * ndf, 4, 2, 1, bias=False), nn.BatchNorm2d(4 * ndf), nn.LeakyReLU(0.2),
            nn.Conv2d(4 * ndf, 8 * ndf, 4, 1, 1, bias=False), nn.BatchNorm2d(8 * ndf), nn.LeakyReLU(0.2),
            nn.Conv2d(8 * ndf, 1, 4, 1, 1),
        )

    def forward(self, x: Tensor) -> Tensor:
        """Real/fake logits (N, 1, H/8 − 2, W/8 − 2) of (N, 6, H, W) inputs in [-1, 1]."""
        return self.model(x)


def init_normal(model: nn.Module, std: float = INIT_STD) -> None:
    """The official ``normal`` initialisation: convolution weights N(0, std), BatchNorm weights
    N(1, std), all biases 0."""
    for m in model.modules():
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d)):
            nn.init.normal_(m.weight, 0.0, std)
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.normal_(m.weight, 1.0, std)
            nn.init.zeros_(m.bias)


class Pix2Pix(nn.Module):
    """The generator and the discriminator, saved together in one state dict.

    Parameters
    ----------
    levels : int
        U-Net levels (see :func:`unet_levels`).
    """

    def __init__(self, levels: int):
        super().__init__()
        self.generator = UNetGenerator(levels)
        self.discriminator = PatchDiscriminator()


def to_signed(images: Tensor) -> Tensor:
    """Images in [0, 1] → [-1, 1] (the networks' range)."""
    return images * 2 - 1


def to_unit(images: Tensor) -> Tensor:
    """Images in [-1, 1] → [0, 1]."""
    return (images + 1) / 2


@contextmanager
def batch_statistics(model: nn.Module) -> Iterator[None]:
    """Run ``model`` as in training — BatchNorm on the batch's own statistics, dropout on — without
    updating the stored running statistics; restores the previous mode afterwards."""
    norms = [m for m in model.modules() if isinstance(m, nn.BatchNorm2d)]
    was_training = model.training
    model.train()
    for m in norms:
        m.track_running_stats = False
    try:
        yield
    finally:
        for m in norms:
            m.track_running_stats = True
        model.train(was_training)


def training_step(gen: torch.nn.Module, disc: torch.nn.Module, opt_g: torch.optim.Optimizer,
                  opt_d: torch.optim.Optimizer, cond: torch.Tensor, real: torch.Tensor,
                  l1_weight: float) -> torch.Tensor:
    """One pix2pix iteration in the official update order, on images in [-1, 1].

    G(x̃); one discriminator step on ½·(BCE(D(x̃, G(x̃)), 0) + BCE(D(x̃, x), 1)); one generator
    step on BCE(D(x̃, G(x̃)), 1) + ``l1_weight``·ℓ1(G(x̃), x).

    Returns
    -------
    torch.Tensor
        (ℓ1 term in [0, 1] image units, generator GAN loss, discriminator loss), detached.
    """
    fake = gen(cond)

    disc.requires_grad_(True)
    opt_d.zero_grad(set_to_none=True)
    logits_fake = disc(torch.cat([cond, fake.detach()], 1))
    logits_real = disc(torch.cat([cond, real], 1))
    loss_d = 0.5 * (F.binary_cross_entropy_with_logits(logits_fake, torch.zeros_like(logits_fake))
                    + F.binary_cross_entropy_with_logits(logits_real, torch.ones_like(logits_real)))
    loss_d.backward()
    opt_d.step()

    disc.requires_grad_(False)
    opt_g.zero_grad(set_to_none=True)
    logits = disc(torch.cat([cond, fake], 1))
    loss_gan = F.binary_cross_entropy_with_logits(logits, torch.ones_like(logits))
    loss_l1 = F.l1_loss(fake, real)
    (loss_gan + l1_weight * loss_l1).backward()
    opt_g.step()
    return torch.stack([loss_l1.detach() / 2, loss_gan.detach(), loss_d.detach()])


@dataclass(frozen=True)
class Pix2PixOptions(Options):
    """Training options of pix2pix (the published configuration; training is fp32)."""

    iters: int = 10000
    """Iterations, each one discriminator and one generator step (1 to
    :data:`~compensation.training.config.MAX_ITERS`; the CompenNet paper's baseline: 10,000 at
    batch 1, 20 epochs of 500 pairs)."""
    batch: int = 1
    """Training pairs per iteration (>= 1; published 1)."""
    lr: float = LR
    """Adam learning rate of both networks, constant (> 0; published 2e-4)."""
    l1_weight: float = LAMBDA_L1
    """λ, the weight of the ℓ1 term beside the GAN loss (>= 0; published 100)."""
    init: str | None = None
    """Run directory, or state dict file (``.pth``), whose weights initialise both networks (same
    U-Net levels)."""

    profiles: ClassVar[dict[str, dict]] = PIX2PIX_PROFILES

    def check(self) -> None:
        self._positive_ints("iters", most=MAX_ITERS)
        self._positive_ints("batch")
        self._number("lr", positive=True)
        self._number("l1_weight", positive=False)
        self._optional_path("init")


class Pix2PixMethod(Method):
    """pix2pix trained on (x̃, x) pairs, the CompenNet paper's baseline (no surface image).

    ``fit`` takes its options from :class:`Pix2PixOptions` (Adam with :data:`BETAS`, a constant
    learning rate, no weight decay, the GAN + λ·ℓ1 objective) and the seed and device from the
    configuration.

    Parameters
    ----------
    device : str
        Torch device for prediction (``"auto"``: CUDA if available); ``fit`` uses the config's.
    """

    name = "pix2pix"
    official_name = "pix2pix"
    options = Pix2PixOptions

    @classmethod
    def check_image_size(cls, options: Pix2PixOptions, width: int, height: int) -> None:
        """Raise :class:`ProcamError` unless the U-Net and PatchGAN take ``width`` × ``height``
        images (:func:`unet_levels`)."""
        unet_levels(height, width)

    def __init__(self, device: str = "auto"):
        self.device = resolve_device(device)
        self.model: Pix2Pix | None = None

    def fit(self, data: SetupData, cfg: TrainConfig, progress: bool = True,
            checkpoint: Path | None = None) -> FitResult:
        """Train generator and discriminator on ``data.train`` (the official update order).

        Each iteration: G(x̃); one discriminator step on ½·(BCE(D(x̃, G(x̃)), 0) + BCE(D(x̃, x), 1));
        one generator step on BCE(D(x̃, G(x̃)), 1) + λ·ℓ1(G(x̃), x), all in [-1, 1] units.

        Returns
        -------
        FitResult
            ``loss_curve`` holds (iteration, ℓ1 term, learning rate) with ℓ1 in [0, 1] image
            units; ``extra`` holds ``iters`` and ``gan_curve`` (iteration, generator GAN loss,
            discriminator loss).

        Raises
        ------
        ProcamError
            If the image size does not fit the U-Net, ``cfg.init`` does not fit the networks, or a
            loss becomes NaN or infinite.
        """
        opt = cfg.options
        self.device = device = resolve_device(cfg.device)
        torch.manual_seed(cfg.seed)  # initialisation and dropout masks
        model = Pix2Pix(unet_levels(*data.size))
        init_normal(model)
        if opt.init is not None:
            load_weights(model, weights_file(opt.init), self.name)
        self.model = model.to(device)
        gen, disc = model.generator, model.discriminator
        opt_g = torch.optim.Adam(gen.parameters(), lr=opt.lr, betas=BETAS, fused=True)
        opt_d = torch.optim.Adam(disc.parameters(), lr=opt.lr, betas=BETAS, fused=True)
        captures, frames = data.train.captures.to(device), data.train.frames.to(device)

        def step(idx: torch.Tensor) -> torch.Tensor:
            return training_step(gen, disc, opt_g, opt_d, to_signed(captures[idx]),
                                 to_signed(frames[idx]), opt.l1_weight)

        model.train()
        stateful = {"model": model, "optimizer_g": opt_g, "optimizer_d": opt_d}
        result = train_loop(step, len(data.train), opt.batch, opt.iters, cfg.seed, device,
                            ("l1", "G GAN", "D"), fit_label(data.name, self.name, cfg.seed, len(data.train)), progress,
                            stateful, checkpoint, cfg.checkpoint_every)
        disc.requires_grad_(True)
        flush_denormals(model)
        rows = result.values
        return FitResult(result.seconds, result.samples_per_second, result.final_loss, result.batch,
                         [(i + 1, r[0], opt.lr) for i, r in enumerate(rows)],
                         {"iters": opt.iters, "gan_curve": [(i + 1, r[1], r[2]) for i, r in enumerate(rows)]})

    @torch.no_grad()
    def predict(self, captures: torch.Tensor, surface: torch.Tensor, batch_size: int = 64) -> torch.Tensor:
        """Projector frames G(x̃) for ``captures``; ``surface`` is not used (no surface input).

        Every image is run alone, in training mode as the paper and the official test script do
        (BatchNorm on the image's own statistics, dropout on with the mask of
        :data:`PREDICT_SEED`), so the result for an image does not depend on the others, on
        ``batch_size`` (accepted for the common interface) or on earlier calls.

        Raises
        ------
        ProcamError
            If called before fit or load, or the captures are not (N, 3, H, W) with H and W
            divisible by 2^levels.
        """
        if self.model is None:
            raise ProcamError(f"{self.name}: predict called before fit or load")
        gen = self.model.generator
        if captures.ndim != 4 or captures.shape[1] != 3:
            raise ProcamError(f"{self.name}: captures must have shape (N, 3, H, W), "
                              f"got {tuple(captures.shape)}")
        check_size(captures.shape[2], captures.shape[3], gen.levels)
        out = torch.empty(captures.shape, dtype=torch.float32)
        devices = []  # CUDA generators forked (and restored) along with the CPU one
        if self.device.type == "cuda":
            devices = [torch.cuda.current_device() if self.device.index is None else self.device.index]
        with batch_statistics(gen), torch.random.fork_rng(devices=devices):
            for i in range(captures.shape[0]):
                torch.manual_seed(PREDICT_SEED)
                x = to_signed(captures[i:i + 1].to(self.device, torch.float32))
                out[i] = to_unit(gen(x))[0].float().cpu()
        return out

    def save(self, run_dir: Path) -> None:
        """Write generator and discriminator to ``run_dir/model.pt`` (one plain state dict)."""
        if self.model is None:
            raise ProcamError(f"{self.name}: nothing to save before fit or load")
        save_state(self.model, Path(run_dir) / CHECKPOINT)

    @classmethod
    def load(cls, run_dir: Path, device: str = "auto") -> Pix2PixMethod:
        """A fitted pix2pix from ``run_dir/model.pt``; the U-Net's levels are read from its weights.

        Raises
        ------
        ProcamError
            If the checkpoint is missing, unreadable, not a pix2pix state dict or does not fit.
        """
        path = Path(run_dir) / CHECKPOINT
        levels = {int(m.group(1)) for key in load_state(path)
                  if (m := re.match(r"generator\.down\.(\d+)\.", key))}
        if not levels:
            raise ProcamError(f"{path}: not a pix2pix checkpoint (no generator.down.* weights)")
        method = cls(device)
        model = Pix2Pix(max(levels) + 1)
        load_weights(model, path, cls.name)
        method.model = model.to(method.device)
        return method
