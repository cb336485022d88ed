"""benchmarks/train.py and benchmarks/pix2pix.py at a tiny size, so that the scripts cannot rot:
every step runs in its own process, the table names the steps measured, and each speed-up printed is
the ratio of the rates (or times) printed beside it, the naive loop (default layout) the unit."""
from __future__ import annotations

import csv
import gc
import math
import re
import statistics

import pytest
import torch
from helpers import BENCHMARKS, run_benchmark

from compensation.methods.compennet import CompenNet
from sim.cores import usable_cores

def output(script: str, *args: str) -> str:
    proc = run_benchmark(script, *args)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout


def cells(row: str) -> list[tuple[float, float]]:
    """The (samples/s, ratio to naive) pairs of a row of benchmarks/train.py's table."""
    return [(float(rate), float(ratio)) for rate, ratio in re.findall(r"([\d.]+) \(([\d.]+)×\)", row)]


@pytest.mark.slow
def test_train_benchmark_runs_every_step(monkeypatch):
    """Two runs and their median: every step named in the header, each measured in every row, its
    ratio its rate over the naive loop's (up to the printed rounding), the median row the median of
    the runs."""
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import train

    out = output("train.py", "--sizes", "16", "--batches", "2", "--rounds", "1", "--runs", "2",
                 "--threads", "1", "--nchw-ab", "--amp-ab", "--concurrent")
    lines = out.splitlines()
    header = lines[1]
    assert header[:11].split() == ["size", "batch"]
    assert [header[i:i + 20].strip() for i in range(11, len(header), 20)] == list(train.STEPS[:-1])
    runs = [cells(line) for line in lines if line.split()[:2] == ["16", "2"]]
    median = [cells(line) for line in lines if line.lstrip().startswith("median")]
    assert len(runs) == 2 and len(median) == 1
    for row in [*runs, *median]:
        assert len(row) == len(train.STEPS) - 1
        assert all(math.isfinite(rate) and rate > 0 and math.isfinite(ratio) for rate, ratio in row)
        assert row[0][1] == 1.0  # the naive loop is the unit
    for row in runs:
        naive = row[0][0]
        assert all(math.isclose(ratio, rate / naive, rel_tol=0.01, abs_tol=0.006) for rate, ratio in row)
    for step, (rate, ratio) in enumerate(median[0]):
        assert math.isclose(rate, statistics.median(r[step][0] for r in runs), abs_tol=0.006)
        assert math.isclose(ratio, statistics.median(r[step][1] for r in runs), abs_tol=0.006)
    ab = re.findall(r"^  16², batch 2: on ([\d.]+), off ([\d.]+), on/off ([\d.]+)×$", out, flags=re.M)
    assert len(ab) == 1, out
    on, off, ratio = map(float, ab[0])
    assert on > 0 and off > 0 and math.isclose(ratio, on / off, rel_tol=0.01, abs_tol=0.002)
    amp = re.findall(r"^  16², batch 2: float32 ([\d.]+), bf16 ([\d.]+), bf16/float32 ([\d.]+)×; "
                     r"loss ([\d.]+) against ([\d.]+)$", out, flags=re.M)
    assert len(amp) == 1, out
    full, half, ratio, loss_full, loss_half = map(float, amp[0])
    assert full > 0 and half > 0 and math.isclose(ratio, half / full, rel_tol=0.01, abs_tol=0.006)
    # the same steps from the same start: bf16 rounding apart, the same loss
    assert loss_full > 0 and math.isclose(loss_half, loss_full, rel_tol=0.05) and loss_half != loss_full
    side = re.findall(r"^  16², batch 2: one process ([\d.]+), (\d+) processes ([\d.]+), ([\d.]+)×$", out, flags=re.M)
    assert len(side) == 1, out
    one, cpus, each, ratio = float(side[0][0]), int(side[0][1]), float(side[0][2]), float(side[0][3])
    assert cpus == usable_cores() and one > 0 and each > 0
    assert math.isclose(ratio, each / one, rel_tol=0.01, abs_tol=0.006)


@pytest.mark.slow
def test_bf16_shapes_give_each_shapes_rate_in_window_samples():
    """--bf16-shapes: one line per shape and nothing of the full table; the rate is the batch's
    pixels in 64² windows over the step's time printed beside it."""
    out = output("train.py", "--sizes", "16,32", "--batches", "4,2", "--rounds", "1", "--threads", "1",
                 "--bf16-shapes")
    assert "naive" not in out
    found = re.findall(r"^  (\d+)², batch (\d+): ([\d.]+) ms a step, ([\d.]+) 64²-window samples/s$", out, flags=re.M)
    assert [(size, batch) for size, batch, _, _ in found] == [("16", "4"), ("32", "2")], out
    for size, batch, ms, rate in found:
        expected = int(batch) * (int(size) / 64) ** 2 / (float(ms) / 1000)
        assert float(ms) > 0 and math.isclose(float(rate), expected, rel_tol=0.01, abs_tol=0.06)


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
    # the A/B's two arms: the wide convolutions changed or not, whatever this CPU's rule
    assert "forward" in vars(train.make_step("retained heap", CompenNet(), x, y, s, nchw=True).model.conv4)
    assert "forward" not in vars(train.make_step("retained heap", CompenNet(), x, y, s, nchw=False).model.conv4)


@pytest.mark.slow
def test_pix2pix_benchmark_runs_every_variant():
    """Each variant's median time and its speed-up over the default layout, which is the unit."""
    out = output("pix2pix.py", "--size", "32", "--rounds", "1")
    assert out.startswith("pix2pix step at 32², batch 1") and "median of 1 interleaved steps" in out
    rows = re.findall(r"^\s+(default layout|channels_last|retained heap)\s+([\d.]+) ms\s+\(([\d.]+)x\)$",
                      out, flags=re.M)
    assert [name for name, _, _ in rows] == ["default layout", "channels_last", "retained heap"]
    times = {name: float(ms) for name, ms, _ in rows}
    assert all(math.isfinite(ms) and ms > 0 for ms in times.values())
    for name, _, ratio in rows:
        assert math.isclose(float(ratio), times["default layout"] / times[name], rel_tol=0.01, abs_tol=0.006)


@pytest.mark.slow
def test_a_failing_step_stops_the_benchmark_with_its_message():
    proc = run_benchmark("pix2pix.py", "--size", "16", "--rounds", "1")
    assert proc.returncode == 1
    assert "benchmark step 'default layout' failed: ProcamError: 16x16 pixels" in proc.stderr
    assert "Traceback" not in proc.stderr


@pytest.mark.slow
def test_patches_benchmark_keys_points_by_their_recipe(setup_dir, tmp_path):
    """benchmarks/patches.py: a point per crop, batch, iterations, seed, learning rate, schedule and
    precision; a rerun trains only the points the CSV does not hold, and rows written before the
    recipe columns read as the paper's recipe."""
    out = tmp_path / "out"
    out.mkdir()
    (out / "patches.csv").write_text("patch,batch,iters,seed,train_seconds,psnr,ssim,uncompensated_psnr\n"
                                     "16,4,3,0,1.0,20.0,0.5,15.0\n")
    common = ("--data", str(setup_dir), "--patches", "16", "--batches", "4", "--iters", "3",
              "--threads", "1", "--out", str(out))
    first = output("patches.py", *common, "--lrs", "1e-3,2e-3", "--schedule", "one-cycle", "--amp")
    trained = [line for line in first.splitlines() if line.startswith("{")]
    assert len(trained) == 2 and all("'schedule': 'one-cycle', 'amp': 1" in line for line in trained)
    again = output("patches.py", *common)  # the paper's recipe: the old row holds it
    assert not [line for line in again.splitlines() if line.startswith("{")]
    with open(out / "patches.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(r["lr"], r["schedule"], r["amp"]) for r in rows] == [("0.001", "step", "0"),
                                                                  ("0.001", "one-cycle", "1"),
                                                                  ("0.002", "one-cycle", "1")]
    assert all(float(r["psnr"]) > 0 for r in rows) and (out / "patches.png").stat().st_size > 0
