"""Physics of the renderer: linearity, energy, falloff, ambient, inter-reflection, determinism."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import tiny_setup
from sim.render import Renderer


def _centre(img: np.ndarray, r: int = 2) -> np.ndarray:
    h, w = img.shape[:2]
    return img[h // 2 - r:h // 2 + r, w // 2 - r:w // 2 + r].reshape(-1, 3).mean(axis=0)


def _head_on(**overrides):
    cam = {"position": [0.0, 0.0, 1.0], **overrides.pop("camera", {})}
    return tiny_setup(camera=cam, **overrides)


@pytest.mark.parametrize("case", ["plane-direct", "corner-path", "thinlens-textured", "thinlens-traced"])
def test_linear_in_projector_irradiance(case, variant):
    """R(a) + R(b) = R(a + b) + R(0) with one seed, for every scene kind."""
    if case == "plane-direct":
        setup = tiny_setup(ambient={"radiance": [0.05, 0.04, 0.03]})
    elif case == "corner-path":
        setup = tiny_setup(surface={"geometry": "corner", "size": [0.6, 1.0]},
                           render={"fidelity": "path", "max_depth": 3})
    else:
        setup = tiny_setup(surface={"texture": "noise"},
                           camera={"aperture_radius": 0.01, "focus_distance": 0.9,
                                   "defocus": "ray" if case == "thinlens-traced" else "image"})
    r = Renderer(setup, variant=variant)
    rng = np.random.default_rng(0)
    a, b = (rng.random((64, 64, 3), dtype=np.float32) for _ in range(2))
    amb = r.ambient_radiance()
    total = lambda irr: r.projector_radiance(irr, seed=7) + amb  # noqa: E731
    lhs = total(a) + total(b)
    rhs = total(a + b) + total(np.zeros_like(a))
    assert np.abs(lhs - rhs).max() / np.abs(rhs).max() < 1e-5


def test_projector_off_gives_ambient_only(variant):
    setup = tiny_setup(ambient={"radiance": [0.03, 0.05, 0.02]})
    r = Renderer(setup, variant=variant)
    black = np.zeros((16, 16, 3), np.uint8)
    np.testing.assert_array_equal(r.radiance(black, seed=3), r.ambient_radiance())
    assert r.ambient_radiance().mean() > 0


def test_head_on_irradiance_one_gives_albedo_and_inverse_square(variant):
    """Irradiance 1 at 1 m head-on: radiance = albedo (±2 %); at 2 m a quarter (±3 %)."""
    ones = np.ones((64, 64, 3), np.float32)
    near = _centre(Renderer(_head_on(), variant=variant).projector_radiance(ones))
    np.testing.assert_allclose(near, 0.8, rtol=0.02)
    far_setup = _head_on(projector={"position": [0.0, 0.0, 2.0]}, camera={"position": [0.0, 0.0, 2.0]})
    far = _centre(Renderer(far_setup, variant=variant).projector_radiance(ones))
    np.testing.assert_allclose(far / near, 0.25, rtol=0.03)


def test_oblique_incidence_follows_cosine():
    """The projector 45° off the normal, same distance: radiance × cos 45°."""
    ones = np.ones((64, 64, 3), np.float32)
    s45 = np.sqrt(0.5)
    setup = _head_on(projector={"position": [0.0, s45, s45]})
    got = _centre(Renderer(setup).projector_radiance(ones))
    np.testing.assert_allclose(got, 0.8 * s45, rtol=0.02)


def test_constant_ambient_gives_albedo_times_radiance():
    """On a uniform diffuse plane each BSDF sample of the constant room light returns albedo ×
    radiance: the ambient image is exact at one sample per pixel, everywhere on the plane."""
    setup = _head_on(ambient={"radiance": [0.1, 0.2, 0.3]}, render={"ambient_spp": 1})
    assert setup.surface.texture == "uniform" and setup.surface.albedo_scale == 0.8
    img = Renderer(setup).ambient_radiance()
    on_plane = img[img.sum(axis=-1) > 0]
    assert len(on_plane) > 0.9 * img.shape[0] * img.shape[1]
    np.testing.assert_allclose(on_plane, np.broadcast_to(0.8 * np.array([0.1, 0.2, 0.3]), on_plane.shape),
                               rtol=1e-5)


def test_ink_density_scales_the_prints_optical_density():
    """``surface.ink_density`` d scales each texel's optical density: albedo = scale · tex^d, so
    half the ink halves -log10 of the relative reflectance, no ink leaves the bare sheet, and a
    lighter print is brighter and less saturated where the room light renders it."""
    from sim.scene import albedo_texture

    surface = {"texture": "curves", "texture_seed": 3, "albedo_scale": 0.8}
    full, half, none = (albedo_texture(tiny_setup(surface={**surface, "ink_density": d}))
                        for d in (1.0, 0.5, 0.0))
    dense = full > 1e-3
    np.testing.assert_allclose(-np.log10(half[dense] / 0.8), -0.5 * np.log10(full[dense] / 0.8),
                               rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(none, 0.8, rtol=1e-6)

    def saturation(img):
        return float(np.mean((img.max(-1) - img.min(-1)) / np.maximum(img.max(-1), 1e-6)))

    assert saturation(half) < saturation(full) - 0.05
    ambient = {"radiance": [0.1, 0.1, 0.1]}
    lit = [Renderer(tiny_setup(surface={**surface, "ink_density": d}, ambient=ambient,
                               render={"ambient_spp": 1})).ambient_radiance() for d in (1.0, 0.5)]
    on = lit[0].sum(-1) > 0
    assert lit[1][on].mean() > 1.2 * lit[0][on].mean() and np.all(lit[1][on] >= lit[0][on] - 1e-6)


def test_corner_path_tracing_adds_interreflection():
    """In a 90° corner each wing lights the other: depth 3 is brighter than direct light."""
    corner = {"geometry": "corner", "size": [0.6, 1.0]}
    proj = {"position": [0.0, 0.0, 1.2]}
    ones = np.ones((64, 64, 3), np.float32)
    setup = tiny_setup(surface=corner, projector=proj, render={"fidelity": "path", "max_depth": 3})
    direct, path = Renderer(setup, fidelity="direct"), Renderer(setup)
    d, p = direct.projector_radiance(ones).mean(), path.projector_radiance(ones).mean()
    assert p > 1.1 * d


def test_same_seed_bit_identical_different_seed_differs():
    setup = tiny_setup(ambient={"radiance": [0.02, 0.02, 0.02]})
    frame = np.full((64, 64, 3), 180, np.uint8)
    a = Renderer(setup).radiance(frame, seed=1)
    b = Renderer(setup).radiance(frame, seed=1)
    c = Renderer(setup).radiance(frame, seed=2)
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).max() > 0


def test_projector_defocus_blurs_a_line():
    """A projector focused at 0.8 m blurs a 1 m surface: a one-pixel line spreads out."""
    frame = np.zeros((64, 64, 3), np.uint8)
    frame[:, 32] = 255
    sharp = Renderer(_head_on(camera={"fov": 30.0}))
    blurred = Renderer(_head_on(camera={"fov": 30.0},
                                projector={"aperture": 0.1, "focus_distance": 0.8}))
    assert blurred.defocus_px > 2
    prof_s = sharp.radiance(frame)[32, :, 1]
    prof_b = blurred.radiance(frame)[32, :, 1]
    width = lambda p: (p > 0.5 * p.max()).sum()  # noqa: E731
    assert width(prof_b) > width(prof_s) + 1
    np.testing.assert_allclose(prof_b.sum(), prof_s.sum(), rtol=0.05)


def test_ambient_image_is_rendered_once_per_setup_in_a_process():
    """Renderers of one setup (the exposure preview, the capture renderer) share the ambient image
    instead of rendering it again; another ambient level is another image, linear in it."""
    from dataclasses import replace

    from sim import render
    setup = tiny_setup(ambient={"radiance": [0.05, 0.05, 0.05]})
    render._ambient_memo.clear()
    first = Renderer(setup, "direct", 4).ambient_radiance()
    assert Renderer(setup, "direct", 8).ambient_radiance() is first  # spp of the projector only
    assert not first.flags.writeable
    brighter = replace(setup, ambient=replace(setup.ambient, radiance=(0.1, 0.1, 0.1)))
    second = Renderer(brighter, "direct", 4).ambient_radiance()
    assert second is not first
    np.testing.assert_allclose(second, 2 * first, rtol=1e-5, atol=1e-7)
    exposed = replace(setup, camera=replace(setup.camera, exposure=2.5))  # what the rule changes
    assert Renderer(exposed, "direct", 4).ambient_radiance() is first
    # the ambient scene has no projector: a projector study's points share the image, and it is
    # the image each would render on its own
    moved = replace(setup, name="other", projector=replace(setup.projector, aperture=0.05,
                                                           position=(0.1, 0.0, 1.0)))
    assert Renderer(moved, "direct", 4).ambient_radiance() is first
    render._ambient_memo.clear()
    np.testing.assert_array_equal(Renderer(moved, "direct", 4).ambient_radiance(), first)
    wider = replace(setup, camera=replace(setup.camera, fov=setup.camera.fov + 5))
    assert Renderer(wider, "direct", 4).ambient_radiance() is not first
