"""Tests of sim.images: plain colours, projector frames, surface textures, user images."""
from __future__ import annotations

import cv2
import imageio.v3 as iio
import numpy as np
import pytest
from scipy.spatial.distance import cdist

from sim import images
from sim.errors import DatasetError, SetupError
from sim.io import write_png


def test_srgb_decode_is_colour_sciences_to_float32_rounding():
    colour = pytest.importorskip("colour")
    x = np.linspace(0, 1, 2**16 + 1)
    got = images.srgb_decode(x)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, colour.cctf_decoding(x.astype(np.float32), "sRGB"), rtol=5e-7, atol=0)


def test_plain_colours_order_and_values():
    c = images.plain_colours()
    assert c.shape == (125, 3) and c.dtype == np.uint8
    np.testing.assert_array_equal(c[0], [0, 0, 0])
    np.testing.assert_array_equal(c[124], [255, 255, 255])
    assert len({tuple(row) for row in c}) == 125
    levels = [round(255 * v) for v in images.PLAIN_LEVELS]
    assert levels == [0, 64, 128, 191, 255]
    for r in range(5):
        for g in range(5):
            for b in range(5):
                expected = [levels[r], levels[g], levels[b]]
                np.testing.assert_array_equal(c[25 * r + 5 * g + b], expected)
    np.testing.assert_array_equal(c[1], [0, 0, 64])  # blue fastest


def test_plain_frame():
    f = images.plain_frame(np.full(3, images.GRAY_LEVEL, np.uint8), (6, 4))
    assert f.shape == (4, 6, 3) and f.dtype == np.uint8
    assert (f == 128).all()
    f = images.plain_frame([1, 2, 3], 5)
    assert f.shape == (5, 5, 3) and (f == [1, 2, 3]).all()


def test_frames_deterministic_and_prefix_stable():
    a = images.projector_frames(5, (24, 16), seed=3)
    assert a.shape == (5, 16, 24, 3) and a.dtype == np.uint8
    np.testing.assert_array_equal(a, images.projector_frames(5, (24, 16), seed=3))
    np.testing.assert_array_equal(a, images.projector_frames(10, (24, 16), seed=3)[:5])
    for other in (images.projector_frames(5, (24, 16), seed=4),
                  images.projector_frames(5, (24, 16), seed=3, stream=1)):
        assert all((x != y).any() for x, y in zip(a, other))


def test_photo_frames_are_natural_crops_of_their_own():
    """Photo frames: deterministic, not the mixed frames, and natural: moderately saturated, with
    none of the patterns' flat regions of one colour or their hue rotations' extreme saturation."""
    photo = images.projector_frames(40, 48, seed=0, stream=1, kind="photo")
    np.testing.assert_array_equal(photo, images.projector_frames(40, 48, seed=0, stream=1, kind="photo"))
    mixed = images.projector_frames(40, 48, seed=0, stream=1)
    np.testing.assert_array_equal(mixed, images.projector_frames(40, 48, seed=0, stream=1, kind="mixed"))
    assert all((a != b).any() for a, b in zip(photo, mixed))
    sat = lambda f: cv2.cvtColor(f.astype(np.float32) / 255, cv2.COLOR_RGB2HSV)[..., 1].mean()
    assert np.mean([sat(f) for f in photo]) < np.mean([sat(f) for f in mixed]) - 0.1
    with pytest.raises(ValueError, match="kind 'cartoon': expected one of mixed, photo"):
        images.projector_frames(1, 8, seed=0, kind="cartoon")


@pytest.fixture(scope="module")
def frames_700():
    """The default dataset's 500 training + 200 test frames, at 64² to keep the test fast."""
    return np.concatenate([images.projector_frames(500, 64, seed=0, stream=0),
                           images.projector_frames(200, 64, seed=0, stream=1)])


def test_frames_pairwise_distinct(frames_700):
    # Mean abs difference of 4×4 block averages is a lower bound on the full-resolution mean abs
    # difference (triangle inequality), so "> 2/255 downsampled" implies it at full resolution.
    small = np.stack([cv2.resize(f, (16, 16), interpolation=cv2.INTER_AREA) for f in frames_700])
    vec = small.reshape(len(small), -1).astype(np.float64) / 255
    dist = cdist(vec, vec, "cityblock") / vec.shape[1]
    np.fill_diagonal(dist, np.inf)
    assert dist.min() > 2 / 255


def test_frames_colourful_with_hue_spread(frames_700):
    hsv = np.stack([cv2.cvtColor(f.astype(np.float32) / 255, cv2.COLOR_RGB2HSV)
                    for f in frames_700])
    sat = hsv[..., 1]
    # Gray frames have saturation 0 and natural photographs average about 0.2–0.35; frames that
    # exercise the three projector primaries independently should be clearly above that.
    assert sat.mean() > 0.4
    assert (sat.mean(axis=(1, 2)) < 0.15).mean() < 0.05  # hardly any near-gray frames
    # Saturation-weighted circular hue histogram: each 30° bin holds > 3 % (uniform: 8.3 %).
    hist = np.histogram(hsv[..., 0], bins=12, range=(0, 360), weights=sat)[0]
    assert (hist / hist.sum()).min() > 0.03
    # Brightness is spread too: both dark and bright pixels occur.
    assert (frames_700 < 32).mean() > 0.02 and (frames_700 > 223).mean() > 0.02


@pytest.mark.parametrize("kind", images.SURFACE_KINDS)
def test_surface_texture(kind):
    tex = images.surface_texture(kind, (48, 32), seed=1)
    assert tex.shape == (32, 48, 3) and tex.dtype == np.float32
    assert tex.min() >= 0 and tex.max() <= 1
    assert tex.std() > 0.005
    np.testing.assert_array_equal(tex, images.surface_texture(kind, (48, 32), seed=1))
    assert np.abs(tex - images.surface_texture(kind, (48, 32), seed=2)).mean() > 0.005


def test_gray_texture_larger_than_source_is_tiled():
    tex = images.surface_texture("brick", (700, 600), seed=0)  # source is 512²
    assert tex.shape == (600, 700, 3)
    assert tex[:, 512:].std() > 0.01 and tex[512:].std() > 0.01


def test_surface_texture_unknown_kind():
    with pytest.raises(ValueError) as err:
        images.surface_texture("marble", (8, 8), seed=0)
    msg = str(err.value)
    assert "'marble'" in msg and all(k in msg for k in images.SURFACE_KINDS)


def test_load_texture_file_is_linear(tmp_path):
    path = tmp_path / "wall.png"
    write_png(path, np.full((20, 30, 3), 128, np.uint8))
    tex = images.load_texture_file(path, (15, 10))
    assert tex.shape == (10, 15, 3) and tex.dtype == np.float32
    np.testing.assert_allclose(tex, ((128 / 255 + 0.055) / 1.055) ** 2.4, rtol=1e-5)


def test_load_texture_file_missing(tmp_path):
    path = tmp_path / "nope.png"
    with pytest.raises(SetupError, match="nope.png"):
        images.load_texture_file(path, (8, 8))


def test_load_image_folder(tmp_path):
    red_blue = np.zeros((30, 40, 3), np.uint8)  # red left quarter, blue elsewhere
    red_blue[:, :10] = [255, 0, 0]
    red_blue[:, 10:] = [0, 0, 255]
    write_png(tmp_path / "c_split.png", red_blue)
    write_png(tmp_path / "a_uniform.png", np.full((50, 70, 3), [10, 200, 90], np.uint8))
    iio.imwrite(tmp_path / "b_gray.PNG", np.full((12, 9), 77, np.uint8))
    rgba = np.zeros((8, 8, 4), np.uint8)
    rgba[..., :3] = [5, 6, 7]
    iio.imwrite(tmp_path / "d_alpha.png", rgba)  # fully transparent: alpha is dropped, not applied
    (tmp_path / "notes.txt").write_text("not an image")

    out = images.load_image_folder(tmp_path, 4, (20, 40))  # aspect 4:3 -> 1:2
    assert out.shape == (4, 40, 20, 3) and out.dtype == np.uint8
    assert (out[0] == [10, 200, 90]).all()  # sorted by name; resized, not recoloured
    assert (out[1] == 77).all()  # gray -> RGB; enlarged
    # Not cropped to the new aspect: the red quarter is still exactly the left quarter.
    assert (out[2][:, :5] == [255, 0, 0]).all() and (out[2][:, 5:] == [0, 0, 255]).all()
    assert (out[3] == [5, 6, 7]).all()
    square = images.load_image_folder(tmp_path, 2, 20)  # first `count` files, square size
    assert square.shape == (2, 20, 20, 3) and (square[0] == [10, 200, 90]).all()

    with pytest.raises(DatasetError) as err:
        images.load_image_folder(tmp_path, 6, 16)
    msg = str(err.value)
    assert str(tmp_path) in msg and "found 4" in msg and "need 6" in msg
    with pytest.raises(DatasetError, match="not found"):
        images.load_image_folder(tmp_path / "missing", 1, 16)
