"""The projector's hardware: scaler (frame area), lens PSF, depth-dependent defocus with its spill
kept, lamp flicker and drift; and that all of it stays exact in the light-transport operator."""
from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np
import pytest
from helpers import tiny_setup

from sim import projector, registration, seeds
from sim.capture import Simulator
from sim.errors import SetupError
from sim.projector import lens_for
from sim.render import Renderer
from sim.transport import TransportRenderer


def _moments(img: np.ndarray) -> tuple[float, float, float, float]:
    """Total, centroid (x, y) and per-axis variance (mean of x and y) of a 2-D image."""
    total = float(img.sum())
    y, x = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    cx, cy = float((img * x).sum() / total), float((img * y).sum() / total)
    var = float((img * ((x - cx) ** 2 + (y - cy) ** 2)).sum() / total) / 2
    return total, cx, cy, var


def _dot(size: tuple[int, int], col: int, row: int) -> np.ndarray:
    w, h = size
    img = np.zeros((h, w, 3), np.float32)
    img[row, col] = 1.0
    return img


# ----------------------------------------------------------------------------------- scaler

def test_frame_area_keeps_the_aspect_centred_on_whole_pixels():
    assert projector.frame_area((800, 600), (256, 256), True) == (100.0, 0.0, 600.0, 600.0)
    assert projector.frame_area((800, 600), (256, 256), False) == (0.0, 0.0, 800.0, 600.0)
    assert projector.frame_area((64, 64), (32, 32), True) == (0.0, 0.0, 64.0, 64.0)
    # 48x32 on 64x64: scale 4/3 -> 64 x 42.67, rounded to keep equal margins: 64 x 42 at y0 = 11
    assert projector.frame_area((64, 64), (48, 32), True) == (0.0, 11.0, 64.0, 42.0)
    for panel, frame in [((801, 600), (256, 256)), ((800, 601), (300, 200)), ((37, 29), (5, 7))]:
        x0, y0, w, h = projector.frame_area(panel, frame, True)
        assert x0 == int(x0) and y0 == int(y0) and 2 * x0 + w == panel[0] and 2 * y0 + h == panel[1]
        assert abs(w / h - frame[0] / frame[1]) <= 2 / min(w, h)  # aspect kept to a pixel
        assert w == panel[0] or h == panel[1]


def test_scaler_fills_the_frame_area_and_leaves_the_rest_dark():
    frame = np.full((16, 16, 3), 0.7, np.float32)
    out = projector.scale_to_panel(frame, (40, 20), True)
    assert out.shape == (20, 40, 3)
    np.testing.assert_allclose(out[:, 10:30], 0.7, atol=1e-6)
    assert not out[:, :10].any() and not out[:, 30:].any()
    np.testing.assert_allclose(projector.scale_to_panel(frame, (40, 20), False), 0.7, atol=1e-6)
    # the black level shows outside the area once the response is applied
    irr = projector.emitted_irradiance(out, 2.2, 0.01, np.eye(3))
    np.testing.assert_allclose(irr[:, :10], 0.01, atol=1e-7)


def test_exact_map_views_the_frame_area():
    """A square frame on a 2:1 panel with keep_aspect sees what a square panel of half the field
    of view sees (the same pixels of the world)."""
    wide = tiny_setup(projector={"resolution": [64, 32], "keep_aspect": True})
    half_fov = math.degrees(2 * math.atan(math.tan(math.radians(30.0) / 2) / 2))
    square = tiny_setup(projector={"resolution": [32, 32], "fov": half_fov})
    a = registration.exact_map(wide, (16, 16))
    b = registration.exact_map(square, (16, 16))
    np.testing.assert_allclose(a.xy, b.xy, atol=1e-3)
    stretched = registration.exact_map(tiny_setup(projector={"resolution": [64, 32], "keep_aspect": False}),
                                       (16, 16))
    assert np.abs(stretched.xy - a.xy).max() > 3  # the whole panel: a wider view


def test_scaler_and_registration_agree_through_the_renderer():
    """A frame with one lit canonical pixel shows up where the exact map says (letterboxed panel)."""
    setup = tiny_setup(projector={"resolution": [64, 32], "keep_aspect": True},
                       camera={"resolution": [64, 64]}, render={"spp": 16})
    size = (16, 16)
    wmap = registration.exact_map(setup, size)
    r = Renderer(setup, "direct")
    frame = np.zeros((16, 16, 3), np.uint8)
    frame[5, 11] = 255
    img = r.projector_radiance(r.emit(frame))[..., 1]
    _, cx, cy, _ = _moments(img)
    np.testing.assert_allclose([cx + 0.5, cy + 0.5], wmap.xy[5, 11], atol=0.3)


# ----------------------------------------------------------------------------------- lens

def test_psf_width_energy_and_linearity():
    lens = lens_for(tiny_setup(projector={"resolution": [32, 32], "psf_sigma": 1.5}))
    assert lens.pad == projector.gaussian_radius(1.5) and lens.diameters is None
    p = lens.pad
    out = lens.apply(_dot((32, 32), 16, 10))[..., 0]
    total, cx, cy, var = _moments(out)
    assert total == pytest.approx(1.0, abs=1e-5)
    assert (cx, cy) == (pytest.approx(16 + p, abs=1e-4), pytest.approx(10 + p, abs=1e-4))
    assert var == pytest.approx(1.5 ** 2, rel=0.03)
    # a pixel on the panel's corner keeps all its light (the padding holds the spill)
    assert lens.apply(_dot((32, 32), 0, 0)).sum() == pytest.approx(3.0, abs=1e-5)


def test_a_lens_focused_on_a_head_on_plane_has_no_defocus_map():
    """An open aperture focused on a head-on plane blurs nothing: the lens is its PSF alone, so
    each capture skips the (identity) defocus pass."""
    keys = {"resolution": [32, 24], "psf_sigma": 0.6, "position": [0.0, 0.0, 1.0],
            "look_at": [0.0, 0.0, 0.0], "focus_distance": 1.0}
    lens = lens_for(tiny_setup(projector={**keys, "aperture": 0.02}))
    psf_only = lens_for(tiny_setup(projector={**keys, "aperture": 0.0}))
    assert lens.diameters is None and lens.pad == psf_only.pad
    frame = np.random.default_rng(0).random((24, 32, 3)).astype(np.float32)
    np.testing.assert_array_equal(lens.apply(frame), psf_only.apply(frame))
    # out of focus, the same plane gets a map
    assert lens_for(tiny_setup(projector={**keys, "aperture": 0.02, "focus_distance": 1.3})).diameters is not None


def _corner_setup(aperture=0.4, **projector_keys):
    return tiny_setup(surface={"geometry": "corner", "size": [1.0, 1.0]},
                      projector={"resolution": [64, 64], "aperture": aperture, "focus_distance": 1.0,
                                 **projector_keys},
                      camera={"position": [0.0, 0.0, 1.2]}, render={"fidelity": "path", "max_depth": 3})


def _corner_depth(col: int, width: int = 64, fov: float = 30.0) -> float:
    """Depth of a projector column on a 90-degree corner whose edge passes through the optical
    axis 1 m away: a ray of horizontal slope a meets the wing z = |x| at depth 1 / (1 + |a|)."""
    a = (2 * (col + 0.5) / width - 1) * math.tan(math.radians(fov) / 2)
    return 1.0 / (1.0 + abs(a))


def test_defocus_follows_each_points_depth_on_a_corner():
    setup = _corner_setup()
    lens = lens_for(setup)
    p = lens.pad
    widths = {}
    for col in (4, 20):
        depth = _corner_depth(col)
        pitch = 2 * depth * math.tan(math.radians(30.0) / 2) / 64
        want = 0.4 * abs(depth - 1.0) / 1.0 / pitch  # thin lens, in projector pixels
        assert lens.diameters[32 + p, col + p] == pytest.approx(want, rel=1e-6)
        total, cx, _, var = _moments(lens.apply(_dot((64, 64), col, 32))[..., 0])
        assert total == pytest.approx(1.0, abs=1e-5)
        assert cx == pytest.approx(col + p, abs=1e-3)
        # a uniform disk of diameter D has per-axis variance D² / 16; the pixel grid adds 1/12
        # (disks of 4 px and more: below, the anti-aliased kernel is up to 8 % wider)
        widths[col] = 4 * math.sqrt(var - 1 / 12)
        assert widths[col] == pytest.approx(want, rel=0.03)
    assert widths[4] > 1.4 * widths[20]  # nearer the viewer, further from focus: more blur
    # the optical axis meets the corner's edge in focus: one disk from it would blur nothing
    assert projector.defocus_blur_diameter_px(0.2, 1.0, 1.0, 30.0, 64) == 0.0


def test_lens_keeps_the_light_and_is_linear():
    lens = lens_for(_corner_setup(psf_sigma=0.8))
    rng = np.random.default_rng(1)
    x, y = rng.random((2, 64, 64, 3), dtype=np.float32)
    a, b = lens.apply(x), lens.apply(y)
    np.testing.assert_allclose(lens.apply(2 * x + 0.5 * y), 2 * a + 0.5 * b, rtol=1e-5, atol=1e-5)
    # all the light of a white panel leaves the lens, some of it past the panel's border
    white = np.ones((64, 64, 3), np.float32)
    out = lens.apply(white)
    assert out.sum() == pytest.approx(white.sum(), rel=1e-5)
    p = lens.pad
    assert out[:, :p].sum() > 0.01 * white[:, 0].sum()


def test_sharp_lens_costs_nothing():
    lens = lens_for(tiny_setup())
    x = np.random.default_rng(0).random((64, 64, 3), dtype=np.float32)
    assert lens.pad == 0 and lens.sharp and lens.apply(x) is x


def test_padded_emitter_lands_where_the_panel_does():
    """Widening the emitter by the padding keeps every panel pixel where it was: a lens with a
    negligible PSF (one pixel of padding) renders what the sharp projector renders."""
    frame = np.random.default_rng(2).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    sharp = Renderer(tiny_setup(), "direct")
    padded = Renderer(tiny_setup(projector={"psf_sigma": 0.01}), "direct")
    assert padded.lens.pad == 1
    a = sharp.projector_radiance(sharp.emit(frame), 3)
    b = padded.projector_radiance(padded.emit(frame), 3)
    assert np.abs(a - b).max() <= 1e-4 * a.max()


def test_spill_past_the_panel_border_reaches_the_surface():
    """A lit column on the panel's border keeps its light when blurred (the surface is larger than
    the projected area): the camera sees the same total radiance as without blur."""
    frame = np.zeros((64, 64, 3), np.uint8)
    frame[8:56, 0] = 255
    sharp = Renderer(tiny_setup(render={"spp": 16}), "direct")
    blurred = Renderer(tiny_setup(projector={"psf_sigma": 1.5, "aperture": 0.05, "focus_distance": 0.8},
                                  render={"spp": 16}), "direct")
    assert blurred.lens.pad >= 7
    a = sharp.projector_radiance(sharp.emit(frame)).sum()
    b = blurred.projector_radiance(blurred.emit(frame)).sum()
    assert b == pytest.approx(a, rel=0.02)


def test_lens_stays_exact_in_the_transport_operator():
    setup = tiny_setup(projector={"resolution": [32, 32], "psf_sigma": 0.7, "aperture": 0.04,
                                  "focus_distance": 0.8},
                       camera={"resolution": [32, 32]}, render={"fidelity": "transport", "spp": 4})
    tr = TransportRenderer(setup)
    assert tr.operator.projector_size == tr.lens.size and tr.lens.pad > 0
    assert tr.operator.info.verify_error <= 1e-4
    frame = np.random.default_rng(4).integers(0, 256, (32, 32, 3), dtype=np.uint8)
    irr = tr.emit(frame)
    direct = Renderer(setup, "direct", 4)
    want = direct.projector_radiance(irr, tr.operator.info.seed)
    got = tr.projector_radiance(irr)
    assert np.abs(got - want).max() <= 1e-4 * want.max()


# ----------------------------------------------------------------------------------- lamp

def test_flicker_and_drift_statistics():
    cfg = tiny_setup(projector={"flicker": 0.05, "drift": -0.1}).projector
    n = 4000
    train = np.array([projector.lamp_gain(cfg, 0, seeds.TRAIN, i) for i in range(n)])
    test = np.array([projector.lamp_gain(cfg, 0, seeds.TEST, i) for i in range(n)])
    loop = np.array([projector.lamp_gain(cfg, 0, seeds.CLOSED_LOOP, i) for i in range(n)])
    se = 0.05 / math.sqrt(n)
    assert abs(train.mean() - 1.0) < 4 * se
    assert abs(test.mean() - 0.9) < 4 * 0.9 * se and abs(loop.mean() - 0.9) < 4 * 0.9 * se
    assert train.std() == pytest.approx(0.05, rel=0.06)
    assert test.std() == pytest.approx(0.9 * 0.05, rel=0.06)
    assert abs(np.corrcoef(train[:-1], train[1:])[0, 1]) < 0.06  # independent captures
    assert not np.array_equal(train, test)
    assert projector.lamp_gain(replace(cfg, flicker=0.0), 0, seeds.EXPOSURE, 0) == 1.0  # calibration
    # steady lamp: exactly 1
    still = tiny_setup().projector
    assert {projector.lamp_gain(still, 0, s, 3) for s in (seeds.TRAIN, seeds.TEST)} == {1.0}


def test_lamp_scales_captures_but_not_the_calibration():
    keys = {"resolution": [16, 16]}
    setup = tiny_setup(projector={**keys, "flicker": 0.1, "drift": 0.2}, camera={"resolution": [16, 16]},
                       ambient={"radiance": [0.05, 0.05, 0.05]}, render={"fidelity": "transport"})
    steady = tiny_setup(projector=keys, camera={"resolution": [16, 16]},
                        ambient={"radiance": [0.05, 0.05, 0.05]}, render={"fidelity": "transport"})
    sim, ref = Simulator(setup, (16, 16)), Simulator(steady, (16, 16))
    np.testing.assert_array_equal(sim.renderer.operator.values, ref.renderer.operator.values)
    frame = np.full((16, 16, 3), 200, np.uint8)
    amb = ref.renderer.ambient_radiance()
    for stream, index in [(seeds.TRAIN, 0), (seeds.TRAIN, 1), (seeds.TEST, 0)]:
        gain = projector.lamp_gain(setup.projector, 0, stream, index)
        want = (ref.linear(frame, stream, index) - amb) * gain + amb
        np.testing.assert_allclose(sim.linear(frame, stream, index), want, rtol=1e-5, atol=1e-7)


# ----------------------------------------------------------------------------------- keys

@pytest.mark.parametrize("key, value, expected", [
    ("keep_aspect", "yes", "expected true or false"),
    ("psf_sigma", -0.5, "expected a number in [0, 50] projector pixels"),
    ("flicker", 0.7, "expected a number in [0, 0.5]"),
    ("drift", -1.0, "expected a number in (-1, 1)"),
])
def test_bad_projector_keys_are_named(key, value, expected):
    with pytest.raises(SetupError, match=rf"projector\.{key} = .*{re.escape(expected)}"):
        tiny_setup(projector={key: value})


# ----------------------------------------------------------------------------------- path depth

def _lit_corner(read_noise: float):
    return tiny_setup(surface={"geometry": "corner", "size": [1.0, 1.0], "albedo_scale": 0.9},
                      projector={"resolution": [32, 32]},
                      camera={"resolution": [32, 32], "position": [0.0, 0.0, 1.2], "read_noise": read_noise},
                      render={"fidelity": "auto", "max_depth": 3})


@pytest.fixture(scope="module")
def corner_probe():
    """A converged reference of a bright corner (depth 16, 1024 spp), two probe classes."""
    from sim import fidelity

    return fidelity.Probe(_lit_corner(0.01), classes=("smooth", "natural"), reference_spp=1024,
                          window=None)


def test_depth_three_misses_interreflected_light(corner_probe):
    """Independently of auto: a depth-3 render of a bright corner lacks a percent or more of the
    converged radiance (the light of two and more bounces between the wings)."""
    setup = corner_probe.setup
    frame = corner_probe.frames["smooth"]
    means = {}
    for depth in (3, 16):
        r = Renderer(replace(setup, render=replace(setup.render, max_depth=depth)), "path", 256)
        means[depth] = float(r.projector_radiance(r.emit(frame), 5).mean())
    assert 0.01 < 1 - means[3] / means[16] < 0.15


def test_auto_picks_the_path_depth_by_measurement(corner_probe):
    from sim import fidelity

    assert corner_probe.reference_depth == fidelity.AUTO_REFERENCE_DEPTH
    choice = fidelity.choose(corner_probe.setup, spp=64, probe=corner_probe)
    depths = [(c["spp"], c["max_depth"], c["error_over_floor"]) for c in choice.candidates]
    # depth 3 misses more light than the camera's noise; one more bounce brings it below
    assert depths[0][:2] == (64, 3) and depths[0][2] > 1.2
    assert choice.max_depth == 4 and depths[-1][:2] == (64, 4) and depths[-1][2] <= 1.0
    assert choice.as_dict()["max_depth"] == 4 and "depth 4" in choice.reason
    assert choice.predicted_error <= choice.noise_floor


def test_simulator_renders_at_the_recorded_depth():
    setup = _lit_corner(0.01)
    sim = Simulator(replace(setup, camera=replace(setup.camera, resolution=(16, 16))), (16, 16),
                    "path", 1, max_depth=5)
    assert sim.renderer.setup.render.max_depth == 5 and sim.choice.max_depth == 5


def test_one_depth_everywhere_is_the_plain_disk_blur():
    img = np.random.default_rng(5).random((40, 50, 3), dtype=np.float32)
    for d in (0.0, 2.5, 3.1):
        np.testing.assert_allclose(projector.varying_defocus(img, np.full((40, 50), d)),
                                   projector.defocus(img, d), rtol=1e-5, atol=1e-6)
