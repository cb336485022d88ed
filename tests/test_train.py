"""compensation.training (config, loop, runs) and the CompenNet methods: the paper's recipe on a tiny
synthetic setup."""
from __future__ import annotations

import csv
import json
import re
import shutil
import warnings
from dataclasses import replace

import numpy as np
import pytest
import torch
from helpers import run_benchmark

from compensation.scores.metrics import evaluate
from compensation.methods import METHODS, check_config, config_from_dict, get_method, make_config
from compensation.methods.base import load_state, subnormal
from compensation.methods.compennet import CompenNet, CompenNetOptions
from compensation.methods.tps import TPSOptions
from compensation.training.config import COMMON, PROFILES, TrainConfig
from compensation.training.loop import BatchSampler, LoopResult
from compensation.experiments.runs import (SSIM_CONVENTION, compensate, load_checkpoint, load_run,
                                        run_size, scores_are_current, train_run)
from sim.errors import ProcamError
from sim.io import read_png, to_uint8

RUN_FILES = {"config.json", "loss.csv", "loss.png", "model.pt", "metrics.json", "examples.png"}


def tiny_config(method: str = "compennet", **options) -> TrainConfig:
    """32², batch 8, CPU: a few seconds per 100 iterations on 2 cores; ``options`` are the
    method's own (CompenNet's iters, lr_step, init, …)."""
    own = get_method(method).options(**{"iters": 100, "batch": 8, **options})
    return TrainConfig(method=method, options=own, eval_batch=8, device="cpu", n_train=None, n_test=None)


def read_losses(run_dir) -> list[float]:
    with open(run_dir / "loss.csv") as f:
        return [float(row["loss"]) for row in csv.DictReader(f)]


pytestmark = pytest.mark.usefixtures("one_torch_thread")


@pytest.fixture(scope="module")
def run(setup_dir, tmp_path_factory):
    """A finished compennet run: 100 iterations on the synthetic setup (measured: the last ten losses
    at 0.07 of the first ten, test PSNR 30.2 dB against 18.4 uncompensated)."""
    out = tmp_path_factory.mktemp("runs") / "compennet"
    train_run(setup_dir, tiny_config(), out, progress=False)
    return out


@pytest.fixture(scope="module")
def nosurf_run(setup_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "nosurf"
    train_run(setup_dir, tiny_config("compennet-nosurf", iters=60), out, progress=False)
    return out


def test_compennet_learns_and_beats_uncompensated(run):
    losses = read_losses(run)
    assert len(losses) == 100
    assert np.mean(losses[-10:]) < 0.5 * np.mean(losses[:10])
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["psnr"] > metrics["uncompensated"]["psnr"]
    assert metrics["rmse"] < metrics["uncompensated"]["rmse"]


def test_uncompensated_row_is_captures_vs_frames(run, data):
    metrics = json.loads((run / "metrics.json").read_text())
    plain = evaluate(data.test.captures, data.test.frames)
    assert metrics["uncompensated"] == pytest.approx(plain)
    assert metrics["ssim_convention"] == "official" and scores_are_current(metrics)


def test_run_directory(run, setup_dir, data):
    assert {p.name for p in run.iterdir()} == RUN_FILES
    assert sorted(p.name for p in run.parent.iterdir()) == ["compennet"]  # nothing half-written beside it
    config = json.loads((run / "config.json").read_text())
    assert config["train"] == {**tiny_config().to_dict(), "n_train": 16, "n_test": 4}
    assert config["train"]["options"] == {"iters": 100, "batch": 8, "lr": 1e-3, "weight_decay": 1e-4,
                                          "lr_schedule": "step", "lr_step": 80, "lr_gamma": 0.2, "loss": "l1+ssim",
                                          "sampler": "epoch", "amp": False, "init": None, "patch": 0}
    assert config_from_dict(config["train"]) == replace(tiny_config(), n_train=16, n_test=4)
    assert config["dataset"] == str(setup_dir.resolve())
    assert config["image_size"] == {"width": 32, "height": 32} and run_size(config) == (32, 32)
    assert config["torch_version"] == torch.__version__
    assert config["device"].startswith("cpu") and "procam_version" in config
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["method"] == "compennet" and metrics["setup"] == "synth"
    assert (metrics["n_train"], metrics["n_test"], metrics["iters"], metrics["batch"]) == (16, 4, 100, 8)
    assert metrics["train_seconds"] > 0 and metrics["samples_per_second"] > 0
    with open(run / "loss.csv") as f:
        rows = list(csv.DictReader(f))
    assert rows[0]["iteration"] == "1" and rows[-1]["iteration"] == "100"
    assert float(rows[0]["lr"]) == pytest.approx(1e-3)
    grid = read_png(run / "examples.png")
    assert grid.shape == (4 * 130 - 2, 4 * 130 - 2, 3)  # rows s̃ | x̃ | π†(x̃) | x of 32² enlarged 4×
    assert np.array_equal(grid[:128:4, :128:4], to_uint8(data.surface[0].permute(1, 2, 0).numpy()))
    assert np.array_equal(grid[130:258:4, 390:518:4], to_uint8(data.test.frames[1].permute(1, 2, 0).numpy()))
    assert read_png(run / "loss.png").shape[2] == 3


def test_learning_rate_steps(setup_dir, tmp_path):
    train_run(setup_dir, tiny_config(iters=7, lr_step=3, lr_gamma=0.5), tmp_path / "r", progress=False)
    with open(tmp_path / "r/loss.csv") as f:
        rates = [float(row["lr"]) for row in csv.DictReader(f)]
    assert rates == pytest.approx([1e-3] * 3 + [5e-4] * 3 + [2.5e-4])


def test_one_cycle_schedule(setup_dir, tmp_path):
    """lr / 10 rising to lr over the first 30 % of the steps, then down to lr / 1000, along half
    cosines; the one-cycle run is not the step run."""
    train_run(setup_dir, tiny_config(iters=20, lr=2e-3, lr_schedule="one-cycle"), tmp_path / "r",
              progress=False)
    with open(tmp_path / "r/loss.csv") as f:
        rates = [float(row["lr"]) for row in csv.DictReader(f)]
    peak = 0.3 * 20 - 1
    rising = [2e-4 + (2e-3 - 2e-4) * (1 - np.cos(np.pi * i / peak)) / 2 for i in range(6)]
    falling = [2e-6 + (2e-3 - 2e-6) * (1 + np.cos(np.pi * (i - peak) / (19 - peak))) / 2
               for i in range(6, 20)]
    assert rates == pytest.approx(rising + falling, rel=1e-5)  # loss.csv keeps 6 digits


def test_one_cycle_takes_no_step_options():
    with pytest.raises(ProcamError, match=re.escape("option lr_step = 5: expected none with "
                                                    "lr_schedule one-cycle")):
        CompenNetOptions(lr_schedule="one-cycle", lr_step=5)
    with pytest.raises(ProcamError, match=re.escape("option lr_gamma = 0.5: expected the default "
                                                    "with lr_schedule one-cycle")):
        CompenNetOptions(lr_schedule="one-cycle", lr_gamma=0.5)
    with pytest.raises(ProcamError, match=re.escape("option lr_schedule = 'cosine': expected "
                                                    "'step' or 'one-cycle'")):
        CompenNetOptions(lr_schedule="cosine")
    # an explicit step option selects the step schedule over a profile's one-cycle
    stepped = make_config("faithful", lr_step=300).options
    assert (stepped.lr_schedule, stepped.lr_step) == ("step", 300)
    assert make_config("faithful", lr_gamma=0.5).options.lr_step == round(0.8 * stepped.iters)
    with pytest.raises(ProcamError, match="option lr_step = 300: expected none"):
        make_config("faithful", lr_step=300, lr_schedule="one-cycle")


def test_load_run_reproduces_the_metrics(run, data):
    method, config = load_run(run, device="cpu")
    assert method.name == config["train"]["method"] == "compennet"
    scores = evaluate(method.predict(data.test.captures, data.surface), data.test.frames)
    metrics = json.loads((run / "metrics.json").read_text())
    assert float(scores["psnr"]) == pytest.approx(metrics["psnr"], abs=1e-9)


@pytest.mark.parametrize("name", ["compennet", "compennet-nosurf"])
def test_checkpoint_round_trip(name, data, tmp_path):
    method = get_method(name)(device="cpu")
    method.fit(data, tiny_config(name, iters=5), progress=False)
    method.save(tmp_path)
    loaded = get_method(name).load(tmp_path, device="cpu")
    assert torch.equal(method.predict(data.test.captures, data.surface),
                       loaded.predict(data.test.captures, data.surface))


def test_nosurf_runs_without_surface_branch(nosurf_run):
    metrics = json.loads((nosurf_run / "metrics.json").read_text())
    assert metrics["method"] == "compennet-nosurf" and np.isfinite(metrics["psnr"])
    losses = read_losses(nosurf_run)
    assert np.mean(losses[-10:]) < np.mean(losses[:10])
    n_params = sum(t.numel() for t in load_state(nosurf_run / "model.pt").values())
    assert n_params == 736_063  # CompenNet w/o surf


def test_surface_input_matters_only_with_the_surface_branch(run, nosurf_run, data):
    x, s, other = data.test.captures, data.surface, data.surface.flip(-1)
    method, _ = load_run(run, device="cpu")
    assert not torch.equal(method.predict(x, s), method.predict(x, other))
    method, _ = load_run(nosurf_run, device="cpu")
    assert torch.equal(method.predict(x, s), method.predict(x, other))


class Opaque:
    """Not a tensor: a weights-only load must refuse it."""


@pytest.mark.parametrize("payload, pickled", [({"w": torch.zeros(2), "obj": Opaque()}, "Opaque"),
                                             ({"w": torch.zeros(2), "f": len}, "len"), (Opaque(), "Opaque")])
def test_pickled_object_checkpoint_is_refused(payload, pickled, run, tmp_path):
    bad = tmp_path / "run"
    shutil.copytree(run, bad)
    torch.save(payload, bad / "model.pt")
    with pytest.raises(ProcamError, match=re.escape(f"{bad / 'model.pt'}: refused to load: it holds a "
                                                    "pickled ") + rf"\S*{pickled},"):
        load_run(bad, device="cpu")


def test_checkpoint_must_be_a_state_dict(tmp_path):
    path = tmp_path / "model.pt"
    torch.save([torch.zeros(2)], path)
    with pytest.raises(ProcamError, match=re.escape(f"{path}: expected a state dict")):
        load_state(path)
    path.write_bytes(b"not a checkpoint")
    with pytest.raises(ProcamError, match=re.escape(f"{path}: cannot read checkpoint")):
        load_state(path)
    with pytest.raises(ProcamError, match=re.escape(f"{tmp_path / 'none.pt'}: checkpoint not found")):
        load_state(tmp_path / "none.pt")


def test_amp_trains_under_bf16_autocast_on_cpu(data):
    """``amp`` on the CPU: the convolutions compute in bf16, the weights stay float32, and the loss
    curve follows float32 training's to bf16 rounding."""
    curves, weights, seen = [], [], []
    for amp in (False, True):
        method = get_method("compennet")(device="cpu")
        original = CompenNet.forward

        def spy(self, x, s=None, features=None):
            out = original(self, x, s, features)
            seen.append((amp, out.dtype))
            return out

        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(CompenNet, "forward", spy)
            fit = method.fit(data, tiny_config(iters=4, amp=amp), progress=False)
        curves.append([loss for _, loss, _ in fit.loss_curve])
        weights.append(method.model.state_dict())
    assert {dtype for amp, dtype in seen if amp} == {torch.bfloat16}
    assert {dtype for amp, dtype in seen if not amp} == {torch.float32}
    assert all(w.dtype == torch.float32 for w in weights[1].values())
    assert curves[1] == pytest.approx(curves[0], rel=2e-2)
    assert not all(torch.equal(weights[0][k], weights[1][k]) for k in weights[0])


def test_a_run_predicts_in_the_precision_it_was_trained_in(run, setup_dir, data, tmp_path):
    """A run trained under ``amp`` predicts under that autocast after training and once loaded:
    bf16 outputs of the convolutions, the loaded run's scores those of its ``metrics.json``, its
    predictions within a few 8-bit levels of float32 prediction; a float32 run predicts in float32."""
    seen, original = [], CompenNet.forward

    def spy(self, x, s=None, features=None):
        out = original(self, x, s, features)
        seen.append(out.dtype)
        return out

    amp_run = tmp_path / "amp"
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(CompenNet, "forward", spy)
        metrics = train_run(setup_dir, tiny_config(iters=4, amp=True), amp_run, progress=False)
    assert seen[-1] == torch.bfloat16  # the test set's prediction, after training
    captures, predicted = data.test.captures, {}
    for name, folder in (("float32", run), ("bf16", amp_run)):
        seen.clear()
        method, config = load_run(folder, device="cpu")
        assert config["train"]["options"]["amp"] is (name == "bf16")
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(CompenNet, "forward", spy)
            predicted[name] = method.predict(captures, data.surface, batch_size=config["train"]["eval_batch"])
        assert set(seen) == {torch.float32 if name == "float32" else torch.bfloat16}
    assert predicted["bf16"].dtype == torch.float32
    scores = evaluate(predicted["bf16"], data.test.frames, config["train"]["eval_batch"], SSIM_CONVENTION)
    assert scores["psnr"] == pytest.approx(metrics["psnr"], abs=1e-9)
    float32 = get_method("compennet")(device="cpu")  # the amp run's weights, predicting in float32
    float32.model = method.model
    difference = (predicted["bf16"] - float32.predict(captures, data.surface)).abs()
    assert 0 < difference.mean() < 1 / 255 and difference.max() < 8 / 255


def _count_subnormal(tensors) -> int:
    return sum(int(subnormal(t).sum()) for t in tensors)


def test_the_prediction_benchmark_scores_every_way(run, data, tmp_path):
    """``benchmarks/predict.py``: both precisions, both layouts and the weights with and without
    their subnormals (planted in a copy of the run's ``model.pt``) timed and scored; the float32
    row the run's own ``metrics.json``, the layouts equal to float rounding, zeroing the subnormals
    changing nothing; the differences printed in 8-bit levels."""
    copy = tmp_path / "run"
    shutil.copytree(run, copy)
    state = load_state(copy / "model.pt")
    weight = state["conv4_s.weight"].view(-1)
    weight[weight.abs().argsort()[:300]] = 1e-40  # the smallest weights made subnormal
    torch.save(state, copy / "model.pt")
    proc = run_benchmark("predict.py", str(copy), "--images", str(len(data.test)), "--repeat", "1",
                         "--threads", "1")
    assert proc.returncode == 0, proc.stderr
    rows = dict(re.findall(r"^  (\S.*?) +[\d.]+ s \(.* PSNR ([\d.]+) ", proc.stdout, re.MULTILINE))
    metrics = json.loads((run / "metrics.json").read_text())
    assert set(rows) == {"float32", "float32, default layout", "float32, subnormals kept", "bf16",
                         "bf16, default layout"}
    assert float(rows["float32"]) == pytest.approx(metrics["psnr"], abs=1e-4)
    assert float(rows["float32, default layout"]) == pytest.approx(metrics["psnr"], abs=1e-4)
    assert float(rows["float32, subnormals kept"]) == pytest.approx(metrics["psnr"], abs=1e-4)
    assert abs(float(rows["bf16"]) - float(rows["float32"])) < 0.5
    levels = r"[\d.]+; \|difference\| mean ([\d.e+-]+), max ([\d.e+-]+) 8-bit levels"
    assert re.search(rf"bf16 / float32 time: {levels}", proc.stdout)
    layouts = re.search(rf"channels-last / default layout time, float32: {levels}", proc.stdout)
    assert layouts and float(layouts[2]) < 0.01
    zeroed = re.search(rf"subnormals zeroed / kept time, float32: {levels}", proc.stdout)
    assert zeroed and float(zeroed[2]) < 0.01
    assert re.search(r"; 300 of \d+ weights in model.pt subnormal", proc.stdout)


def test_subnormal_weights_are_zeroed_when_trained_and_loaded(data, tmp_path):
    """A fitted or loaded network holds no subnormal weights (they slow a CPU's float32 multiplies
    several-fold); zeroing them leaves its predictions as they were."""
    def training_that_leaves_subnormals(step, *args, **kwargs):
        for _ in range(3):
            step(torch.arange(8))
        with torch.no_grad():
            method.model.conv1.weight[0, 0] = 1e-40  # one 3x3 kernel
        return LoopResult(1.0, 24.0, 8, [[0.1, 1e-3]] * 3)

    method = get_method("compennet")(device="cpu")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("compensation.methods.compennet.train_loop", training_that_leaves_subnormals)
        method.fit(data, tiny_config(iters=3), progress=False)
    assert _count_subnormal(method.model.parameters()) == 0
    captures = data.test.captures
    with torch.no_grad():  # plant subnormal weights where the trained ones are smallest
        weight = method.model.conv4_s.weight
        smallest = weight.abs().flatten().argsort()[:500]
        weight.view(-1)[smallest] = torch.where(weight.view(-1)[smallest] < 0, -1e-40, 1e-40)
    assert _count_subnormal(method.model.parameters()) == 500
    planted = method.predict(captures, data.surface)
    method.save(tmp_path)
    assert _count_subnormal(load_state(tmp_path / "model.pt").values()) == 500
    loaded = get_method("compennet").load(tmp_path, device="cpu")
    assert _count_subnormal(loaded.model.parameters()) == 0
    assert torch.equal(loaded.predict(captures, data.surface), planted)


def test_prediction_layouts_agree(run, data, monkeypatch):
    """Prediction in the channels-last layout (procam's) equals the default layout's to float
    rounding, returns a tensor in the default layout and leaves the network in the layout it had,
    also when the forward pass fails."""
    method, _ = load_run(run, device="cpu")
    fast = method.predict(data.test.captures, data.surface)
    method.layout = torch.contiguous_format
    torch.testing.assert_close(fast, method.predict(data.test.captures, data.surface), rtol=0, atol=1e-5)
    assert fast.is_contiguous() and method.model.conv1.weight.is_contiguous()
    method.layout = torch.channels_last
    method.model.to(memory_format=torch.channels_last)  # as while training
    method.predict(data.test.captures[:1], data.surface)
    assert not method.model.conv1.weight.is_contiguous()
    method.model.to(memory_format=torch.contiguous_format)

    def failing(*args, **kwargs):
        raise RuntimeError("out of memory")

    monkeypatch.setattr(CompenNet, "forward", failing)
    with pytest.raises(RuntimeError, match="out of memory"):
        method.predict(data.test.captures[:1], data.surface)
    assert method.model.conv1.weight.is_contiguous()


@pytest.mark.parametrize("options, expected", [
    ({"amp": "yes"}, "option amp = 'yes': expected true or false"),
    ("amp", "train.options = 'amp': expected an object of the method's options"),
])
def test_a_run_whose_recorded_options_cannot_predict_is_named(run, tmp_path, options, expected):
    """Keys a later version records are ignored; a value the method cannot predict with, or options
    that are not an object, name the file."""
    broken = tmp_path / "run"
    shutil.copytree(run, broken)
    config = json.loads((run / "config.json").read_text())
    config["train"]["options"] |= {"option_of_a_later_version": 1}
    (broken / "config.json").write_text(json.dumps(config))
    assert load_run(broken, device="cpu")[0].amp is False
    config["train"]["options"] = options
    (broken / "config.json").write_text(json.dumps(config))
    with pytest.raises(ProcamError, match=re.escape(f"{broken / 'config.json'}: {expected}")):
        load_run(broken, device="cpu")


def test_amp_warns_on_a_cpu_without_native_bf16(data, monkeypatch):
    """Training and prediction under amp both warn where the CPU would emulate bf16; float32 does not."""
    monkeypatch.setattr(torch.ops.mkldnn, "_is_mkldnn_bf16_supported", lambda: False)
    expected = (r"for which this CPU has no native support .* may train and predict slower than in float32 "
                r"\(--no-amp\)")
    method = get_method("compennet")(device="cpu")
    with pytest.warns(UserWarning, match=re.escape(f"{data.name}: amp computes in bf16, ") + expected):
        method.fit(data, tiny_config(iters=2, amp=True), progress=False)
    with pytest.warns(UserWarning, match="compennet: amp computes in bf16, " + expected) as warned:
        method.predict(data.test.captures[:1], data.surface)
    assert warned[0].filename == __file__  # the caller's line, not the method's or torch's
    method.amp = False
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        method.predict(data.test.captures[:1], data.surface)


@pytest.mark.slow
def test_init_from_a_run(run, setup_dir, tmp_path):
    out = tmp_path / "finetuned"
    train_run(setup_dir, tiny_config(iters=10, init=str(run)), out, progress=False)
    pretrained, scratch = read_losses(out), read_losses(run)
    # Starting from the trained weights, the first losses are already near the end of the first run.
    assert np.mean(pretrained[:5]) < 0.6 * np.mean(scratch[:5])
    assert json.loads((out / "config.json").read_text())["train"]["options"]["init"] == str(run.resolve())


def test_init_from_another_architecture_is_refused(nosurf_run, setup_dir, tmp_path):
    message = f"{nosurf_run / 'model.pt'}: weights do not fit the compennet architecture (missing "
    with pytest.raises(ProcamError, match=re.escape(message)):
        train_run(setup_dir, tiny_config(iters=2, init=str(nosurf_run)), tmp_path / "r", progress=False)
    assert not (tmp_path / "r").exists() and not list(tmp_path.rglob("metrics.json"))


@pytest.mark.slow
def test_existing_run_is_replaced_only_when_asked(setup_dir, tmp_path):
    out = tmp_path / "r"
    train_run(setup_dir, tiny_config(iters=2), out, progress=False)
    with pytest.raises(ProcamError, match=re.escape(f"{out}: a finished run already exists")):
        train_run(setup_dir, tiny_config(iters=3), out, progress=False)
    train_run(setup_dir, tiny_config(iters=3), out, progress=False, overwrite=True)
    assert len(read_losses(out)) == 3
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r"]
    (tmp_path / "other").mkdir()
    with pytest.raises(ProcamError, match="is not a run directory"):
        train_run(setup_dir, tiny_config(iters=2), tmp_path / "other", progress=False, overwrite=True)


def test_compensate_uses_the_run_dataset_surface(run, data, tmp_path):
    desired = data.test.frames[:2]
    method, _ = load_run(run, device="cpu")
    expected = method.predict(desired, data.surface)
    assert torch.equal(compensate(run, desired, device="cpu"), expected)
    moved = tmp_path / "run"
    shutil.copytree(run, moved)
    config = json.loads((moved / "config.json").read_text())
    config["dataset"] = str(tmp_path / "gone" / "synth")
    (moved / "config.json").write_text(json.dumps(config))
    with pytest.raises(ProcamError, match=re.escape(f"{tmp_path / 'gone/synth/cam/warp/ref'}: 0 PNG images; "
                                                    "the surface image")):
        compensate(moved, desired, device="cpu")
    assert torch.equal(compensate(moved, desired, surface=data.surface, device="cpu"), expected)
    with pytest.raises(ProcamError, match="expected shape"):
        compensate(run, desired[:, :, :16], device="cpu")


def test_batches_without_replacement():
    batches = BatchSampler(10, 4, seed=0)
    drawn = torch.cat([next(batches) for _ in range(10)])  # 40 indices: exactly 4 epochs
    for b in drawn.view(10, 4):
        assert len(set(b.tolist())) == 4
    for epoch in drawn.view(4, 10):
        assert sorted(epoch.tolist()) == list(range(10))


def test_random_sampler_draws_each_batch_afresh():
    """The official code's sampler: distinct indices within a batch, no epoch structure."""
    batches = BatchSampler(10, 4, seed=0, mode="random")
    drawn = torch.stack([next(batches) for _ in range(50)])
    assert all(len(set(b.tolist())) == 4 for b in drawn)
    assert any(sorted(e.tolist()) != list(range(10)) for e in drawn[:10].reshape(4, 10))
    again = BatchSampler(10, 4, seed=0, mode="random")
    assert torch.equal(torch.stack([next(again) for _ in range(50)]), drawn)
    with pytest.raises(ValueError, match="sampler mode 'shuffle'"):
        BatchSampler(10, 4, seed=0, mode="shuffle")


def test_sampler_option_is_used(data):
    weights = {}
    for sampler in ("epoch", "random"):
        method = get_method("compennet")(device="cpu")
        method.fit(data, tiny_config(iters=3, sampler=sampler), progress=False)
        weights[sampler] = method.model.state_dict()["conv1.weight"]
    assert not torch.equal(weights["epoch"], weights["random"])


def test_unknown_sampler_is_refused_by_the_config():
    with pytest.raises(ProcamError, match=re.escape("option sampler = 'shuffle': expected")):
        make_config("quick", sampler="shuffle")


def test_data_parallel_checkpoint_loads_without_prefix(run, tmp_path):
    """Checkpoints saved under torch.nn.DataParallel (keys prefixed ``module.``) load as plain ones."""
    state = load_state(run / "model.pt")
    torch.save({f"module.{k}": v for k, v in state.items()}, tmp_path / "model.pt")
    loaded = load_state(tmp_path / "model.pt")
    assert loaded.keys() == state.keys() and all(torch.equal(loaded[k], state[k]) for k in state)


def test_official_checkpoint_file(run, nosurf_run, data, tmp_path, capsys):
    """A state dict file (.pth) as the official code saves it, here under DataParallel: ``--init`` and
    ``compensate`` take it; compensate needs the surface image, whose size it takes."""
    state = load_state(run / "model.pt")
    pth = tmp_path / "official.pth"
    torch.save({f"module.{k}": v for k, v in state.items()}, pth)
    # --init: the network starts from the file's weights (a learning rate of 1e-12 keeps them)
    method = get_method("compennet")(device="cpu")
    method.fit(data, tiny_config(init=str(pth), iters=1, lr=1e-12), progress=False)
    assert all(torch.allclose(v, state[k], atol=1e-9) for k, v in method.model.state_dict().items())
    # compensate: a .pth predicts as the run it came from; the surface is required
    desired = data.test.frames[:2]
    expected = compensate(run, desired, device="cpu")
    assert torch.equal(compensate(pth, desired, surface=data.surface, device="cpu"), expected)
    with pytest.raises(ProcamError, match=re.escape(f"{pth}: a state dict file holds no surface image")):
        compensate(pth, desired, device="cpu")
    assert load_checkpoint(nosurf_run / "model.pt", "cpu").name == "compennet-nosurf"
    from compensation.cli import main
    from sim.io import write_png

    write_png(tmp_path / "y.png", to_uint8(desired[0].permute(1, 2, 0).numpy()))
    write_png(tmp_path / "s.png", to_uint8(data.surface[0].permute(1, 2, 0).numpy()))
    assert main(["compensate", str(pth), str(tmp_path / "y.png"), "--surface", str(tmp_path / "s.png"),
                 "--out", str(tmp_path / "x.png")]) == 0
    # the CLI compensates its one image as a batch of one (a batch of two may round differently)
    single = compensate(run, desired[:1], device="cpu")
    # (float rounding in the convolutions depends on the kernels oneDNN picks: on an AVX-512
    # machine one code in 3072 differed by 1)
    diff = np.abs(read_png(tmp_path / "x.png").astype(int)
                  - to_uint8(single[0].permute(1, 2, 0).numpy()).astype(int))
    assert diff.max() <= 1 and np.mean(diff > 0) < 1e-3
    assert main(["compensate", str(pth), str(tmp_path / "y.png"), "--out", str(tmp_path / "x.png")]) == 2
    assert "a state dict file needs --surface IMAGE" in capsys.readouterr().err


def test_make_config_profiles_and_errors():
    quick = make_config("quick", iters=7, n_train=None)
    assert quick.profile == "quick" and quick.method == "compennet" and quick.options.iters == 7
    assert quick.options.batch == CompenNetOptions.profiles["quick"]["batch"]
    assert quick.options.lr_step == 6  # the paper's proportion: 80 % of 7 iterations
    assert quick.n_train == PROFILES["quick"]["n_train"]
    assert make_config("quick").options.lr_step == 400
    assert make_config("quick", iters=2000).options.lr_step == 1600
    assert make_config("quick", iters=2000, lr_step=300).options.lr_step == 300
    assert make_config("quick", iters=1).options.lr_step == 1
    faithful = make_config("faithful")
    f = faithful.options
    assert (faithful.n_train, faithful.n_test, PROFILES["faithful"]["size"]) == (125, 100, 256)
    assert (f.patch, f.iters, f.batch, f.lr, f.lr_schedule, f.lr_step, f.amp, f.loss) == \
        (64, 5000, 16, 2e-3, "one-cycle", None, True, "l1+ssim")
    assert make_config("faithful", "tps").options == make_config("paper", "tps").options
    assert make_config("faithful", "tps-textured").options == make_config("paper", "tps-textured").options
    assert config_from_dict(faithful.to_dict()) == faithful
    paper = make_config("paper")
    o = paper.options
    assert (paper.n_train, paper.n_test, o.iters, o.batch, o.lr, o.weight_decay, o.lr_step, o.lr_gamma,
            o.loss, o.amp, o.init, paper.seed) == (500, 200, 1000, 64, 1e-3, 1e-4, 800, 0.2, "l1+ssim",
                                                   False, None, 0)
    assert make_config("quick", "tps", smoothing=0.5, seed=3).options == TPSOptions(smoothing=0.5)
    with pytest.raises(ProcamError, match="profile 'fast': choose one of paper, quick, faithful"):
        make_config("fast")
    with pytest.raises(ProcamError, match=re.escape("method 'compennet' does not use option 'iterations' "
                                                    "(its options: iters, batch, lr,")):
        make_config("quick", iterations=3)
    with pytest.raises(ProcamError, match="unknown method 'tps9'"):
        make_config("quick", method="tps9")
    with pytest.raises(ProcamError, match=re.escape("option batch = 0: expected a positive integer")):
        make_config("quick", batch=0)
    with pytest.raises(ProcamError, match=re.escape("option loss = 'l3': expected one of l1, l2, ssim")):
        make_config("quick", loss="l3")
    with pytest.raises(ProcamError, match=re.escape("n_test = 0: expected a positive integer")):
        make_config("quick", n_test=0)


def test_train_config_checks_its_options():
    assert make_config("quick", "tps").options == TPSOptions()  # the method's defaults
    with pytest.raises(ProcamError, match="method 'tps' takes TPSOptions, got CompenNetOptions"):
        check_config(TrainConfig(method="tps", options=CompenNetOptions()))
    with pytest.raises(ProcamError, match="method 'tps' takes TPSOptions, got CompenNetOptions"):
        train_run("unused", TrainConfig(method="tps", options=CompenNetOptions()), "unused")
    with pytest.raises(ProcamError, match="options must be the method's Options dataclass, got dict"):
        TrainConfig(method="tps", options={"smoothing": 0.1})
    assert set(COMMON) == {"n_train", "n_test", "seed", "device", "eval_batch", "checkpoint_every"}
    for name in METHODS:  # to_dict / config_from_dict round trip, for every method's defaults
        cfg = make_config("quick", name)
        assert config_from_dict(json.loads(json.dumps(cfg.to_dict()))) == cfg


def test_registry():
    assert {"compennet", "compennet-nosurf"} <= set(METHODS)
    assert all(cls.name == name for name, cls in METHODS.items())
    with pytest.raises(ProcamError, match="unknown method 'nope'; choose one of: ") as error:
        get_method("nope")
    assert all(name in str(error.value) for name in METHODS)
