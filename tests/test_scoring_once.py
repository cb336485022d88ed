"""Work a bench does once per dataset, not once per run: the uncompensated scores of a test set are
computed once per process, and a freshly trained run's official outputs of the test captures are its
own predictions, not predicted again."""
from __future__ import annotations

import numpy as np
import pytest
import torch

import compensation.experiments.runs as runs
from compensation.data import load_setup_data
from compensation.experiments.jobs import BaselineJob, FitJob, baselines, fit
from compensation.experiments.runs import load_run, uncompensated_scores
from compensation.methods import make_config
from compensation.methods.tps import TPSMethod
from compensation.scores.metrics import evaluate
from sim.io import read_png
from synthetic import make_dataset


@pytest.fixture
def counted(monkeypatch):
    """Counts the calls of ``evaluate`` made through the run module (the uncompensated scores)."""
    calls = []

    def counting(*args, **kwargs):
        calls.append(args[0].shape)
        return evaluate(*args, **kwargs)

    monkeypatch.setattr(runs, "evaluate", counting)
    monkeypatch.setattr(runs, "_UNCOMPENSATED", {})
    return calls


def test_uncompensated_scores_are_computed_once_per_test_set(counted):
    gen = torch.Generator().manual_seed(0)
    x, y = torch.rand(3, 3, 16, 16, generator=gen), torch.rand(3, 3, 16, 16, generator=gen)
    first = uncompensated_scores(x, y)
    assert first == evaluate(x, y, convention="official")
    first["psnr"] = 0.0  # the caller's copy: the kept scores stay as computed
    assert uncompensated_scores(x.clone(), y.clone()) == evaluate(x, y, convention="official")
    assert len(counted) == 1
    y[0, 0, 0, 0] = 1 - y[0, 0, 0, 0]  # one value of another test set: scored again
    assert uncompensated_scores(x, y) == evaluate(x, y, convention="official")
    assert len(counted) == 2


@pytest.mark.slow
def test_runs_and_baselines_share_one_uncompensated_scoring(tmp_path, counted, monkeypatch):
    setup = make_dataset(tmp_path / "data", n_train=8, n_test=3)
    predicted = []
    original = TPSMethod.predict

    def predict(self, captures, surface, batch_size=64):
        predicted.append(captures.shape[0])
        return original(self, captures, surface, batch_size)

    monkeypatch.setattr(TPSMethod, "predict", predict)
    results = [fit(FitJob(setup, make_config("quick", method, n_train=8, n_test=3), tmp_path / method,
                          closed_loop=False, official=tmp_path / "official"))
               for method in ("tps", "tps-textured")]
    base = baselines(BaselineJob(setup, 3, closed_loop=False))
    data = load_setup_data(setup, n_train=1, n_test=3)
    plain = evaluate(data.test.captures, data.test.frames, convention="official")
    assert [r["metrics"]["uncompensated"] for r in results] == [plain, plain]
    assert base["uncompensated"] == plain
    assert len(counted) == 3  # each run's own π†(x̃) once, the uncompensated set once
    # per run: π†(x̃) once for its scores and official outputs, π†(y) once for the official outputs
    assert predicted == [3, 3, 3, 3]
    for r in results:
        method, _ = load_run(r["run"])
        folder = tmp_path / "official" / "cam" / "cmp" / r["official_tag"]
        written = np.stack([read_png(folder / f"img_{i:04d}.png") for i in (1, 2, 3)])
        again = method.predict(data.test.captures, data.surface).permute(0, 2, 3, 1).numpy()
        assert np.array_equal(written, np.uint8(again * 255))


def test_official_outputs_refuse_predictions_of_another_test_set(tmp_path):
    from compensation.experiments.official import write_official_outputs
    from compensation.experiments.runs import train_run
    from sim.errors import ProcamError

    setup = make_dataset(tmp_path / "data", n_train=8, n_test=3)
    metrics, predicted = train_run(setup, make_config("quick", "tps", n_train=8, n_test=3), tmp_path / "run",
                                   progress=False, return_predicted=True)
    assert predicted.shape == (3, 3, 32, 32)
    data = load_setup_data(setup, n_train=1, n_test=3)
    with pytest.raises(ProcamError, match=r"\(2, 3, 32, 32\) predictions given for \(3, 3, 32, 32\) test captures"):
        write_official_outputs(tmp_path / "run", data, tmp_path / "official", "TPS", cam=predicted[:2])
    assert not (tmp_path / "official").exists()  # nothing half-written
