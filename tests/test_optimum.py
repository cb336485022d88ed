"""The exact optimum: its solvers against SciPy's bounded least squares, its Jacobians against a
known model, and the optimum itself against the feedback oracle and fitted methods on the noise-free
model."""
from __future__ import annotations

import re

import numpy as np
import pytest
import torch
from scipy.optimize import lsq_linear

from compensation.data import load_setup_data
from compensation.experiments.closed_loop import (closed_loop_target, iterative_refinement, project,
                                                 simulator_for)
from compensation.experiments.optimum import (_apply, _apply_transposed, _offsets, box_least_squares,
                                             colour_jacobian, evaluation_count, local_jacobian, local_least_squares, optimum)
from compensation.experiments.targets import TargetPolicy
from compensation.methods import METHODS, make_config
from compensation.scores.metrics import delta_e_per_image, psnr_per_image, ssim_per_image
from helpers import tiny_setup
from sim import seeds
from sim.dataset import FrameSpec, write_setup

NONE = TargetPolicy("none")


def _bounded(a: np.ndarray, b: np.ndarray, lo: np.ndarray, hi: np.ndarray, mu: float) -> np.ndarray:
    """SciPy's minimiser of ‖A·d − b‖² + μ‖d‖² on [lo, hi] (the damping as extra rows)."""
    n = a.shape[1]
    stacked = np.vstack([a, np.sqrt(mu) * np.eye(n)])
    return lsq_linear(stacked, np.concatenate([b, np.zeros(n)]), bounds=(lo, hi), tol=1e-12,
                      lsmr_tol="auto").x


def test_the_box_step_is_scipys_bounded_least_squares():
    g = torch.Generator().manual_seed(0)
    jac = torch.randn(200, 3, 3, generator=g, dtype=torch.float64) + 2 * torch.eye(3, dtype=torch.float64)
    r = 0.6 * torch.randn(200, 3, generator=g, dtype=torch.float64)
    lo = -torch.rand(200, 3, generator=g, dtype=torch.float64) * 0.3
    hi = torch.rand(200, 3, generator=g, dtype=torch.float64) * 0.3
    d = box_least_squares(jac, r, lo, hi, 1e-3)
    active = 0
    for i in range(200):
        ref = _bounded(jac[i].numpy(), r[i].numpy(), lo[i].numpy(), hi[i].numpy(), 1e-3)
        np.testing.assert_allclose(d[i].numpy(), ref, atol=1e-7)
        active += int(np.any(np.isclose(ref, lo[i].numpy()) | np.isclose(ref, hi[i].numpy())))
    assert active > 100  # most of the problems have a bound active: the faces are exercised


def _blur_model(kernel: torch.Tensor, mix: torch.Tensor):
    """A known model: a 3×3 spatial kernel per output channel after a colour mixing matrix, in
    8-bit steps as the simulator's captures are not (continuous, so differences are exact)."""
    def model(x: torch.Tensor) -> torch.Tensor:
        mixed = torch.einsum("oc,nchw->nohw", mix, x.double())
        return torch.nn.functional.conv2d(mixed, kernel.expand(3, 1, 3, 3), padding=1, groups=3).float()
    return model


KERNEL = torch.tensor([[0.05, 0.1, 0.05], [0.1, 0.4, 0.1], [0.05, 0.1, 0.05]], dtype=torch.float64)
MIX = torch.tensor([[0.8, 0.15, 0.05], [0.1, 0.85, 0.05], [0.05, 0.1, 0.85]], dtype=torch.float64)


def test_the_jacobians_of_a_known_model():
    model = _blur_model(KERNEL, MIX)
    x = torch.full((2, 3, 12, 12), 128 / 255)  # frames are on the projector's 8-bit grid
    x[1, :, :, :6] = 250 / 255  # near the top: the step goes down there
    jac = local_jacobian(model, x, model(x))
    for k, (dy, dx) in enumerate(_offsets(1)):
        inner = jac[:, 2:-2, 2:-2, :, k, :]
        expected = (KERNEL[1 - dy, 1 - dx] * MIX).expand_as(inner)  # conv2d correlates: flipped offset
        torch.testing.assert_close(inner, expected, atol=1e-5, rtol=1e-4)
    # the per-pixel Jacobian is the response to a change uniform over the frame: the kernel's sum
    # (where the neighbours move the same way: not beside image 1's border between up and down)
    own = colour_jacobian(model, x, model(x))[0, 2:-2, 2:-2]
    torch.testing.assert_close(own, (KERNEL.sum() * MIX).expand_as(own), atol=1e-5, rtol=1e-4)


@pytest.mark.slow
def test_the_step_across_pixels_is_scipys_bounded_least_squares():
    model = _blur_model(KERNEL, MIX)
    g = torch.Generator().manual_seed(1)
    x = (torch.rand(1, 3, 6, 6, generator=g) * 255).round() / 255
    jac = local_jacobian(model, x, model(x))
    n = 3 * 36
    dense = np.stack([_apply(jac, torch.eye(n, dtype=torch.float64)[i].reshape(1, 6, 6, 3), 1).reshape(-1).numpy()
                      for i in range(n)], axis=1)
    r = torch.randn(1, 6, 6, 3, generator=g, dtype=torch.float64) * 0.3
    xp = x.permute(0, 2, 3, 1).double()
    mu = torch.tensor([1e-3], dtype=torch.float64)
    ref = _bounded(dense, r.reshape(-1).numpy(), (-xp).reshape(-1).numpy(), (1 - xp).reshape(-1).numpy(), 1e-3)
    own = box_least_squares(jac.sum(dim=-2), r, -xp, 1 - xp, mu)
    d = local_least_squares(jac, r, -xp, 1 - xp, mu, own, iterations=3000)

    def cost(v):
        return np.sum((dense @ v - r.reshape(-1).numpy()) ** 2) + 1e-3 * np.sum(v ** 2)
    assert cost(d.reshape(-1).numpy()) == pytest.approx(cost(ref), rel=1e-4)
    assert cost(d.reshape(-1).numpy()) < 0.95 * cost(own.reshape(-1).numpy())  # measured 0.90: neighbours matter


def test_the_transposed_jacobian_is_the_adjoint():
    g = torch.Generator().manual_seed(2)
    jac = torch.randn(2, 5, 7, 3, 9, 3, generator=g, dtype=torch.float64)
    d, u = (torch.randn(2, 5, 7, 3, generator=g, dtype=torch.float64) for _ in range(2))
    # <G d, u> = <d, G^T u> for each image, at the edges too (shifted-in zeros)
    lhs, rhs = (_apply(jac, d, 1) * u).sum((1, 2, 3)), (d * _apply_transposed(jac, u, 1)).sum((1, 2, 3))
    assert torch.allclose(lhs, rhs, rtol=1e-12, atol=1e-12)


def _dataset(tmp_path, name: str, n_test: int = 4, **sections):
    setup = tiny_setup(**sections)
    setup = type(setup)(**{**setup.__dict__, "name": name})
    setup_dir = write_setup(tmp_path, setup, FrameSpec(2, n_test, (32, 32)), progress=False)
    return setup_dir, load_setup_data(setup_dir), simulator_for(setup_dir)


@pytest.mark.slow
def test_on_a_white_surface_without_room_light_the_optimum_is_exact(tmp_path, capsys):
    """Albedo 1, no ambient light, the camera on the projector's axis: every target in reach is
    shown to within the 8-bit steps of projector and camera."""
    _, data, sim = _dataset(tmp_path, "white", surface={"texture": "uniform", "albedo_scale": 1.0},
                            camera={"response": "gamma:2.2", "shot_noise": 1e-5, "read_noise": 1e-3,
                                    "position": [0.0, 0.0, 1.0], "fov": 30.0},
                            projector={"black_level": 0.0, "resolution": [32, 32]})
    # in reach: between the captures of plain black and plain white (global: 1 % may fall outside)
    scores, frames = optimum(data, sim, policy=TargetPolicy("global", out_of_reach=0.0), progress=True)
    # its progress counts evaluations of the test set in tenths, not in float noise
    last = capsys.readouterr().err.split("\r")[-1]
    assert re.search(r"exact optimum: .*\| \d+\.\d/\d+ \[", last), last
    assert scores["noise_free"]["psnr"] >= 40.0
    assert scores["psnr"] >= 38.0  # the same frames through the noisy camera
    assert frames.min() >= 0 and frames.max() <= 1
    assert torch.equal(frames, (frames * 255).round() / 255)  # 8-bit projector input


@pytest.fixture(scope="module")
def textured(tmp_path_factory):
    """A textured surface under room light, seen at an angle, with camera noise and the default
    hardware's camera response: blur from the camera's resampling couples neighbours."""
    return _dataset(tmp_path_factory.mktemp("textured"), "textured", n_test=6,
                    surface={"texture": "noise", "texture_resolution": 64},
                    ambient={"radiance": [0.05, 0.05, 0.05]},
                    camera={"shot_noise": 2e-4, "read_noise": 2e-3})


def _per_image(model, frames: torch.Tensor, target: torch.Tensor) -> dict[str, np.ndarray]:
    captured = project(model, frames, seeds.OPTIMUM)
    return {"psnr": np.array(psnr_per_image(captured, target)),
            "ssim": ssim_per_image(captured, target).numpy(),
            "deltaE": delta_e_per_image(captured, target).numpy()}


@pytest.mark.slow
def test_the_optimum_beats_the_oracle_and_every_method_on_every_image(textured, tmp_path):
    setup_dir, data, sim = textured
    full = load_setup_data(setup_dir)
    policy = TargetPolicy("global")
    y, _ = closed_loop_target(data, data.test.frames, policy)
    model = sim.noise_free()
    _, oracle = iterative_refinement(data, sim, policy=policy, return_frames=True)
    scores, best = optimum(data, sim, policy=policy, starts=(oracle,))
    assert scores["evaluations"] == evaluation_count(starts=1) == 61
    candidates = {"oracle": oracle, "y' as is": y}
    for name in ("tps", "nayar"):
        method = METHODS[name]()
        method.fit(full, make_config("quick", name, n_train=2), progress=False)
        candidates[name] = method.predict(y, data.surface)
    ours = _per_image(model, best, y)
    np.testing.assert_allclose(ours["psnr"], scores["noise_free"]["psnr_per_image"], atol=1e-3)
    for name, frames in candidates.items():
        theirs = _per_image(model, frames, y)
        assert np.all(ours["psnr"] >= theirs["psnr"] - 1e-3), name
        assert np.all(ours["ssim"] >= theirs["ssim"] - 1e-3), name
        assert np.all(ours["deltaE"] <= theirs["deltaE"] + 1e-3), name
    # better than the oracle's frames by a margin a broken solver would miss
    assert np.mean(ours["psnr"]) > np.mean(_per_image(model, oracle, y)["psnr"]) + 0.3


@pytest.mark.slow
def test_the_stage_across_pixels_runs_beyond_its_pilot_only_where_it_pays(textured, monkeypatch):
    """Two pilot images: on the textured setup (the camera's resampling couples neighbours) the stage
    pays on them and runs on the other four too; asked for more than it can give, it stops at them."""
    import compensation.experiments.optimum as module

    _, data, sim = textured
    monkeypatch.setattr(module, "PILOT_IMAGES", 2)
    scores, frames = optimum(data, sim, policy=TargetPolicy("global"))
    record = scores["across_pixels"]
    assert record["pilot_images"] == 2 and record["pilot_gain_db"] >= module.PILOT_GAIN_DB and record["applied"]
    assert scores["evaluations"] == evaluation_count(starts=0)
    monkeypatch.setattr(module, "CHUNK", 2)  # the rest in two chunks: each image is solved alone
    chunked, again = optimum(data, sim, policy=TargetPolicy("global"))
    assert torch.equal(again, frames) and chunked["noise_free"]["psnr"] == scores["noise_free"]["psnr"]
    monkeypatch.setattr(module, "PILOT_GAIN_DB", 100.0)
    scores, _ = optimum(data, sim, policy=TargetPolicy("global"))
    assert not scores["across_pixels"]["applied"]
    per_pixel, across = 1 + 5 * module.ROUNDS, 3 * 9 + 2 * module.SPATIAL_ROUNDS
    assert scores["evaluations"] == pytest.approx(per_pixel + across * 2 / 6, abs=0.05)
