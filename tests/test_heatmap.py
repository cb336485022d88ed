"""The heatmaps of a two-axis study: the grid of a hand-made summary holds each cell's mean over
seeds (the gain's with its bootstrap interval), and write_charts writes one PNG and SVG per method
and score (closed loop and gain only where scored)."""
from __future__ import annotations

import math

import imageio.v3 as iio
import numpy as np
import pytest

from compensation.reports.charts import heatmap_grid, write_charts
from compensation.reports.summary import breakpoints, summarize

AXES = [{"key": "camera.read_noise", "values": [0.002, 0.008, 0.03], "label": "read noise"},
        {"key": "camera.bayer", "values": ["none", "RGGB"]}]
SEEDS = (0, 1, 2)


def psnr(method: str, i: int, j: int, seed: int) -> float:
    """The surrogate PSNR of a run: falls along both axes, spread over seeds."""
    return (25.0 if method == "tps" else 22.0) - 2.0 * i - 1.5 * j + 0.4 * seed


def uncompensated(i: int) -> float:
    """The closed-loop PSNR of the uncompensated projection at the i-th read noise."""
    return 20.0 - 0.5 * i


def rows(closed_loop: set[str]) -> list[dict]:
    """results rows of every (read noise, Bayer) point, method and seed; ``closed_loop`` methods
    scored in closed loop too (3 dB below their surrogate PSNR, beside the uncompensated
    projection's :func:`uncompensated`)."""
    out = []
    for j, bayer in enumerate(AXES[1]["values"]):
        for i, noise in enumerate(AXES[0]["values"]):
            for method in ("tps", "nayar"):
                for seed in SEEDS:
                    p = psnr(method, i, j, seed)
                    out.append({"point": 3 * j + i, "camera.read_noise": noise, "camera.bayer": bayer,
                                "setup": f"s{j}{i}", "method": method, "n_train": 8, "seed": seed,
                                "status": "ok", "psnr": p, "ssim": 0.7,
                                "cl_psnr": p - 3.0 if method in closed_loop else math.nan,
                                "cl_unc_psnr": uncompensated(i) if method in closed_loop else math.nan})
    return out


def test_grid_values_are_the_means_over_seeds():
    summary = summarize(rows({"tps"}), [a["key"] for a in AXES])
    grid = heatmap_grid(summary, AXES, "tps", 8, "psnr")
    assert grid["x"] == AXES[0]["values"] and grid["y"] == AXES[1]["values"]
    expected = [[np.mean([psnr("tps", i, j, s) for s in SEEDS]) for i in range(3)] for j in range(2)]
    assert grid["mean"] == pytest.approx(np.array(expected))
    assert grid["std"] == pytest.approx(np.full((2, 3), np.std([0.0, 0.4, 0.8], ddof=1)))
    assert (grid["runs"] == len(SEEDS)).all()
    cl = heatmap_grid(summary, AXES, "tps", 8, "cl_psnr")["mean"]
    assert cl == pytest.approx(np.array(expected) - 3.0)
    assert np.isnan(heatmap_grid(summary, AXES, "nayar", 8, "cl_psnr")["mean"]).all()
    # the gain over uncompensated, the mean over seeds inside its bootstrap interval over them
    gain = heatmap_grid(summary, AXES, "tps", 8, "gain")
    unc = np.array([uncompensated(i) for i in range(3)])
    assert gain["mean"] == pytest.approx(np.array(expected) - 3.0 - unc)
    assert (gain["lo"] < gain["mean"]).all() and (gain["mean"] < gain["hi"]).all()
    assert (gain["hi"] - gain["lo"] <= 0.8 + 1e-9).all()  # within the seeds' range
    assert np.isnan(grid["lo"]).all()  # PSNR heatmaps carry the std, not an interval
    assert np.isnan(heatmap_grid(summary, AXES, "nayar", 8, "gain")["mean"]).all()


@pytest.mark.slow
def test_two_axes_write_one_heatmap_per_method_and_score(tmp_path):
    study = {"name": "noise-bayer", "axes": AXES}
    summary = summarize(rows({"tps"}), [a["key"] for a in AXES])
    written = write_charts(tmp_path, study, summary, breakpoints(summary, study), [])
    heatmaps = sorted(p.name for p in written if p.name.startswith("heatmap"))
    assert heatmaps == ["heatmap_cl_psnr_tps.png", "heatmap_gain_tps.png", "heatmap_psnr_nayar.png",
                        "heatmap_psnr_tps.png"]
    for name in heatmaps:
        path = tmp_path / "charts" / name
        assert iio.imread(path).ndim == 3 and path.with_name(name[:-3] + "svg").is_file()


@pytest.mark.slow
def test_several_training_sizes_keep_theirs_in_the_names(tmp_path):
    study = {"name": "noise-bayer", "axes": AXES}
    sized = [{**r, "n_train": n} for r in rows(set()) if r["method"] == "tps" for n in (8, 16)]
    summary = summarize(sized, [a["key"] for a in AXES])
    written = write_charts(tmp_path, study, summary, breakpoints(summary, study), [])
    assert sorted(p.name for p in written if p.name.startswith("heatmap")) == [
        "heatmap_psnr_tps_n_train=16.png", "heatmap_psnr_tps_n_train=8.png"]


def test_one_axis_writes_no_heatmap(tmp_path):
    study = {"name": "noise", "axes": AXES[:1]}
    one = [r for r in rows({"tps"}) if r["camera.bayer"] == "none"]
    summary = summarize(one, [AXES[0]["key"]])
    written = write_charts(tmp_path, study, summary, breakpoints(summary, study), [])
    assert written and not list((tmp_path / "charts").glob("heatmap*"))
