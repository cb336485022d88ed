"""Registration as a real pipeline does it: the method a setup asks for, the records and ground
truth a dataset keeps, corner jitter, and the closed loop warping as its dataset did."""
from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from compensation.cli import main
from compensation.experiments.closed_loop import simulator_for
from helpers import tiny_setup
from sim import registration
from sim.capture import Simulator
from sim.dataset import read_raw
from sim.errors import SetupError
from sim.io import read_png
from sim.setup import dump_setup, load_setup, parse_setup

SIZE = (64, 64)
PLANE = {"camera": {"resolution": [128, 128], "shot_noise": 2e-4, "read_noise": 2e-3},
         "surface": {"texture": "noise", "texture_resolution": 64},
         "ambient": {"radiance": [0.01, 0.01, 0.01]}}


def _plane(**registration_keys):
    return tiny_setup(**PLANE, registration=registration_keys)


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float(10 * np.log10(255.0 ** 2 / mse))


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    """One root holding the same plane registered three ways: auto (a homography), exact, and a
    homography from corners jittered by 1.5 canonical pixels; the captures at camera resolution
    kept (--raw)."""
    tmp = tmp_path_factory.mktemp("reg")
    names = {"auto": {}, "exact": {"method": "exact"}, "jitter": {"method": "homography", "jitter": 1.5}}
    for name, keys in names.items():
        path = tmp / f"{name}.toml"
        path.write_text(dump_setup(tiny_setup(**PLANE, name=name, registration=keys)))
        assert main(["render", str(path), "--out", str(tmp / "data"), "--size", "64",
                     "--n-train", "2", "--n-test", "2", "--quiet", "--raw"]) == 0
    return tmp / "data"


def _meta(root, name):
    return json.loads((root / name / "meta.json").read_text())


@pytest.mark.slow
def test_auto_on_a_plane_warps_by_the_estimated_homography(rendered):
    reg = _meta(rendered, "auto")["registration"]
    assert reg["method"] == "homography" and reg["requested"] == "auto" and reg["jitter"] == 0.0
    assert reg["homography"]["status"] == "ok"
    # Over 8 noise realisations of this setup (either noise version) the mean error was 0.03-0.07
    # px and the largest corner's 0.17-0.40 px.
    assert reg["homography"]["mean_px"] < 0.1 and reg["homography"]["max_px"] < 0.5
    assert reg["visible_fraction"] == pytest.approx(reg["exact_visible_fraction"], abs=0.01)
    exact = _meta(rendered, "exact")["registration"]
    assert exact["method"] == "exact" and exact["homography"]["matrix"] == reg["homography"]["matrix"]


@pytest.mark.slow
def test_homography_captures_are_close_to_the_exact_ones(rendered):
    """Same raw captures, two warps: within a small fraction of a pixel they agree to well above
    the camera noise's PSNR; corners jittered by 1.5 px are visibly worse."""
    for split, i in (("ref", 126), ("train", 1), ("test", 2)):
        name = f"img_{i:04d}.png"
        raw = [read_raw(rendered / s, split, i) for s in ("auto", "exact", "jitter")]
        assert np.array_equal(raw[0], raw[1]) and np.array_equal(raw[0], raw[2])
        auto, exact, jitter = (read_png(rendered / s / "cam" / "warp" / split / name)
                               for s in ("auto", "exact", "jitter"))
        assert not np.array_equal(auto, exact)
        assert _psnr(auto, exact) > 40
        assert _psnr(jitter, exact) < _psnr(auto, exact) - 10


@pytest.mark.slow
def test_ground_truth_and_records_are_on_disk(rendered):
    for name in ("auto", "exact", "jitter"):
        folder = rendered / name / "registration"
        with np.load(folder / "exact_map.npz") as saved:
            xy, mask = saved["xy"], saved["mask"]
        truth = registration.exact_map(load_setup(rendered / name / "setup.toml"), SIZE)
        assert xy.dtype == np.float32 and xy.shape == (64, 64, 2) and mask.dtype == bool
        assert np.array_equal(xy, truth.xy) and np.array_equal(mask, truth.mask)
        record = json.loads((folder / "registration.json").read_text())
        assert _meta(rendered, name)["registration"] == {**record,
                                                         "ground_truth": "registration/exact_map.npz"}
        assert np.asarray(record["homography"]["matrix"]).shape == (3, 3)


@pytest.mark.slow
def test_exact_method_warps_with_the_recorded_ground_truth(rendered):
    """With ``method = "exact"`` each warped capture is its raw capture warped by the saved map."""
    with np.load(rendered / "exact" / "registration" / "exact_map.npz") as saved:
        wmap = registration.WarpMap(saved["xy"], saved["mask"])
    for split, i in (("ref", 60), ("train", 2)):
        name = f"img_{i:04d}.png"
        raw = read_raw(rendered / "exact", split, i)
        assert np.array_equal(read_png(rendered / "exact" / "cam" / "warp" / split / name),
                              registration.warp(raw, wmap))


@pytest.mark.slow
def test_closed_loop_warps_as_its_dataset(rendered):
    """The closed loop's simulator re-estimates the same homography from the same seeded
    checkerboard captures, so its captures are warped as the dataset's."""
    for name in ("auto", "jitter"):
        sim = simulator_for(rendered / name)
        recorded = _meta(rendered, name)["registration"]["homography"]["matrix"]
        assert sim.registration.method == "homography"
        np.testing.assert_array_equal(sim.registration.homography, np.asarray(recorded))
        frame = read_png(rendered / "train" / "img_0001.png")
        raw = read_raw(rendered / name, "train", 1)
        assert np.array_equal(sim.warp(raw), read_png(rendered / name / "cam" / "warp" / "train" / "img_0001.png"))
        # the same seeded capture (stream TRAIN, index 1) comes out as the dataset's, bit for bit
        assert np.array_equal(sim.capture(frame[None], stream=1, start=1)[0],
                              read_png(rendered / name / "cam" / "warp" / "train" / "img_0001.png"))


def test_jitter_raises_the_error_in_proportion():
    """The same seeded displacements, scaled: the homography's error (camera pixels) grows with the
    jitter (canonical pixels) in proportion once it dominates the detection error."""
    errors = {}
    for jitter in (0.0, 0.5, 1.0, 2.0):
        setup = _plane(method="homography", jitter=jitter)
        errors[jitter] = Simulator(setup, SIZE).registration.record(setup)["homography"]["mean_px"]
    assert errors[0.5] > 5 * errors[0.0]
    assert errors[1.0] / errors[0.5] == pytest.approx(2.0, rel=0.2)
    assert errors[2.0] / errors[1.0] == pytest.approx(2.0, rel=0.2)


def test_homography_map_masks_what_falls_outside_the_camera_frame():
    """camera → canonical halves coordinates: canonical x in (0, 64) is camera x in (0, 128), of
    which a 100-pixel-wide camera sees x <= 100, i.e. canonical columns 0..49."""
    hom = np.diag([0.5, 0.5, 1.0])
    wmap = registration.homography_map(hom, (64, 32), (100, 200))
    np.testing.assert_allclose(wmap.xy[3, 7], [15.0, 7.0])
    assert wmap.mask[:, :50].all() and not wmap.mask[:, 50:].any()


def test_non_planar_auto_is_exact_and_explicit_homography_needs_the_corners():
    corner = tiny_setup(surface={"geometry": "corner", "size": [0.6, 1.0]},
                        render={"fidelity": "path", "spp": 1, "max_depth": 3})
    assert registration.resolve_method(corner) == "exact"
    assert registration.resolve_method(_plane()) == "homography"
    assert registration.resolve_method(_plane(method="exact")) == "exact"
    # at 16² the checkerboard's squares are under two pixels: auto falls back, homography refuses
    sim = Simulator(_plane(), (16, 16))
    assert sim.registration.method == "exact"
    assert sim.registration.status == "checkerboard corners not found: exact map used"
    with pytest.raises(SetupError, match=r'registration.method = "homography": the checkerboard corners '
                                         r"were not found .* 16x16"):
        Simulator(_plane(method="homography"), (16, 16))


@pytest.mark.parametrize("keys, message", [
    ({"method": "affine"}, r'registration.method = "affine": expected one of "auto", "homography", "exact"'),
    ({"method": 1}, r"registration.method = 1: expected one of"),
    ({"jitter": -0.5}, r"registration.jitter = -0.5: expected a number >= 0 canonical pixels"),
    ({"jitter": True}, r"registration.jitter = true: expected a number"),
    ({"jiter": 1.0}, r"registration.jiter: unknown key; valid keys of \[registration\]: jitter, method"),
])
def test_bad_registration_values_are_named(keys, message):
    with pytest.raises(SetupError, match=message):
        _plane(**keys)


def test_registration_section_round_trips():
    setup = _plane(method="homography", jitter=0.25)
    text = dump_setup(setup)
    assert "[registration]" in text and 'method = "homography"' in text and "jitter = 0.25" in text
    assert parse_setup(tomllib.loads(text)) == setup
