"""Training losses for compensation networks, as small pure functions of (pred, target).

Every loss takes two tensors (N, 3, H, W), float in [0, 1], and returns a differentiable scalar
tensor averaged over the batch. The SSIM terms use the metric's own SSIM in the official code's
convention (:func:`compensation.scores.metrics.structural_similarity`: 11×11 Gaussian window,
σ = 1.5, data range 1, each image's border replicated by 5 pixels). :data:`LOSSES` maps the names
accepted by the training configuration to the functions; :func:`get_loss` looks one up.
"""

from __future__ import annotations

from typing import Callable

import torch.nn.functional as F
from torch import Tensor

from compensation.scores.metrics import structural_similarity


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


def ssim_loss(pred: Tensor, target: Tensor) -> Tensor:
    """SSIM dissimilarity ``1 - ssim(pred, target)``, 0 for identical images.

    Examples
    --------
    >>> import torch
    >>> x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    >>> ssim_loss(x, x).abs().item() < 1e-6
    True
    """
    return 1 - structural_similarity(pred, target)


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


def l1_l2(pred: Tensor, target: Tensor) -> Tensor:
    """``l1 + l2`` (a loss of the official code's later versions).

    Examples
    --------
    >>> import torch
    >>> l1_l2(torch.zeros(1, 3, 4, 4), torch.full((1, 3, 4, 4), 0.5))
    tensor(0.7500)
    """
    return l1(pred, target) + l2(pred, target)


def l2_ssim(pred: Tensor, target: Tensor) -> Tensor:
    """``l2 + (1 - ssim)`` (a loss of the official code's later versions).

    Examples
    --------
    >>> import torch
    >>> x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    >>> l2_ssim(x, x).abs().item() < 1e-6
    True
    """
    return l2(pred, target) + ssim_loss(pred, target)


def l1_l2_ssim(pred: Tensor, target: Tensor) -> Tensor:
    """``l1 + l2 + (1 - ssim)``, the loss of CompenHR.

    Examples
    --------
    >>> import torch
    >>> x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    >>> l1_l2_ssim(x, x).abs().item() < 1e-6
    True
    """
    return l1(pred, target) + l2(pred, target) + ssim_loss(pred, target)


LOSSES: dict[str, Callable[[Tensor, Tensor], Tensor]] = {
    "l1": l1,
    "l2": l2,
    "ssim": ssim_loss,
    "l1+ssim": l1_ssim,
    "l1+l2": l1_l2,
    "l2+ssim": l2_ssim,
    "l1+l2+ssim": l1_l2_ssim,
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
