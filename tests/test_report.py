"""Summaries, charts and the HTML report of a study folder (hand-made results with known break
points, Pareto front and failures) and of a real bench folder; the page rendered in headless Chromium."""
from __future__ import annotations

import csv
import json
import re
import shutil
import subprocess
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from compensation.cli import main
from compensation.reports.charts import pareto_front, speed_points
from compensation.reports.report import build_report, load_folder
from compensation.experiments.jobs import PER_IMAGE_SCORES, RESULT_COLUMNS, result_row
from compensation.reports.summary import bootstrap_interval, breakpoints, summarize
from helpers import csv_rows
from sim.errors import ProcamError
from sim.io import write_png
from synthetic import make_dataset
from test_latex import latex_problems

AXIS = "projector.aperture"
VALUES = [0.0, 1.0, 2.0]
UNC = [17.0, 16.5, 16.0]
"""Closed-loop PSNR of y projected as is, per point."""
OPTIMUM = [26.0, 25.0, 24.0]
"""Closed-loop PSNR of the exact optimum, per point (the feedback oracle 1 dB below it)."""
CL = {"tps": [25.0, 22.0, 16.5], "nayar": [23.5, 22.5, 22.0], "compennet": [20.0, 19.0, 18.0]}
"""Mean closed-loop PSNR per method and point (seeds 0 and 1 at mean ∓ 0.5; each run's four test
images at its PSNR -1, -0.5, +0.5, +1 dB). tps stays within 3 dB of the optimum at 0.0 and 1.0 (3 dB
exactly: not beyond with 95 % confidence) and falls 7.5 dB below it at 2.0 (its break point), where
its gain (seeds at +1.5 and -0.5 dB) is uncertain on both sides of 1 dB; nayar stays within 2.5 dB
of the optimum: no break; compennet is 6 dB below it everywhere, but its runs at 0.0 and 1.0 were
still training (undertrained): it breaks at 2.0."""
OFFSETS = [-1.0, -0.5, 0.5, 1.0]
"""Each test image's closed-loop PSNR about its run's (dB)."""
UNDERTRAINED = {("compennet", 0), ("compennet", 1)}
"""(method, point) whose runs' training loss was still falling at the end."""
FIT_S = {"tps": 0.05, "nayar": 0.2, "compennet": 10.0}
"""Fit time per method: tps and nayar are the Pareto front, compennet is slower and worse."""
DISTINCT = (212, 23, 97)
"""Colour of the nayar closed-loop captures: found in the screenshot only if the inline images show."""
MARKER = "# setup file marker 7431"


def _row(point, method, seed, cl, status="ok", error=""):
    return {"point": point, AXIS: VALUES[point], "setup": f"p{point}", "method": method, "n_train": 8,
            "seed": seed, "status": status, "error": error,
            "psnr": cl + 3 if status == "ok" else "", "ssim": 0.8 - 0.05 * point if status == "ok" else "",
            "deltae": 5.0 + point, "cl_psnr": cl if status == "ok" else "",
            "cl_ssim": 0.75 - 0.05 * point if status == "ok" else "", "unc_psnr": UNC[point] - 1,
            "unc_ssim": 0.5, "cl_unc_psnr": UNC[point], "cl_unc_ssim": 0.45, "oracle_psnr": OPTIMUM[point] - 1.0,
            "optimum_psnr": OPTIMUM[point], "optimum_ssim": 0.92,
            "oracle_ssim": 0.9, "fit_s": FIT_S[method], "infer_ms": 1.0 + FIT_S[method],
            "run": f"runs/p{point}/{method}-s{seed}", "undertrained": int((method, point) in UNDERTRAINED),
            "reachable_fraction": 0.9 - 0.2 * point}


def _images(row):
    """The per_image.csv rows of an ok run: its PSNR spread over four images, the uncompensated,
    oracle and optimum images about theirs."""
    if row["status"] != "ok":
        return []
    return [{**{k: row[k] for k in ("point", AXIS, "setup", "method", "n_train", "seed")}, "image": i + 1,
             "psnr": row["psnr"] + d, "cl_psnr": row["cl_psnr"] + d,
             "cl_unc_psnr": row["cl_unc_psnr"] + 0.2 * (-1) ** i, "oracle_psnr": row["oracle_psnr"] + 0.3 * (-1) ** i,
             "optimum_psnr": row["optimum_psnr"] + 0.3 * (-1) ** i}
            for i, d in enumerate(OFFSETS)]


def make_study(folder: Path) -> Path:
    """A study folder as the engine writes it: study.json, results.csv, datasets, runs with
    closed-loop captures."""
    rows = []
    for point in range(3):
        for method, means in CL.items():
            for seed in (0, 1):
                value = means[point] + (0.5 if seed else -0.5)
                if method == "compennet" and point == 2:  # seed 1 diverged: the mean is seed 0's
                    rows.append(_row(point, method, seed, means[point]) if seed == 0 else
                                _row(point, method, seed, 0, "diverged", "loss inf at iteration 7"))
                    continue
                if method == "tps" and point == 2:  # seed 1 below uncompensated: a failure
                    value = 15.5 if seed else 17.5
                rows.append(_row(point, method, seed, value))
    columns = ["point", AXIS, *RESULT_COLUMNS]
    with open(folder / "results.csv", "w", newline="") as f:
        w = csv.DictWriter(f, columns, restval="")
        w.writeheader()
        w.writerows(rows)
    with open(folder / "per_image.csv", "w", newline="") as f:
        w = csv.DictWriter(f, ["point", AXIS, "setup", "method", "n_train", "seed", "image", *PER_IMAGE_SCORES])
        w.writeheader()
        w.writerows([i for r in rows for i in _images(r)])
    for point in range(3):
        setup = make_dataset(folder / "data", f"p{point}", size=32, n_train=2, n_test=4)
        (setup / "setup.toml").write_text(f'{MARKER}\nname = "p{point}"\n')
        for method in CL:
            for seed in (0, 1):
                run = folder / "runs" / f"p{point}" / f"{method}-s{seed}"
                (run / "closed_loop").mkdir(parents=True)
                (run / "config.json").write_text(json.dumps({"dataset": str(setup.resolve())}))
                for i in range(1, 5):
                    img = np.full((32, 32, 3), 128, np.uint8)
                    if method == "nayar":
                        img[:] = DISTINCT
                    write_png(run / "closed_loop" / f"img_{i:04d}.png", img)
    study = {"name": "aperture-test", "question": "Where does projector defocus break each method?",
             "kind": "study", "base": "default", "methods": list(CL), "seeds": [0, 1], "n_train": 8,
             "n_test": 4, "size": [32, 32], "overrides": {"iters": 20},
             "axes": [{"key": AXIS, "values": VALUES, "label": "aperture", "unit": "mm"}],
             "versions": {"procam": "0.test", "torch": "2.x", "mitsuba": "3.x", "python": "3.11"},
             "setups": {f"p{p}": f"data/p{p}/setup.toml" for p in range(3)},
             "created": "2026-12-01T22:00:00"}
    (folder / "study.json").write_text(json.dumps(study))
    return folder


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    folder = make_study(tmp_path_factory.mktemp("study"))
    assert main(["report", str(folder)]) == 0
    return folder


def test_summary_mean_std_over_seeds(study):
    rows = {(r["point"], r["method"]): r for r in csv_rows(study / "summary.csv")}
    assert len(rows) == 9
    tps0 = rows[("0", "tps")]
    assert float(tps0["cl_psnr_mean"]) == pytest.approx(25.0)
    assert float(tps0["cl_psnr_std"]) == pytest.approx(np.std([24.5, 25.5], ddof=1), rel=1e-5)
    assert tps0[AXIS] == "0" and tps0["runs"] == "2" and tps0["ok"] == "2"
    cn2 = rows[("2", "compennet")]  # the diverged seed is left out of the mean, not zero-filled
    assert (cn2["runs"], cn2["ok"]) == ("2", "1") and float(cn2["cl_psnr_mean"]) == pytest.approx(18.0)
    assert float(cn2["cl_psnr_std"]) == 0.0


def test_break_points(study):
    breaks = {r["method"]: r for r in csv_rows(study / "breakpoints.csv")}
    tps = breaks["tps"]
    assert (tps["break_value"], tps["kind"], tps["point"]) == ("2", "optimum", "2")
    assert float(tps["optimum_gap_db"]) == pytest.approx(7.5)
    assert 3.0 < float(tps["optimum_gap_lo"]) < 7.5 < float(tps["optimum_gap_hi"])
    # its gain (0.5 dB on average) is not below 1 dB with 95 % confidence: no gain break
    assert float(tps["gain_db"]) == pytest.approx(0.5) and float(tps["gain_lo"]) < 0.5 < 1.0 < float(tps["gain_hi"])
    assert "below the optimum's" in tps["reason"] and tps["undertrained"] == ""
    assert breaks["nayar"]["kind"] == "none" and breaks["nayar"]["break_value"] == ""
    cn = breaks["compennet"]  # 6 dB below the optimum at 0.0 and 1.0 too, but still training there
    assert (cn["break_value"], cn["kind"], cn["undertrained"]) == ("2", "optimum", "0; 1")
    summary = {(r["point"], r["method"]): r for r in csv_rows(study / "summary.csv")}
    assert summary[("1", "tps")]["undertrained"] == "0" and summary[("1", "compennet")]["undertrained"] == "2"
    lo, hi = float(summary[("1", "tps")]["optimum_gap_lo"]), float(summary[("1", "tps")]["optimum_gap_hi"])
    assert lo < 3.0 < hi  # 3 dB below the optimum on average: within the margin's reach, no break


def test_break_point_by_gain_and_per_second_axis(tmp_path):
    """Without nayar and with both tps seeds at 16.5 dB at 2.0, tps breaks where its gain is below
    1 dB with confidence (0.5 dB, every sample); with a second axis each of its values gets its own
    break point."""
    study, rows = load_folder(make_study(tmp_path))
    kept = [r for r in rows if r["method"] != "nayar"]
    for r in kept:
        if r["method"] == "tps" and r["point"] == 2:
            r["cl_psnr"], r["per_image"] = 16.5, {**r["per_image"], "cl_psnr": [16.5 + 0.2 * (-1) ** i for i in range(4)]}
    found = {b["method"]: b for b in breakpoints(summarize(kept, [AXIS]), study)}
    assert (found["tps"]["break_value"], found["tps"]["kind"]) == (2.0, "gain")
    assert found["tps"]["gain_db"] == pytest.approx(0.5) and found["tps"]["gain_hi"] == pytest.approx(0.5)
    two = [{**r, "camera.read_noise": noise, "point": r["point"] + 10 * k}
           for k, noise in enumerate((0.0, 0.01)) for r in kept
           if not (noise == 0.01 and r["method"] == "tps" and r["point"] == 1)]
    for r in two:
        if r["camera.read_noise"] == 0.01 and r["method"] == "tps" and r["point"] == 12:
            r["cl_psnr"], r["per_image"] = 25.0, {}  # no break at the last value either
    study2 = {"axes": [*study["axes"], {"key": "camera.read_noise", "values": [0.0, 0.01]}]}
    found = {(b["method"], b["camera.read_noise"]): b
             for b in breakpoints(summarize(two, [AXIS, "camera.read_noise"]), study2)}
    assert found[("tps", 0.0)]["break_value"] == 2.0
    assert found[("tps", 0.01)]["kind"] == "none"


def test_bootstrap_interval():
    """Hand-computed: the mean of 4 resamples of [0, 0, 0, 1] is k/4, k ~ Binomial(4, 1/4): P(k <= 2)
    = 243/256 < 97.5 % <= P(k <= 3), P(k = 0) = 81/256 > 2.5 %: the 95 % interval is (0, 0.75).
    Constructed: 400 values of N(2, 1) drawn in mirrored pairs (mean exactly 2) give an interval
    holding 2, about 2 · 1.96 / 20 wide; the same seed gives the same interval; over 200 samples of
    N(2, 1) the interval holds 2 about 95 % of the time."""
    assert bootstrap_interval([0.0, 0.0, 0.0, 1.0]) == (0.0, 0.75)
    assert bootstrap_interval([0.0, 1.0]) == (0.0, 1.0)
    rng = np.random.default_rng(7)
    z = rng.normal(0.0, 1.0, 200)
    draws = np.concatenate([2.0 + z, 2.0 - z])
    lo, hi = bootstrap_interval(draws)
    assert lo < 2.0 < hi and hi - lo == pytest.approx(2 * 1.96 * draws.std() / 20, rel=0.15)
    assert bootstrap_interval(draws) == (lo, hi) and bootstrap_interval(draws, seed=1) != (lo, hi)
    held = [lo < 2.0 < hi for lo, hi in (bootstrap_interval(rng.normal(2.0, 1.0, 50), samples=500)
                                         for _ in range(200))]
    assert 0.88 <= np.mean(held) <= 0.99
    assert all(np.isnan(bootstrap_interval([float("nan")])))


def test_undertrained_run_from_its_loss(tmp_path):
    """A run whose loss.csv still falls over its last 10 % of iterations is flagged undertrained;
    one that has levelled off (noise within the tolerance) is not."""
    metrics = {"psnr": 20.0, "rmse": 0.2, "ssim": 0.7, "deltaE": 5.0, "final_loss": 0.1,
               "uncompensated": {"psnr": 15.0, "rmse": 0.3, "ssim": 0.5, "deltaE": 9.0},
               "psnr_per_image": [19.0, 21.0]}
    curves = {"falling": [1.0 / (1 + 0.05 * i) for i in range(200)],
              "flat": [1.0 / (1 + 0.05 * i) for i in range(100)] + [0.17 + 0.001 * (-1) ** i for i in range(100)]}
    flags = {}
    for name, losses in curves.items():
        run = tmp_path / name
        run.mkdir()
        (run / "loss.csv").write_text("iteration,loss,lr\n" + "".join(f"{i},{v},0.001\n" for i, v in enumerate(losses)))
        row = result_row({"ok": True, "metrics": metrics, "run": str(run)}, None, tmp_path)
        assert row["status"] == "ok" and row["per_image"] == {"psnr": [19.0, 21.0]}
        flags[name] = row["undertrained"]
    assert flags == {"falling": 1, "flat": 0}


def test_failures_listed(study):
    fails = csv_rows(study / "failures.csv")
    kinds = sorted((f["method"], f["point"], f["seed"], f["kind"]) for f in fails)
    assert kinds == [("compennet", "2", "1", "diverged"), ("tps", "2", "1", "worse")]
    assert next(f for f in fails if f["kind"] == "diverged")["detail"] == "loss inf at iteration 7"


def test_speed_accuracy_pareto(study):
    _, rows = load_folder(study)
    points = speed_points(summarize(rows, [AXIS]))
    front = [points[i]["method"] for i in pareto_front([(p["fit_s"], p["psnr"]) for p in points])]
    assert front == ["tps", "nayar"]
    assert all(p["score"] == "closed loop" for p in points)


def _colours(img: np.ndarray) -> int:
    """Number of distinct RGB colours."""
    rgb = img[..., :3].astype(np.int64)
    return len(np.unique((rgb[..., 0] << 16) | (rgb[..., 1] << 8) | rgb[..., 2]))


def _png_ok(path: Path, min_side: int = 300) -> np.ndarray:
    img = iio.imread(path)
    assert img.ndim == 3 and min(img.shape[:2]) >= min_side, path
    assert _colours(img) > 50, f"{path} looks blank"
    return img


def test_charts_written(study):
    charts = study / "charts"
    for name in ("study", "gain", "speed"):
        _png_ok(charts / f"{name}.png")
        assert (charts / f"{name}.svg").stat().st_size > 10_000
    grid = _png_ok(charts / "grid_point0.png")
    # the nayar column shows its closed-loop captures: the distinctive colour fills whole cells
    assert (np.abs(grid[..., :3].astype(int) - DISTINCT).max(-1) <= 2).sum() > 4 * 100 * 100


def test_report_self_contained(study):
    page = (study / "report.html").read_text()
    assert not re.search(r"""(src|href)\s*=\s*["']?(https?:|//|file:)""", page)
    assert "<script" not in page and "<link" not in page and "@import" not in page
    uris = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', page)
    assert len(uris) >= 3 + 3  # three figure grids (first, middle, last value) and three charts
    assert "Where does projector defocus break each method?" in page
    assert "dB below the optimum" in page and "loss inf at iteration 7" in page
    assert "compennet (n=8) at 0; 1" in page and "undertrained, not broken" in page
    assert MARKER in page and "0.test" in page and "2026-12-01T22:00:00" in page
    assert (study / "report.html").stat().st_size < 3_000_000


def test_report_errors(tmp_path, capsys):
    assert main(["report", str(tmp_path / "missing")]) == 2
    assert "folder not found" in capsys.readouterr().err
    (tmp_path / "a.csv").write_text("point\n")
    assert main(["report", str(tmp_path / "a.csv")]) == 2
    assert "a.csv: a file, not a study or bench folder" in capsys.readouterr().err
    folder = make_study(tmp_path / "s") if (tmp_path / "s").mkdir() is None else None
    text = (folder / "results.csv").read_text().replace(",ok,", ",fine,", 1)
    (folder / "results.csv").write_text(text)
    with pytest.raises(ProcamError, match=r"results.csv, line 2: status 'fine'"):
        build_report(folder)
    (folder / "results.csv").write_text("point,setup\n0,a\n")
    assert main(["report", str(folder)]) == 2
    assert f"missing column(s) {AXIS}, method, n_train, seed, status" in capsys.readouterr().err


def _chromium() -> str | None:
    return shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.mark.slow
def test_report_renders_in_chromium(study, tmp_path):
    """The page as a browser shows it: not blank, and the inline images are drawn (the nayar
    captures' colour appears in the screenshot)."""
    browser = _chromium()
    if browser is None:
        pytest.skip("chromium not found: `make chromium` installs Debian's package (root + apt-get)")
    shot = tmp_path / "shot.png"
    proc = subprocess.run([browser, "--headless", "--disable-gpu", "--no-sandbox", "--hide-scrollbars",
                           f"--screenshot={shot}", "--window-size=1400,2600",
                           (study / "report.html").resolve().as_uri()],
                          capture_output=True, text=True, timeout=180)
    assert shot.is_file(), proc.stderr[-2000:]
    img = iio.imread(shot)[..., :3].astype(int)
    assert img.std() > 20 and _colours(img) > 200  # not blank
    near = np.abs(img - DISTINCT).max(-1) <= 6
    assert near.sum() > 2000  # the figure grid's nayar cells, scaled by the browser


@pytest.mark.slow
def test_real_bench_folder(tmp_path, capsys):
    """A folder written by `procam bench` (no study.json / results.csv yet) is reported from its
    Table 1 rows: the table with the paper's column, the speed chart, the grid of the dataset."""
    make_dataset(tmp_path / "data", "synth", size=32, n_train=8, n_test=4)
    out = tmp_path / "bench"
    assert main(["bench", "--data", str(tmp_path / "data"), "--out", str(out), "--methods", "tps,nayar",
                 "--sizes", "8", "--tables", "1", "--n-test", "4", "--quiet"]) == 0
    capsys.readouterr()
    assert main(["report", str(out)]) == 0
    assert str(out / "report.html") in capsys.readouterr().out
    page = (out / "report.html").read_text()
    assert "paper PSNR" in page and "Table 1" in page
    _png_ok(out / "charts" / "speed.png")
    _png_ok(out / "charts" / "grid_point0.png", min_side=200)
    summary = {r["method"]: r for r in csv_rows(out / "summary.csv")}
    assert set(summary) == {"tps", "nayar"}
    assert float(summary["tps"]["psnr_mean"]) > float(summary["tps"]["unc_psnr_mean"]) + 5
    assert csv_rows(out / "breakpoints.csv") == []
    # every table also in LaTeX beside its Markdown and CSV, valid as far as can be seen without LaTeX
    for name in ("table1", "table1_paired", "per_setup"):
        assert (out / f"{name}.md").is_file()
        header = (out / f"{name}.csv").read_text().splitlines()[0].split(",")
        assert latex_problems((out / f"{name}.tex").read_text(), len(header)) == []
    assert r"tps ($\lambda$ = 0.01)" in (out / "table1.tex").read_text()
    # tps against nayar on the same 4 test images of the one setup: their per-image PSNR differences
    images = {(r["method"], r["image"]): float(r["psnr"]) for r in csv_rows(out / "per_image.csv")}
    diffs = [images[("tps", str(i))] - images[("nayar", str(i))] for i in range(1, 5)]
    [paired] = csv_rows(out / "table1_paired.csv")
    assert [paired[k] for k in ("A", "B", "n_train", "score", "setups", "images", "p")] == [
        "tps (λ = 0.01)", "nayar", "8", "surrogate", "1", "4", "1.0000"]  # one setup: no sign to flip
    assert float(paired["mean diff dB"]) == pytest.approx(np.mean(diffs), abs=2e-4)
    assert float(paired["CI low"]) <= float(paired["mean diff dB"]) <= float(paired["CI high"])
    assert float(paired["share A better"]) == np.mean(np.array(diffs) > 0)
    assert "sign-flip permutation test" in (out / "table1_paired.md").read_text()
    assert "Table 1, paired: method A against method B" in page


def test_training_size_factor():
    """A factor that sets n_train (a training-size study): one line per method across sizes, and
    the break points are found along it (not one point per size)."""
    from compensation.reports.charts import study_lines

    key = "train.n_train"
    cl = {"tps": [20.0, 22.0, 24.0], "compennet": [15.0, 20.0, 25.0]}
    rows = [{"point": p, key: float(n), "setup": "s", "method": m, "n_train": n, "seed": 0, "status": "ok",
             "cl_psnr": v[p], "cl_unc_psnr": 17.0} for m, v in cl.items() for p, n in enumerate((8, 16, 32))]
    study = {"axes": [{"key": key, "values": [8, 16, 32]}]}
    summary = summarize(rows, [key])
    assert set(study_lines(summary, key, [8, 16, 32], "cl_psnr")) == {("tps", ""), ("compennet", "")}
    found = {b["method"]: b for b in breakpoints(summary, study)}
    assert (found["compennet"]["break_value"], found["compennet"]["kind"]) == (8.0, "gain")
    assert found["compennet"]["gain_db"] == -2.0  # one run per size: its own gain is the interval
    assert (found["tps"]["kind"], found["tps"]["break_value"]) == ("none", "")  # 3 to 7 dB of gain
    assert found["tps"]["n_train"] == ""


@pytest.mark.slow
def test_bench_results_with_tables(tmp_path):
    """A bench's results.csv names each row's table and variant: the summary and break points take
    Table 1 (methods x sizes), Tables 2 and 3 (variants of CompenNet) stay out of its lines."""
    folder = make_study(tmp_path)
    text = (folder / "results.csv").read_text().splitlines()
    head = text[0] + ",table,variant"
    body = [line + ",1,v" for line in text[1:]]
    body += [line.replace(",tps,", ",compennet,").replace(",ok,", ",failed,") + ",3,compennet-n8-l1"
             for line in text[1:3]]
    (folder / "results.csv").write_text("\n".join([head, *body]) + "\n")
    images = (folder / "per_image.csv").read_text().splitlines()
    (folder / "per_image.csv").write_text("\n".join([images[0] + ",table,variant",
                                                     *(line + ",1,v" for line in images[1:])]) + "\n")
    build_report(folder)
    summary = csv_rows(folder / "summary.csv")
    assert len(summary) == 9 and all(r["runs"] == "2" for r in summary if r["method"] == "compennet")
    failed = [f for f in csv_rows(folder / "failures.csv") if f["kind"] == "failed"]
    assert len(failed) == 2  # the Table 3 failures are listed all the same


def test_axis_on_n_train_round_trip(tmp_path):
    """An axis on n_train is the n_train column itself: written once, read back as an integer."""
    from compensation.experiments.jobs import write_results, write_study_record
    from compensation.reports.summary import read_results

    rows = [{"point": p, "setup": "s", "method": "tps", "n_train": n, "seed": 0, "status": "ok",
             "cl_psnr": 20.0 + p, "cl_unc_psnr": 17.0, "fit_s": 0.123456789} for p, n in enumerate((8, 16))]
    write_study_record(tmp_path, {"name": "t", "kind": "study", "axes": [{"key": "n_train", "values": [8, 16]}]})
    results = write_results(tmp_path, ["n_train"], rows)
    header = (tmp_path / "results.csv").read_text().splitlines()[0].split(",")
    assert header.count("n_train") == 1 and header[:2] == ["point", "setup"]
    back = read_results(results, ["n_train"])
    assert [r["n_train"] for r in back] == [8, 16] and abs(back[0]["fit_s"] - 0.123457) < 1e-9
    assert json.loads((tmp_path / "study.json").read_text())["versions"]["python"]


def test_a_damaged_results_table_is_refused_and_named(tmp_path):
    """Cut short (a truncated 0.483852 must not read as 0), not UTF-8, or a row of another width."""
    from compensation.experiments.jobs import write_results
    from compensation.reports.summary import read_results

    rows = [{"point": 0, "setup": "s", "method": "tps", "n_train": 8, "seed": 0, "status": "ok",
             "cl_psnr": 20.483852, "cl_unc_psnr": 17.0}]
    path = write_results(tmp_path, [], rows)
    whole = path.read_bytes()
    assert read_results(path, [])[0]["cl_psnr"] == pytest.approx(20.4839, abs=1e-4)
    cut = whole.rstrip(b"\r\n")
    for damaged, message in ((cut[:cut.rindex(b".") + 1], "cut short"),
                             (whole + b"\xff\xfe\n", "not UTF-8"),
                             (whole + b"0,s,tps\r\n", "line 3: ")):
        path.write_bytes(damaged)
        with pytest.raises(ProcamError, match=re.escape(f"{path}") + ".*" + re.escape(message)):
            read_results(path, [])


def test_a_folder_where_every_run_failed_still_gets_its_report(tmp_path):
    """No score to draw: no study chart, but the page with its failures (not a traceback)."""
    from compensation.experiments.jobs import write_results, write_study_record

    write_study_record(tmp_path, {"name": "t", "kind": "study", "methods": ["tps"], "seeds": [0],
                                  "axes": [{"key": "ambient.radiance", "values": [0.1, 0.2]}]})
    write_results(tmp_path, ["ambient.radiance"],
                  [{"point": p, "ambient.radiance": v, "setup": f"s{p}", "method": "tps", "n_train": 8,
                    "seed": 0, "status": "failed", "error": "simulated"} for p, v in enumerate((0.1, 0.2))])
    page = build_report(tmp_path).read_text()
    assert "Failures (2)" in page and "simulated" in page
    assert not list((tmp_path / "charts").glob("study*.png"))


@pytest.mark.slow
def test_each_value_of_a_second_axis_keeps_its_own_chart_files(tmp_path):
    """Chart names keep the second axis's key and value: with a dotted key, two values give four
    chart files (study and gain), none overwriting another (``with_suffix`` had cut
    ``.read_noise=0.01`` off every name)."""
    from compensation.reports.charts import write_charts

    study, rows = load_folder(make_study(tmp_path))
    two = [{**r, "camera.read_noise": noise, "point": r["point"] + 10 * k}
           for k, noise in enumerate((0.0, 0.01)) for r in rows]
    axes = [*study["axes"], {"key": "camera.read_noise", "values": [0.0, 0.01]}]
    study2 = {**study, "axes": axes}
    summary = summarize(two, [AXIS, "camera.read_noise"])
    written = write_charts(tmp_path / "two", study2, summary, breakpoints(summary, study2), [])
    names = sorted(p.name for p in written)
    assert {"study_camera.read_noise=0.png", "study_camera.read_noise=0.01.png",
            "speed_camera.read_noise=0.png", "speed_camera.read_noise=0.01.png"} <= set(names)
    assert "speed.png" not in names  # no chart averages over the second axis
    assert len(set(names)) == len(names) and all(p.is_file() for p in written)
    assert all(p.with_name(p.name[:-3] + "svg").is_file() for p in written)


def _study_json(folder: Path, change) -> None:
    study = json.loads((folder / "study.json").read_text())
    change(study)
    (folder / "study.json").write_text(json.dumps(study))


def _results_cell(folder: Path, column: str, value: str, line: int = 2, name: str = "results.csv") -> None:
    lines = (folder / name).read_text().splitlines()
    header = lines[0].split(",")
    cells = lines[line - 1].split(",")
    cells[header.index(column)] = value
    lines[line - 1] = ",".join(cells)
    (folder / name).write_text("\n".join(lines) + "\n")


def _drop_column(folder: Path, column: str) -> None:
    lines = [line.split(",") for line in (folder / "results.csv").read_text().splitlines()]
    gone = lines[0].index(column)
    (folder / "results.csv").write_text("\n".join(",".join(c for i, c in enumerate(cells) if i != gone)
                                                   for cells in lines) + "\n")


HOSTILE = {
    "a setup path not naming setup.toml": (
        lambda f: _study_json(f, lambda s: s["setups"].update(p0="/etc/passwd")),
        "study.json: setups.p0 = '/etc/passwd': expected the path of a setup file named setup.toml"),
    "a setup path of another type": (
        lambda f: _study_json(f, lambda s: s["setups"].update(p0=5)), "setups.p0 = 5: expected"),
    "an axis key of another type": (
        lambda f: _study_json(f, lambda s: s["axes"][0].update(key=5)), "each key a string"),
    "an axis label of another type": (
        lambda f: _study_json(f, lambda s: s["axes"][0].update(label=5)), "label = 5: expected a string"),
    "a target without its share": (
        lambda f: _study_json(f, lambda s: s.update(target={"policy": "global"})),
        "study.json: target {'policy': 'global'}: out of reach None: expected a fraction in [0, 1)"),
    "a target share as text": (
        lambda f: _study_json(f, lambda s: s.update(target={"policy": "global", "out_of_reach": "x"})),
        "out of reach 'x': expected a fraction"),
    "a target of no policy": (
        lambda f: _study_json(f, lambda s: s.update(target={"policy": "best", "out_of_reach": 0.01})),
        "target policy 'best': expected one of"),
    "an empty axis cell": (lambda f: _results_cell(f, AXIS, ""),
                           f"results.csv, line 2: column {AXIS}: expected the run's axis value, found ''"),
    "an axis value the study does not list": (
        lambda f: _results_cell(f, AXIS, "0.5"),
        f"results.csv, line 2: column {AXIS}: 0.5 is not one of the study's values (0.0, 1.0, 2.0; study.json)"),
    "a point given other axis values": (  # line 2 is point 0 at 0.0; point 0 again, at 1.0
        lambda f: _results_cell(f, AXIS, "1.0", line=3),
        f"results.csv, line 3: point 0 ({AXIS} = 1.0): line 2 gives this point other axis values"),
    "axis values given as two points": (
        lambda f: _results_cell(f, "point", "1"),
        f"results.csv, line 3: point 0 ({AXIS} = 0.0): line 2 gives these axis values as point 1"),
    "a run ok without a score": (
        lambda f: (_results_cell(f, "psnr", ""), _results_cell(f, "cl_psnr", "")),
        "results.csv, line 2: status ok but column psnr holds no finite number ('')"),
    "a run ok with an infinite score": (
        lambda f: _results_cell(f, "cl_psnr", "inf"),
        "results.csv, line 2: status ok but column cl_psnr holds no finite number ('inf')"),
    "a per-image run results.csv does not hold": (
        lambda f: _results_cell(f, "n_train", "eight", name="per_image.csv"),
        "per_image.csv, line 2: run point 0, setup p0, method tps, n_train eight, seed 0 is not a run of "
        "results.csv"),
    "a per-image row cut short": (
        lambda f: (f / "per_image.csv").write_text(
            "\n".join(t if i != 1 else t.rsplit(",", 1)[0] for i, t in
                      enumerate((f / "per_image.csv").read_text().splitlines())) + "\n"),
        "per_image.csv, line 2: 12 columns in the header, another number in this row"),
    "a results table without a score": (lambda f: _drop_column(f, "psnr"),
                                         "results.csv: missing column(s) psnr"),
    "a run given twice": (
        lambda f: (f / "results.csv").write_text((f / "results.csv").read_text() +
                                                 (f / "results.csv").read_text().splitlines()[1] + "\n"),
        "is given twice (first on line 2)"),
    "a file where the charts folder goes": (
        lambda f: (f / "charts").write_text("not a folder"),
        lambda f: f"{f / 'charts'}: File exists: expected a folder (or nothing) there, found a file"),
    "a capture of another size": (
        lambda f: write_png(f / "runs" / "p0" / "tps-s0" / "closed_loop" / "img_0001.png",
                            np.zeros((24, 40, 3), np.uint8)),
        lambda f: f"{f / 'runs' / 'p0' / 'tps-s0' / 'closed_loop' / 'img_0001.png'}: 40x24 pixels but "
                  f"{(f / 'data' / 'test' / 'img_0001.png').resolve()} is 32x32 (all images of a dataset "
                  "must have one size)"),
}


@pytest.mark.parametrize("case", list(HOSTILE))
def test_a_hostile_folder_is_refused_in_one_line_naming_what_is_wrong(tmp_path, capsys, case):
    folder = tmp_path / "s"
    folder.mkdir()
    make_study(folder)
    damage, message = HOSTILE[case]
    damage(folder)
    message = message(folder) if callable(message) else message
    assert main(["report", str(folder)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("procam: error: ") and message in err, err
    assert len(err.strip().splitlines()) == 1 and "root:" not in err
    assert not (folder / "report.html").exists()


@pytest.mark.parametrize("values", [[0.0, 1e-4, 1e-2, 1.0], [0.0, 0.00125, 0.0025, 0.005, 0.01]],
                         ids=["decades", "doublings"])
def test_a_factor_spanning_decades_from_zero_is_drawn_on_a_symlog_axis(tmp_path, monkeypatch, values):
    """A smoothing λ of 0, 1e-4, 1e-2 and 1, or an aperture of 0 then doubling four times: 0 at the
    left and every step equally wide, 0 to the first value too (a linear axis would squeeze the
    small values into one spot), every value a tick."""
    from compensation.reports import charts

    summary = [{"point": p, "smoothing": v, "method": "tps", "n_train": 125, "runs": 1,
                "psnr_mean": 25.0 + p, "psnr_std": 0.0, "unc_psnr_mean": 12.0}
               for p, v in enumerate(values)]
    drawn = []

    def keep(plt, fig, stem):
        drawn.append([(ax.get_xscale(), list(ax.get_xticks()),
                       ax.transData.transform([(v, 0.0) for v in values])[:, 0]) for ax in fig.axes])
        plt.close(fig)
        return []

    monkeypatch.setattr(charts, "_saved", keep)
    charts.draw_study(summary, [], [], {"key": "smoothing", "values": values, "label": "λ"},
                      tmp_path / "study", "smoothing")
    (scale, ticks, x), = drawn[0]
    assert scale == "symlog" and ticks == pytest.approx(values)
    steps = np.diff(x)
    assert steps == pytest.approx(np.full(len(steps), steps[0]), rel=1e-6) and np.all(steps > 0)


def test_the_speed_chart_has_a_column_per_factor_value(study, monkeypatch):
    """Fit time, inference time and the captures the fit needs against PSNR per value of the
    factor (a method's cost and score differ along it), each point with its ± std bars, none
    averaged over the values."""
    from compensation.reports import charts

    folder, rows = load_folder(study)
    summary = summarize(rows, [AXIS])
    points = speed_points(summary, AXIS)
    assert {(p["method"], p["value"]) for p in points} == {(m, v) for m in ("tps", "nayar", "compennet")
                                                           for v in VALUES}
    for p in points:
        row = next(r for r in summary if (r["method"], r[AXIS]) == (p["method"], p["value"]))
        assert (p["fit_s"], p["psnr"], p["psnr_std"]) == (row["fit_s_mean"], row["cl_psnr_mean"], row["cl_psnr_std"])
        # TPS and Nayar fit the 125 plain colours; CompenNet its training pairs and the surface image
        assert p["captures"] == {"tps": 125, "nayar": 125}.get(p["method"], int(row["n_train"]) + 1)
    drawn = []
    monkeypatch.setattr(charts, "_saved", lambda plt, fig, stem: drawn.append(
        [(ax.get_title(), ax.get_xlabel(), sorted(c.lines[0].get_xdata()[0] for c in ax.containers))
         for ax in fig.axes]) or plt.close(fig) or [])
    charts.draw_speed(points, Path("speed"), "speed", folder["axes"][0])
    panels = drawn[0]
    assert len(panels) == 3 * len(VALUES)
    name = folder["axes"][0].get("label") or AXIS
    assert [t for t, _, _ in panels if t] == [f"{name} = {v:g}" for v in VALUES]
    assert all(len(xs) == 3 for _, _, xs in panels)  # one error bar per method in every panel
    captures = [xs for _, label, xs in panels if label.startswith("captures")]
    assert captures == [sorted(p["captures"] for p in points if p["value"] == v) for v in VALUES]
