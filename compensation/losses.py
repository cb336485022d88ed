"""Training losses for compensation networks, as small pure functions of (pred, target).

Every loss takes two tensors (N, 3, H, W), float in [0, 1], and returns a differentiable scalar
tensor averaged over the batch. The SSIM terms use pytorch-msssim with the paper's window (11×11
Gaussian, σ = 1.5, data range 1), so H and W must be at least 11. :data:`LOSSES` maps the names
accepted by the training configuration to the functions; :func:`get_loss` looks one up.
"""

from __future__ import annotations

from typing import Callable

import pytorch_msssim
import torch
import torch.nn.functional as F
from torch import Tensor

WIN_SIZE = 11
"""Side of the Gaussian SSIM window (pixels)."""
WIN_SIGMA = 1.5
"""Standard deviation of the Gaussian SSIM window (pixels)."""


def gaussian_window(size: int = WIN_SIZE, sigma: float = WIN_SIGMA) -> Tensor:
    """Normalised 1-D Gaussian SSIM window, float64, shaped (1, 1, 1, size) for pytorch-msssim.

    Built in float64 because pytorch-msssim's own window is computed and normalised in float32,
    which moves float64 SSIM values by about 1e-6 from scikit-image's; pytorch-msssim casts the
    window to the images' dtype.

    Examples
    --------
    >>> w = gaussian_window()
    >>> w.shape, round(w.sum().item(), 12)
    (torch.Size([1, 1, 1, 11]), 1.0)
    """
    x = torch.arange(size, dtype=torch.float64) - size // 2
    g = torch.exp(-x**2 / (2 * sigma**2))
    return (g / g.sum()).reshape(1, 1, 1, size)


_WINDOW = gaussian_window()


def l1(pred: Tensor, target: Tensor) -> Tensor:
    """Mean absolute error over all pixels, channels and images.

    Examples
    --------
    >>> import torch
    >>> l1(torch.zeros(1, 3, 4, 4), torch.full((1, 3, 4, 4), 0.25))
    tensor(0.2500)
    """
    return F.l1_loss(pred, target)


def l2(pred: Tensor, target: Tensor) -> Tensor:
    """Mean squared error (MSE) over all pixels, channels and images.

    Examples
    --------
    >>> import torch
    >>> l2(torch.zeros(1, 3, 4, 4), torch.full((1, 3, 4, 4), 0.5))
    tensor(0.2500)
    """
    return F.mse_loss(pred, target)


def ssim(pred: Tensor, target: Tensor, per_image: bool = False) -> Tensor:
    """Structural similarity (1 for identical images), mean over RGB channels and images.

    pytorch-msssim's SSIM with an 11×11 Gaussian window (:func:`gaussian_window`, σ = 1.5
    pixels), data range 1, K = (0.01, 0.03), averaged over the valid (unpadded) window positions
    of each channel. Not a loss itself: see
    :func:`ssim_loss`.

    Parameters
    ----------
    pred, target : Tensor
        (N, 3, H, W) images in [0, 1], H and W at least 11 pixels.
    per_image : bool
        Return the (N,) SSIM of each image (mean over its channels) instead of the batch mean.

    Raises
    ------
    ValueError
        If the shapes differ or an image is smaller than the 11×11 window (pytorch-msssim would
        silently skip the smoothing along that axis).

    Examples
    --------
    >>> import torch
    >>> x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    >>> round(ssim(x, x).item(), 6)
    1.0
    >>> ssim(x, x, per_image=True).shape
    torch.Size([2])
    """
    if pred.shape != target.shape:
        raise ValueError(f"ssim: pred and target shapes differ: {tuple(pred.shape)} vs "
                         f"{tuple(target.shape)}")
    if pred.ndim != 4 or min(pred.shape[2:]) < WIN_SIZE:
        raise ValueError(f"ssim: expected (N, C, H, W) images with H and W at least {WIN_SIZE} "
                         f"pixels (the SSIM window), got shape {tuple(pred.shape)}")
    win = _WINDOW.repeat(pred.shape[1], 1, 1, 1)  # one window per channel (grouped convolution)
    return pytorch_msssim.ssim(pred, target, data_range=1.0, size_average=not per_image, win=win)


def ssim_loss(pred: Tensor, target: Tensor) -> Tensor:
    """SSIM dissimilarity ``1 - ssim(pred, target)``, 0 for identical images.

    Examples
    --------
    >>> import torch
    >>> x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    >>> ssim_loss(x, x).abs().item() < 1e-6
    True
    """
    return 1 - ssim(pred, target)


def l1_ssim(pred: Tensor, target: Tensor) -> Tensor:
    """The paper's training loss ``l1 + (1 - ssim)``.

    Examples
    --------
    >>> import torch
    >>> x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    >>> l1_ssim(x, x).abs().item() < 1e-6
    True
    >>> l1_ssim(torch.zeros(1, 3, 16, 16), torch.full((1, 3, 16, 16), 0.5)) > 0.5
    tensor(True)
    """
    return l1(pred, target) + ssim_loss(pred, target)


LOSSES: dict[str, Callable[[Tensor, Tensor], Tensor]] = {
    "l1": l1,
    "l2": l2,
    "ssim": ssim_loss,
    "l1+ssim": l1_ssim,
}
"""Loss functions by configuration name; ``"ssim"`` is the loss ``1 - ssim``."""


def get_loss(name: str) -> Callable[[Tensor, Tensor], Tensor]:
    """The loss function called ``name`` in :data:`LOSSES`.

    Raises
    ------
    ValueError
        If ``name`` is not a key of :data:`LOSSES`; the message lists the valid names.

    Examples
    --------
    >>> get_loss("l1+ssim") is l1_ssim
    True
    """
    try:
        return LOSSES[name]
    except KeyError:
        raise ValueError(f"unknown loss {name!r}; choose one of: {', '.join(LOSSES)}") from None
