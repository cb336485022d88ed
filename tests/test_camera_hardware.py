"""Tests of the camera hardware model: the fast 8-bit encoder against the straightforward
definition, and the physics of each effect (PSF width, veiling glare, Bayer sampling and
per-channel noise after white balance, vignetting falloff, a checkerboard through distortion, JPEG,
exposure rule)."""
from __future__ import annotations

import math
import tomllib
from dataclasses import replace
from types import SimpleNamespace

import cv2
import numpy as np
import pytest

from helpers import tiny_setup
from sim import camera
from sim.camera import optics
from sim.errors import SetupError
from sim.setup import dump_setup, parse_setup
from sim.setup.schema import CameraConfig

LINEAR = replace(CameraConfig(), response="linear", shot_noise=0.0, read_noise=0.0)


def straightforward_noise(s, cfg, rng):
    """The noise of this process's version written plainly. Version 3: the kernel on the whole
    signal, keyed by one 64-bit draw (its law is tested in ``test_camera_kernel.py``). Version 2:
    float64 draws block by block of ``camera.BLOCK`` values, block k from the k-th spawned child
    generator, one thread. Then the full-well clip; float32."""
    if camera.noise_version() == 3:
        from sim.camera.kernel import noisy_signal
        return noisy_signal(s, cfg.shot_noise, cfg.read_noise, int(rng.integers(2**64, dtype=np.uint64)))
    flat, noisy = s.ravel(), []
    starts = range(0, flat.size, camera.BLOCK)
    for start, g in zip(starts, rng.spawn(len(starts))):
        b = flat[start:start + camera.BLOCK].astype(np.float64)
        if cfg.shot_noise > 0:
            b = cfg.shot_noise * g.poisson(b / cfg.shot_noise)
        if cfg.read_noise > 0:
            b = b + cfg.read_noise * g.standard_normal(b.size, np.float32)
        noisy.append(b)
    return np.clip(np.concatenate(noisy), 0.0, 1.0).astype(np.float32).reshape(s.shape)


def straightforward_capture(radiance, cfg, rng):
    """The camera model written plainly (all hardware effects off): the exposed signal, its noise
    (:func:`straightforward_noise`), then the response curve and rint(255 x)."""
    rad = np.asarray(radiance, dtype=np.float32)
    s = np.maximum(rad * np.float32(cfg.exposure) * np.asarray(cfg.white_balance, np.float32), 0.0)
    return camera.quantise(camera.encode(straightforward_noise(s, cfg, rng), cfg.response))


@pytest.mark.parametrize("response", ["sRGB", "linear", "gamma:2.2", "ITU-R BT.709", "scurve:9",
                                      "scurve:0.2", "gamma:0.15"])
def test_codes_equal_encode_then_quantise_bit_for_bit(response):
    rng = np.random.default_rng(0)
    t = camera.code_thresholds(response)
    x = np.concatenate([rng.random(100_000, dtype=np.float32) * 1.4 - 0.2,
                        rng.random(20_000, dtype=np.float32) ** 12,  # deep shadows
                        (t - 1).view(np.float32), t.view(np.float32), (t + 1).view(np.float32),
                        np.array([-0.0, 0.0, 1.0, 7.0, -3.0, 1e-38], np.float32)])
    np.testing.assert_array_equal(camera.codes(x, response), camera.quantise(camera.encode(x, response)))


@pytest.mark.parametrize("pattern,method", [("RGGB", "bilinear"), ("GRBG", "edgeaware"), ("BGGR", "vng")])
def test_bayer_capture_is_bit_identical_to_the_straightforward_model(pattern, method):
    """The Bayer path (mosaic by slices, the encoder in threaded blocks) against the chain written
    plainly: mosaic by the channel map, the plain noise on its sites, white balance, clip, 16-bit
    quantisation, OpenCV, then the whole image's response and rint."""
    rng = np.random.default_rng(2)
    rad = rng.random((211, 163, 3), dtype=np.float32) * 1.2  # odd sides, several blocks
    cfg = replace(CameraConfig(), bayer=pattern, demosaic=method, white_balance=(1.6, 1.0, 1.3))
    site = camera.channel_map(pattern, 163, 211)
    plain = np.take_along_axis(rad, site[..., None], axis=2)[..., 0]
    noisy = straightforward_noise(np.maximum(plain * np.float32(cfg.exposure), 0.0), cfg,
                                  np.random.default_rng(9))
    wb = np.clip(noisy * np.asarray(cfg.white_balance, np.float32)[site], 0.0, 1.0)
    cv_pattern = {"RGGB": "BG", "BGGR": "RG", "GRBG": "GB", "GBRG": "GR"}[pattern]  # OpenCV's names
    if method == "vng":
        expected = cv2.cvtColor(camera.quantise(camera.encode(wb, cfg.response)),
                                getattr(cv2, f"COLOR_Bayer{cv_pattern}2RGB_VNG"))
    else:
        q = np.rint(wb * np.float32(65535)).astype(np.uint16)
        suffix = "_EA" if method == "edgeaware" else ""
        rgb = cv2.cvtColor(q, getattr(cv2, f"COLOR_Bayer{cv_pattern}2RGB{suffix}"))
        expected = camera.quantise(camera.encode(rgb.astype(np.float32) * np.float32(1 / 65535),
                                                 cfg.response))
    np.testing.assert_array_equal(camera.capture(rad, cfg, np.random.default_rng(9)), expected)


@pytest.mark.parametrize("kw", [{}, {"shot_noise": 0.0}, {"read_noise": 0.0},
                                {"white_balance": (1.3, 1.0, 0.6), "response": "gamma:2.2",
                                 "exposure": 1.7}])
def test_capture_is_bit_identical_to_the_straightforward_model(kw):
    rng = np.random.default_rng(1)
    rad = (rng.random((267, 145, 3), dtype=np.float32) * 1.3 - 0.1)  # blocks, the last partial
    cfg = replace(CameraConfig(), **kw)
    fast = camera.capture(rad, cfg, np.random.default_rng(9))
    np.testing.assert_array_equal(fast, straightforward_capture(rad, cfg, np.random.default_rng(9)))
    # the same draws as the signal function
    signal = camera.sensor_signal(rad, cfg.exposure, cfg.white_balance, cfg.shot_noise, cfg.read_noise,
                                  np.random.default_rng(9))
    np.testing.assert_array_equal(fast, camera.quantise(camera.encode(signal, cfg.response)))


def test_effects_off_by_default_and_free():
    rad = np.random.default_rng(2).random((20, 30, 3), dtype=np.float32)
    assert camera.apply_optics(rad, CameraConfig()) is rad
    bare = SimpleNamespace(exposure=1.0, white_balance=(1.0, 1.0, 1.0), shot_noise=2e-4, read_noise=2e-3,
                           response="sRGB", bit_depth=8)  # an object without the hardware keys
    np.testing.assert_array_equal(camera.capture(rad, CameraConfig(), np.random.default_rng(3)),
                                  camera.capture(rad, bare, np.random.default_rng(3)))


def test_psf_of_a_point_has_the_set_width():
    img = np.zeros((81, 81, 3), np.float32)
    img[40, 40] = 1.0
    for sigma in (0.7, 1.5, 3.0):
        out = camera.apply_optics(img, replace(CameraConfig(), psf_sigma=sigma))[..., 1].astype(np.float64)
        assert out.sum() == pytest.approx(1.0, rel=1e-5)  # energy kept
        y, x = np.mgrid[:81, :81]
        var_x = (out * (x - 40) ** 2).sum()
        var_y = (out * (y - 40) ** 2).sum()
        # a sampled Gaussian's variance is sigma^2 (+1/12 below one pixel, where sampling matters)
        assert var_x == pytest.approx(sigma**2, rel=0.06) and var_y == pytest.approx(var_x, rel=1e-6)
        assert out[40, 40] == out.max()


def test_glare_lifts_a_black_patch_in_white_by_the_veiling_glare():
    """ISO 9358's setup: a black patch in a white field receives the glare fraction times the share
    of the veil's Gaussian that falls on the white (the field reaches 10 sigma; the patch holds
    erf(h / (sigma sqrt 2))² of it); the light is kept and the stage is linear."""
    size, half, glare, sigma = 256, 8, 0.03, 0.05  # sigma: 12.8 px
    white = np.ones((size, size, 3), np.float32)
    white[128 - half:128 + half, 128 - half:128 + half] = 0.0
    cfg = replace(CameraConfig(), glare=glare, glare_sigma=sigma)
    out = camera.apply_optics(white, cfg)
    s = sigma * size
    in_patch = math.erf(half / (s * math.sqrt(2))) ** 2
    assert out[127:129, 127:129].mean() == pytest.approx(glare * (1 - in_patch), rel=0.03)
    assert out[40, 40, 0] == pytest.approx(1.0, abs=1e-3)  # far from the patch and the edges
    dot = np.zeros((size, size, 3), np.float32)
    dot[100, 140] = 1.0
    assert camera.apply_optics(dot, cfg).sum() == pytest.approx(3.0, rel=1e-5)
    rng = np.random.default_rng(6)
    x, y = (rng.random((64, 96, 3), dtype=np.float32) for _ in range(2))
    np.testing.assert_allclose(camera.apply_optics(0.4 * x + 0.6 * y, cfg),
                               0.4 * camera.apply_optics(x, cfg) + 0.6 * camera.apply_optics(y, cfg),
                               rtol=1e-5, atol=1e-6)
    assert camera.apply_optics(x, replace(cfg, glare=0.0)) is x  # off: skipped, whatever its width


@pytest.mark.parametrize("pattern", camera.BAYER_PATTERNS)
def test_bayer_sites_keep_only_their_channel(pattern):
    rgb = np.random.default_rng(4).random((6, 8, 3), dtype=np.float32)
    raw = camera.mosaic(rgb, pattern)
    channel = {"R": 0, "G": 1, "B": 2}
    for dy in range(2):
        for dx in range(2):
            c = channel[pattern[2 * dy + dx]]
            np.testing.assert_array_equal(raw[dy::2, dx::2], rgb[dy::2, dx::2, c])
    odd = rgb[:5, :7]  # odd sides: the last row and column hold half a 2x2 block
    np.testing.assert_array_equal(camera.mosaic(odd, pattern), np.take_along_axis(
        odd, camera.channel_map(pattern, 7, 5)[..., None], axis=2)[..., 0])
    assert np.bincount(camera.channel_map(pattern, 8, 6).ravel()).tolist() == [12, 24, 12]
    # a flat colour survives mosaic and OpenCV demosaicing with the pattern's own code
    colour = np.array([0.8, 0.4, 0.15], np.float32)
    cfg = replace(LINEAR, bayer=pattern)
    for method in camera.DEMOSAIC_METHODS:
        out = camera.capture(np.broadcast_to(colour, (16, 16, 3)), replace(cfg, demosaic=method),
                             np.random.default_rng(0))
        np.testing.assert_allclose(out[4:-4, 4:-4].reshape(-1, 3), np.tile(colour * 255, (64, 1)), atol=1.0)


def test_bayer_noise_is_raw_and_white_balance_scales_it_per_channel():
    s, a, r = 0.2, 1e-3, 1e-2
    gains = (2.0, 1.0, 1.5)
    cfg = replace(CameraConfig(), bayer="RGGB", shot_noise=a, read_noise=r, white_balance=gains)
    raw = camera.raw_signal(np.full((256, 256, 3), s, np.float32), cfg, np.random.default_rng(5))
    ch = camera.channel_map("RGGB", 256, 256)
    for c, g in enumerate(gains):
        v = raw[ch == c].astype(np.float64)
        assert v.mean() == pytest.approx(g * s, rel=2e-3)
        assert v.var() == pytest.approx(g**2 * (a * s + r**2), rel=0.06)
    # neighbours are independent: the noise was drawn per site, before demosaicing
    d = raw - np.array([raw[ch == c].mean() for c in range(3)], np.float32)[ch]
    assert abs(np.mean(d[:, 1:] * d[:, :-1])) < 0.02 * d.var()


def test_vignetting_follows_the_cos4_profile():
    w, h, vig = 120, 80, 0.4
    out = camera.apply_optics(np.ones((h, w, 3), np.float32), replace(CameraConfig(), vignetting=vig))
    c, r = np.array([w / 2, h / 2]), np.hypot(w, h) / 2
    for (x, y) in [(0, 0), (59, 39), (60, 10), (119, 40), (30, 70)]:
        rho2 = ((x + 0.5 - c[0]) ** 2 + (y + 0.5 - c[1]) ** 2) / r**2
        k = (1 - vig) ** -0.5 - 1
        assert out[y, x, 0] == pytest.approx((1 + k * rho2) ** -2, rel=1e-6)
    # the corner loses the set fraction (extrapolated to the very corner), the centre nothing
    corner = optics.vignetting_profile(2000, 2000, vig)[0, 0, 0]
    assert corner == pytest.approx(1 - vig, abs=2e-3)
    assert out[39:41, 59:61].min() > 0.999
    assert np.all(np.diff(out[40, 60:, 0]) < 0)  # falls monotonically outwards


def _checkerboard(w: int, h: int, square: int, origin: tuple[int, int]) -> np.ndarray:
    y, x = np.mgrid[:h, :w]
    board = (((x - origin[0]) // square + (y - origin[1]) // square) % 2).astype(np.float32)
    return np.repeat(board[..., None], 3, axis=2) * 0.8 + 0.1


@pytest.mark.parametrize("k1", [0.08, -0.06])
def test_checkerboard_corners_move_as_distort_points_says(k1):
    w, h, square, origin = 320, 240, 32, (16, 24)
    cfg = replace(LINEAR, resolution=(w, h), distortion=k1)
    img = camera.capture(_checkerboard(w, h, square, origin), cfg, np.random.default_rng(0))
    gray = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
    inner = (w // square - 2, h // square - 2)  # inner corners (9, 6)
    found, corners = cv2.findChessboardCorners(gray, inner)
    assert found
    corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1),
                               (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4))
    seen = corners.reshape(-1, 2).astype(np.float64) + 0.5  # OpenCV's pixel centres are at integers
    ideal = np.array([(origin[0] + square * (i + 1), origin[1] + square * (j + 1))
                      for j in range(inner[1]) for i in range(inner[0])], np.float64)
    predicted = camera.distort_points(ideal, cfg)
    # the detector may list the corners in either direction: match each to its nearest prediction
    err = np.min(np.linalg.norm(seen[:, None] - predicted[None], axis=2), axis=1)
    assert err.max() < 0.15
    assert np.max(np.linalg.norm(predicted - ideal, axis=1)) > 2.0  # the distortion is visible
    np.testing.assert_array_equal(camera.distort_points(ideal, replace(cfg, distortion=0.0)), ideal)


def test_jpeg_error_falls_with_quality_and_zero_is_off():
    rng = np.random.default_rng(6)
    low = rng.random((12, 16, 3)).astype(np.float32)
    rad = cv2.resize(low, (128, 96), interpolation=cv2.INTER_CUBIC).clip(0, 1)
    cfg = CameraConfig()
    plain = camera.capture(rad, cfg, np.random.default_rng(7))
    np.testing.assert_array_equal(camera.capture(rad, replace(cfg, jpeg_quality=0), np.random.default_rng(7)),
                                  plain)
    err = {q: np.sqrt(np.mean((camera.capture(rad, replace(cfg, jpeg_quality=q),
                                              np.random.default_rng(7)).astype(float) - plain) ** 2))
           for q in (100, 90, 50)}
    assert 0 < err[100] < err[90] < err[50]
    assert err[50] > 1.0  # visibly lossy


def test_exposure_rule_clips_the_documented_fraction_of_white():
    h, w = 90, 120
    y, x = np.mgrid[:h, :w]
    white = (0.3 + 0.5 * np.exp(-((x - 60) ** 2 + (y - 45) ** 2) / 2000.0))[..., None] * np.array(
        [1.0, 0.9, 0.7], np.float32)
    white = white.astype(np.float32)
    black = np.full_like(white, 0.01)
    cfg = replace(CameraConfig(), shot_noise=0.0, read_noise=0.0, exposure_mode="rule", vignetting=0.2)
    rule = camera.rule_exposure(white, black, cfg)
    img = camera.capture(white, replace(cfg, exposure=rule["exposure"]), np.random.default_rng(0))
    clipped = np.mean((img == 255).any(axis=-1))
    n = h * w
    assert clipped == pytest.approx(camera.WHITE_CLIPPED_FRACTION, abs=1.5 / n)
    assert rule["white_clipped_fraction"] == pytest.approx(clipped, abs=1.5 / n)
    dark = camera.capture(black, replace(cfg, exposure=rule["exposure"]), np.random.default_rng(0))
    assert rule["black_zero_fraction"] == np.mean((dark == 0).all(axis=-1))
    with pytest.raises(SetupError, match="plain white is black"):
        camera.rule_exposure(np.zeros_like(white), black, cfg)


def test_exposure_rule_in_the_simulator():
    from sim.capture import Simulator

    # the tiny world's white is flat (0.8 on the lit area): vignetting gives it a falloff
    setup = tiny_setup(camera={"exposure_mode": "rule", "exposure": 0.01, "vignetting": 0.3})
    sim = Simulator(setup, (32, 32))
    assert sim.exposure["mode"] == "rule" and sim.setup.camera.exposure == sim.exposure["exposure"]
    white = sim.raw(np.full((32, 32, 3), 255, np.uint8), 0, 0)
    clipped = np.mean((white == 255).any(axis=-1))
    assert clipped == pytest.approx(camera.WHITE_CLIPPED_FRACTION, abs=0.005)
    # the rule's render of white and this one differ by their Monte-Carlo noise only
    assert clipped == pytest.approx(sim.exposure["white_clipped_fraction"], abs=0.002)
    assert sim.exposure["black_zero_fraction"] == 1.0  # no ambient light in the tiny world
    assert Simulator(tiny_setup(), (32, 32)).exposure == {"mode": "manual", "exposure": 1.0}


def test_auto_fidelity_weighs_its_errors_at_the_rule_exposure(monkeypatch):
    """``auto`` compares render errors with the camera noise in signal units: it must see the
    exposure the captures will use, not the setup file's placeholder."""
    import sim.capture
    from sim.capture import Simulator

    seen = []
    real = sim.capture.resolve
    monkeypatch.setattr(sim.capture, "resolve", lambda setup, *a, **k: seen.append(setup) or real(setup, *a, **k))
    sim_ = Simulator(tiny_setup(camera={"exposure_mode": "rule", "exposure": 0.01}), (32, 32))
    assert seen[0].camera.exposure == sim_.exposure["exposure"] != 0.01


@pytest.mark.parametrize("key,value,expected", [
    ("psf_sigma", -0.5, "expected a number in [0, 16] camera pixels"),
    ("bayer", "RGBG", 'expected one of "none", "RGGB"'),
    ("demosaic", "ahd", 'expected one of "bilinear", "vng", "edgeaware"'),
    ("vignetting", 1.0, "expected a number in [0, 1)"),
    ("distortion", -0.3, "expected a number in [-0.14, 1]"),
    ("glare", 0.6, "expected a number in [0, 0.5]"),
    ("glare_sigma", 0.0, "expected a number in (0, 2]"),
    ("jpeg_quality", 101, "expected an integer in [0, 100]"),
    ("jpeg_quality", 90.0, "expected an integer"),
    ("exposure_mode", "auto", 'expected one of "manual", "rule"'),
])
def test_bad_camera_keys_are_named(key, value, expected):
    with pytest.raises(SetupError) as err:
        parse_setup({"name": "n", "camera": {key: value}}, source="x.toml")
    assert f"x.toml: camera.{key} = " in str(err.value) and expected in str(err.value)


def test_camera_keys_round_trip_and_default_off():
    s = parse_setup({"name": "n", "camera": {"psf_sigma": 0.7, "bayer": "GBRG", "demosaic": "vng",
                                             "vignetting": 0.3, "distortion": -0.05, "jpeg_quality": 90,
                                             "exposure_mode": "rule", "glare": 0.02, "glare_sigma": 0.3}})
    assert parse_setup(tomllib.loads(dump_setup(s))) == s
    d = parse_setup({"name": "n"}).camera
    assert (d.psf_sigma, d.bayer, d.vignetting, d.distortion, d.jpeg_quality, d.exposure_mode,
            d.glare) == (0.0, "none", 0.0, 0.0, 0, "manual", 0.0)


@pytest.mark.slow
def test_dataset_records_the_exposure_used(tmp_path):
    import json

    from sim.dataset import FrameSpec, write_setup

    spec = FrameSpec(n_train=1, n_test=1, size=(32, 32))
    rule = write_setup(tmp_path / "a", tiny_setup(camera={"exposure_mode": "rule", "vignetting": 0.3}),
                       spec, progress=False)
    meta = json.loads((rule / "meta.json").read_text())["camera_exposure"]
    assert meta["mode"] == "rule" and meta["exposure"] > 0
    assert meta["white_clipped_fraction"] == pytest.approx(camera.WHITE_CLIPPED_FRACTION, abs=0.005)
    manual = write_setup(tmp_path / "b", tiny_setup(camera={"exposure": 0.7}), spec, progress=False)
    assert json.loads((manual / "meta.json").read_text())["camera_exposure"] == {"mode": "manual",
                                                                                 "exposure": 0.7}
