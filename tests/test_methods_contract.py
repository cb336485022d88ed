"""The contract every registered method keeps, checked for each name in the registry with no entry
of its own (a new method is covered by registering it): trained with its own quick profile for a
few iterations on an easy synthetic setup, it beats every answer that learns nothing by a fixed
margin, predicts the same after save / load, records all its options in a run's ``config.json``,
and is refused options it does not have. How well each method compensates is tested in its own
module (test_train, test_tps_nayar, test_pix2pix)."""
from __future__ import annotations

import json
import re

import pytest
import torch

from compensation.cli import main
from compensation.data import SetupData, load_setup_data
from compensation.scores.metrics import evaluate
from compensation.methods import METHODS, get_method, make_config, option_owners
from compensation.training.config import COMMON, TrainConfig
from compensation.experiments.runs import load_run, train_run
from sim.errors import ProcamError
from synthetic import make_dataset

pytestmark = pytest.mark.usefixtures("one_torch_thread")

ITERS = 50
"""Training iterations of the contract, for the methods that iterate (at their quick profile's batch)."""
DIM = {"offset": 0.05, "gain": 0.4}
"""The easy setup: the synthetic per-pixel affine degradation with a dim projector, whose captures
(at most 0.45) are far from the frames wanted, so doing nothing scores low."""
MARGIN_DB = 1.5
"""Test PSNR above the better answer that learns nothing (:func:`do_nothing_psnr`) every method reaches.

Measured on the dim setup (uncompensated 9.9 dB, best constant frame 14.8 dB) with one torch
thread: compennet 23.3 dB, compennet-nosurf 24.9, pix2pix 17.3 (batch 1, 40 iterations: 16.7),
tps 46.7, tps-textured 46.5, nayar 48.1."""


@pytest.fixture(scope="module")
def dim(tmp_path_factory) -> SetupData:
    """The synthetic dataset of the :data:`DIM` setup."""
    return load_setup_data(make_dataset(tmp_path_factory.mktemp("dim"), **DIM))


def contract_config(name: str, **values) -> TrainConfig:
    """The method's quick profile, its iterations (if it has them) capped at :data:`ITERS`, on
    16 / 4 pairs on the CPU, with ``values`` over it."""
    quick = make_config("quick", name).options
    budget = {"iters": min(quick.iters, ITERS)} if "iters" in quick.names() else {}
    return make_config("quick", name, n_train=16, n_test=4, device="cpu", eval_batch=4, **budget, **values)


def do_nothing_psnr(data: SetupData) -> float:
    """The better test PSNR of the answers that learn nothing: the capture x̃ itself as the frame
    (uncompensated) and the best constant frame (gray 0.5 or the mean training frame)."""
    x, y = data.test.captures, data.test.frames
    constants = (torch.full_like(y, 0.5), data.train.frames.mean(0, keepdim=True).expand_as(y).contiguous())
    return max(evaluate(answer, y)["psnr"] for answer in (x, *constants))


def foreign_option(name: str) -> str:
    """An option some other registered method takes and ``name`` does not."""
    mine = set(get_method(name).options.names())
    return next(option for option in sorted(option_owners()) if option not in mine)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(METHODS))
def test_method_contract(name, dim, tmp_path):
    cls = get_method(name)
    assert cls.name == name and set(cls.options.names()).isdisjoint(COMMON)
    assert re.fullmatch(r"[A-Za-z0-9_]+", cls.official_name)  # a folder name part of the official tag
    cfg = contract_config(name)
    method = cls("cpu")
    stats = method.fit(dim, cfg, progress=False)
    assert stats.seconds > 0 and stats.samples_per_second > 0
    assert torch.isfinite(torch.tensor(stats.final_loss))

    x, s, y = dim.test.captures, dim.surface, dim.test.frames
    predicted = method.predict(x, s, batch_size=cfg.eval_batch)
    assert predicted.shape == y.shape and predicted.dtype == torch.float32
    assert predicted.min() >= 0 and predicted.max() <= 1

    method.save(tmp_path)
    loaded = cls.load(tmp_path, "cpu")
    assert type(loaded) is cls
    assert torch.equal(loaded.predict(x, s, batch_size=cfg.eval_batch), predicted)

    psnr, floor = evaluate(predicted, y)["psnr"], do_nothing_psnr(dim)
    assert psnr >= floor + MARGIN_DB, f"{name}: {psnr:.2f} dB, needs {floor:.2f} + {MARGIN_DB} dB"

    option = foreign_option(name)
    with pytest.raises(ProcamError, match=re.escape(f"method {name!r} does not use option {option!r}")):
        contract_config(name, **{option: 1})


@pytest.mark.parametrize("name", sorted(METHODS))
@pytest.mark.slow
def test_run_config_records_every_option(name, setup_dir, tmp_path):
    """``config.json`` holds the resolved options of the method, all of them, and they load back."""
    cls = get_method(name)
    budget = {k: 1 for k in ("iters", "batch") if k in cls.options.names()}
    cfg = make_config("quick", name, n_train=4, n_test=2, device="cpu", **budget)
    train_run(setup_dir, cfg, tmp_path / "run", progress=False)
    config = json.loads((tmp_path / "run" / "config.json").read_text())
    assert config["train"]["method"] == name
    assert set(config["train"]["options"]) == set(cls.options.names())
    assert cls.options(**config["train"]["options"]) == cfg.options
    method, loaded = load_run(tmp_path / "run", "cpu")
    assert type(method) is cls and loaded == config


def test_cli_train_refuses_an_option_the_method_does_not_use(setup_dir, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", str(setup_dir), "--method", "tps", "--loss", "ssim", "--out", str(out),
                 "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "method 'tps' does not use option 'loss'" in err and "its options: smoothing, scale_invariant, workers" in err
    assert not out.exists()


def test_cli_train_passes_method_options(setup_dir, tmp_path, capsys):
    out = tmp_path / "run"
    assert main(["train", str(setup_dir), "--method", "tps", "--smoothing", "0.05", "--workers", "1",
                 "--n-train", "16", "--n-test", "2", "--device", "cpu", "--out", str(out),
                 "--quiet"]) == 0
    assert "procam: tps on synth" in capsys.readouterr().out
    train = json.loads((out / "config.json").read_text())["train"]
    assert train["options"] == {"smoothing": 0.05, "scale_invariant": False, "workers": 1}
    assert (train["n_train"], train["n_test"], train["profile"], train["device"]) == (16, 2, "quick", "cpu")
