"""The camera's thin lens in image space (``camera.defocus = "image"``) against Mitsuba's traced
thin lens, its disk widths, energy and linearity, and the pinhole operator and ambient it shares."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import tiny_setup
from sim import transport
from sim.camera import thinlens
from sim.errors import SetupError
from sim.projector import varying_defocus
from sim.render import Renderer

SPP = 1024
INNER = slice(8, -8)  # away from the border, where a disk would bring light from outside the view


def _lens(radius: float, model: str, spp: int = SPP, **camera):
    return tiny_setup(surface={"texture": "noise"}, ambient={"radiance": [0.05, 0.05, 0.05]},
                      render={"spp": spp, "ambient_spp": spp},
                      camera={"aperture_radius": radius, "focus_distance": 0.6, "defocus": model, **camera})


def _rmse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((a[INNER, INNER] - b[INNER, INNER]) ** 2)))


def test_diameters_follow_the_thin_lens_formula():
    """2 r F |d - f| / (f d) camera pixels, d the depth along the axis: head-on at 1 m, focused at
    0.6 m, r = 2 cm on a 64-pixel 40-degree camera is 2 * 0.02 * 87.9 * 0.4 / 0.6 = 2.34 px."""
    setup = tiny_setup(camera={"position": [0.0, 0.0, 1.0], "aperture_radius": 0.02,
                               "focus_distance": 0.6})
    d = thinlens.diameters(setup)
    focal = 32 / np.tan(np.radians(20))
    want_centre = 2 * 0.02 * focal * 0.4 / 0.6
    assert d[31:33, 31:33] == pytest.approx(want_centre, rel=1e-6)  # the plane is at depth 1 everywhere
    assert np.ptp(d) < 1e-9
    away = tiny_setup(surface={"size": [0.2, 0.2]},  # most pixels see no surface: infinite depth
                      camera={"position": [0.0, 0.0, 1.0], "aperture_radius": 0.02, "focus_distance": 0.6})
    assert thinlens.diameters(away)[0, 0] == pytest.approx(2 * 0.02 * focal / 0.6, rel=1e-6)
    tilted = thinlens.diameters(_lens(0.02, "image"))  # the camera 0.25 m off axis: depth varies
    assert np.ptp(tilted) > 0.05 * tilted.mean()


@pytest.mark.parametrize("radius", [0.015, 0.03])
def test_image_defocus_matches_the_traced_thin_lens(radius):
    """Pinhole render + per-pixel disks against Mitsuba's thin-lens sensor (1024 spp) on a noise
    texture lit by a random frame: closer than the sharp image by 3x (1.6-2.1 px disks) and 10x
    (3.2-4.1 px), and closer by a quarter than disks 20 % narrower or wider (the formula's diameter
    is the one that matches the traced lens best: on 3-7 px disks at 2048 spp, 5 % off already
    adds 10-20 % to the error)."""
    ray, image = Renderer(_lens(radius, "ray")), Renderer(_lens(radius, "image"))
    irr = image.emit(np.random.default_rng(1).random((64, 64, 3), dtype=np.float32))
    truth = ray.projector_radiance(irr, seed=3) + ray.ambient_radiance()
    pinhole = image.transport_radiance(irr, seed=5) + image.transport_ambient()
    model = image.projector_radiance(irr, seed=5) + image.ambient_radiance()
    err = _rmse(model, truth)
    assert err < _rmse(pinhole, truth) / (3 if radius < 0.02 else 10)
    for scale in (0.8, 1.2):  # the whole image (ambient too) through disks of another size
        assert err < 0.8 * _rmse(varying_defocus(pinhole, scale * image.camera_defocus.diameters), truth)
    np.testing.assert_allclose(model[INNER, INNER].mean(), truth[INNER, INNER].mean(), rtol=0.01)


def test_image_defocus_is_linear_keeps_energy_and_spreads_a_line_as_the_disk_does():
    setup = _lens(0.03, "image", position=[0.0, 0.0, 1.0])  # head-on: one diameter
    blur = thinlens.ImageDefocus(setup)
    d = float(blur.diameters[32, 32])
    rng = np.random.default_rng(0)
    a, b = (rng.random((64, 64, 3), dtype=np.float32) for _ in range(2))
    np.testing.assert_allclose(blur(a + b), blur(a) + blur(b), atol=1e-5)
    spot = np.zeros((64, 64, 3), np.float32)
    spot[30:34, 30:34] = 1.0
    assert blur(spot).sum() == pytest.approx(spot.sum(), rel=1e-5)
    line = np.zeros((64, 64, 3), np.float32)
    line[:, 32] = 1.0
    profile = blur(line)[32, :, 0].astype(np.float64)
    x = np.arange(64) - 32
    assert (profile * x).sum() == pytest.approx(0.0, abs=1e-6)  # centred on the line
    # across a line, a uniform disk of radius R spreads with variance R² / 4, plus the pixel's 1/12
    assert (profile * x * x).sum() / profile.sum() == pytest.approx((d / 2) ** 2 / 4 + 1 / 12, rel=0.03)


def test_the_image_model_renders_and_calibrates_the_pinhole_camera(tmp_path):
    """Every aperture and focus in image space shares the pinhole's operator and ambient render;
    a traced lens has its own."""
    pinhole = tiny_setup()
    image = tiny_setup(camera={"aperture_radius": 0.03, "focus_distance": 0.6})
    assert transport.cache_key(image, 4, "v") == transport.cache_key(pinhole, 4, "v")
    traced = tiny_setup(camera={"aperture_radius": 0.03, "focus_distance": 0.6, "defocus": "ray"})
    assert transport.cache_key(traced, 4, "v") != transport.cache_key(pinhole, 4, "v")
    op = transport.TransportRenderer(image, 4, cache_dir=tmp_path)
    again = transport.TransportRenderer(pinhole, 4, cache_dir=tmp_path)
    assert again.loaded_from_cache and again.camera_defocus is None
    frame = np.random.default_rng(2).random((64, 64, 3), dtype=np.float32)
    np.testing.assert_allclose(op.projector_radiance(frame),
                               op.camera_defocus(again.projector_radiance(frame)), atol=1e-6)


def test_a_pinhole_or_an_unknown_model():
    assert thinlens.image_defocus(tiny_setup()) is None
    assert thinlens.image_defocus(_lens(0.03, "ray")) is None
    # disks wider than this 64-pixel image are spread (auto's probe window crops a larger camera)
    assert 64 < thinlens.diameters(_lens(0.6, "image")).max() <= thinlens.MAX_DISK_PX
    with pytest.raises(SetupError, match=r'camera\.defocus = "blur": expected one of "image", "ray"'):
        _lens(0.03, "blur")


def test_a_simulator_captures_through_the_lens_in_image_space(tmp_path):
    """The capture path (transport level, exposure rule, registration) sees the blurred radiance:
    each capture's linear radiance is the pinhole simulator's through the disks."""
    from sim.capture import Simulator

    keys = {"surface": {"texture": "noise"}, "ambient": {"radiance": [0.02, 0.02, 0.02]},
            "registration": {"method": "exact"}, "camera": {"exposure_mode": "rule"}}
    pinhole = Simulator(tiny_setup(**keys), (32, 32), fidelity="transport", cache_dir=tmp_path)
    lens = {**keys, "camera": {**keys["camera"], "aperture_radius": 0.03, "focus_distance": 0.6}}
    blurred = Simulator(tiny_setup(**lens), (32, 32), fidelity="transport", cache_dir=tmp_path)
    assert blurred.renderer.loaded_from_cache  # the pinhole's operator
    frame = np.random.default_rng(3).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    want = blurred.renderer.camera_defocus(pinhole.linear(frame, 0, 0))
    np.testing.assert_allclose(blurred.linear(frame, 0, 0), want, rtol=1e-5, atol=1e-7)
    sharp, soft = (np.diff(s.capture(frame[None], 0)[0].astype(float), axis=1).std() for s in (pinhole, blurred))
    assert soft < 0.8 * sharp
