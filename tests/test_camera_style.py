"""The camera's processing of the encoded image: the picture style (S-shaped tone curve,
saturation), sharpening (unsharp mask) and the content-adaptive tone; where the camera applies them
(after the response curve, before the 8-bit quantisation), and that off they change nothing."""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from sim import camera
from sim.camera import adaptive, sensor, style
from sim.errors import SetupError
from sim.setup import parse_setup
from sim.setup.schema import CameraConfig

STYLED = {"adaptive_tone": 0.6, "style_contrast": 0.4, "style_saturation": 1.3, "sharpen_radius": 1.2,
          "sharpen_amount": 0.8}


def _signal(seed: int, shape=(61, 83, 3), scale: float = 1.0) -> np.ndarray:
    return np.random.default_rng(seed).random(shape, dtype=np.float32) * np.float32(scale)


# ------------------------------------------------------------------------------------ picture style

@pytest.mark.parametrize("contrast", [0.2, 0.5, 1.0])
def test_s_curve_fixes_black_mid_grey_and_white_and_steepens_the_mid_tones(contrast):
    v = np.linspace(0, 1, 1001, dtype=np.float32)
    out = style.contrast_curve(v, contrast)
    assert out[0] == 0.0 and out[500] == 0.5 and out[-1] == 1.0
    assert np.all(np.diff(out) >= 0)  # monotone
    around = style.contrast_curve(np.array([0.499, 0.501], np.float32), contrast)
    assert (around[1] - around[0]) / 0.002 == pytest.approx(1 + contrast / 2, rel=1e-3)  # the slope
    assert np.all(out[300:500] < v[300:500]) and np.all(out[501:700] > v[501:700])  # pulled from grey
    np.testing.assert_array_equal(style.contrast_curve(v, 0.0), v)


def test_saturation_leaves_greys_and_luma_and_scales_chroma():
    greys = np.repeat(np.linspace(0, 1, 11, dtype=np.float32)[None, :, None], 3, axis=2)
    for s in (0.0, 0.5, 2.0):
        np.testing.assert_allclose(style.saturate(greys, s), greys, atol=1e-6)
    colours = np.random.default_rng(1).uniform(0.35, 0.65, (8, 8, 3)).astype(np.float32)
    y = style.luma(colours)
    for s in (0.0, 0.5, 1.6):  # within [0, 1]: no clipping
        out = style.saturate(colours, s)
        np.testing.assert_allclose(style.luma(out), y, atol=1e-6)
        np.testing.assert_allclose(out - y, s * (colours - y), atol=1e-6)


def test_unsharp_mask_keeps_a_flat_field_and_overshoots_an_edge_by_the_predicted_amount():
    sigma, amount, lo, hi = 1.5, 1.0, 0.2, 0.6
    flat = np.full((20, 30, 3), 0.4, np.float32)
    np.testing.assert_allclose(style.unsharp_mask(flat, sigma, amount), flat, atol=1e-6)
    edge = np.full((20, 40, 3), lo, np.float32)
    edge[:, 20:] = hi  # a grey step between columns 19 and 20
    out = style.unsharp_mask(edge, sigma, amount)
    # the blurred step at the first bright column lacks the kernel's weight past the edge
    r = int(np.ceil(4 * sigma))
    w = np.exp(-np.arange(-r, r + 1) ** 2 / (2 * sigma**2))
    past = w[r + 1:].sum() / w.sum()
    overshoot = amount * (hi - lo) * past
    np.testing.assert_allclose(out[:, 20], hi + overshoot, rtol=1e-5)
    np.testing.assert_allclose(out[:, 19], lo - overshoot, rtol=1e-5)
    assert overshoot == pytest.approx(0.4 * 0.367, rel=0.01)  # 1 - Phi(0.5 / sigma) for a wide sigma
    np.testing.assert_allclose(out[:, :10], lo, atol=1e-6)  # far from the edge: unchanged
    np.testing.assert_allclose(out[:, 30:], hi, atol=1e-6)


# ------------------------------------------------------------------------------------ adaptive tone

def test_adaptive_tone_lifts_a_dark_frames_shadows_by_its_formula():
    v = _signal(2, (40, 40, 3), 0.4)
    v[0, 0] = 0.0
    m = float(np.mean(v.reshape(-1, 3), axis=0) @ np.asarray(style.LUMA))
    assert m == pytest.approx(0.2, abs=0.01)
    out = adaptive.shadow_lift(v, 1.0)
    k = 1.0 - 2 * m
    np.testing.assert_allclose(out, v + k * v * (1 - v) ** 2, rtol=1e-5)
    assert out[0, 0, 0] == 0.0 and np.all(out[v > 0] > v[v > 0])
    # the darker the frame, the stronger the lift of the same value
    lifted = []
    for scale in (0.7, 0.5, 0.3):  # mean luma 0.45, 0.35, 0.25
        frame = np.full((4, 4, 3), 0.2, np.float32)
        frame[:2] = scale
        lifted.append(adaptive.shadow_lift(frame, 1.0)[3, 0, 0])
    assert 0.2 < lifted[0] < lifted[1] < lifted[2]


def test_adaptive_tone_leaves_a_mid_grey_or_brighter_frame_unchanged():
    half = np.full((10, 10, 3), 0.25, np.float32)
    half[:, 5:] = 0.75  # mean luma 1/2
    np.testing.assert_array_equal(adaptive.shadow_lift(half, 1.0), half)
    bright = _signal(3, (10, 10, 3)) * 0.4 + 0.5
    assert adaptive.shadow_lift(bright, 1.0) is bright


# ------------------------------------------------------------------------------------ in the camera

def test_processing_acts_between_the_response_curve_and_the_quantisation():
    """Without a Bayer sensor: the capture is the noisy signal's encoding, processed in order, then
    rint(255 x), bit for bit (one quantisation)."""
    rad = _signal(4, scale=0.9)
    cfg = replace(CameraConfig(), **STYLED)
    signal = camera.sensor_signal(rad, cfg.exposure, cfg.white_balance, cfg.shot_noise, cfg.read_noise,
                                  np.random.default_rng(9))
    v = camera.encode(signal, cfg.response)
    v = style.unsharp_mask(style.saturate(style.contrast_curve(adaptive.shadow_lift(v, 0.6), 0.4), 1.3), 1.2, 0.8)
    np.testing.assert_array_equal(camera.capture(rad, cfg, np.random.default_rng(9)), camera.quantise(v))


@pytest.mark.parametrize("method", ["bilinear", "vng"])
def test_processing_follows_demosaicing(method):
    """With a Bayer sensor the processing acts on the demosaiced, encoded image: the styled capture
    is the plain one's encoded image processed (at 16-bit raw precision; VNG's at 8 bits)."""
    rad = _signal(5, scale=0.8)
    plain = replace(CameraConfig(), bayer="RGGB", demosaic=method)
    styled = replace(plain, **STYLED)
    got = camera.capture(rad, styled, np.random.default_rng(3))
    if method == "vng":  # OpenCV's VNG is 8-bit only: the plain capture's codes are processed
        encoded = camera.capture(rad, plain, np.random.default_rng(3)).astype(np.float32) * np.float32(1 / 255)
    else:  # the demosaiced 16-bit raw image, encoded
        raw = camera.raw_signal(rad, styled, np.random.default_rng(3))
        rgb = camera.demosaic(np.rint(raw * np.float32(65535)).astype(np.uint16), "RGGB", method)
        encoded = camera.encode(rgb.astype(np.float32) * np.float32(1 / 65535), styled.response)
    np.testing.assert_array_equal(got, camera.quantise(sensor.process(encoded, styled)))


def test_off_values_capture_bit_for_bit_as_before():
    """At their off values (whatever the sharpening radius) the processing stages are skipped:
    the capture is the one of a camera without their keys, with or without a Bayer sensor."""
    rad = _signal(6, scale=1.1)
    off = replace(CameraConfig(), sharpen_radius=3.0)
    assert all(stage.is_off(off) for stage, _ in sensor.PROCESSING)
    for extra in ({}, {"bayer": "GRBG"}, {"bayer": "RGGB", "demosaic": "vng"}):
        bare = SimpleNamespace(exposure=1.0, white_balance=(1.0, 1.0, 1.0), shot_noise=2e-4, read_noise=2e-3,
                               response="sRGB", bit_depth=8, **extra)
        np.testing.assert_array_equal(camera.capture(rad, replace(off, **extra), np.random.default_rng(7)),
                                      camera.capture(rad, bare, np.random.default_rng(7)))
    cfg = replace(CameraConfig(), shot_noise=0.0, read_noise=0.0)
    signal = camera.sensor_signal(rad, 1.0, (1.0, 1.0, 1.0))
    np.testing.assert_array_equal(camera.capture(rad, replace(cfg, sharpen_radius=3.0), None),
                                  camera.quantise(camera.encode(signal, "sRGB")))


# ------------------------------------------------------------------------------------ keys

@pytest.mark.parametrize("key, value, expected", [
    ("style_contrast", 1.5, "expected a number in [0, 1]"),
    ("style_saturation", -0.1, "expected a number in [0, 2]"),
    ("sharpen_radius", 0.0, "expected a number in (0, 5] camera pixels"),
    ("sharpen_radius", 6, "expected a number in (0, 5] camera pixels"),
    ("sharpen_amount", 3.5, "expected a number in [0, 3]"),
    ("adaptive_tone", 2, "expected a number in [0, 1]"),
    ("adaptive_tone", True, "expected a number in [0, 1]"),
])
def test_bad_processing_keys_are_named(key, value, expected):
    with pytest.raises(SetupError) as err:
        parse_setup({"name": "n", "camera": {key: value}}, source="x.toml")
    assert f"x.toml: camera.{key} = " in str(err.value) and expected in str(err.value)


def test_processing_keys_default_off():
    d = parse_setup({"name": "n"}).camera
    assert (d.adaptive_tone, d.style_contrast, d.style_saturation, d.sharpen_amount) == (0.0, 0.0, 1.0, 0.0)
