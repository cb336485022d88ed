"""Registration: exact map from the geometry, warping, and the homography a real system would fit."""
from __future__ import annotations

import cv2
import numpy as np

from conftest import tiny_setup
from sim import registration
from sim.capture import Simulator

SIZE = (64, 64)


def _beside():
    """Camera 0.25 m beside the projector, 128² so the projection covers many camera pixels."""
    return tiny_setup(camera={"position": [0.25, 0.0, 1.0], "resolution": [128, 128]},
                      ambient={"radiance": [0.01, 0.01, 0.01]})


def test_checkerboard_warped_lines_up_within_one_pixel():
    sim = Simulator(_beside(), SIZE)
    frame, _ = registration.checkerboard(SIZE)
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


def test_exact_map_matches_homography_on_a_plane():
    sim = Simulator(_beside(), SIZE)
    check = sim.homography_check()
    assert check["status"] == "ok"
    assert check["mean_px"] < 0.5 and check["max_px"] < 1.5


def test_corner_map_marks_occluded_pixels():
    """A camera far to the right of a 90° corner sees the back of the right wing only."""
    setup = tiny_setup(surface={"geometry": "corner", "size": [0.6, 1.0]},
                       camera={"position": [1.5, 0.0, 1.0]},
                       render={"fidelity": "path", "max_depth": 3})
    wmap = registration.exact_map(setup, SIZE)
    assert 0.05 < (~wmap.mask).mean() < 0.95
    # the unseen pixels are the right wing (world +x, the projector image's right half), which
    # turns its back to a camera standing on the right; the left wing faces it and is seen
    unseen_cols = np.nonzero(~wmap.mask)[1]
    assert unseen_cols.min() >= SIZE[0] // 2 - 1
    assert wmap.mask[:, : SIZE[0] // 2 - 1].all()


def test_warp_of_float_images_keeps_values():
    setup = _beside()
    wmap = registration.exact_map(setup, SIZE)
    flat = np.full((128, 128, 3), 0.25, np.float32)
    out = registration.warp(flat, wmap)
    np.testing.assert_allclose(out[wmap.mask], 0.25, atol=1e-6)
