"""Tests of sim.camera: response curves, Poisson-Gaussian sensor noise, clipping, quantisation."""
from __future__ import annotations

import subprocess
import sys
import warnings
from types import SimpleNamespace

import colour
import numpy as np
import pytest

from sim import camera

PARAMETRIC = ["gamma:1.8", "gamma:0.5", "gamma:2.2", "scurve:2.5", "scurve:0.4", "scurve:1"]
# Standards whose rounded constants leave a small jump where the linear toe meets the power
# segment: encoded values inside the jump are not produced by encode, so encode(decode(y)) lands
# on its edge (at most 2.5e-4 away, 0.06 of an 8-bit level).
TOE_GAP = {"ITU-R BT.601", "ITU-R BT.709", "ITU-R BT.2020", "SMPTE 240M"}
X = np.linspace(0.0, 1.0, 4001)
CODES = np.arange(256) / 255.0


def cam(**kw):
    values = dict(exposure=1.0, white_balance=(1.0, 1.0, 1.0), shot_noise=2e-4, read_noise=2e-3,
                  response="sRGB", bit_depth=8)
    values.update(kw)
    return SimpleNamespace(**values)


def _qualifies(encode, decode) -> bool:
    """The inclusion rule of sim.camera for a colour-science CCTF, checked on a dense grid."""
    try:
        with warnings.catch_warnings(), np.errstate(all="ignore"):
            warnings.simplefilter("ignore")
            y = np.asarray(encode(X), np.float64)
            back = np.asarray(decode(y), np.float64)
    except Exception:  # a curve that cannot even evaluate [0, 1] does not qualify
        return False
    return bool(np.all(np.isfinite(y)) and abs(y[0]) < 1e-6 and abs(y[-1] - 1) < 1e-6
                and np.all(np.diff(y) > 0) and np.max(np.abs(back - X)) < 1e-5)


@pytest.mark.parametrize("name", list(camera.response_names()) + PARAMETRIC)
def test_response_is_a_monotonic_invertible_map_of_unit_interval(name):
    camera.check_response(name)
    y = camera.encode(X, name)
    assert y.dtype == np.float64
    assert np.all(np.diff(y) > 0)
    assert abs(y[0]) < 1e-6 and abs(y[-1] - 1) < 1e-6
    np.testing.assert_allclose(camera.decode(y, name), X, atol=1e-5)
    np.testing.assert_allclose(camera.encode(camera.decode(CODES, name), name), CODES, atol=1e-5)
    gap = 3e-4 if name in TOE_GAP else 1e-5
    np.testing.assert_allclose(camera.encode(camera.decode(X, name), name), X, atol=gap)


def test_included_colour_curves_are_exactly_the_qualifying_ones():
    """Every colour-science CCTF is tested; those left out fail the rule (see sim.camera)."""
    included = set(camera.response_names()) - {"linear"}
    assert {"sRGB", "Gamma 2.2", "ITU-R BT.709", "Protune", "REDLog"} <= included
    for name in colour.CCTF_ENCODINGS:
        ok = _qualifies(colour.CCTF_ENCODINGS[name], colour.CCTF_DECODINGS[name])
        assert ok == (name in included), name


def test_named_curves_match_colour_science_and_parametric_forms():
    x = np.linspace(0, 1, 101)
    np.testing.assert_allclose(camera.encode(x, "sRGB"), colour.cctf_encoding(x, "sRGB"),
                               atol=1e-12)
    np.testing.assert_allclose(camera.encode(x, "gamma:2.2"), camera.encode(x, "Gamma 2.2"),
                               atol=1e-12)
    np.testing.assert_array_equal(camera.encode(x, "linear"), x)
    np.testing.assert_allclose(camera.encode(x, "scurve:1"), x, atol=1e-12)
    s = camera.encode(np.array([0.25, 0.5, 0.75]), "scurve:3")
    np.testing.assert_allclose(s, [1 / 28, 0.5, 27 / 28], atol=1e-12)  # S-shaped, symmetric


def test_encode_keeps_float32_and_clips():
    y = camera.encode(np.array([-0.5, 0.5, 2.0], np.float32), "sRGB")
    assert y.dtype == np.float32
    assert y[0] == 0 and y[2] == 1


@pytest.mark.parametrize("name, match", [
    ("nope", "unknown camera response 'nope'"),
    ("srgb ", "unknown camera response"),
    ("gamma:abc", r"number in \(0.1, 10\)"),
    ("gamma:20", r"number in \(0.1, 10\)"),
    ("scurve:0", r"number in \(0.1, 10\)"),
    ("scurve:nan", r"number in \(0.1, 10\)"),
    (2.2, "expected a string"),
])
def test_unknown_response_lists_the_valid_forms(name, match):
    with pytest.raises(ValueError, match=match) as err:
        camera.check_response(name)
    if "unknown" in match or "string" in match:
        assert "'sRGB'" in str(err.value) and "'gamma:<g>'" in str(err.value)
    with pytest.raises(ValueError):
        camera.encode(np.zeros(3), name)


def test_sensor_noise_variance_matches_poisson_gaussian_model(noise_version):
    rng = np.random.default_rng(12345)
    flat = np.full((128, 128, 3), 0.3, np.float32)
    s = camera.sensor_signal(flat, 1.0, (1.0, 1.0, 1.0), 1e-3, 1e-2, rng)
    assert s.dtype == np.float32
    expected = 0.3e-3 + 1e-4
    assert s.var(dtype=np.float64) == pytest.approx(expected, rel=0.05)
    assert s.mean(dtype=np.float64) == pytest.approx(0.3, abs=1e-3)
    assert float(camera.noise_sigma(0.3, 1e-3, 1e-2)) == pytest.approx(expected ** 0.5, rel=1e-12)


@pytest.fixture(params=[2, 3])
def noise_version(request, monkeypatch):
    """Each noise version in turn (version 3 where Dr.Jit's LLVM backend runs)."""
    from sim.camera import noise
    from sim.variant import llvm_usable
    if request.param == 3 and not llvm_usable():
        pytest.skip("Dr.Jit's LLVM backend is not usable here")
    monkeypatch.setattr(noise, "stream_version", lambda: request.param)
    return request.param


def test_noise_blocks_are_independent_poisson_gaussian_draws(noise_version):
    """Every block of ``camera.BLOCK`` values (version 2: its own child generator) has the
    model's mean and variance, and neighbouring blocks are uncorrelated."""
    n = 4 * camera.BLOCK
    level, shot, read = 0.3, 1e-3, 1e-2
    s = camera.sensor_signal(np.full((n // 3 + 1, 3), level, np.float32), 1.0, (1.0, 1.0, 1.0), shot, read,
                             np.random.default_rng(7)).ravel().astype(np.float64)
    blocks = (s[:4 * camera.BLOCK] - level).reshape(4, camera.BLOCK)
    expected = shot * level + read ** 2
    assert blocks.var(axis=1) == pytest.approx([expected] * 4, rel=0.03)
    assert np.abs(blocks.mean(axis=1)).max() < 5 * (expected / camera.BLOCK) ** 0.5
    r = np.corrcoef(blocks)[np.triu_indices(4, 1)]
    assert np.abs(r).max() < 5 / camera.BLOCK ** 0.5  # independent streams, not shifted copies


def test_noise_is_the_same_on_any_number_of_threads(monkeypatch, noise_version):
    from concurrent.futures import ThreadPoolExecutor

    import drjit as dr

    from sim.camera import threads
    rad = np.random.default_rng(3).random((300, 200, 3), dtype=np.float32)  # several blocks
    cams = (cam(), cam(bayer="RGGB", demosaic="bilinear"), cam(bayer="GBRG", demosaic="vng"))
    outs = []
    cores = dr.thread_count()
    try:
        for workers in (1, 4):  # the camera's threads, and Dr.Jit's (version 3's kernel)
            monkeypatch.setattr(threads, "_pool", ThreadPoolExecutor(workers))
            dr.set_thread_count(workers)
            outs.append([camera.capture(rad, c, np.random.default_rng(11)) for c in cams])
    finally:
        dr.set_thread_count(cores)
    for one, four in zip(*outs):  # the noise and the encoder of a demosaiced image run in blocks
        np.testing.assert_array_equal(one, four)


def test_noise_free_path_is_exact():
    rad = np.random.default_rng(5).random((6, 7, 3), dtype=np.float32) * 1.5
    wb = np.array([1.1, 1.0, 0.9], np.float32)
    s = camera.sensor_signal(rad, 0.8, wb, 0.0, 0.0, np.random.default_rng(0))
    np.testing.assert_array_equal(s, np.clip(rad * np.float32(0.8) * wb, 0, 1))
    np.testing.assert_array_equal(camera.sensor_signal(rad, 0.8, wb), s)  # the noiseless signal
    with pytest.raises(ValueError, match="random generator"):
        camera.sensor_signal(rad, 0.8, wb, read_noise=1e-3)
    out = camera.capture(np.full((2, 2, 3), 0.36, np.float32),
                         cam(shot_noise=0.0, read_noise=0.0, response="gamma:2"),
                         np.random.default_rng(0))
    np.testing.assert_array_equal(out, 153)  # sqrt(0.36) * 255 = 153


def test_full_well_clips_to_white():
    out = camera.capture(np.full((8, 8, 3), 5.0, np.float32), cam(), np.random.default_rng(1))
    assert out.dtype == np.uint8 and out.shape == (8, 8, 3)
    assert np.all(out == 255)


def test_quantise_rounds_to_nearest_code():
    x = np.array([0.0, 0.4 / 255, 0.6 / 255, 127.4 / 255, 127.6 / 255, 1.0, 1.3, -0.2])
    q = camera.quantise(x)
    assert q.dtype == np.uint8
    assert q.tolist() == [0, 0, 1, 127, 128, 255, 255, 0]
    with pytest.raises(ValueError, match="only 8"):
        camera.quantise(x, 16)


def test_seeded_noise_is_reproducible():
    rad = np.random.default_rng(6).random((16, 16, 3), dtype=np.float32)
    a = camera.capture(rad, cam(), np.random.default_rng(7))
    b = camera.capture(rad, cam(), np.random.default_rng(7))
    c = camera.capture(rad, cam(), np.random.default_rng(8))
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()


def test_quantisation_sigma_matches_simulated_rounding():
    assert np.allclose(camera.quantisation_sigma(np.linspace(0, 1, 11), "linear"),
                       (1 / 255) / 12 ** 0.5)
    # Slope of sqrt at 0.25 is 1: the same sigma in linear units.
    assert float(camera.quantisation_sigma(0.25, "gamma:2")) == \
        pytest.approx((1 / 255) / 12 ** 0.5, rel=1e-3)
    # Against the error of actually encoding, rounding and decoding signals near 0.2 (sRGB).
    s = np.random.default_rng(9).uniform(0.19, 0.21, 200_000)
    err = camera.decode(camera.quantise(camera.encode(s, "sRGB")) / 255.0, "sRGB") - s
    predicted = np.sqrt(np.mean(camera.quantisation_sigma(s, "sRGB") ** 2))
    assert np.sqrt(np.mean(err ** 2)) == pytest.approx(predicted, rel=0.05)
    # Finite where the response's slope is 0 (scurve at 0) and positive where it is infinite.
    edge = camera.quantisation_sigma(np.array([0.0, 1.0]), "scurve:3")
    assert np.all(np.isfinite(edge)) and np.all(edge > 0)
    assert float(camera.quantisation_sigma(0.0, "Gamma 2.2")) > 0


def test_a_forked_child_draws_noise_with_its_own_threads(noise_version):
    """The camera's thread pool does not survive fork(); a child starts its own (it would wait
    forever on the parent's threads otherwise)."""
    import multiprocessing

    rad = np.random.default_rng(4).random((200, 200, 3), dtype=np.float32)  # several blocks
    here = camera.capture(rad, cam(), np.random.default_rng(2))  # the pool exists now
    with multiprocessing.get_context("fork").Pool(1) as pool:
        there = pool.apply_async(camera.capture, (rad, cam(), np.random.default_rng(2))).get(timeout=60)
    np.testing.assert_array_equal(here, there)


def test_checking_a_setup_leaves_colour_science_to_the_first_capture():
    # importing colour-science takes about a second: the command line and setup validation do without
    code = ("import sys, compensation.cli; from sim.setup import load_setup, scene_path; "
            "load_setup(scene_path('default')); print('colour' in sys.modules); "
            "from sim.camera import encode; encode(0.5, 'sRGB'); print('colour' in sys.modules)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert proc.stdout.split() == ["False", "True"]
