"""Training resumes after kill -9 or SIGTERM with results bit-identical to an uninterrupted run."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from compensation.methods.base import load_state
from compensation.experiments.runs import CHECKPOINT_FILE, partial_dir

ROOT = Path(__file__).resolve().parents[1]


def _train(setup_dir: Path, out: Path, method: str, iters: int, every: int = 4) -> subprocess.Popen:
    """``procam train`` in a child process (CPU, quiet), a checkpoint every ``every`` iterations."""
    cmd = [sys.executable, "-m", "compensation.cli", "train", str(setup_dir), "--method", method,
           "--out", str(out), "--iters", str(iters), "--batch", "4", "--n-train", "16",
           "--n-test", "4", "--device", "cpu", "--checkpoint-every", str(every), "--quiet"]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    """Poll until ``path`` exists (the child must still be running then)."""
    end = time.monotonic() + timeout
    while not path.exists():
        assert proc.poll() is None, f"training ended before {path.name} appeared: {proc.communicate()}"
        assert time.monotonic() < end, f"{path} did not appear within {timeout} s"
        time.sleep(0.02)


@pytest.mark.slow
@pytest.mark.parametrize("method,how", [("compennet", signal.SIGKILL), ("pix2pix", signal.SIGTERM)])
def test_resume_is_bit_identical(setup_dir, tmp_path, method, how):
    iters = 12  # checkpoints at 4 and 8: the child is stopped after the first it writes
    reference = _train(setup_dir, tmp_path / "whole", method, iters)
    out, err = reference.communicate()
    assert reference.returncode == 0, err

    run = tmp_path / "stopped"
    proc = _train(setup_dir, run, method, iters)
    _wait_for(partial_dir(run) / CHECKPOINT_FILE, proc)
    proc.send_signal(how)
    _, err = proc.communicate()
    assert proc.returncode != 0 and not run.exists()
    if how == signal.SIGTERM:  # a clean stop says where the state is and how to resume
        assert proc.returncode == 2 and "stopped by SIGTERM" in err and "Traceback" not in err
    state = torch.load(partial_dir(run) / CHECKPOINT_FILE, weights_only=True)
    assert 4 <= state["iteration"] < iters

    # under another checkpoint interval (that it resumes rather than restarts: the test below)
    resumed = _train(setup_dir, run, method, iters, every=5)
    _, err = resumed.communicate()
    assert resumed.returncode == 0, err
    assert not partial_dir(run).exists()
    a, b = load_state(tmp_path / "whole" / "model.pt"), load_state(run / "model.pt")
    assert a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)
    ma, mb = (json.loads((d / "metrics.json").read_text()) for d in (tmp_path / "whole", run))
    assert (ma["psnr"], ma["ssim"], ma["final_loss"]) == (mb["psnr"], mb["ssim"], mb["final_loss"])
    assert (tmp_path / "whole" / "loss.csv").read_text() == (run / "loss.csv").read_text()


@pytest.mark.slow
def test_changed_config_discards_partial_state(setup_dir, tmp_path):
    """A partial run of another configuration is not resumed: it is replaced."""
    from compensation.methods import make_config
    from compensation.experiments.runs import train_run

    run = tmp_path / "run"
    partial = partial_dir(run)
    partial.mkdir()
    (partial / "config.json").write_text('{"train": {"method": "other"}}')
    (partial / CHECKPOINT_FILE).write_bytes(b"not a checkpoint")
    cfg = make_config("quick", "compennet", iters=3, batch=4, n_train=16, n_test=4, device="cpu")
    train_run(setup_dir, cfg, run, progress=False)
    assert (run / "metrics.json").exists() and not partial.exists()
    assert not (run / CHECKPOINT_FILE).exists()


def test_checkpoint_interval_and_device_name_do_not_make_another_run(tmp_path):
    """A partial run is resumed under another checkpoint interval or thread count; another seed or
    device type replaces it."""
    from compensation.experiments.runs import _prepare_partial

    base = {"train": {"method": "compennet", "seed": 0, "device": "cpu", "checkpoint_every": 50},
            "dataset": "/data/s", "device": "cpu (2 threads)"}
    kept = {**base, "train": {**base["train"], "checkpoint_every": 5}, "device": "cpu (16 threads)"}
    for other, resumed in ((kept, True), ({**base, "train": {**base["train"], "seed": 1}}, False),
                           ({**base, "train": {**base["train"], "device": "cuda:0"}}, False)):
        partial = tmp_path / f"run{len(list(tmp_path.iterdir()))}"
        (_prepare_partial(partial, base)).write_bytes(b"state")
        assert (_prepare_partial(partial, other)).exists() == resumed, other
        assert json.loads((partial / "config.json").read_text()) == other
