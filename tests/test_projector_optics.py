"""The projector's hardware: scaler (frame area), lens PSF, depth-dependent defocus with its spill
kept, lens distortion about its offset axis, the surface's translucency, flare and its contrasts,
lamp flicker and drift; and that all of it stays exact in the light-transport operator."""
from __future__ import annotations

import math
import re
from dataclasses import replace

import numpy as np
import pytest
from helpers import tiny_setup

from sim import projector, registration, seeds
from sim.capture import Simulator
from sim.errors import ProcamError, SetupError
from sim.projector import distortion, flare, lens_for, translucency
from sim.render import Renderer
from sim.setup import load_setup, scene_path
from sim.stages import run
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


# ----------------------------------------------------------------------------------- distortion

def _blob(lens: projector.Lens, x: float, y: float, sigma: float = 3.0) -> np.ndarray:
    """A small Gaussian spot of total 1 at panel point ``(x, y)`` on the lens's padded grid."""
    w, h = lens.size
    gy, gx = np.mgrid[0:h, 0:w] + 0.5 - lens.pad
    spot = np.exp(-((gx - x) ** 2 + (gy - y) ** 2) / (2 * sigma ** 2))
    return np.repeat((spot / spot.sum()).astype(np.float32)[..., None], 3, axis=2)


def test_distortion_moves_a_point_where_browns_model_says_about_the_offset_axis():
    """A spot leaves the lens at u = a + (x - a)(1 + k1 rho² + k2 rho⁴) about the axis point a,
    half a panel height below the image centre here: the centre moves straight up, a point near
    the axis stays; the flux is kept (the Jacobian; but for the bilinear resampling's moiré,
    under 1 % for a spot this small)."""
    lens = projector.Lens((128, 96), 12)
    k1, k2, offset = 0.05, 0.01, 0.5
    axis = np.array([64.0, 96.0])
    for point in ([64.0, 48.0], [96.0, 24.0], [20.0, 70.0], [64.0, 93.0]):
        out = distortion.distort(_blob(lens, *point), lens, k1, k2, offset)[..., 1]
        total, cx, cy, _ = _moments(out)
        rho2 = np.sum(((np.array(point) - axis) / 80.0) ** 2)
        want = axis + (np.array(point) - axis) * (1 + k1 * rho2 + k2 * rho2 ** 2)
        np.testing.assert_allclose(want, distortion.distort_points(point, (128, 96), k1, k2, offset))
        np.testing.assert_allclose([cx + 0.5 - lens.pad, cy + 0.5 - lens.pad], want, atol=0.06)
        assert total == pytest.approx(1.0, abs=0.01)
    centre = distortion.distort_points([64.0, 48.0], (128, 96), k1, k2, offset)
    assert centre[0] == 64.0 and 47.0 < centre[1] < 47.2  # up by ~0.93 px, along the axis line
    # barrel pulls towards the axis
    out = distortion.distort(_blob(lens, 96.0, 24.0), lens, -0.05, 0.0, offset)[..., 1]
    _, cx, cy, _ = _moments(out)
    assert np.hypot(cx + 0.5 - lens.pad - 64, cy + 0.5 - lens.pad - 96) < np.hypot(32, 72) - 3


def test_distortion_is_linear_keeps_smooth_light_and_refuses_a_fold():
    lens = projector.Lens((80, 60), 6)
    rng = np.random.default_rng(3)
    x, y = (rng.random((72, 92, 3), dtype=np.float32) for _ in range(2))
    f = lambda v: distortion.distort(v, lens, -0.04, 0.01, 0.6)  # noqa: E731
    np.testing.assert_allclose(f(0.3 * x + 0.7 * y), 0.3 * f(x) + 0.7 * f(y), rtol=1e-5, atol=1e-6)
    smooth = np.zeros((72, 92, 3), np.float32)
    smooth[10:62, 10:82] = 0.5 + 0.4 * np.sin(np.arange(72)[:, None] / 5.0)[10:62, None]
    assert f(smooth).sum() == pytest.approx(smooth.sum(), rel=2e-3)
    with pytest.raises(ProcamError, match=r"projector\.distortion_k1 = -0\.1.*folds the image over"):
        distortion.distort(x, lens, -0.1, 0.0, 1.0)


# ----------------------------------------------------------------------------------- translucency

def test_lens_knows_its_pixel_on_the_surface():
    lens = lens_for(tiny_setup())  # 64 px, fov 30, head-on at 1 m
    assert lens.surface_pitch == pytest.approx(2 * math.tan(math.radians(15)) / 64, rel=1e-9)
    assert lens_for(tiny_setup(projector={"position": [0.0, 0.0, 2.0]})).surface_pitch == \
        pytest.approx(2 * lens.surface_pitch, rel=1e-9)


def test_translucency_kernel_has_the_exponential_second_moment_and_keeps_the_light():
    """exp(-r / mfp) in 2-D has mean r² = 6 mfp²; integrated over pixels, the pixel adds 1/6. The
    kernel's length is the surface's millimetres in projector pixels."""
    lens = projector.Lens((96, 96), 0, surface_pitch=0.5e-3)  # 0.5 mm per projector pixel
    mfp_mm, fraction = 1.5, 0.6  # 3 px
    out = translucency.translucent(_dot((96, 96), 48, 48), lens, mfp_mm, fraction)[..., 0]
    total, cx, cy, var = _moments(out)
    assert total == pytest.approx(1.0, abs=1e-5)
    assert (cx, cy) == (pytest.approx(48, abs=1e-4), pytest.approx(48, abs=1e-4))
    kernel = translucency.exponential_kernel(3.0)
    assert 2 * var == pytest.approx(fraction * (6 * 3.0 ** 2 + 1 / 6), rel=0.01)
    assert out[48, 48] == pytest.approx(1 - fraction + fraction * kernel.max(), rel=1e-5)
    n = kernel.shape[0] // 2
    yy, xx = np.mgrid[-n:n + 1, -n:n + 1]
    assert float((kernel * (xx ** 2 + yy ** 2)).sum()) == pytest.approx(6 * 9 + 1 / 6, rel=0.01)
    # a kernel far below a pixel keeps most of the light in place
    tiny = translucency.exponential_kernel(0.1)
    assert tiny.shape == (5, 5) and tiny[2, 2] > 0.95


# ----------------------------------------------------------------------------------- flare

def test_flare_veil_keeps_the_light_and_has_its_width():
    lens = projector.Lens((400, 300), 0)
    cfg = replace(tiny_setup().projector, flare=0.05, flare_sigma=0.05)  # 20 px
    out = flare.FLARE.apply(_dot((400, 300), 200, 150), cfg, lens)[..., 0]
    total, cx, cy, var = _moments(out - 0.95 * _dot((400, 300), 200, 150)[..., 0])
    assert out.sum() == pytest.approx(1.0, abs=1e-5)
    assert total == pytest.approx(0.05, rel=1e-4)
    assert abs(cx - 200) <= 20 / 16 and abs(cy - 150) <= 20 / 16  # its coarse block's centre
    assert math.sqrt(var) == pytest.approx(20.0, rel=0.02)


def test_default_projector_flare_gives_the_ansi_contrast_of_reviews():
    """projector reviews: ~160:1 ANSI (4x4 checkerboard) where full-on/full-off is far higher; the
    flare lowers the one and leaves the other."""
    setup = load_setup(scene_path("default"))
    lens = lens_for(setup)

    def emit(cfg):
        return lambda frame: run(projector.chain.EMISSION, frame, cfg, lens)

    p = setup.projector
    no_flare = replace(p, flare=0.0)
    ansi = flare.ansi_contrast(emit(p), lens)
    assert ansi == pytest.approx(160, rel=0.15)
    assert flare.ansi_contrast(emit(no_flare), lens) > 3 * ansi
    full = flare.full_contrast(emit(p), lens)
    assert full == pytest.approx(flare.full_contrast(emit(no_flare), lens), rel=1e-5)
    assert full == pytest.approx(1 / p.black_level, rel=1e-3)


# ----------------------------------------------------------------------------------- off

def test_new_stages_switched_off_change_nothing():
    """At their off values the distortion, translucency and flare are skipped, whatever their
    other keys: the emitted light is bit for bit that of the chain without them."""
    setup = tiny_setup(projector={"psf_sigma": 0.8, "lens_offset": 0.6, "translucency_fraction": 0.3,
                                  "flare_sigma": 0.7})
    lens = lens_for(setup)
    frame = np.random.default_rng(5).random((64, 64, 3), dtype=np.float32)
    chain = projector.chain.EMISSION
    new = (distortion.DISTORTION, translucency.TRANSLUCENCY, flare.FLARE)
    assert chain[-3:] == new and all(s.is_off(setup.projector) for s in new)
    np.testing.assert_array_equal(run(chain, frame, setup.projector, lens),
                                  run(chain[:-3], frame, setup.projector, lens))
    on = replace(setup.projector, distortion_k1=0.02, translucency_mfp=2.0, flare=0.05)
    assert not np.array_equal(run(chain, frame, on, lens), run(chain[:-3], frame, on, lens))


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


def test_the_noise_free_model_keeps_the_drift_and_drops_every_random_draw():
    """Simulator.noise_free: the camera's noise and the lamp's flicker off (two captures of the same
    frame in different streams agree bit for bit at the transport level), the test-time drift kept
    (a deterministic gain), and the camera's expected value: the mean of noisy captures."""
    keys = {"resolution": [16, 16], "flicker": 0.1, "drift": 0.2}
    setup = tiny_setup(projector=keys, camera={"resolution": [16, 16], "shot_noise": 2e-4, "read_noise": 4e-3},
                       ambient={"radiance": [0.05, 0.05, 0.05]}, render={"fidelity": "transport"})
    sim = Simulator(setup, (16, 16))
    model = sim.noise_free()
    frame = np.full((1, 16, 16, 3), 150, np.uint8)
    a, b = model.capture(frame, seeds.TEST), model.capture(frame, seeds.OPTIMUM)
    np.testing.assert_array_equal(a, b)
    assert model.setup.camera.shot_noise == 0 and model.setup.camera.read_noise == 0
    assert (model.setup.projector.flicker, model.setup.projector.drift) == (0.0, 0.2)
    assert (sim.setup.projector.flicker, sim.setup.camera.shot_noise) == (0.1, 2e-4)  # the original as it was
    steady = Simulator(replace(setup, projector=replace(setup.projector, flicker=0.0)), (16, 16))
    noisy = np.stack([steady.capture(frame, seeds.CLOSED_LOOP + 1 + k)[0] for k in range(24)]).astype(float)
    assert abs(noisy.mean() - a.astype(float).mean()) < 0.5  # 8-bit levels: the expected capture
    assert noisy.std(axis=0).mean() > 0.5  # while each noisy capture differs


# ----------------------------------------------------------------------------------- keys

@pytest.mark.parametrize("key, value, expected", [
    ("keep_aspect", "yes", "expected true or false"),
    ("psf_sigma", -0.5, "expected a number in [0, 50] projector pixels"),
    ("flicker", 0.7, "expected a number in [0, 0.5]"),
    ("drift", -1.0, "expected a number in (-1, 1)"),
    ("distortion_k1", 0.2, "expected a number in [-0.1, 0.1]"),
    ("lens_offset", 1.5, "expected a number in [-1, 1]"),
    ("translucency_mfp", -1.0, "expected a number in [0, 10] millimetres"),
    ("translucency_fraction", 1.2, "expected a number in [0, 1]"),
    ("flare", 0.6, "expected a number in [0, 0.5]"),
    ("flare_sigma", 0.0, "expected a number in (0, 2]"),
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
