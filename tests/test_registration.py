"""Registration: exact map from the geometry, warping, and the homography a real system would fit."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from helpers import tiny_setup
from sim import geometry, registration
from sim.capture import Simulator
from sim.render import Renderer

SIZE = (64, 64)


def _beside(projector=(64, 64)):
    """Camera 0.25 m beside the projector, 128² so the projection covers many camera pixels."""
    return tiny_setup(camera={"position": [0.25, 0.0, 1.0], "resolution": [128, 128]},
                      projector={"resolution": list(projector)},
                      ambient={"radiance": [0.01, 0.01, 0.01]})


# (canonical size, projector resolution), both (width, height): a canonical view of another aspect
# than the projector's is the projector's image stretched to it (canonical pixels not square)
@pytest.mark.parametrize("size, projector", [(SIZE, (64, 64)), ((64, 48), (64, 64)), ((48, 64), (64, 64)),
                                             (SIZE, (64, 48))])
def test_checkerboard_warped_lines_up_within_one_pixel(size, projector):
    sim = Simulator(_beside(projector), size)
    frame, _ = registration.checkerboard(size)
    assert frame.shape == (size[1], size[0], 3) and sim.warp_map.mask.shape == (size[1], size[0])
    warped = sim.capture(frame[None], stream=40)[0].astype(float).mean(axis=2)
    white = sim.capture(np.full_like(frame, 255)[None], stream=41)[0].astype(float).mean(axis=2)
    seen_white = warped > 0.5 * white
    truth_white = frame[..., 0] > 127
    mask = sim.warp_map.mask
    assert mask.mean() > 0.99
    # every disagreement lies within one canonical pixel of an edge of the pattern
    edges = np.zeros_like(truth_white)
    edges[:, 1:] |= truth_white[:, 1:] != truth_white[:, :-1]
    edges[:, :-1] |= truth_white[:, 1:] != truth_white[:, :-1]
    edges[1:] |= truth_white[1:] != truth_white[:-1]
    edges[:-1] |= truth_white[1:] != truth_white[:-1]
    dist = cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 5)
    wrong = (seen_white != truth_white) & mask
    assert dist[wrong].max(initial=0) <= 1.0
    assert wrong.mean() < 0.05


@pytest.mark.parametrize("size", [(64, 64), (64, 48), (50, 37), (128, 96)])
def test_checkerboard_corners_are_where_the_squares_meet(size):
    """Each target corner lies on a pixel boundary where the four neighbouring pixels alternate
    black and white, and the squares' edges are nowhere else."""
    frame, corners = registration.checkerboard(size)
    black = frame[..., 0] == 0
    assert corners.shape == (8 * 5, 2)
    np.testing.assert_array_equal(corners, np.round(corners))  # whole numbers: pixel boundaries
    for x, y in corners.astype(int):
        quad = black[y - 1:y + 1, x - 1:x + 1]
        assert quad[0, 0] == quad[1, 1] and quad[0, 1] == quad[1, 0] and quad[0, 0] != quad[0, 1]
    # the columns and rows where the colour changes inside the pattern are the corners' ones
    mid_row = black[int(corners[0, 1]) - 1]
    changes = np.nonzero(mid_row[1:] != mid_row[:-1])[0] + 1
    np.testing.assert_array_equal(changes[1:-1], np.unique(corners[:, 0]))


def test_homography_error_at_64px_is_a_small_fraction_of_a_pixel():
    """The corner targets are the true corners of the drawn pattern: on a plane at 64² the fitted
    homography matches the exact map to a few hundredths of a camera pixel (targets off by up to
    half a canonical pixel gave about 1 px)."""
    setup = tiny_setup(camera={"position": [0.25, 0.0, 1.0], "resolution": [256, 256], "fov": 36.0},
                       projector={"resolution": [256, 256]},
                       ambient={"radiance": [0.01, 0.01, 0.01]})
    check = Simulator(setup, SIZE).registration.record(setup)["homography"]
    assert check["status"] == "ok"
    assert check["mean_px"] < 0.1 and check["max_px"] < 0.25


def test_a_camera_too_small_for_the_corner_finder_falls_back_to_the_exact_map():
    """A 12 × 12 camera is below the window of OpenCV's adaptive threshold, which used to raise
    a cv2.error (a traceback from ``procam render``): the corners count as not found."""
    setup = tiny_setup(camera={"resolution": [12, 12]})
    with pytest.warns(UserWarning, match="corners were not found at the canonical size 16x16"):
        sim = Simulator(setup, (16, 16))
    assert sim.registration.method == "exact"
    assert sim.registration.status == "checkerboard corners not found: exact map used"


def test_a_camera_upside_down_registers_the_right_way_up():
    """A camera turned by 180° about its axis finds the corners from the other end of the grid:
    the pattern, not symmetric under that turn, picks the order, so the homography agrees with the
    exact map (with a 9 × 7 board both orders fit equally and the captures came out turned)."""
    setup = tiny_setup(camera={"position": [0.25, 0.0, 1.0], "up": [0.0, -1.0, 0.0], "resolution": [192, 192]},
                       projector={"resolution": [128, 128]}, ambient={"radiance": [0.01, 0.01, 0.01]})
    sim = Simulator(setup, (128, 128))
    check = sim.registration.record(setup)["homography"]
    assert check["status"] == "ok" and sim.registration.method == "homography"
    assert check["mean_px"] < 0.5 and check["max_px"] < 1.5
    frame, _ = registration.checkerboard((128, 128))
    turned = np.ascontiguousarray(frame[::-1, ::-1])
    assert np.mean(turned != frame) > 0.3  # black and white swap under the turn


def test_exact_map_matches_homography_on_a_plane():
    """On a plane the homography fitted to detected checkerboard corners agrees with the exact
    map to sub-pixel accuracy (camera pixels)."""
    setup = tiny_setup(camera={"position": [0.25, 0.0, 1.0], "resolution": [192, 192]},
                       projector={"resolution": [128, 128]},
                       ambient={"radiance": [0.01, 0.01, 0.01]})
    check = Simulator(setup, (128, 128)).registration.record(setup)["homography"]
    assert check["status"] == "ok"
    assert check["mean_px"] < 0.5 and check["max_px"] < 1.5


def test_corner_map_marks_occluded_pixels():
    """A camera far to the right of a 90° corner sees the back of the right wing (unseen), and
    the right wing also hides the part of the left wing next to the edge."""
    setup = tiny_setup(surface={"geometry": "corner", "size": [0.6, 1.0]},
                       camera={"position": [1.5, 0.0, 1.0]},
                       render={"fidelity": "path", "max_depth": 3})
    wmap = registration.exact_map(setup, SIZE)
    half = SIZE[0] // 2  # the projector image's right half lands on the right wing (world +x)
    assert not wmap.mask[:, half + 1:].any()
    seen_cols = np.nonzero(wmap.mask.any(axis=0))[0]
    assert seen_cols.min() == 0 and seen_cols.max() < half - 4  # the edge region is occluded
    # the occlusion boundary is where the line from the camera grazes the right wing's outer
    # edge (0.6 cos 45°, *, 0.6 cos 45°): check it against that ray
    edge = np.array([0.6 * np.sqrt(0.5), 0.0, 0.6 * np.sqrt(0.5)])
    cam = np.array([1.5, 0.0, 1.0])
    d = edge - cam
    u = -(cam[0] + cam[2]) / (d[0] + d[2])  # hit on the left wing's plane x = -z
    boundary = cam + u * d
    proj = geometry.Pinhole.from_config(setup.projector, SIZE)
    col = proj.project(boundary[None])[0][0, 0]
    assert abs(seen_cols.max() + 1 - col) <= 1.0


def test_warp_of_float_images_keeps_values():
    setup = _beside()
    wmap = registration.exact_map(setup, SIZE)
    flat = np.full((128, 128, 3), 0.25, np.float32)
    out = registration.warp(flat, wmap)
    np.testing.assert_allclose(out[wmap.mask], 0.25, atol=1e-6)


def test_resampled_pinhole_keeps_the_image_area():
    """A pinhole resampled to another pixel grid (the canonical view) sees the same image area:
    a point lands at the same fraction of the width and height whatever the grid's aspect."""
    cfg = _beside((64, 48)).projector
    points = np.array([[0.1, 0.05, 0.0], [-0.2, 0.15, 0.0], [0.0, -0.1, 0.0]])
    own = geometry.Pinhole.from_config(cfg)
    want = own.project(points)[0] / [own.width, own.height]
    for size in [(64, 64), (64, 48), (48, 64), (30, 20)]:
        pin = geometry.Pinhole.from_config(cfg, size)
        np.testing.assert_allclose(pin.project(points)[0] / size, want, atol=1e-12)
        # the rays through the grid's corner pixel centres hit the fractions of those centres
        rays = pin.pixel_rays()
        hit = pin.position + rays * (-pin.position[2] / rays[..., 2])[..., None]  # plane z = 0
        frac = own.project(hit)[0] / [own.width, own.height]
        np.testing.assert_allclose(frac[0, 0], [0.5 / size[0], 0.5 / size[1]], atol=1e-9)
        np.testing.assert_allclose(frac[-1, -1], [1 - 0.5 / size[0], 1 - 0.5 / size[1]], atol=1e-9)


def test_exact_map_follows_the_lens_distortion():
    """With barrel distortion the camera sees each surface point elsewhere: the exact map follows
    the distorted image, so warped captures of a texture agree with the undistorted camera's,
    while the map without distortion misplaces them."""
    base = dict(camera={"position": [0.25, 0.0, 1.0], "resolution": [128, 128]},
                surface={"texture": "checker", "texture_seed": 3, "albedo_scale": 0.8},
                ambient={"radiance": [0.01, 0.01, 0.01]}, registration={"method": "exact"})
    straight = tiny_setup(**base)
    bent = tiny_setup(**{**base, "camera": {**base["camera"], "distortion": -0.12}})
    size = (48, 48)
    plain, curved = registration.exact_map(straight, size), registration.exact_map(bent, size)
    shift = np.linalg.norm(curved.xy - plain.xy, axis=-1)[plain.mask & curved.mask]
    assert shift.max() > 2.0  # the lens moves the projected image by pixels at its corners
    white = np.full((size[1], size[0], 3), 255, np.uint8)
    views = {}
    for name, setup in (("straight", straight), ("bent", bent)):
        sim = Simulator(setup, size)
        views[name] = sim.capture(white[None], stream=42)[0].astype(float)
        views[name + "_raw"] = sim.raw(white, 42, 0)
    wrong = registration.warp(views["bent_raw"], plain).astype(float)
    mask = plain.mask & curved.mask
    inner = np.zeros_like(mask)
    inner[4:-4, 4:-4] = True
    m = mask & inner
    err_right = np.abs(views["bent"] - views["straight"])[m].mean()
    err_wrong = np.abs(wrong - views["straight"])[m].mean()
    assert err_right < 0.5 * err_wrong and err_right < 6.0


@pytest.mark.parametrize("relief, k", [(0.0, (-0.06, -0.01)), (4.0, (-0.06, -0.01)), (0.0, (0.05, 0.0))])
def test_exact_map_follows_the_projector_distortion_as_rendered(relief, k):
    """A canonical pixel lit alone lands, in the rendered capture, where the exact map says: the
    centroid of its spot agrees to a fraction of a camera pixel with a strongly distorted, offset
    projector lens, barrel (also on a sheet with relief) or pincushion (whose corners the lens's
    padded grid must keep), while the map of an undistorted lens is pixels away."""
    base = dict(projector={"resolution": [96, 96], "black_level": 0.0},
                camera={"resolution": [128, 128], "position": [0.25, 0.0, 1.0]},
                surface={"relief": relief, "relief_length": 40.0})
    straight = tiny_setup(**base)
    bent = tiny_setup(**{**base, "projector": {**base["projector"], "distortion_k1": k[0],
                                                 "distortion_k2": k[1], "lens_offset": 0.5}})
    size = (24, 24)
    maps = {name: registration.exact_map(s, size) for name, s in (("straight", straight), ("bent", bent))}
    renderer = Renderer(bent, "direct", 16)
    for row, col in ((2, 2), (2, 21), (6, 12)):  # far from the axis (the bottom edge)
        frame = np.zeros((size[1], size[0], 3), np.uint8)
        frame[row, col] = 255
        image = renderer.projector_radiance(renderer.emit(frame), seed=3)[..., 1].astype(np.float64)
        image[image < 0.05 * image.max()] = 0  # the spot only
        ys, xs = np.mgrid[0:image.shape[0], 0:image.shape[1]] + 0.5
        centroid = np.array([(xs * image).sum(), (ys * image).sum()]) / image.sum()
        assert np.linalg.norm(centroid - maps["bent"].xy[row, col]) < 0.35, (row, col)
        assert np.linalg.norm(centroid - maps["straight"].xy[row, col]) > 1.0, (row, col)
