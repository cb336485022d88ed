"""``procam demo`` end to end on a tiny size: the table's rows, margins over uncompensated, the figure
and the JSON on disk, resumable."""
import csv
import json
import math

import imageio.v3 as iio
import pytest

from compensation.demo import METHODS, N_FIGURE, ORACLE_ITERATIONS, run_demo
from compensation.experiments.targets import TargetPolicy

SMALL = dict(size=32, n_train=8, n_test=N_FIGURE, iters=10, batch=4)
"""32² with 8 training pairs; CompenNet trains 10 iterations (TPS takes neither)."""
TPS_SURROGATE_MARGIN_DB = 6.0
"""TPS surrogate PSNR (π†(x̃) vs x) above uncompensated (measured +12.8 dB on the default setup,
the paper's hardware)."""
CLOSED_LOOP_MARGIN_DB = 1.0
"""Closed-loop PSNR of TPS and of the feedback oracle above y projected as is (measured +1.8 and
+2.0 dB: only 29 % of the desired pixels are within the projector's reach on the default setup)."""
REACHABLE_MARGIN_DB = 4.0
"""The same on the reachable pixels only (measured +6.4 and +8.0 dB)."""


@pytest.mark.slow
def test_demo_tiny(tmp_path, capsys):
    # the margins below are those of the desired images themselves (target policy none, the
    # closed loop as it was before target policies)
    results = run_demo(tmp_path, progress=False, target=TargetPolicy("none"), **SMALL)
    out = capsys.readouterr().out
    assert "closed loop against y' = y, the desired image itself (target policy none)" in out
    assert f"({SMALL['size']}² px, {SMALL['n_train']} train / {SMALL['n_test']} test pairs)" in out
    for name in METHODS:
        assert f"{name}: surrogate" in out and f"{name}: closed loop" in out
        closed = results[name]["closed_loop"]
        assert all(math.isfinite(closed[k]) for k in ("psnr", "rmse", "ssim", "psnr_reachable"))
        assert closed["reachable_fraction"] == results["uncompensated"]["reachable_fraction"]
        assert closed["projections"] == N_FIGURE
    assert f"oracle: feedback, {ORACLE_ITERATIONS} it." in out and "physically reachable" in out

    unc, tps, oracle = results["uncompensated"], results["tps"], results["oracle"][-1]
    assert 0 < unc["reachable_fraction"] < 1
    assert tps["surrogate"]["psnr"] > unc["psnr"] + TPS_SURROGATE_MARGIN_DB
    assert tps["closed_loop"]["psnr"] > unc["psnr"] + CLOSED_LOOP_MARGIN_DB
    assert tps["closed_loop"]["psnr_reachable"] > unc["psnr_reachable"] + REACHABLE_MARGIN_DB
    # the oracle corrects by the measured error: it beats y projected as is by far
    assert oracle["iterations"] == ORACLE_ITERATIONS
    assert oracle["psnr"] > unc["psnr"] + CLOSED_LOOP_MARGIN_DB
    assert oracle["psnr_reachable"] > unc["psnr_reachable"] + REACHABLE_MARGIN_DB
    # the exact optimum starts from the oracle's frames and only improves on them (noise-free model)
    best = results["optimum"]
    assert "exact optimum (" in out and best["noise_free"]["psnr"] >= oracle["psnr"] - 0.5
    assert best["psnr"] > max(tps["closed_loop"]["psnr"], oracle["psnr"]) - 0.5
    # CompenNet is only run here: 10 iterations on 8 pairs do not beat uncompensated on the rendered
    # setup (measured 11.9 dB in closed loop against 14.0); its margin is held on the synthetic setup
    # by tests/test_methods_contract.py.
    assert results["compennet"]["train_seconds"] > 0

    assert json.loads((tmp_path / "demo.json").read_text()).keys() == results.keys()
    # the folder is a one-point bench that `procam report` reads; the demo wrote its report
    assert f"report -> {tmp_path / 'report.html'}" in out
    page = (tmp_path / "report.html").read_text()
    assert page.count("data:image/png;base64,") >= 2 and "http" not in page.split("<body>")[0]
    with open(tmp_path / "results.csv", newline="") as f:
        rows = {r["method"]: r for r in csv.DictReader(f)}
    assert set(rows) == set(METHODS)
    for name in METHODS:
        # results.csv keeps 6 significant digits
        assert float(rows[name]["cl_psnr"]) == pytest.approx(results[name]["closed_loop"]["psnr"], rel=1e-5)
        assert float(rows[name]["fit_s"]) > 0 and float(rows[name]["infer_ms"]) > 0
        kept = sorted(p.name for p in (tmp_path / rows[name]["run"] / "closed_loop").glob("*.png"))
        assert kept == [f"img_{i:04d}.png" for i in range(1, N_FIGURE + 1)]
    grid = iio.imread(tmp_path / "demo.png")
    assert grid.ndim == 3 and grid.shape[2] == 3 and grid.shape[1] > grid.shape[0]  # 6 columns × 4 rows
    # resumable: a second run reuses the dataset and the runs and gives the same numbers
    def stamps(pattern):
        return {p: p.stat().st_mtime_ns for p in tmp_path.rglob(pattern)}

    trained, kept = stamps("loss.csv") | stamps("config.json"), stamps("baselines/*.json")
    assert len(kept) == 1 and len(trained) >= len(METHODS)
    again = run_demo(tmp_path, progress=False, **SMALL)
    assert stamps("loss.csv") | stamps("config.json") == trained  # trained once
    assert stamps("baselines/*.json") != kept  # the oracle and the optimum scored again under the new target
    for name in METHODS:
        assert again[name]["surrogate"] == results[name]["surrogate"]
        # the second run took the default target policy: scored again against y', not reused
        assert results[name]["closed_loop"]["target"]["policy"] == "none"
        assert again[name]["closed_loop"]["target"]["policy"] == "global"
        assert again[name]["closed_loop"]["psnr"] != results[name]["closed_loop"]["psnr"]
    assert "(target policy global: at most" in capsys.readouterr().out
    with open(tmp_path / "results.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert {r["target_policy"] for r in rows} == {"global"}
    # the share the map left out of reach is kept beside the policy's: within the 1 % asked where
    # that leaves contrast, raised above it only where it leaves none (one 8-bit level of contrast)
    target = again["tps"]["closed_loop"]["target"]
    used = target["out_of_reach_used"]
    assert 0 <= used < 1 and (used <= 0.01 or target["a"] == pytest.approx(1 / 255, rel=1e-3))
    assert all(float(r["target_out_of_reach_used"]) == pytest.approx(used, rel=1e-5) for r in rows)

    # unchanged, a third run reuses everything: no training, no closed loop, no oracle, no optimum
    finished = stamps("metrics.json") | stamps("baselines/*.json") | stamps("closed_loop/*.png")
    assert len(finished) == len(METHODS) * (1 + N_FIGURE) + 1
    third = run_demo(tmp_path, progress=False, **SMALL)
    assert stamps("metrics.json") | stamps("baselines/*.json") | stamps("closed_loop/*.png") == finished
    assert third == again
