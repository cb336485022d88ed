"""Losses and the paper's metrics: SSIM (official convention) against an independent filter, the
scikit-image convention against scikit-image, PSNR/RMSE and CIEDE2000 by hand, all images count."""
from __future__ import annotations

import doctest
import math

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter
from skimage import data
from skimage.metrics import structural_similarity

from compensation.scores import losses, metrics
from compensation.methods import compennet


def to_tensor(images: list[np.ndarray]) -> torch.Tensor:
    """(H, W, 3) float arrays -> (N, 3, H, W) float64 tensor."""
    return torch.from_numpy(np.stack(images)).permute(0, 3, 1, 2).contiguous()


def skimage_ssim(a: np.ndarray, b: np.ndarray) -> float:
    return structural_similarity(a, b, channel_axis=-1, gaussian_weights=True, sigma=1.5,
                                 use_sample_covariance=False, data_range=1)


def official_ssim(a: np.ndarray, b: np.ndarray) -> float:
    """The official code's SSIM written from its definition: an 11×11 σ = 1.5 Gaussian over the
    image with its border replicated by 5 pixels (``mode="nearest"``, radius 5), a map of the image's
    size, C1 = 0.01², C2 = 0.03², mean over pixels and channels."""
    def blur(x):
        return gaussian_filter(x, sigma=(1.5, 1.5, 0), mode="nearest", truncate=5 / 1.5)

    mu_a, mu_b = blur(a), blur(b)
    var_a, var_b = blur(a * a) - mu_a ** 2, blur(b * b) - mu_b ** 2
    cov = blur(a * b) - mu_a * mu_b
    c1, c2 = 0.01 ** 2, 0.03 ** 2
    ssim_map = ((2 * mu_a * mu_b + c1) * (2 * cov + c2)) / ((mu_a ** 2 + mu_b ** 2 + c1) * (var_a + var_b + c2))
    assert ssim_map.shape == a.shape
    return float(ssim_map.mean())


def natural_pairs(size: tuple[int, int]) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Crops of bundled photographs (targets) and noisy / blurred / dimmed versions (predictions)."""
    h, w = size
    rng = np.random.default_rng(0)
    targets, preds = [], []
    for image, (y, x) in ((data.astronaut(), (100, 180)), (data.chelsea(), (50, 150)),
                          (data.coffee(), (100, 200))):
        a = image[y:y + h, x:x + w].astype(np.float64) / 255
        for b in (np.clip(a + rng.normal(0, 0.1, a.shape), 0, 1),
                  gaussian_filter(a, sigma=(1.2, 1.2, 0)),
                  np.clip(0.7 * a + 0.1 + rng.normal(0, 0.02, a.shape), 0, 1)):
            targets.append(a)
            preds.append(b)
    return targets, preds


@pytest.mark.parametrize("size", [(64, 64), (128, 128), (64, 96)])
def test_ssim_matches_skimage_on_natural_images(size):
    targets, preds = natural_pairs(size)
    expected = np.array([skimage_ssim(a, b) for a, b in zip(targets, preds)])
    assert expected.min() < 0.5 and expected.max() > 0.8  # a spread of qualities
    target, pred = to_tensor(targets), to_tensor(preds)
    per_image = metrics.ssim_per_image(pred, target, convention="skimage").numpy()
    # Same window, constants and averaging region: float64 agrees to rounding.
    np.testing.assert_allclose(per_image, expected, rtol=0, atol=1e-10)
    assert metrics.ssim(pred, target, "skimage") == pytest.approx(expected.mean(), abs=1e-10)


@pytest.mark.parametrize("size", [(64, 64), (32, 48), (12, 11)])
def test_official_ssim_matches_its_definition(size):
    targets, preds = natural_pairs(size)
    expected = np.array([official_ssim(a, b) for a, b in zip(targets, preds)])
    target, pred = to_tensor(targets), to_tensor(preds)
    np.testing.assert_allclose(metrics.ssim_per_image(pred, target).numpy(), expected, rtol=0, atol=1e-6)
    assert metrics.ssim(pred, target) == pytest.approx(expected.mean(), abs=1e-6)
    assert metrics.evaluate(pred, target, batch_size=4)["ssim"] == pytest.approx(expected.mean(), abs=1e-6)
    # The float32 training SSIM (what the losses use) is the same definition, to float32 rounding.
    loss_ssim = metrics.structural_similarity(pred.float(), target.float(), per_image=True).double().numpy()
    np.testing.assert_allclose(loss_ssim, expected, rtol=0, atol=1e-4)
    assert 1 - losses.ssim_loss(pred.float(), target.float()).item() == pytest.approx(expected.mean(),
                                                                                       abs=1e-4)
    # The conventions differ by the border windows only.
    if min(size) > 11:
        skimage = np.array([skimage_ssim(a, b) for a, b in zip(targets, preds)])
        assert np.abs(expected - skimage).max() > 1e-3


def test_ssim_conventions_by_name():
    x = torch.rand(1, 3, 16, 8, generator=torch.Generator().manual_seed(0))
    assert metrics.ssim(x, x) == 1.0  # the official border makes any size at least the window
    with pytest.raises(ValueError, match=r"at least 11 pixels \(skimage convention\)"):
        metrics.ssim(x, x, "skimage")
    with pytest.raises(ValueError, match="convention 'matlab': expected one of official, skimage"):
        metrics.evaluate(x, x, convention="matlab")


def srgb_lightness(v: int) -> float:
    """CIE L* of the neutral 8-bit sRGB grey ``v`` (IEC 61966-2-1 decoding, CIE 1976 lightness)."""
    c = v / 255
    y = c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4
    return 116 * y ** (1 / 3) - 16 if y > (6 / 29) ** 3 else y * (29 / 3) ** 3


def test_lab_of_every_level_matches_colour_per_pixel():
    """srgb_to_lab looks the decoding up per 8-bit level: the same Lab as colour-science decoding
    every pixel, levels rounded half to even (values at half a level and outside [0, 1] included)."""
    import colour

    x = torch.rand(3, 3, 9, 10, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    x[0, 0, 0, :6] = torch.tensor([0.5, 1.5, 2.5, 254.5, -3.0, 300.0], dtype=torch.float64) / 255
    rgb = np.rint(x.clamp(0, 1).permute(0, 2, 3, 1).numpy() * 255) / 255
    expected = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(rgb))
    assert np.array_equal(metrics.srgb_to_lab(x), expected)
    assert np.array_equal(metrics.srgb_to_lab(x.float()), colour.XYZ_to_Lab(colour.sRGB_to_XYZ(
        np.rint(x.float().double().clamp(0, 1).permute(0, 2, 3, 1).numpy() * 255) / 255)))


def test_delta_e_by_hand():
    """CIEDE2000 of neutral greys reduces to ΔL' / S_L with S_L = 1 + 0.015 (L̄ − 50)² / √(20 + (L̄ − 50)²)."""
    def grey(v, n=1):
        return torch.full((n, 3, 4, 4), v / 255, dtype=torch.float64)

    assert metrics.delta_e(grey(0), grey(255)) == pytest.approx(100.0, abs=1e-3)
    l1, l2 = srgb_lightness(60), srgb_lightness(200)
    mean = (l1 + l2) / 2
    expected = (l2 - l1) / (1 + 0.015 * (mean - 50) ** 2 / math.sqrt(20 + (mean - 50) ** 2))
    assert metrics.delta_e(grey(60), grey(200)) == pytest.approx(expected, abs=1e-3)
    # 8-bit sRGB: values are rounded to the same level before the conversion.
    assert metrics.delta_e(grey(60), grey(60) + 0.4 / 255) == 0.0
    # The mean over pixels and images: half the pixels of one of two images differ.
    pred, target = grey(60, 2), grey(60, 2)
    pred[1, :, :2] = 200 / 255
    assert metrics.delta_e_per_image(pred, target).tolist() == pytest.approx([0.0, expected / 2], abs=1e-3)
    assert metrics.evaluate(pred, target)["deltaE"] == pytest.approx(expected / 4, abs=1e-3)


def test_gaussian_window():
    w = metrics.gaussian_window()
    assert w.dtype == torch.float64 and w.shape == (1, 1, 1, metrics.WIN_SIZE) == (1, 1, 1, 11)
    assert w.sum().item() == pytest.approx(1.0, abs=1e-15)
    x = torch.arange(11, dtype=torch.float64) - 5
    expected = torch.exp(-x ** 2 / (2 * metrics.WIN_SIGMA ** 2))
    torch.testing.assert_close(w.flatten(), expected / expected.sum(), rtol=0, atol=1e-16)
    assert metrics.WIN_SIGMA == 1.5


def test_psnr_rmse_by_hand():
    target = torch.zeros(2, 3, 2, 2)
    pred = target.clone()
    pred[0] = 0.5   # 12 values with squared error 0.25
    pred[1, 0] = 0.25  # 4 values with squared error 0.0625
    mse = (12 * 0.25 + 4 * 0.0625) / 24
    assert metrics.mse(pred, target) == pytest.approx(mse, rel=1e-12)
    assert metrics.psnr(pred, target) == pytest.approx(10 * math.log10(1 / mse), rel=1e-12)
    assert metrics.rmse(pred, target) == pytest.approx(math.sqrt(3 * mse), rel=1e-12)
    assert metrics.psnr(target, target) == math.inf
    assert metrics.rmse(target, target) == 0.0


def test_evaluate_counts_every_image():
    # Five images with constant errors 0.1 ... 0.5; batch 2 leaves a remainder of one image.
    n = 5
    g = torch.Generator().manual_seed(0)
    target = 0.25 + 0.5 * torch.rand(n, 3, 16, 16, generator=g)
    errors = torch.tensor([0.1, 0.2, 0.3, 0.4, 0.5])
    pred = target + errors.view(n, 1, 1, 1)
    mse = float(np.mean(errors.double().numpy() ** 2))
    result = metrics.evaluate(pred, target, batch_size=2)
    assert set(result) == {"psnr", "rmse", "ssim", "deltaE"}
    assert all(type(v) is float for v in result.values())
    assert result["psnr"] == pytest.approx(10 * math.log10(1 / mse), rel=1e-6)
    assert result["rmse"] == pytest.approx(math.sqrt(3 * mse), rel=1e-6)
    per_image = [metrics.ssim(pred[i:i + 1], target[i:i + 1]) for i in range(n)]
    assert result["ssim"] == pytest.approx(np.mean(per_image), abs=1e-12)
    # Dropping the last image (as the official code does with a remainder) would change both.
    dropped = metrics.evaluate(pred[:4], target[:4], batch_size=2)
    assert abs(dropped["psnr"] - result["psnr"]) > 0.5
    assert abs(dropped["ssim"] - result["ssim"]) > 1e-4
    whole = {"psnr": metrics.psnr(pred, target), "rmse": metrics.rmse(pred, target),
             "ssim": metrics.ssim(pred, target), "deltaE": metrics.delta_e(pred, target)}
    for batch_size in (1, 3, 64):
        assert metrics.evaluate(pred, target, batch_size=batch_size) == pytest.approx(whole,
                                                                                      rel=1e-12)


@pytest.mark.parametrize(("pred_shape", "target_shape", "match"), [
    ((2, 3, 16, 16), (2, 3, 16, 12), "shapes differ"),
    ((2, 3, 16, 16), (3, 3, 16, 16), "shapes differ"),
    ((2, 2, 16, 16), (2, 2, 16, 16), r"\(N, 3, H, W\) with N > 0, got \(2, 2, 16, 16\)"),
    ((3, 16, 16), (3, 16, 16), r"\(N, 3, H, W\) with N > 0"),
    ((0, 3, 16, 16), (0, 3, 16, 16), "N > 0"),
])
def test_evaluate_rejects_bad_shapes(pred_shape, target_shape, match):
    with pytest.raises(ValueError, match=match):
        metrics.evaluate(torch.zeros(pred_shape), torch.zeros(target_shape))


def test_evaluate_rejects_bad_batch_size():
    x = torch.zeros(2, 3, 16, 16)
    with pytest.raises(ValueError, match="batch_size must be a positive integer, got 0"):
        metrics.evaluate(x, x, batch_size=0)


def test_loss_values():
    target = torch.zeros(2, 3, 16, 16)
    pred = target.clone()
    pred[0] = 0.5
    pred[1, :, :8] = 1.0
    assert losses.l1(pred, target).item() == pytest.approx((0.5 + 0.5) / 2)
    assert losses.l2(pred, target).item() == pytest.approx((0.25 + 0.5) / 2)
    g = torch.Generator().manual_seed(0)
    x = torch.rand(2, 3, 16, 16, generator=g)
    assert losses.l1_ssim(x, x).item() == pytest.approx(0.0, abs=1e-6)
    assert losses.ssim_loss(x, x).item() == pytest.approx(0.0, abs=1e-6)
    y = torch.rand(2, 3, 16, 16, generator=g)
    assert losses.l1_ssim(x, y).item() == pytest.approx(
        losses.l1(x, y).item() + 1 - metrics.structural_similarity(x, y).item(), abs=1e-6)
    assert 0.9 < losses.ssim_loss(x, y).item() < 1.1  # independent noise: SSIM near 0
    # The sums of the official code's later versions are the sums of their terms.
    terms = {"l1": losses.l1(x, y).item(), "l2": losses.l2(x, y).item(),
             "ssim": losses.ssim_loss(x, y).item()}
    for name in ("l1+ssim", "l1+l2", "l2+ssim", "l1+l2+ssim"):
        expected = sum(terms[t] for t in name.split("+"))
        assert losses.get_loss(name)(x, y).item() == pytest.approx(expected, abs=1e-6), name


@pytest.mark.parametrize("name", sorted(losses.LOSSES))
def test_gradients_flow(name):
    g = torch.Generator().manual_seed(0)
    target = torch.rand(2, 3, 16, 16, generator=g)
    pred = torch.rand(2, 3, 16, 16, generator=g).requires_grad_()
    loss = losses.get_loss(name)(pred, target)
    assert loss.ndim == 0
    loss.backward()
    assert torch.isfinite(pred.grad).all() and pred.grad.abs().sum() > 0
    # A small step against the gradient lowers the loss.
    with torch.no_grad():
        stepped = losses.get_loss(name)(pred - 1e-2 * pred.grad / pred.grad.abs().max(), target)
    assert stepped < loss


def test_get_loss():
    assert list(losses.LOSSES) == ["l1", "l2", "ssim", "l1+ssim", "l1+l2", "l2+ssim", "l1+l2+ssim"]
    assert losses.get_loss("l1+ssim") is losses.l1_ssim
    assert losses.get_loss("ssim") is losses.ssim_loss
    with pytest.raises(ValueError,
                       match=r"unknown loss 'mse'; choose one of: l1, l2, ssim, l1\+ssim, l1\+l2, "):
        losses.get_loss("mse")


def test_ssim_loss_shapes():
    x = torch.rand(1, 3, 8, 8, generator=torch.Generator().manual_seed(0))
    assert losses.ssim_loss(x, x).abs().item() < 1e-6  # the official border: smaller than the window
    with pytest.raises(ValueError, match="shapes differ"):
        metrics.structural_similarity(torch.zeros(1, 3, 16, 16), torch.zeros(1, 3, 16, 12))


@pytest.mark.parametrize("module", [losses, metrics, compennet])
def test_modules_keep_their_examples(module):
    """The examples themselves run with the doctests of every module (``--doctest-modules`` in
    pyproject.toml); these modules must keep some."""
    assert sum(len(t.examples) for t in doctest.DocTestFinder().find(module)) > 0
