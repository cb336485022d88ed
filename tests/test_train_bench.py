"""benchmarks/train.py and benchmarks/pix2pix.py at a tiny size, so that the scripts cannot rot:
every step runs in its own process and gets a positive rate, the naive loop is the unit."""
from __future__ import annotations

import gc
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from compensation.methods.compennet import CompenNet

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
ROOT = BENCHMARKS.parent


def run(script: str, *args: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(ROOT), OMP_WAIT_POLICY="PASSIVE")
    return subprocess.run([sys.executable, str(BENCHMARKS / script), *args], capture_output=True,
                          text=True, timeout=600, env=env, cwd=ROOT)


def output(script: str, *args: str) -> str:
    proc = run(script, *args)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


@pytest.mark.slow
def test_train_benchmark_runs_every_step():
    out = output("train.py", "--sizes", "16", "--batches", "2", "--rounds", "1", "--runs", "2",
                 "--threads", "1")
    lines = out.splitlines()
    assert lines[1].split()[:3] == ["size", "batch", "naive"]
    assert lines[1].rstrip().endswith("retained heap")
    rows = [line for line in lines if line.lstrip().startswith(("16", "median"))]
    assert len(rows) == 3  # two runs and their median
    for row in rows:
        cells = re.findall(r"([\d.]+) \(([\d.]+)×\)", row)
        assert len(cells) == 7  # naive … retained heap
        assert all(float(rate) > 0 for rate, _ in cells)
        assert cells[0][1] == "1.00"


def test_procams_step_keeps_its_layers_changed(monkeypatch):
    """The benchmark's last step is the training loop's: the backward replacements stay in force
    for the step's lifetime (a context left to the garbage collector would undo them)."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import train

    x, y, s = torch.rand(2, 3, 8, 8), torch.rand(2, 3, 8, 8), torch.rand(1, 3, 8, 8)
    step = train.make_step("retained heap", CompenNet(), x, y, s)
    gc.collect()
    assert "forward" in vars(step.model.transConv2)
    assert step() > 0
    assert "forward" not in vars(train.make_step("inplace relu", CompenNet(), x, y, s).model.transConv2)


@pytest.mark.slow
def test_pix2pix_benchmark_runs_every_variant():
    out = output("pix2pix.py", "--size", "32", "--rounds", "1")
    times = dict(re.findall(r"^\s+(default layout|channels_last|retained heap)\s+([\d.]+) ms", out,
                            flags=re.M))
    assert set(times) == {"default layout", "channels_last", "retained heap"}
    assert all(float(t) > 0 for t in times.values())


@pytest.mark.slow
def test_a_failing_step_stops_the_benchmark_with_its_message():
    proc = run("pix2pix.py", "--size", "16", "--rounds", "1")
    assert proc.returncode == 1
    assert "benchmark step 'default layout' failed: ProcamError: 16x16 pixels" in proc.stderr
    assert "Traceback" not in proc.stderr
