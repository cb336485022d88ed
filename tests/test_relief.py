"""Surface relief: the height field's statistics, ray intersection against Mitsuba's own, the mesh's
texture layout, parallax against the thin-baseline formula, the homography's residual, the
transport level's exactness on a relief sheet, and the setup keys' checks."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from helpers import tiny_setup
from sim import registration, surfaces
from sim.errors import SetupError
from sim.render import Renderer
from sim.setup import parse_setup
from sim.surfaces.plane import Plane, PlaneOptions
from sim.surfaces.relief import HeightField, height_field


def _sheet(**options) -> Plane:
    return Plane((1.2, 1.0), 512, PlaneOptions(**options))


# ------------------------------------------------------------------------------ the height field

def test_random_relief_has_its_rms_and_correlation_length():
    """RMS exactly the key's; mean 0; the correlation at a lag of one correlation length is e^-1
    (averaged over seeds and both axes) and falls from 1 at lag 0."""
    length_mm = 40.0
    corr = []
    for seed in range(6):
        field = height_field((1.2, 1.0), 2.0, length_mm, seed, 0.0)
        z = field.heights
        assert abs(np.sqrt(np.mean(z ** 2)) - 2e-3) < 1e-12 and abs(z.mean()) < 1e-12
        lag = round(length_mm * 1e-3 / (1.2 / field.cells[0]))  # grid steps in one correlation length
        var = np.mean(z ** 2)
        corr += [np.mean(z[:, lag:] * z[:, :-lag]) / var, np.mean(z[lag:] * z[:-lag]) / var]
    assert abs(np.mean(corr) - np.exp(-1)) < 0.08, np.mean(corr)


def test_bow_is_zero_on_the_edges_and_its_value_at_the_centre():
    field = height_field((1.2, 1.0), 0.0, 30.0, 0, -4.0)
    z = field.heights
    for edge in (z[0], z[-1], z[:, 0], z[:, -1]):
        np.testing.assert_allclose(edge, 0.0, atol=1e-15)
    h, _, _ = field.height_and_slope(np.array([0.0]), np.array([0.0]))
    assert abs(h[0] + 4e-3) < 1e-9
    assert field.heights.max() <= 1e-15  # concave everywhere: no point stands out


def test_seeds_differ_and_repeat():
    a, b = (height_field((1.2, 1.0), 1.0, 30.0, s, 0.0).heights for s in (0, 1))
    assert np.abs(a - b).max() > 1e-3
    np.testing.assert_array_equal(a, height_field((1.2, 1.0), 1.0, 30.0, 0, 0.0).heights)


def test_intersection_lies_on_the_field_and_agrees_with_mitsuba(variant):
    """Rays from a projector-like origin hit the piecewise-linear field exactly where Mitsuba's own
    ray tracer hits the mesh procam renders (an independent intersection)."""
    import mitsuba as mi
    from sim.variant import use_variant

    use_variant(variant)
    sheet = _sheet(relief=3.0, relief_length=20.0, relief_seed=3, bow=5.0)
    origin = np.array([0.1, -0.05, 1.0])
    rng = np.random.default_rng(0)
    targets = np.concatenate([rng.uniform(-0.5, 0.5, (64, 2)), np.zeros((64, 1))], axis=1)
    dirs = targets - origin
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    t, index = sheet.intersect(origin, dirs)
    assert np.isfinite(t).all() and (index == 0).all()
    points = origin + t[:, None] * dirs
    height, _, _ = sheet.field.height_and_slope(points[:, 0], points[:, 1])
    np.testing.assert_allclose(points[:, 2], height, atol=1e-10)
    assert np.ptp(points[:, 2]) > 3e-3  # the relief is really there

    mesh = sheet.shapes(np.ones((4, 4, 3), np.float32), lambda part: {"type": "diffuse"})["surface_0"]
    scene = mi.load_dict({"type": "scene", "sheet": mesh})
    for o_row, d_row, t_row in zip(np.broadcast_to(origin, dirs.shape)[:8], dirs[:8], t[:8]):
        si = scene.ray_intersect(mi.Ray3f(mi.Point3f(*map(float, o_row)), mi.Vector3f(*map(float, d_row))))
        assert abs(float(np.asarray(si.t).ravel()[0]) - t_row) < 2e-6


def test_misses_outside_the_sheet_and_from_behind():
    sheet = _sheet(relief=1.0)
    t, index = sheet.intersect(np.array([0.0, 0.0, 1.0]), np.array([[0.8, 0.0, -0.6], [0.0, 0.0, 1.0]]))
    assert np.isinf(t).all() and (index == -1).all()


def test_normals_tilt_with_the_slope():
    field = HeightField((2.0, 2.0), np.array([[0.0, 0.2], [0.0, 0.2]]))  # rises 0.2 m over 2 m along x
    n = field.normals(np.array([[0.3, 0.1, 0.0]]))
    np.testing.assert_allclose(n[0], np.array([-0.1, 0.0, 1.0]) / np.sqrt(1.01))


# ------------------------------------------------------------------------------ rendering

def test_a_sheet_with_negligible_bow_renders_as_the_rectangle(variant):
    """The mesh carries the texture exactly as the rectangle does (no flip, no shift): with a bow of
    a nanometre the two renders agree to float precision."""
    base = dict(surface={"texture": "checker", "texture_resolution": 64},
                render={"fidelity": "direct", "spp": 4, "ambient_spp": 4})
    frame = np.random.default_rng(2).integers(0, 256, (64, 64, 3), dtype=np.uint8)
    flat = Renderer(tiny_setup(**base), variant=variant)
    bowed = tiny_setup(**{**base, "surface": {**base["surface"], "bow": 1e-6}})
    assert surfaces.surface_for(bowed.surface).field is not None
    mesh = Renderer(bowed, variant=variant)
    a, b = flat.radiance(frame, seed=1), mesh.radiance(frame, seed=1)
    assert np.abs(a - b).max() < 1e-3 * a.max(), np.abs(a - b).max()


def test_parallax_of_a_bow_follows_the_baseline_formula():
    """A bow of +10 mm brings the sheet's centre towards the pair: the camera, 0.25 m to the side,
    sees the projector's centre pixel moved by f·b·dz / z² (small-angle parallax)."""
    size = (64, 64)
    flat = tiny_setup()
    bowed = tiny_setup(surface={"bow": 10.0})
    a = registration.exact_map(flat, size).xy[32, 32]
    b = registration.exact_map(bowed, size).xy[32, 32]
    cam = flat.camera
    f = cam.resolution[0] / 2 / np.tan(np.radians(cam.fov) / 2)  # camera focal length, pixels
    expected = f * 0.25 * 0.010 / 1.0 ** 2
    assert abs(abs(b[0] - a[0]) - expected) < 0.05 * expected, (b - a, expected)
    assert abs(b[1] - a[1]) < 0.02 * expected


def test_the_homography_residual_grows_with_relief():
    """One homography fits a flat sheet to the corners' noise; relief leaves a residual the exact
    map measures, recorded in canonical pixels."""
    size = (64, 64)
    residual = {}
    for relief in (0.0, 5.0):
        setup = tiny_setup(surface={"relief": relief, "relief_length": 60.0})
        exact = registration.exact_map(setup, size)
        # the homography of the exact correspondences at the frame's corners region (noise-free fit)
        import cv2

        uv = np.stack(np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5), axis=-1)[::8, ::8].reshape(-1, 2)
        xy = exact.xy[::8, ::8].reshape(-1, 2)
        hom, _ = cv2.findHomography(xy.astype(np.float64), uv.astype(np.float64))
        residual[relief] = registration.homography_error(hom, exact)["canonical_px"]
    assert residual[0.0]["max"] < 1e-3
    assert 0.02 < residual[5.0]["mean"] < residual[5.0]["p95"] <= residual[5.0]["max"]


def test_transport_equals_direct_on_a_relief_sheet():
    """The operator's footprints hold on a sheet with relief and bow: T p is the direct render of p
    at the calibration seed to float precision."""
    from sim.transport import TransportRenderer

    setup = tiny_setup(surface={"texture": "checker", "texture_resolution": 64, "relief": 4.0,
                                "relief_length": 30.0, "bow": 6.0})
    tr = TransportRenderer(setup, 4)
    cal = Renderer(setup, "direct", tr.operator.info.spp)
    x = np.random.default_rng(5).random((64, 64, 3), dtype=np.float32)
    want = cal.projector_radiance(x, tr.operator.info.seed)
    np.testing.assert_allclose(tr.projector_radiance(x), want, rtol=0, atol=1e-5 * want.max())


# ------------------------------------------------------------------------------ setup keys

@pytest.mark.parametrize("key, value, expected", [
    ("relief", -1.0, "relief"), ("relief", 51.0, "relief"), ("relief_length", 2.0, "relief_length"),
    ("bow", 200.0, "bow"), ("relief_seed", -1, "relief_seed")])
def test_relief_keys_are_range_checked(key, value, expected):
    with pytest.raises(SetupError, match=expected):
        parse_setup({"name": "x", "surface": {key: value}}, source="<test>")


def test_relief_keys_belong_to_the_plane():
    with pytest.raises(SetupError, match="relief"):
        parse_setup({"name": "x", "surface": {"geometry": "corner", "relief": 1.0}}, source="<test>")
    s = parse_setup({"name": "x", "surface": {"relief": 1.5, "bow": -2.0}}, source="<test>")
    assert s.surface.shape == PlaneOptions(relief=1.5, bow=-2.0)
    assert replace(s.surface.shape, relief=0.0, bow=0.0).flat
