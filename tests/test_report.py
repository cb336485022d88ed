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
from compensation.experiments.jobs import RESULT_COLUMNS
from compensation.reports.summary import summarize
from helpers import csv_rows
from sim.errors import ProcamError
from sim.io import write_png
from synthetic import make_dataset

AXIS = "projector.aperture"
VALUES = [0.0, 1.0, 2.0]
UNC = [17.0, 16.5, 16.0]
"""Closed-loop PSNR of y projected as is, per point."""
CL = {"tps": [25.0, 22.0, 16.5], "nayar": [21.0, 22.5, 22.0], "compennet": [20.0, 19.0, 18.0]}
"""Mean closed-loop PSNR per method and point (seeds 0 and 1 at mean ∓ 0.5). tps leads at 0.0 and
falls below nayar at 1.0 (its break point: overtaken); compennet and nayar keep >= 1 dB of gain and
never fall below a method they matched: no break."""
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
            "unc_ssim": 0.5, "cl_unc_psnr": UNC[point], "cl_unc_ssim": 0.45, "oracle_psnr": 28.0 - point,
            "oracle_ssim": 0.9, "fit_s": FIT_S[method], "infer_ms": 1.0 + FIT_S[method],
            "run": f"runs/p{point}/{method}-s{seed}"}


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
    assert breaks["tps"]["break_value"] == "1" and breaks["tps"]["kind"] == "overtaken"
    assert breaks["tps"]["other"] == "nayar" and breaks["tps"]["point"] == "1"
    assert "nayar" in breaks["tps"]["reason"]
    assert breaks["nayar"]["kind"] == "none" and breaks["nayar"]["break_value"] == ""
    assert breaks["compennet"]["kind"] == "none"


def test_break_point_by_gain_and_per_second_axis(tmp_path):
    """Without nayar, tps breaks where its gain falls below 1 dB (0.5 dB at 2.0); with a second axis
    each of its values gets its own break point."""
    study, rows = load_folder(make_study(tmp_path))
    from compensation.reports.summary import breakpoints

    kept = [r for r in rows if r["method"] != "nayar"]
    found = {b["method"]: b for b in breakpoints(summarize(kept, [AXIS]), study)}
    assert (found["tps"]["break_value"], found["tps"]["kind"]) == (2.0, "gain")
    assert found["tps"]["gain_db"] == pytest.approx(0.5)
    two = [{**r, "camera.read_noise": noise, "point": r["point"] + 10 * k}
           for k, noise in enumerate((0.0, 0.01)) for r in kept
           if not (noise == 0.01 and r["method"] == "tps" and r["point"] == 1)]
    for r in two:
        if r["camera.read_noise"] == 0.01 and r["method"] == "tps" and r["point"] == 12:
            r["cl_psnr"] = 25.0  # no gain break at the last value either
    study2 = {"axes": [*study["axes"], {"key": "camera.read_noise", "values": [0.0, 0.01]}]}
    found = {(b["method"], b["camera.read_noise"]): b
             for b in breakpoints(summarize(two, [AXIS, "camera.read_noise"]), study2)}
    assert found[("tps", 0.0)]["break_value"] == 2.0
    assert found[("tps", 0.01)]["kind"] == "none"


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
    for name in ("study", "speed"):
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
    assert len(uris) >= 3 + 2  # three figure grids (first, middle, last value) and two charts
    assert "Where does projector defocus break each method?" in page
    assert "falls below nayar" in page and "loss inf at iteration 7" in page
    assert MARKER in page and "0.test" in page and "2026-12-01T22:00:00" in page
    assert (study / "report.html").stat().st_size < 3_000_000


def test_report_errors(tmp_path, capsys):
    assert main(["report", str(tmp_path / "missing")]) == 2
    assert "folder not found" in capsys.readouterr().err
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


def test_training_size_factor():
    """A factor that sets n_train (a training-size study): one line per method across sizes, and
    the break points are found along it (not one point per size)."""
    from compensation.reports.charts import study_lines
    from compensation.reports.summary import breakpoints

    key = "train.n_train"
    cl = {"tps": [20.0, 22.0, 24.0], "compennet": [15.0, 20.0, 25.0]}
    rows = [{"point": p, key: float(n), "setup": "s", "method": m, "n_train": n, "seed": 0, "status": "ok",
             "cl_psnr": v[p], "cl_unc_psnr": 17.0} for m, v in cl.items() for p, n in enumerate((8, 16, 32))]
    study = {"axes": [{"key": key, "values": [8, 16, 32]}]}
    summary = summarize(rows, [key])
    assert set(study_lines(summary, key, [8, 16, 32], "cl_psnr")) == {("tps", ""), ("compennet", "")}
    found = {b["method"]: b for b in breakpoints(summary, study)}
    assert (found["compennet"]["break_value"], found["compennet"]["kind"]) == (8.0, "gain")
    assert (found["tps"]["break_value"], found["tps"]["other"]) == (32.0, "compennet")
    assert found["tps"]["n_train"] == ""


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
