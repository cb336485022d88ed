"""compensation.methods.pix2pix: the published networks, the training step, the method's life cycle."""
from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from compensation.data import PairSet, SetupData
from compensation.methods import get_method
from compensation.methods.base import CHECKPOINT, save_state
from compensation.methods.compennet import CompenNet, CompenNetOptions, count_parameters
from compensation.methods.pix2pix import (LAMBDA_L1, LR, PIX2PIX_PROFILES, PatchDiscriminator, Pix2Pix,
                                          Pix2PixMethod, Pix2PixOptions, UNetGenerator, check_size,
                                          init_normal, unet_levels)
from compensation.methods import make_config
from compensation.training.config import TrainConfig
from compensation.experiments.runs import train_run
from sim.errors import ProcamError
from synthetic import make_dataset, random_frames


def meta_count(make) -> int:
    """Parameters of a network built on the meta device (no memory, no initialisation)."""
    with torch.device("meta"):
        return count_parameters(make())


@pytest.mark.parametrize("levels, expected", [
    (8, 54_413_955),  # unet_256; the official code prints "[Network G] ... : 54.414 M"
    (7, 41_828_995),  # unet_128
    (5, 16_659_075),  # the 32² network of these tests
])
def test_generator_parameter_counts(levels, expected):
    assert meta_count(lambda: UNetGenerator(levels)) == expected


def test_discriminator_parameter_count():
    # 70×70 PatchGAN on concat(condition, image); the official code prints "[Network D] ... : 2.769 M"
    assert meta_count(PatchDiscriminator) == 2_768_705


def test_patchgan_receptive_field_is_70_pixels():
    disc = PatchDiscriminator().eval()  # eval: BatchNorm with fixed statistics couples no pixels
    x = torch.randn(1, 6, 128, 128, requires_grad=True)
    logits = disc(x)
    assert logits.shape == (1, 1, 14, 14)
    logits[0, 0, 7, 7].backward()
    rows, cols = torch.nonzero(x.grad.abs().sum((0, 1))).unbind(1)
    assert (rows.max() - rows.min() + 1, cols.max() - cols.min() + 1) == (70, 70)


def test_shapes_32px_five_levels():
    torch.manual_seed(0)
    gen, disc = UNetGenerator(unet_levels(32, 32)), PatchDiscriminator()
    assert gen.levels == 5 and len(gen.down) == len(gen.up) == 5
    x = torch.rand(2, 3, 32, 32) * 2 - 1
    y = gen(x)
    assert y.shape == (2, 3, 32, 32) and y.abs().max() < 1  # Tanh output
    assert disc(torch.cat([x, y], 1)).shape == (2, 1, 2, 2)
    # Dropout sits in the decoder of levels 4 … levels-2: three levels for unet_256, two for unet_128.
    with torch.device("meta"):
        dropout = {n: [i for i, up in enumerate(UNetGenerator(n).up)
                       if any(isinstance(m, torch.nn.Dropout) for m in up)] for n in (4, 5, 7, 8)}
    assert dropout == {4: [], 5: [], 7: [4, 5], 8: [4, 5, 6]}


@pytest.mark.parametrize("size, levels", [((256, 256), 8), ((128, 128), 7), ((64, 64), 6), ((32, 32), 5),
                                          ((512, 512), 8), ((64, 128), 6), ((48, 64), 4), ((48, 48), 4),
                                          ((96, 128), 5)])
def test_levels_from_image_size(size, levels):
    assert unet_levels(*size) == levels


@pytest.mark.parametrize("size, message", [
    ((40, 40), "40x40 pixels: pix2pix's U-Net needs width and height divisible by 2^4 = 16 "
               "(e.g. 64x48, 128 or 256)"),
    ((64, 24), "24x64 pixels: pix2pix's U-Net needs width and height divisible by 2^4 = 16"),
    ((8, 8), "8x8 pixels: pix2pix's U-Net needs width and height divisible by 2^4 = 16"),
    ((16, 16), "16x16 pixels: pix2pix's PatchGAN needs width and height of at least 32 pixels"),
])
def test_size_not_divisible_is_refused(size, message):
    with pytest.raises(ProcamError, match=re.escape(message)):
        unet_levels(*size)


def in_memory_setup(captures: torch.Tensor, frames: torch.Tensor) -> SetupData:
    pairs = PairSet(captures, frames)
    return SetupData(name="mem", setup_dir=Path("mem"), train=pairs, test=pairs, ref=pairs,
                     surface=captures[:1])


def tiny_config(**options) -> TrainConfig:
    """30 iterations at batch 1 (pix2pix options over ``options``), CPU, all pairs."""
    own = Pix2PixOptions(**{"iters": 30, "batch": 1, **options})
    return TrainConfig(method="pix2pix", options=own, eval_batch=4, device="cpu", n_train=None, n_test=None)


@pytest.fixture(scope="module")
def inverse_setup() -> SetupData:
    """A trivially learnable mapping on 32² images: frame = 1 − capture."""
    captures = torch.from_numpy(random_frames(4, 32, np.random.default_rng(0))).permute(0, 3, 1, 2) / 255
    return in_memory_setup(captures, 1 - captures)


@pytest.fixture(scope="module")
def fitted(inverse_setup):
    """pix2pix after 30 iterations at batch 1 on the inverse mapping, its initial weights, its stats."""
    torch.manual_seed(0)  # fit seeds the initialisation with cfg.seed = 0
    initial = Pix2Pix(5)
    init_normal(initial)
    method = Pix2PixMethod(device="cpu")
    stats = method.fit(inverse_setup, tiny_config(), progress=False)
    return method, initial.state_dict(), stats


def test_normal_initialisation(fitted):
    _, initial, _ = fitted
    conv, norm = initial["generator.down.2.1.weight"], initial["generator.down.2.2.weight"]
    assert conv.mean().abs() < 1e-3 and conv.std() == pytest.approx(0.02, rel=0.02)
    assert norm.mean() == pytest.approx(1, abs=0.01) and norm.std() == pytest.approx(0.02, rel=0.3)
    assert not initial["generator.up.0.1.bias"].any() and not initial["discriminator.model.0.bias"].any()


def test_training_changes_weights_and_reduces_l1(fitted):
    method, initial, stats = fitted
    state = method.model.state_dict()
    for prefix in ("generator.", "discriminator."):
        assert any(not torch.equal(state[k], initial[k]) for k in state if k.startswith(prefix))
    l1 = [row[1] for row in stats.loss_curve]
    assert len(l1) == stats.extra["iters"] == 30 and stats.batch == 1
    assert np.mean(l1[-5:]) < 0.6 * np.mean(l1[:5])
    assert stats.final_loss == pytest.approx(np.mean(l1[-10:]))
    assert {row[2] for row in stats.loss_curve} == {LR}
    assert all(np.isfinite(row[1:]).all() for row in stats.extra["gan_curve"])


def test_prediction_is_deterministic_and_per_image(fitted, inverse_setup):
    method, _, _ = fitted
    x = inverse_setup.test.captures
    before = {k: v.clone() for k, v in method.model.state_dict().items()}
    method.model.eval()  # predict runs in training mode whatever the mode, and restores it
    out = method.predict(x, inverse_setup.surface)
    assert out.shape == x.shape and out.dtype == torch.float32 and 0 <= out.min() and out.max() <= 1
    assert torch.equal(out, method.predict(x, inverse_setup.surface, batch_size=1))
    assert torch.equal(out[2:3], method.predict(x[2:3], inverse_setup.surface))
    assert torch.equal(out, method.predict(x, inverse_setup.surface.flip(-1)))  # no surface input
    # Test-time BatchNorm uses each image's statistics and leaves the running statistics alone.
    assert all(torch.equal(v, before[k]) for k, v in method.model.state_dict().items())
    assert not method.model.generator.training


def test_checkpoint_round_trip(fitted, inverse_setup, tmp_path):
    method, _, _ = fitted
    method.save(tmp_path)
    loaded = get_method("pix2pix").load(tmp_path, device="cpu")
    assert loaded.model.generator.levels == 5
    x = inverse_setup.test.captures
    assert torch.equal(method.predict(x, inverse_setup.surface), loaded.predict(x, inverse_setup.surface))


def test_predict_refuses_sizes_the_unet_cannot_take(fitted):
    method, _, _ = fitted
    with pytest.raises(ProcamError, match=re.escape("40x40 pixels: pix2pix's U-Net with 5 levels")):
        method.predict(torch.rand(1, 3, 40, 40), torch.rand(1, 3, 40, 40))
    assert method.predict(torch.rand(1, 3, 64, 32), torch.rand(1, 3, 64, 32)).shape == (1, 3, 64, 32)


def test_fit_refuses_a_dataset_size_the_unet_cannot_take():
    x = torch.rand(2, 3, 40, 40)
    with pytest.raises(ProcamError, match=re.escape("40x40 pixels: pix2pix's U-Net needs width and height "
                                                    "divisible by 2^4 = 16")):
        Pix2PixMethod(device="cpu").fit(in_memory_setup(x, x), tiny_config(iters=1), progress=False)


def test_other_checkpoints_are_refused(tmp_path):
    save_state(CompenNet(), tmp_path / CHECKPOINT)
    with pytest.raises(ProcamError, match="not a pix2pix checkpoint"):
        Pix2PixMethod.load(tmp_path, device="cpu")


@pytest.mark.slow
def test_train_run_writes_a_run_directory(tmp_path):
    setup_dir = make_dataset(tmp_path / "data")
    out = tmp_path / "run"
    metrics = train_run(setup_dir, tiny_config(iters=3), out, progress=False)
    assert {p.name for p in out.iterdir()} == {"config.json", "loss.csv", "loss.png", "model.pt",
                                               "metrics.json", "examples.png"}
    assert metrics["method"] == "pix2pix" and np.isfinite(metrics["psnr"]) and metrics["batch"] == 1
    assert json.loads((out / "metrics.json").read_text()) == metrics
    with open(out / "loss.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 3 and float(rows[0]["lr"]) == pytest.approx(LR)


def test_schedule_uses_pix2pix_profiles_unless_overridden():
    assert PIX2PIX_PROFILES["paper"] == dict(iters=10000, batch=1)
    assert Pix2PixOptions.profiles is PIX2PIX_PROFILES
    sched = lambda cfg: (cfg.options.iters, cfg.options.batch)  # noqa: E731
    assert sched(make_config("paper", method="pix2pix")) == (10000, 1)
    assert sched(make_config("paper", method="compennet")) == (1000, 64)
    quick = PIX2PIX_PROFILES["quick"]
    assert sched(make_config("quick", method="pix2pix")) == (quick["iters"], 1)
    assert sched(make_config("quick", method="pix2pix", iters=7)) == (7, 1)
    assert sched(make_config("quick", method="pix2pix", batch=4)) == (quick["iters"], 4)
    compennet = CompenNetOptions.profiles["quick"]
    assert sched(make_config("quick", method="pix2pix", iters=compennet["iters"], batch=compennet["batch"])) == (
        compennet["iters"], compennet["batch"])  # an explicit value equal to CompenNet's is still honoured
    paper = make_config("paper", method="pix2pix").options
    assert (paper.lr, paper.l1_weight, paper.init) == (LR, LAMBDA_L1, None) == (2e-4, 100.0, None)


@pytest.mark.parametrize("option, value", [("loss", "l1"), ("weight_decay", 0.0), ("lr_step", 10),
                                           ("lr_gamma", 0.5), ("amp", True), ("smoothing", 0.1)])
def test_options_pix2pix_does_not_use_are_refused(option, value):
    """pix2pix trains with its own fixed objective, a constant learning rate and no weight decay:
    CompenNet's (and TPS's) options are refused, naming the method and the option."""
    with pytest.raises(ProcamError, match=re.escape(f"method 'pix2pix' does not use option {option!r} "
                                                    "(its options: iters, batch, lr, l1_weight, init;")):
        make_config("quick", "pix2pix", **{option: value})


@pytest.mark.slow
def test_lr_and_l1_weight_are_used(inverse_setup):
    """The learning rate is recorded in the loss curve and changes the fit; λ = 0 (GAN loss only)
    trains other weights than the published λ = 100."""
    def fit(**options):
        method = Pix2PixMethod(device="cpu")
        stats = method.fit(inverse_setup, tiny_config(iters=3, **options), progress=False)
        return stats, method.model.state_dict()

    base_stats, base = fit()
    lr_stats, other_lr = fit(lr=1e-3)
    _, no_l1 = fit(l1_weight=0.0)
    assert {row[2] for row in base_stats.loss_curve} == {LR}
    assert {row[2] for row in lr_stats.loss_curve} == {1e-3}
    key = "generator.down.0.weight"
    assert not torch.equal(base[key], other_lr[key]) and not torch.equal(base[key], no_l1[key])
    with pytest.raises(ProcamError, match=re.escape("option l1_weight = -1.0: expected a number >= 0")):
        Pix2PixOptions(l1_weight=-1.0)
    with pytest.raises(ProcamError, match=re.escape("option lr = 0.0: expected a positive number")):
        Pix2PixOptions(lr=0.0)


def test_check_size_accepts_multiples():
    check_size(64, 96, 5)
    with pytest.raises(ProcamError, match="divisible by 2\\^5 = 32"):
        check_size(64, 80, 5)
