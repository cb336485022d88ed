"""The light-transport operator: agreement with converged renders, exact linearity, defocus,
caching, and clear refusals for what it cannot represent."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import torch

from helpers import tiny_setup
from sim import camera, projector
from sim.capture import Simulator
from sim.errors import SetupError
from sim.fidelity import probe_frame
from sim.render import Renderer
from sim.setup import load_setup, scene_path
from sim.transport import MAX_SPACING, TransportOperator, TransportRenderer, cache_key, footprint_ranges

SIZE = (64, 64)


def _shipped(name: str):
    """A shipped scene shrunk to a 64² projector and camera (same poses, optics and surface)."""
    s = load_setup(scene_path(name))
    return replace(s, projector=replace(s.projector, resolution=SIZE),
                   camera=replace(s.camera, resolution=SIZE),
                   surface=replace(s.surface, texture_resolution=128))


@pytest.fixture(scope="module")
def default_op():
    """The planar default setup's operator, calibrated at 256 spp."""
    setup = _shipped("ideal")
    return setup, TransportRenderer(setup, 256)


def _psnr(x: np.ndarray, ref: np.ndarray) -> float:
    return float(10 * np.log10(ref.max() ** 2 / np.mean((x - ref) ** 2)))


@pytest.mark.parametrize("kind", ["smooth", "stripes2"])
def test_agrees_with_converged_direct_on_default_setup(default_op, kind):
    """Transport vs a 1024-spp direct render: >= 40 dB in linear radiance (projector + ambient)."""
    setup, tr = default_op
    frame = probe_frame(kind, SIZE, seed=3)
    ref = Renderer(setup, "direct", 1024)
    want = ref.projector_radiance(tr.emit(frame), seed=11) + ref.ambient_radiance()
    assert _psnr(tr.radiance(frame), want) >= 40.0


@pytest.mark.slow
@pytest.mark.parametrize("model", ["ray", "image"])
def test_defocused_camera_and_projector_agree_with_converged_direct(model):
    """A traced thin-lens camera widens each pixel's footprint, one in image space blurs the
    operator's output; either way the operator reproduces a converged direct render."""
    setup = _shipped("defocus")
    setup = replace(setup, camera=replace(setup.camera, defocus=model))
    tr = TransportRenderer(setup, 256)
    frame = probe_frame("stripes2", SIZE, seed=4)
    ref = Renderer(setup, "direct", 1024).projector_radiance(tr.emit(frame), seed=12)
    assert _psnr(tr.projector_radiance(tr.emit(frame)), ref) >= 40.0


def test_equals_direct_render_at_its_calibration_seed(default_op):
    """The dot frames sum to any frame: T p is the direct render of p at the calibration spp and
    seed, to float precision, even for independent random pixels."""
    setup, tr = default_op
    cal = Renderer(setup, "direct", tr.operator.info.spp)
    x = np.random.default_rng(5).random((64, 64, 3), dtype=np.float32)
    want = cal.projector_radiance(x, tr.operator.info.seed)
    np.testing.assert_allclose(tr.projector_radiance(x), want, rtol=0, atol=1e-5 * want.max())


def test_every_linear_effect_stays_exact():
    """The projector lens's distortion, the surface's translucency and the projector's flare act
    before T (on the emitted light), the camera's glare after it: with all of them on, on a sheet
    with relief, T p still equals the direct render of p at the calibration spp and seed, and the
    camera sees the same."""
    keys = {"resolution": [32, 32], "psf_sigma": 0.7, "distortion_k1": -0.05, "distortion_k2": 0.01,
            "lens_offset": 0.6, "translucency_mfp": 10.0, "translucency_fraction": 0.5,
            "flare": 0.05, "flare_sigma": 0.2}
    setup = tiny_setup(projector=keys, camera={"resolution": [32, 32], "glare": 0.02, "glare_sigma": 0.3},
                       surface={"relief": 3.0, "relief_length": 30.0, "bow": 4.0},  # on a relief sheet
                       render={"fidelity": "transport", "spp": 4})
    tr = TransportRenderer(setup)
    assert tr.operator.info.verify_error <= 1e-4
    frame = np.random.default_rng(8).integers(0, 256, (32, 32, 3), dtype=np.uint8)
    irr = tr.emit(frame)
    plain = Renderer(replace(setup, projector=replace(setup.projector, translucency_mfp=0.0, flare=0.0)),
                     "direct", 4)  # the same grid (pincushion k2 widens it)
    assert irr.shape == plain.emit(frame).shape and np.abs(irr - plain.emit(frame)).max() > 0.01
    direct = Renderer(setup, "direct", 4)
    np.testing.assert_array_equal(direct.emit(frame), irr)
    want = direct.projector_radiance(irr, tr.operator.info.seed)
    got = tr.projector_radiance(irr)
    assert np.abs(got - want).max() <= 1e-4 * want.max()
    seen = [camera.apply_optics(x, setup.camera) for x in (got, want)]
    assert not np.array_equal(seen[0], got) and np.abs(seen[0] - seen[1]).max() <= 1e-4 * want.max()


def test_content_dependent_effects_stay_exact():
    """The projector's dynamic lamp and white segment act on the frame before T (in its emission),
    the camera's adaptive tone, picture style and sharpening on each capture after it: none is
    linear, yet with all of them on T p still equals the direct render of p at the calibration spp
    and seed, and the camera's captures of the two agree."""
    keys = {"resolution": [32, 32], "dynamic_lamp": 0.55, "dynamic_lamp_statistic": "mean",
            "white_boost": 1.0, "black_level": 0.002}
    processing = {"adaptive_tone": 0.8, "style_contrast": 0.5, "style_saturation": 1.4,
                  "sharpen_radius": 1.0, "sharpen_amount": 1.0}
    setup = tiny_setup(projector=keys, camera={"resolution": [32, 32], **processing},
                       surface={"texture": "noise"}, render={"fidelity": "transport", "spp": 4})
    tr = TransportRenderer(setup)
    assert tr.operator.info.verify_error <= 1e-4
    frame = np.random.default_rng(8).integers(0, 256, (32, 32, 3), dtype=np.uint8)
    irr = tr.emit(frame)
    plain = Renderer(replace(setup, projector=replace(setup.projector, dynamic_lamp=0.0, white_boost=0.0)),
                     "direct", 4)
    assert np.abs(irr - plain.emit(frame)).max() > 0.01
    direct = Renderer(setup, "direct", 4)
    np.testing.assert_array_equal(direct.emit(frame), irr)
    want = direct.projector_radiance(irr, tr.operator.info.seed)
    got = tr.projector_radiance(irr)
    assert np.abs(got - want).max() <= 1e-4 * want.max()
    cam = replace(setup.camera, exposure=1.0 / float(want.max()))
    seen = [camera.capture(x, cam, None).astype(int) for x in (got, want)]
    plain_cam = camera.capture(want, camera.sensor_alone(cam), None).astype(int)
    assert np.abs(seen[0] - plain_cam).max() > 10  # the processing is on
    assert np.abs(seen[0] - seen[1]).max() <= 1


def test_exactly_linear_and_batched(default_op):
    """T (a + b) = T a + T b; the torch batch path equals the per-image NumPy path."""
    _, tr = default_op
    op = tr.operator
    rng = np.random.default_rng(6)
    a, b = (rng.random((64, 64, 3), dtype=np.float32) for _ in range(2))
    lhs = op.project_image(a + b)
    np.testing.assert_allclose(lhs, op.project_image(a) + op.project_image(b), rtol=1e-6, atol=1e-7)
    batch = torch.from_numpy(np.stack([a, b])).permute(0, 3, 1, 2)
    out = op.project(batch)
    assert out.shape == (2, 3, 64, 64)
    np.testing.assert_allclose(out[1].permute(1, 2, 0).numpy(), op.project_image(b), rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(op.project(batch[0]).permute(1, 2, 0).numpy(), op.project_image(a),
                               rtol=1e-5, atol=1e-7)


def test_thin_line_has_the_defocus_blur_width():
    """Head-on, camera pixel = projector pixel: a 1-pixel line spreads over the circle of confusion
    of the projector lens. A line blurred by a disk of diameter D has variance D²/16 (plus 1/12
    for its own width), so D = 4 sqrt(var - 1/12); it must match the geometry within 20 %."""
    setup = tiny_setup(projector={"aperture": 0.2, "focus_distance": 0.8, "black_level": 0.0},
                       camera={"position": [0.0, 0.0, 1.0], "fov": 30.0})
    expected = projector.defocus_blur_diameter_px(0.2, 0.8, 1.0, 30.0, 64)
    assert expected > 4
    frame = np.zeros((64, 64, 3), np.uint8)
    frame[:, 32] = 255
    sim = Simulator(setup, SIZE, fidelity="transport", spp=16)
    profile = sim.linear(frame, 0, 0)[24:40, :, 1].mean(axis=0)
    x = np.arange(64) + 0.5
    mean = (profile * x).sum() / profile.sum()
    var = (profile * (x - mean) ** 2).sum() / profile.sum()
    width = 4 * np.sqrt(var - 1 / 12)
    assert abs(width - expected) <= 0.2 * expected
    assert abs(mean - 32.5) < 0.1


def test_operator_is_cached_per_setup(tmp_path, default_op):
    setup, _ = default_op
    first = TransportRenderer(setup, 4, cache_dir=tmp_path)
    assert not first.loaded_from_cache and len(list(tmp_path.glob("transport_*.npz"))) == 1
    again = TransportRenderer(setup, 4, cache_dir=tmp_path)
    assert again.loaded_from_cache
    x = np.random.default_rng(7).random((64, 64, 3), dtype=np.float32)
    np.testing.assert_array_equal(first.projector_radiance(x), again.projector_radiance(x))
    np.testing.assert_array_equal(first.ambient_radiance(), again.ambient_radiance())
    assert again.operator.info == first.operator.info
    other = TransportRenderer(setup, 16, cache_dir=tmp_path)  # another spp: another operator
    assert not other.loaded_from_cache and len(list(tmp_path.glob("transport_*.npz"))) == 2


def _triples(op: TransportOperator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The operator's (camera pixel, projector pixel, values) triples in camera-pixel order."""
    order = np.lexsort((op.cols, op.rows))
    return op.rows[order], op.cols[order], op.values[order]


def test_cache_file_is_compressed_and_reads_back_bit_for_bit(tmp_path, default_op):
    _, tr = default_op
    op = tr.operator
    op.save(tmp_path / "op.npz")
    back = TransportOperator.load(tmp_path / "op.npz")
    for got, want in zip(_triples(back), _triples(op)):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(back.ambient, op.ambient)
    assert back.values.dtype == op.ambient.dtype == np.float32
    assert (back.camera_size, back.projector_size, back.info) == (op.camera_size, op.projector_size, op.info)
    measured = op.nnz * (4 + 4 + 12) + op.ambient.nbytes  # int32 indices, float32 values
    assert (tmp_path / "op.npz").stat().st_size < 0.8 * measured


SEEN_ELSEWHERE = {"projector": {"gamma": 1.8, "black_level": 0.01, "mixing": [[0.9, 0.1, 0.0], [0.0, 1.0, 0.0],
                                                                              [0.0, 0.1, 0.9]],
                                "flare": 0.02, "flicker": 0.01, "translucency_mfp": 5.0,
                                "translucency_fraction": 0.3},
                  "camera": {"shot_noise": 1e-3, "read_noise": 1e-2, "response": "gamma:2.2", "exposure": 2.0,
                             "psf_sigma": 0.5, "vignetting": 0.2, "jpeg_quality": 80,
                             "aperture_radius": 0.002, "focus_distance": 0.8},  # defocus in image space
                  "registration": {"method": "homography", "jitter": 0.5}}
"""Keys of the stages before and after the light transport, a camera defocus applied in image
space, and keys of the registration."""


def test_setups_that_differ_outside_the_transport_share_one_operator(tmp_path):
    """Setups that differ in the camera's stages and its defocus in image space, the projector's
    stages that leave its padded grid alone, the registration and the name calibrate the same operator, bit for bit, and share one
    cache file; what the transport sees (pose, brightness, padding, surface, room light, seed,
    spp) makes another."""
    scene = {"surface": {"texture": "noise"}, "ambient": {"radiance": [0.02, 0.02, 0.02]}}
    base = tiny_setup(**scene)
    other = tiny_setup(**scene, name="other", **SEEN_ELSEWHERE)
    assert cache_key(base, 4, "v") == cache_key(other, 4, "v")
    a = TransportRenderer(base, 4, cache_dir=tmp_path / "a").operator
    b = TransportRenderer(other, 4, cache_dir=tmp_path / "b").operator
    for got, want in zip(_triples(b), _triples(a)):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(b.ambient, a.ambient)
    assert TransportRenderer(other, 4, cache_dir=tmp_path / "a").loaded_from_cache
    assert len(list((tmp_path / "a").glob("transport_*.npz"))) == 1
    apart = [tiny_setup(**scene, projector={"brightness": 2.0}),
             tiny_setup(**scene, projector={"psf_sigma": 1.0}),  # a wider emitter grid
             tiny_setup(**scene, projector={"position": [0.01, 0.0, 1.0]}),
             tiny_setup(**scene, camera={"aperture_radius": 0.002, "defocus": "ray"}),
             tiny_setup(surface={"texture": "noise", "texture_seed": 3}, ambient=scene["ambient"]),
             tiny_setup(surface=scene["surface"], ambient={"radiance": [0.03, 0.03, 0.03]}),
             tiny_setup(**scene, render={"seed": 1})]
    keys = {cache_key(s, 4, "v") for s in apart} | {cache_key(base, 8, "v"), cache_key(base, 4, "w")}
    assert len(keys) == len(apart) + 2 and cache_key(base, 4, "v") not in keys


def test_footprint_bounds_where_the_camera_pixel_lands():
    """Identical optics, camera shifted by a quarter projector pixel in x and y (parallel axes):
    camera pixel (row i, column j) covers projector [j + 1/4, j + 5/4] x [i + 1/4, i + 5/4], so
    its range is columns j..j+1 and rows i..i+1 (clipped to the frame)."""
    d = 0.25 * 2 * np.tan(np.radians(15)) / 64  # a quarter of a projector pixel at 1 m, metres
    setup = tiny_setup(camera={"position": [d, -d, 1.0], "look_at": [d, -d, 0.0], "fov": 30.0})
    lo, hi, seen = footprint_ranges(setup)
    assert seen.all()
    j, i = np.meshgrid(np.arange(64), np.arange(64))
    np.testing.assert_array_equal(lo, np.stack([j, i], axis=-1))
    np.testing.assert_array_equal(hi, np.minimum(lo + 1, 63))


def test_declines_interreflection():
    corner = tiny_setup(surface={"geometry": "corner", "size": [0.6, 1.0]},
                        render={"fidelity": "path", "max_depth": 3})
    with pytest.raises(SetupError, match="inter-reflection"):
        TransportRenderer(corner, 4)
    with pytest.raises(SetupError, match='fidelity "transport" cannot represent'):
        Simulator(corner, SIZE, fidelity="transport")
    with pytest.raises(SetupError, match='render.fidelity = "transport"'):
        tiny_setup(surface={"geometry": "corner", "size": [0.6, 1.0]}, render={"fidelity": "transport"})


def test_declines_footprints_too_wide_to_calibrate():
    """An 8² camera over a 256² projector: each camera pixel covers ~25 projector pixels."""
    setup = tiny_setup(camera={"resolution": [8, 8]}, projector={"resolution": [256, 256]})
    with pytest.raises(SetupError, match=f"limit {MAX_SPACING ** 2}"):
        TransportOperator.calibrate(Renderer(setup, "direct", 1))
