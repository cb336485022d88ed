"""Closed loop: project π†(y) through the same simulated setup; iterative refinement; reachability."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from compensation.data import load_setup_data
from compensation.experiments.closed_loop import (closed_loop, closed_loop_scores, iterative_refinement,
                                                 reachable_mask, reachable_overlay, simulator_for)
from compensation.scores.metrics import masked_scores, psnr, rmse
from compensation.methods.base import Method
from compensation.training.config import NoOptions
from helpers import tiny_setup
from sim.capture import Simulator
from sim.dataset import FrameSpec, write_setup


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
def textured(tmp_path_factory):
    return _dataset(tmp_path_factory.mktemp("tex"), "tex", surface={"texture": "noise", "albedo_scale": 0.9},
                    ambient={"radiance": [0.02, 0.02, 0.02]},
                    camera={"shot_noise": 1e-5, "read_noise": 1e-3})


def test_identity_on_a_white_surface_reproduces_the_desired_image(white):
    data, sim = white
    scores = closed_loop(Identity(), data, sim)
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
    rows = iterative_refinement(data, sim, desired=desired, report=(0, 1, 2, 3, 4))
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

    rows = iterative_refinement(data, Counting(), report=(0, 1))
    y, mask = data.test.frames, reachable_mask(data, data.test.frames)
    assert rows[0] == {"iterations": 0, **closed_loop_scores(data.test.captures, y, mask), "projections": 4}
    assert len(calls) == 1 and rows[1]["projections"] == 8


def test_reachable_mask_flags_what_the_projector_cannot_do(textured):
    data, _ = textured
    white_img = torch.ones(1, 3, 32, 32)
    assert reachable_mask(data, white_img).float().mean() < 0.5  # albedo < 1: too bright
    grey = data.ref.captures[62:63]  # a capture is reachable by definition (mid gray frame)
    assert reachable_mask(data, grey).float().mean() > 0.9
    assert np.isclose(float(reachable_mask(data, data.ref.captures[124:125]).float().mean()), 1.0)


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
