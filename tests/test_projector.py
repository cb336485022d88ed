"""Tests of sim.projector: response, black level, primaries mixing, defocus pre-blur."""
from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from sim import projector

EYE = np.eye(3)


@pytest.mark.parametrize("frame", [np.zeros((2, 3, 3), np.uint8), np.zeros((2, 3, 3))])
def test_black_input_emits_black_level(frame):
    out = projector.emitted_irradiance(frame, 2.2, 0.01, EYE)
    assert out.dtype == np.float32 and out.shape == (2, 3, 3)
    np.testing.assert_allclose(out, 0.01, rtol=1e-6)


@pytest.mark.parametrize("frame", [np.full((2, 3, 3), 255, np.uint8), np.ones((2, 3, 3))])
def test_white_input_emits_one(frame):
    np.testing.assert_allclose(projector.emitted_irradiance(frame, 2.2, 0.01, EYE), 1.0, rtol=1e-6)


def test_gamma_curve_at_half():
    out = projector.emitted_irradiance(np.full((1, 1, 3), 0.5), 2.4, 0.02, EYE)
    np.testing.assert_allclose(out, 0.02 + 0.98 * 0.5 ** 2.4, rtol=1e-6)


@pytest.mark.parametrize("shape", [(4, 5, 3), (600, 800, 3)])  # a panel: OpenCV's vector paths
def test_planted_mixing_matrix(shape):
    rng = np.random.default_rng(0)
    x = rng.random(shape)
    mix = np.array([[0.9, 0.1, 0.0], [0.05, 0.8, 0.15], [0.0, 0.2, 0.7]])
    out = projector.emitted_irradiance(x, 2.0, 0.01, mix)
    primaries = 0.01 + 0.99 * x ** 2.0
    expected = np.einsum("ij,hwj->hwi", mix, primaries)
    np.testing.assert_allclose(out, expected, rtol=1e-5)
    # A primary that only feeds one channel lights only that channel.
    only_red = np.zeros((1, 1, 3))
    only_red[..., 0] = 1.0
    np.testing.assert_allclose(projector.emitted_irradiance(only_red, 2.0, 0.0, mix)[0, 0],
                               mix[:, 0], rtol=1e-6)


def test_uint8_and_float_inputs_agree():
    frame = np.random.default_rng(1).integers(0, 256, (8, 8, 3), dtype=np.uint8)
    a = projector.emitted_irradiance(frame, 2.2, 0.005, EYE)
    b = projector.emitted_irradiance(frame / 255.0, 2.2, 0.005, EYE)
    np.testing.assert_allclose(a, b, atol=1e-6)


def test_config_convenience_matches_pure_function():
    cfg = SimpleNamespace(gamma=1.8, black_level=0.03,
                          mixing=((1.0, 0.1, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 0.9)))
    frame = np.random.default_rng(2).random((3, 4, 3))
    np.testing.assert_array_equal(
        projector.projector_irradiance(frame, cfg),
        projector.emitted_irradiance(frame, 1.8, 0.03, cfg.mixing))


@pytest.mark.parametrize("frame, mixing, match", [
    (np.zeros((4, 4)), EYE, r"\(H, W, 3\)"),
    (np.zeros((4, 4, 4)), EYE, r"\(H, W, 3\)"),
    (np.zeros((4, 4, 3)), np.eye(2), "3x3"),
    (np.full((4, 4, 3), 1.5), EYE, r"\[0, 1\]"),
    (np.full((4, 4, 3), np.nan), EYE, r"\[0, 1\]"),
])
def test_bad_input_is_rejected(frame, mixing, match):
    with pytest.raises(ValueError, match=match):
        projector.emitted_irradiance(frame, 2.2, 0.0, mixing)


def test_blur_diameter_formula():
    assert projector.defocus_blur_diameter_px(0.02, 1.0, 1.0, 30.0, 256) == 0.0
    assert projector.defocus_blur_diameter_px(0.0, 1.0, 1.7, 30.0, 256) == 0.0
    # Behind focus: c = 0.02 * 0.5 / 1 = 0.01 m; pixel pitch 2 * 1.5 * tan(15 deg) / 256 m.
    expected = 0.01 / (3.0 * 0.2679491924311227 / 256)
    assert projector.defocus_blur_diameter_px(0.02, 1.0, 1.5, 30.0, 256) == \
        pytest.approx(expected, rel=1e-12) == pytest.approx(3.18469, rel=1e-5)
    # In front of focus: the same 0.01 m disk over a pitch three times smaller.
    assert projector.defocus_blur_diameter_px(0.02, 1.0, 0.5, 30.0, 256) == \
        pytest.approx(3 * expected, rel=1e-12)
    with pytest.raises(ValueError, match="distance"):
        projector.defocus_blur_diameter_px(0.02, 0.0, 1.0, 30.0, 256)


@pytest.mark.parametrize("diameter", [0.0, 5e-4, 0.3, 2.0, 5.0, 7.3, 12.4])
def test_disk_kernel_normalised_and_symmetric(diameter):
    k = projector.disk_kernel(diameter)
    assert k.dtype == np.float32 and k.shape[0] == k.shape[1] and k.shape[0] % 2 == 1
    assert k.sum() == pytest.approx(1.0, abs=1e-6)
    assert np.all(k >= 0)
    for sym in (k.T, k[::-1], k[:, ::-1], np.rot90(k)):
        np.testing.assert_array_equal(k, sym)
    assert k[0].any() and k[:, 0].any()  # no empty border


def test_disk_kernel_identity_and_moments():
    assert projector.disk_kernel(0.0).tolist() == [[1.0]]
    d = 12.4
    k = projector.disk_kernel(d).astype(np.float64)
    c = (k.shape[0] - 1) // 2
    x = np.arange(-c, c + 1)
    # Second moment of a uniform disk of radius r: r^2 / 4 per axis (+1/12 for the pixel box).
    assert (k.sum(axis=0) * x ** 2).sum() == pytest.approx((d / 2) ** 2 / 4 + 1 / 12, rel=0.01)
    # Radial profile: full coverage inside, none outside the disk.
    r = np.hypot(*np.meshgrid(x, x))
    assert np.ptp(k[r < d / 2 - 1]) < 1e-7 and np.all(k[r > d / 2 + 1] == 0)


def test_defocus_preserves_energy_of_interior_spot():
    img = np.zeros((48, 48, 3), np.float32)
    img[22:26, 20:23] = [1.0, 0.5, 0.25]
    out = projector.defocus(img, 7.3)
    assert out.dtype == np.float32 and out.shape == img.shape
    np.testing.assert_allclose(out.sum(axis=(0, 1)), img.sum(axis=(0, 1)), rtol=1e-5)
    assert out[:, :, 0].max() < 0.5 and (out[:, :, 0] > 1e-6).sum() > 4 * (img[:, :, 0] > 0).sum()


def test_defocus_widens_a_line_by_the_diameter():
    img = np.zeros((65, 65, 3), np.float32)
    img[:, 32] = 1.0
    d = 9.0
    profile = projector.defocus(img, d)[32, :, 1].astype(np.float64)
    support = np.flatnonzero(profile > 1e-6)
    assert len(support) == 9 and support[0] == 28 and support[-1] == 36
    x = np.arange(65) - 32
    std = math.sqrt((profile * x ** 2).sum() / profile.sum())
    assert std == pytest.approx(math.sqrt((d / 2) ** 2 / 4 + 1 / 12), rel=0.02)


def test_defocus_is_linear_and_zero_outside_the_frame():
    rng = np.random.default_rng(3)
    a, b = rng.random((2, 20, 24, 3), dtype=np.float32)
    d = 4.5
    np.testing.assert_allclose(projector.defocus(a + b, d),
                               projector.defocus(a, d) + projector.defocus(b, d), atol=1e-5)
    # A uniform frame loses light at its border (nothing comes in from outside).
    flat = projector.defocus(np.ones((20, 24, 3), np.float32), d)
    assert flat[10, 12, 0] == pytest.approx(1.0, abs=1e-5) and flat[0, 0, 0] < 0.5


def test_defocus_zero_diameter_is_identity():
    img = np.random.default_rng(4).random((6, 7, 3)).astype(np.float32)
    out = projector.defocus(img, 0.0)
    np.testing.assert_array_equal(out, img)
    assert out is not img
