"""Closed loop: project π†(y) through the same simulated setup; iterative refinement; reachability."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from compensation.data import load_setup_data
from compensation.experiments.closed_loop import (closed_loop, closed_loop_scores, closed_loop_target,
                                                 iterative_refinement, project, reachable_mask,
                                                 reachable_overlay, simulator_for, uncompensated)
from compensation.experiments.targets import TargetPolicy
from compensation.scores.metrics import masked_scores, psnr, rmse
from compensation.methods.base import Method
from compensation.training.config import NoOptions
from helpers import tiny_setup
from sim.capture import Simulator
from sim import seeds
from sim.dataset import FrameSpec, write_setup

NONE = TargetPolicy("none")


class Identity(Method):
    """π†(y) = y: the right compensation for a perfect white surface."""

    name = "identity"
    options = NoOptions

    def fit(self, data, cfg, progress=True):
        return {}

    def predict(self, captures, surface, batch_size=64):
        return captures.clone()

    def save(self, run_dir):
        pass

    @classmethod
    def load(cls, run_dir, device="auto"):
        return cls()


def _dataset(tmp_path, name: str, **sections):
    setup = tiny_setup(**sections)
    setup = type(setup)(**{**setup.__dict__, "name": name})
    setup_dir = write_setup(tmp_path, setup, FrameSpec(2, 4, (32, 32)), progress=False)
    return load_setup_data(setup_dir), simulator_for(setup_dir)


@pytest.fixture(scope="module")
def white(tmp_path_factory):
    """Albedo 1, no ambient, no black level, gamma 2.2 projector into a gamma 2.2 camera seeing
    exactly the projector's view (2×2 camera pixels per projector pixel): the capture of y is y
    itself up to noise and 8-bit rounding."""
    return _dataset(tmp_path_factory.mktemp("white"), "white",
                    surface={"texture": "uniform", "albedo_scale": 1.0},
                    camera={"response": "gamma:2.2", "shot_noise": 1e-5, "read_noise": 1e-3,
                            "position": [0.0, 0.0, 1.0], "fov": 30.0},
                    projector={"black_level": 0.0, "resolution": [32, 32]})


@pytest.fixture(scope="module")
def matte(tmp_path_factory):
    """A uniform grey surface in a dim room: the projector reaches a band of values, not [0, 1]."""
    return _dataset(tmp_path_factory.mktemp("matte"), "matte", surface={"texture": "uniform", "albedo_scale": 0.6},
                    ambient={"radiance": [0.02, 0.02, 0.02]},
                    camera={"shot_noise": 1e-5, "read_noise": 1e-3})


@pytest.fixture(scope="module")
def textured(tmp_path_factory):
    return _dataset(tmp_path_factory.mktemp("tex"), "tex", surface={"texture": "noise", "albedo_scale": 0.9},
                    ambient={"radiance": [0.02, 0.02, 0.02]},
                    camera={"shot_noise": 1e-5, "read_noise": 1e-3})


def test_identity_on_a_white_surface_reproduces_the_desired_image(white):
    data, sim = white
    scores = closed_loop(Identity(), data, sim, policy=NONE)
    assert scores["psnr"] > 30 and scores["ssim"] > 0.95
    # only the brightest pixels towards the frame's edges (irradiance falls off as cos³ off-axis)
    # are beyond reach
    assert 0.7 < scores["reachable_fraction"] < 1.0
    assert scores["projections"] == 4
    # what the projector can produce it does produce: better on the reachable pixels than overall
    assert scores["psnr_reachable"] > scores["psnr"]


def test_masked_scores_match_the_plain_metrics():
    g = torch.Generator().manual_seed(0)
    pred, target = torch.rand(3, 3, 16, 16, generator=g), torch.rand(3, 3, 16, 16, generator=g)
    everything = torch.ones(3, 16, 16, dtype=torch.bool)
    full = masked_scores(pred, target, everything)
    assert full["psnr"] == pytest.approx(psnr(pred, target), abs=1e-12)
    assert full["rmse"] == pytest.approx(rmse(pred, target), abs=1e-12)
    half = everything.clone()
    half[:, :, 8:] = False
    part = masked_scores(pred, target, half)
    assert part["rmse"] == pytest.approx(rmse(pred[..., :8], target[..., :8]), abs=1e-12)
    assert np.isnan(masked_scores(pred, target, ~everything)["psnr"])
    with pytest.raises(ValueError, match="mask must have shape"):
        masked_scores(pred, target, everything[:, :8])


def test_reachable_overlay_tints_only_unreachable_pixels():
    y = torch.full((1, 3, 2, 2), 0.5)
    mask = torch.tensor([[[True, False], [True, True]]])
    out = reachable_overlay(y, mask)
    assert torch.equal(out[0, :, 0, 0], y[0, :, 0, 0])
    assert torch.allclose(out[0, :, 0, 1], torch.tensor([0.85, 0.15, 0.85]))


def test_iterative_refinement_lowers_the_error_monotonically(textured):
    """On desired images inside the reachable range (between the black and white captures) the
    feedback loop converges: every correction lowers the error, by far overall."""
    data, sim = textured
    black, white = data.ref.captures[0:1], data.ref.captures[124:125]
    desired = black + (white - black) * (0.1 + 0.8 * data.test.frames)
    assert reachable_mask(data, desired).all()
    rows = iterative_refinement(data, sim, desired=desired, report=(0, 1, 2, 3, 4), policy=NONE)
    rmse = [r["rmse"] for r in rows]
    assert all(b < a for a, b in zip(rmse, rmse[1:])), rmse
    assert rmse[-1] < 0.5 * rmse[0]
    assert [r["projections"] for r in rows] == [4 * (k + 1) for k in range(5)]


def test_iterative_refinement_starts_from_the_datasets_test_captures(textured):
    """y projected as is was captured with the dataset: the oracle's first row scores those
    captures (no new projection), and its corrections start from them."""
    data, sim = textured
    calls = []

    class Counting:
        def __getattr__(self, name):
            return getattr(sim, name)

        def capture(self, frames, stream, start=0):
            calls.append(stream)
            return sim.capture(frames, stream, start)

    rows = iterative_refinement(data, Counting(), report=(0, 1), policy=NONE)
    y, mask = data.test.frames, reachable_mask(data, data.test.frames)
    assert rows[0] == {"iterations": 0, **closed_loop_scores(data.test.captures, y, mask), "projections": 4}
    assert len(calls) == 1 and rows[1]["projections"] == 8
    # another target was never captured: the first row projects it, as the uncompensated row does
    calls.clear()
    policy = TargetPolicy("global", 0.2)  # this dim textured surface: 1 % leaves no contrast
    rows = iterative_refinement(data, Counting(), report=(0,), policy=policy)
    assert calls == [seeds.CLOSED_LOOP + 1]
    unc, _ = uncompensated(data, sim, policy=policy)
    assert rows[0]["psnr_per_image"] == unc["psnr_per_image"] and rows[0]["psnr"] == unc["psnr"]


def test_the_policy_none_is_the_closed_loop_against_the_desired_image(textured):
    """Under ``none`` every closed-loop score is what it was before target policies: the capture
    of π†(y) against y, the dataset's test captures for the uncompensated row."""
    data, sim = textured
    y = data.test.frames
    target, record = closed_loop_target(data, y, NONE)
    assert target is y and (record["a"], record["b"]) == (1.0, 0.0)
    scores = closed_loop(Identity(), data, sim, policy=NONE)
    by_hand = closed_loop_scores(project(sim, y, seeds.CLOSED_LOOP), y, reachable_mask(data, y))
    assert {k: scores[k] for k in by_hand} == by_hand
    assert scores["target"]["policy"] == "none"
    unc, captured = uncompensated(data, sim, policy=NONE)
    assert captured is data.test.captures
    assert {k: unc[k] for k in by_hand} == closed_loop_scores(data.test.captures, y, reachable_mask(data, y))


def test_global_and_image_targets_are_within_reach(matte):
    """The global map keeps at least 99 % of every target's pixels in reach (the mask allows two
    levels of noise on top), the closed loop compares with y' and the image map never has less
    contrast than the global one (every global map is feasible for each image)."""
    data, sim = matte
    y = data.test.frames
    assert reachable_mask(data, y).float().mean() < 0.5  # the desired images themselves are not
    target, record = closed_loop_target(data, y, TargetPolicy())
    assert 0.2 < record["a"] < 1 and record["b"] > 0 and record["gap"] == 0
    assert torch.allclose(target, (record["a"] * y + record["b"]).clamp(0, 1), atol=1e-6)
    assert (reachable_mask(data, target).float().mean(dim=(1, 2)) >= 0.99).all()
    scores = closed_loop(Identity(), data, sim)
    assert scores["target"] == record and scores["reachable_fraction"] >= 0.99
    image, per_image = closed_loop_target(data, y, TargetPolicy("image"))
    assert all(a >= record["a"] - g for a, g in zip(per_image["a_per_image"], [per_image["gap"]] * len(y)))
    assert (reachable_mask(data, image).float().mean(dim=(1, 2)) >= 0.99).all()
    # on targets within reach the feedback oracle gains far more than on y itself
    gain = {name: [r["psnr"] for r in iterative_refinement(data, sim, report=(0, 4), policy=TargetPolicy(name))]
            for name in ("none", "global")}
    assert gain["global"][1] - gain["global"][0] > 3 + gain["none"][1] - gain["none"][0], gain


def test_a_textured_surface_relaxes_the_share_out_of_reach(textured):
    """This dim textured surface under room light leaves no grey level in reach of 99 % of its
    pixels: the global map takes the smallest share that admits a contrast, and says so."""
    data, _ = textured
    target, record = closed_loop_target(data, data.test.frames, TargetPolicy())
    assert record["out_of_reach"] == 0.01 and 0.01 < record["out_of_reach_used"] < 0.9 and record["a"] > 0
    assert (reachable_mask(data, target).float().mean(dim=(1, 2)) >= 1 - record["out_of_reach_used"]).all()


def test_reachable_mask_flags_what_the_projector_cannot_do(textured):
    data, _ = textured
    white_img = torch.ones(1, 3, 32, 32)
    assert reachable_mask(data, white_img).float().mean() < 0.5  # albedo < 1: too bright
    grey = data.ref.captures[62:63]  # a capture is reachable by definition (mid gray frame)
    assert reachable_mask(data, grey).float().mean() > 0.9
    assert np.isclose(float(reachable_mask(data, data.ref.captures[124:125]).float().mean()), 1.0)


@pytest.mark.slow
def test_closed_loop_refuses_a_simulator_that_differs_from_the_dataset(tmp_path):
    """The closed loop rebuilds the dataset's simulator from its records (the exposure is taken
    from them): a homography that comes out otherwise (another machine's variant, an edited record) is refused
    by name instead of scoring against another setup."""
    import json

    from sim.errors import DatasetError

    setup = tiny_setup(camera={"exposure_mode": "rule", "resolution": [128, 128]},
                       registration={"method": "homography"},
                       surface={"texture": "noise"})
    setup = type(setup)(**{**setup.__dict__, "name": "rec"})
    setup_dir = write_setup(tmp_path, setup, FrameSpec(2, 2, (64, 64)), progress=False)
    sim = simulator_for(setup_dir)  # the records reproduce
    meta_path = setup_dir / "meta.json"
    meta = json.loads(meta_path.read_text())
    assert meta["camera_exposure"]["mode"] == "rule" and meta["registration"]["homography"]["matrix"]
    # the recorded rule exposure is taken without rendering its preview again, and it is what the
    # preview gives
    assert sim.exposure == meta["camera_exposure"] and sim.setup.camera.exposure == sim.exposure["exposure"]
    assert Simulator(setup, (64, 64)).exposure == meta["camera_exposure"]
    for key, edit in (("camera_exposure.exposure = 'bright'", lambda m: m["camera_exposure"].update(exposure="bright")),
                      ("homography", lambda m: m["registration"]["homography"]["matrix"][0].__setitem__(2, 9.0)),
                      ("variant", lambda m: m.update(variant="scalar_spectral"))):
        changed = json.loads(json.dumps(meta))
        edit(changed)
        meta_path.write_text(json.dumps(changed))
        with pytest.raises(DatasetError, match=key):
            simulator_for(setup_dir)
    meta_path.write_text(json.dumps(meta))



def test_the_simulator_of_a_dataset_is_reused_until_its_files_change(tmp_path):
    """A reused simulator captures what a new one would, bit for bit; a dataset written again gets
    a new one."""
    from sim.io import atomic_write

    setup_dir = write_setup(tmp_path, tiny_setup(surface={"texture": "noise"}), FrameSpec(2, 2, (32, 32)),
                            progress=False)
    sim = simulator_for(setup_dir)
    assert simulator_for(setup_dir) is sim
    frames = np.random.default_rng(0).integers(0, 256, (2, 32, 32, 3), np.uint8)
    captured = sim.capture(frames, seeds.CLOSED_LOOP)
    meta = setup_dir / "meta.json"
    atomic_write(meta, meta.read_bytes())  # the same bytes, written again
    fresh = simulator_for(setup_dir)
    assert fresh is not sim and simulator_for(setup_dir) is fresh
    assert np.array_equal(fresh.capture(frames, seeds.CLOSED_LOOP), captured)
    assert np.array_equal(sim.capture(frames, seeds.CLOSED_LOOP), captured)  # used before: the same
