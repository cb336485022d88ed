"""Image-quality metrics of the CompenNet paper and its successors, over *all* test images.

Definitions for predictions and targets (N, 3, H, W) in [0, 1]:

* MSE  — mean squared error over all pixels, channels and images (one number for the whole set);
* PSNR — ``10 · log10(1 / MSE)`` in dB (``inf`` for identical sets);
* RMSE — ``sqrt(3 · MSE)``, the root mean squared RGB-vector distance per pixel;
* SSIM — an 11×11 Gaussian window (σ = 1.5 pixels) per RGB channel, data range 1,
  C1 = 0.01², C2 = 0.03²; the mean of the SSIM map over its pixels, the channels and the images;
* ΔE   — CIEDE2000 colour difference of the 8-bit sRGB images in CIE Lab (D65), the mean over
  pixels and images (reported by the CompenNet line's later papers).

Two SSIM conventions differ in which window positions the map holds (:data:`SSIM_CONVENTIONS`):

``"official"`` (the default), as the official CompenNet code computes it
    each image is first padded by 5 pixels on every side by edge replication, then the window runs
    over the padded image without further padding, so the SSIM map has the image's own size and
    the border pixels count with replicated neighbours.
``"skimage"``
    only window positions that fit inside the image: the map is (H − 10) × (W − 10). This equals
    scikit-image's ``structural_similarity(a, b, channel_axis=-1, gaussian_weights=True,
    sigma=1.5, use_sample_covariance=False, data_range=1)``, which filters with reflect padding
    and then crops the 5-pixel border before averaging.

The border counts for a larger share of small images: on the 100 test captures of the shipped
default setup at 64² (uncompensated, against the frames) the official SSIM is 0.5501, scikit-image's
0.5798. Both run the valid window over the (padded or unpadded) images as two 1-D passes of a float64
Gaussian (:func:`gaussian_window`), so float64 values agree with scikit-image to about 1e-15.

Unlike the official code, nothing is dropped when N is not a multiple of the batch size:
:func:`evaluate` streams over batches, accumulating the squared-error sum and the per-image SSIM and
ΔE sums, so its result equals the full-set definitions with bounded memory.
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor


WIN_SIZE = 11
"""Side of the Gaussian SSIM window (pixels)."""
WIN_SIGMA = 1.5
"""Standard deviation of the Gaussian SSIM window (pixels)."""


def gaussian_window(size: int = WIN_SIZE, sigma: float = WIN_SIGMA) -> Tensor:
    """Normalised 1-D Gaussian SSIM window, float64, shaped (1, 1, 1, size) (a horizontal kernel).

    Built in float64 (a window normalised in float32 moves float64 SSIM values by about 1e-6 from
    scikit-image's); :func:`gaussian_filter` casts it to the images' dtype.

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

SSIM_CONVENTIONS = ("official", "skimage")
"""SSIM conventions by name: the official CompenNet code's (edge-replicated border) and
scikit-image's (window positions inside the image only); see the module docstring."""


def window_band(n: int, dtype: torch.dtype = torch.float64, device=None) -> Tensor:
    """The valid 1-D Gaussian filter of length-``n`` signals as an (n, n − 10) banded matrix.

    Column j holds :func:`gaussian_window` in rows j … j + 10, so ``signal @ window_band(n)`` is
    the window's weighted mean at every position that fits inside the signal.

    Examples
    --------
    >>> band = window_band(12)
    >>> band.shape, [round(v, 12) for v in band.sum(0).tolist()]
    (torch.Size([12, 2]), [1.0, 1.0])
    >>> bool(torch.equal(band[1:, 1], band[:-1, 0]))
    True
    """
    win = _WINDOW.flatten().to(device, dtype)
    band = torch.zeros(n, n - WIN_SIZE + 1, dtype=dtype, device=device)
    cols = torch.arange(n - WIN_SIZE + 1, device=device)
    for k in range(WIN_SIZE):
        band[cols + k, cols] = win[k]
    return band


def gaussian_filter(images: Tensor) -> Tensor:
    """Valid 11×11 Gaussian filtering of every channel: a vertical then a horizontal 1-D pass.

    The separable form of the 2-D window (the outer product of :func:`gaussian_window` with
    itself). float64 images (the metrics) are filtered as two products with banded matrices
    (:func:`window_band`), which run on the BLAS: on 64 images of 266² on one CPU thread 0.4 s,
    against 1.7 s for grouped convolutions in the default memory layout and 4.0 s in the
    channels-last one (float64 convolutions have no optimised CPU kernel). Other dtypes (the
    losses, float32) run :func:`grouped_filter`, one grouped (per-channel) convolution per pass,
    which is the faster of the two for the training step at 256² (forward and backward).

    Parameters
    ----------
    images : Tensor
        (N, C, H, W) with H and W at least :data:`WIN_SIZE`.

    Returns
    -------
    Tensor
        (N, C, H − 10, W − 10): the window's weighted mean at every position that fits inside.

    Examples
    --------
    >>> x = torch.zeros(1, 1, 11, 11, dtype=torch.float64)
    >>> x[0, 0, 5, 5] = 1.0  # the filtered centre is the window's central weight squared
    >>> bool(torch.isclose(gaussian_filter(x)[0, 0, 0, 0], gaussian_window()[0, 0, 0, 5] ** 2))
    True
    >>> y = torch.rand(1, 2, 13, 12, dtype=torch.float64)  # float64 and float32 paths agree
    >>> bool(torch.allclose(gaussian_filter(y), gaussian_filter(y.float()).double(), atol=1e-6))
    True
    """
    if images.dtype != torch.float64:
        return grouped_filter(images)
    height, width = images.shape[-2:]
    vertical = window_band(height, images.dtype, images.device)
    return vertical.T @ (images @ window_band(width, images.dtype, images.device))


def grouped_filter(images: Tensor) -> Tensor:
    """:func:`gaussian_filter` as two grouped (per-channel) convolutions, a vertical and a
    horizontal pass, whatever the dtype (its path for float32 images).

    Examples
    --------
    >>> y = torch.rand(1, 2, 13, 12, dtype=torch.float64)
    >>> bool(torch.allclose(grouped_filter(y), gaussian_filter(y), rtol=0, atol=1e-15))
    True
    """
    channels = images.shape[1]
    win = _WINDOW.to(images.device, images.dtype)
    vertical = win.reshape(1, 1, WIN_SIZE, 1).repeat(channels, 1, 1, 1)
    horizontal = win.repeat(channels, 1, 1, 1)
    out = F.conv2d(images, vertical, groups=channels)
    return F.conv2d(out, horizontal, groups=channels)


def structural_similarity(pred: Tensor, target: Tensor, per_image: bool = False,
                          convention: str = "official") -> Tensor:
    """Structural similarity (1 for identical images), mean over RGB channels and images.

    SSIM with an 11×11 Gaussian window (:func:`gaussian_window`, σ = 1.5 pixels, applied by
    :func:`gaussian_filter`), data range 1, C1 = 0.01², C2 = 0.03², averaged over the SSIM map of
    each channel; under the ``"official"`` convention the images are first padded by 5 pixels by
    edge replication (see the module docstring). The five local moments (means, second moments,
    cross moment) are filtered in the channels-last memory layout, where the per-channel
    convolutions of float32 images (the losses) run fastest on the CPU (forward and backward
    together measured 1.5–1.9× faster than in the default layout at 128² and 256² on 2 cores);
    float64 images (the metrics) take the banded products of :func:`gaussian_filter` in either
    layout. The values do not depend on the layout. Differentiable: the SSIM losses build on it.

    Parameters
    ----------
    pred, target : Tensor
        (N, C, H, W) images in [0, 1]; under ``"skimage"`` H and W at least 11.
    per_image : bool
        Return the (N,) SSIM of each image (mean over its channels) instead of the batch mean.
    convention : str
        ``"official"`` (edge-replicated border, a map of the image's size) or ``"skimage"``
        (window positions inside the image only), see :data:`SSIM_CONVENTIONS`.

    Raises
    ------
    ValueError
        If the convention is unknown, the shapes differ, or an image is smaller than the 11×11
        window under ``"skimage"``.

    Examples
    --------
    >>> x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    >>> round(structural_similarity(x, x).item(), 6)
    1.0
    >>> structural_similarity(x, x, per_image=True).shape
    torch.Size([2])
    >>> y = (x + 0.1 * torch.rand(x.shape, generator=torch.Generator().manual_seed(1))).clamp(0, 1)
    >>> [round(structural_similarity(x, y, convention=c).item(), 4) for c in SSIM_CONVENTIONS]
    [0.9903, 0.9904]
    """
    if convention not in SSIM_CONVENTIONS:
        raise ValueError(f"ssim: convention {convention!r}: expected one of "
                         f"{', '.join(SSIM_CONVENTIONS)}")
    if pred.shape != target.shape:
        raise ValueError(f"ssim: pred and target shapes differ: {tuple(pred.shape)} vs "
                         f"{tuple(target.shape)}")
    smallest = 1 if convention == "official" else WIN_SIZE
    if pred.ndim != 4 or min(pred.shape[2:]) < smallest:
        raise ValueError(f"ssim: expected (N, C, H, W) images with H and W at least {smallest} "
                         f"pixel{'s' * (smallest > 1)} ({convention} convention), got shape "
                         f"{tuple(pred.shape)}")
    if convention == "official":
        border = (WIN_SIZE // 2,) * 4
        pred, target = F.pad(pred, border, mode="replicate"), F.pad(target, border, mode="replicate")
    pred = pred.contiguous(memory_format=torch.channels_last)
    target = target.contiguous(memory_format=torch.channels_last)
    mu1, mu2 = gaussian_filter(pred), gaussian_filter(target)
    pred_sq, target_sq = gaussian_filter(pred * pred), gaussian_filter(target * target)
    cross = gaussian_filter(pred * target)
    mu1_sq, mu2_sq, mu12 = mu1 * mu1, mu2 * mu2, mu1 * mu2
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    contrast_structure = (2 * (cross - mu12) + c2) / ((pred_sq - mu1_sq) + (target_sq - mu2_sq) + c2)
    ssim_map = (2 * mu12 + c1) / (mu1_sq + mu2_sq + c1) * contrast_structure
    per_channel = ssim_map.flatten(2).mean(-1)
    return per_channel.mean(1) if per_image else per_channel.mean()


def _check_pair(pred: Tensor, target: Tensor) -> None:
    """Raise ``ValueError`` unless both are (N, 3, H, W) tensors of one shape with N > 0."""
    for name, t in (("pred", pred), ("target", target)):
        if not isinstance(t, Tensor):
            raise ValueError(f"metrics: {name} must be a torch.Tensor, got {type(t).__name__}")
        if t.ndim != 4 or t.shape[1] != 3 or t.shape[0] == 0:
            raise ValueError(f"metrics: {name} must have shape (N, 3, H, W) with N > 0, "
                             f"got {tuple(t.shape)}")
    if pred.shape != target.shape:
        raise ValueError(f"metrics: pred and target shapes differ: {tuple(pred.shape)} vs "
                         f"{tuple(target.shape)}")


def psnr_from_mse(mse: float) -> float:
    """PSNR in dB of images in [0, 1] with mean squared error ``mse`` (``inf`` for 0).

    Examples
    --------
    >>> psnr_from_mse(0.01)
    20.0
    """
    return math.inf if mse == 0 else 10.0 * math.log10(1.0 / mse)


def mse_per_image(pred: Tensor, target: Tensor) -> Tensor:
    """Each image's mean squared error over its pixels and channels, float64 (N,).

    Examples
    --------
    >>> mse_per_image(torch.full((2, 3, 2, 2), 0.5), torch.zeros(2, 3, 2, 2)).tolist()
    [0.25, 0.25]
    """
    return ((pred.double() - target.double()) ** 2).mean(dim=(1, 2, 3))


def psnr_per_image(pred: torch.Tensor, target: torch.Tensor, digits: int = 4) -> list[float]:
    """Each image's PSNR in dB (float64 mean squared error), rounded to ``digits`` decimals: the
    samples of the reports' confidence intervals.

    Examples
    --------
    >>> psnr_per_image(torch.full((2, 3, 2, 2), 0.1), torch.zeros(2, 3, 2, 2))
    [20.0, 20.0]
    """
    return [round(psnr_from_mse(float(m)), digits) for m in mse_per_image(pred, target)]


def rmse_from_mse(mse: float) -> float:
    """The paper's RMSE, ``sqrt(3 · mse)``, of RGB images with per-channel mean squared error.

    Examples
    --------
    >>> rmse_from_mse(0.03)
    0.3
    """
    return math.sqrt(3.0 * mse)


def mse(pred: Tensor, target: Tensor) -> float:
    """Mean squared error over all pixels, channels and images (float64).

    Examples
    --------
    >>> mse(torch.zeros(2, 3, 4, 4), torch.full((2, 3, 4, 4), 0.5))
    0.25
    """
    _check_pair(pred, target)
    return torch.mean((pred.double() - target.double()) ** 2).item()


def psnr(pred: Tensor, target: Tensor) -> float:
    """PSNR in dB, ``10 · log10(1 / MSE)`` with MSE over all pixels, channels and images.

    Examples
    --------
    >>> round(psnr(torch.zeros(2, 3, 4, 4), torch.full((2, 3, 4, 4), 0.25)), 4)  # MSE 1/16
    12.0412
    """
    return psnr_from_mse(mse(pred, target))


def rmse(pred: Tensor, target: Tensor) -> float:
    """The paper's RMSE, ``sqrt(3 · MSE)`` with MSE over all pixels, channels and images.

    Examples
    --------
    >>> rmse(torch.zeros(2, 3, 4, 4), torch.full((2, 3, 4, 4), 0.5)) == 0.75 ** 0.5
    True
    """
    return rmse_from_mse(mse(pred, target))


def ssim_per_image(pred: Tensor, target: Tensor, convention: str = "official") -> Tensor:
    """SSIM of each image pair, mean over its RGB channels, float64 tensor (N,).

    11×11 Gaussian window, σ = 1.5 pixels, data range 1, the border as ``convention`` says
    (:func:`structural_similarity`; under ``"skimage"`` H and W must be at least 11).

    Examples
    --------
    >>> x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    >>> ssim_per_image(x, x)
    tensor([1., 1.], dtype=torch.float64)
    """
    _check_pair(pred, target)
    return structural_similarity(pred.double(), target.double(), per_image=True,
                                 convention=convention)


def ssim(pred: Tensor, target: Tensor, convention: str = "official") -> float:
    """Mean over images of the per-image SSIM of :func:`ssim_per_image`.

    Examples
    --------
    >>> x = torch.rand(2, 3, 16, 16, generator=torch.Generator().manual_seed(0))
    >>> ssim(x, x)
    1.0
    """
    return ssim_per_image(pred, target, convention).mean().item()


def srgb_to_lab(images: Tensor) -> np.ndarray:
    """CIE Lab (D65) of (N, 3, H, W) sRGB images in [0, 1], rounded to 8 bits first: (N, H, W, 3).

    colour-science's sRGB decoding and matrix (D65 white), then ``XYZ_to_Lab`` under D65; L in
    [0, 100]. The decoding is evaluated once for the 256 levels and looked up per pixel (the
    same values as decoding every pixel, at a fraction of the time).

    Examples
    --------
    >>> lab = srgb_to_lab(torch.tensor([0.0, 1.0]).view(2, 1, 1, 1).expand(2, 3, 1, 1))
    >>> lab.shape, [round(float(v), 2) for v in lab[:, 0, 0, 0]]
    ((2, 1, 1, 3), [0.0, 100.0])
    """
    import colour

    levels = (images.detach().double().clamp(0, 1) * 255).round().to(torch.uint8)
    decoded = colour.models.eotf_sRGB(np.arange(256) / 255)
    linear = decoded[levels.permute(0, 2, 3, 1).cpu().numpy()]
    return colour.XYZ_to_Lab(colour.sRGB_to_XYZ(linear, apply_cctf_decoding=False))


def delta_e_per_image(pred: Tensor, target: Tensor) -> Tensor:
    """Mean CIEDE2000 ΔE of each image pair over its pixels, float64 tensor (N,).

    Both images are rounded to 8-bit sRGB and converted by :func:`srgb_to_lab`; the difference is
    ``colour.delta_E(..., method="CIE 2000")``.

    Examples
    --------
    >>> black, white = torch.zeros(1, 3, 2, 2), torch.ones(1, 3, 2, 2)
    >>> [round(v, 3) for v in delta_e_per_image(black, white).tolist()]
    [100.0]
    """
    import colour

    _check_pair(pred, target)
    per_pixel = colour.delta_E(srgb_to_lab(pred), srgb_to_lab(target), method="CIE 2000")
    return torch.from_numpy(np.asarray(per_pixel, np.float64).reshape(pred.shape[0], -1).mean(axis=1))


def delta_e(pred: Tensor, target: Tensor) -> float:
    """Mean CIEDE2000 ΔE over all pixels and images (:func:`delta_e_per_image`).

    Examples
    --------
    >>> x = torch.rand(2, 3, 4, 4, generator=torch.Generator().manual_seed(0))
    >>> delta_e(x, x)
    0.0
    """
    return delta_e_per_image(pred, target).mean().item()


def masked_scores(pred: Tensor, target: Tensor, mask: Tensor) -> dict[str, float]:
    """PSNR and RMSE over the pixels a mask selects (all channels, all images pooled).

    The definitions of :func:`psnr` and :func:`rmse` with the MSE taken over the selected pixels
    only; SSIM is windowed and has no masked form here.

    Parameters
    ----------
    pred, target : Tensor
        (N, 3, H, W) images in [0, 1].
    mask : Tensor
        bool (N, H, W), True where a pixel counts.

    Returns
    -------
    dict
        ``psnr`` (dB) and ``rmse``; both ``nan`` when the mask selects nothing.

    Examples
    --------
    >>> x, y = torch.zeros(1, 3, 2, 2), torch.zeros(1, 3, 2, 2)
    >>> y[..., 0, 0] = 1.0  # a wrong pixel, masked out
    >>> masked_scores(x, y, torch.tensor([[[False, True], [True, True]]]))["rmse"]
    0.0
    """
    _check_pair(pred, target)
    if mask.shape != (pred.shape[0], *pred.shape[2:]):
        raise ValueError(f"masked_scores: mask must have shape {(pred.shape[0], *pred.shape[2:])}, "
                         f"got {tuple(mask.shape)}")
    n = int(mask.sum()) * pred.shape[1]
    if n == 0:
        return {"psnr": math.nan, "rmse": math.nan}
    err = ((pred.double() - target.double()) ** 2).sum(dim=1)
    mean_squared = err[mask].sum().item() / n
    return {"psnr": psnr_from_mse(mean_squared), "rmse": rmse_from_mse(mean_squared)}


def evaluate(pred: Tensor, target: Tensor, batch_size: int = 64,
             convention: str = "official") -> dict[str, float]:
    """PSNR, RMSE, SSIM and ΔE of a whole test set, streamed over batches of ``batch_size`` images.

    Every image counts (the last batch may be smaller); the result equals :func:`psnr`,
    :func:`rmse`, :func:`ssim` and :func:`delta_e` on the full tensors up to float64 rounding.

    Parameters
    ----------
    pred, target : Tensor
        (N, 3, H, W) images in [0, 1]; under the ``"skimage"`` SSIM convention H and W at least 11.
    batch_size : int
        Images per batch (bounds the float64 working memory).
    convention : str
        SSIM convention (:data:`SSIM_CONVENTIONS`), ``"official"`` by default.

    Returns
    -------
    dict
        ``psnr`` (dB), ``rmse``, ``ssim`` and ``deltaE`` (CIEDE2000) as Python floats.

    Raises
    ------
    ValueError
        On mismatched or non-(N, 3, H, W) shapes, an unknown convention, images smaller than the
        SSIM window under ``"skimage"``, or a ``batch_size`` below 1.

    Examples
    --------
    >>> x = torch.zeros(5, 3, 16, 16)
    >>> y = torch.full((5, 3, 16, 16), 0.5)
    >>> {k: round(v, 4) for k, v in evaluate(x, y, batch_size=2).items()}
    {'psnr': 6.0206, 'rmse': 0.866, 'ssim': 0.0004, 'deltaE': 39.9345}
    """
    _check_pair(pred, target)
    if not isinstance(batch_size, int) or batch_size < 1:
        raise ValueError(f"evaluate: batch_size must be a positive integer, got {batch_size!r}")
    squared_error = ssim_sum = delta_e_sum = 0.0
    for i in range(0, pred.shape[0], batch_size):
        p, t = pred[i:i + batch_size].double(), target[i:i + batch_size].double()
        squared_error += torch.sum((p - t) ** 2).item()
        ssim_sum += ssim_per_image(p, t, convention).sum().item()
        delta_e_sum += delta_e_per_image(p, t).sum().item()
    mean_squared = squared_error / target.numel()
    return {"psnr": psnr_from_mse(mean_squared), "rmse": rmse_from_mse(mean_squared),
            "ssim": ssim_sum / pred.shape[0], "deltaE": delta_e_sum / pred.shape[0]}
