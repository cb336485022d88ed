"""`procam compare A B`: two hand-made study folders (written by the engine's own writers) matched
run by run, B − A checked against a hand computation, the runs of one folder only listed, and the
bad inputs refused with status 2 and one line naming the folder."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from compensation.cli import main
from compensation.experiments.jobs import write_results
from compensation.reports.summary import bootstrap_interval
from helpers import csv_rows

AXIS = "projector.aperture"
VALUES = [0.0, 1.0]
IMAGES = [-1.0, 1.0]
"""Each test image's PSNR about its run's (dB)."""
SHIFT = {0: 0.5, 1: 1.0}
"""B's PSNR and closed-loop PSNR over A's, per seed (dB), on every image too."""


def _row(point: int, method: str, seed: int, shift: float, setup: str) -> dict:
    psnr, cl = 20.0 + point + seed, 15.0 + point + 0.5 * seed
    return {"point": point, AXIS: VALUES[point], "setup": setup, "method": method, "n_train": 8,
            "seed": seed, "status": "ok", "psnr": psnr + shift, "ssim": 0.8 - 0.1 * seed + shift / 10,
            "deltae": 5.0 + seed - shift, "cl_psnr": cl + shift, "cl_ssim": 0.6, "cl_deltae": 9.0,
            "per_image": {"psnr": [psnr + shift + d for d in IMAGES],
                          "cl_psnr": [cl + shift + d for d in IMAGES]}}


def make_folder(folder: Path, rows: list[dict], per_image: bool = True, kind: str = "study") -> Path:
    """A study folder: ``study.json`` with the fields the readers use, ``results.csv`` and
    ``per_image.csv`` as the engine writes them (the latter removed unless ``per_image``)."""
    folder.mkdir(parents=True)
    (folder / "study.json").write_text(json.dumps({
        "name": folder.name, "kind": kind, "methods": ["tps", "nayar"], "seeds": [0, 1, 2],
        "axes": [{"key": AXIS, "values": VALUES, "label": "aperture", "unit": "mm"}] if kind == "study" else []}))
    write_results(folder, [AXIS] if kind == "study" else [], rows)
    if not per_image:
        (folder / "per_image.csv").unlink()
    return folder


@pytest.fixture
def folders(tmp_path):
    """A: tps seeds 0, 1 at both points, nayar at point 0 (only in A); B: the same tps runs, each
    setup under a leading folder, shifted by :data:`SHIFT`, and tps seed 2 at point 1 (only in B)."""
    a = [_row(p, "tps", s, 0.0, f"p{p}") for p in (0, 1) for s in (0, 1)] + [_row(0, "nayar", 0, 0.0, "p0")]
    b = [_row(p, "tps", s, SHIFT[s], f"data/p{p}") for p in (0, 1) for s in (0, 1)]
    b.append(_row(1, "tps", 2, 0.0, "data/p1"))
    return make_folder(tmp_path / "a", a), make_folder(tmp_path / "b", b)


def _scored(rows: list[dict], level: str, score: str, **key) -> dict:
    found = [r for r in rows if r["level"] == level and r["score"] == score
             and all(r[k] == str(v) for k, v in key.items())]
    assert len(found) == 1, (level, score, key)
    return found[0]


def test_matched_differences_equal_a_hand_computation(folders, capsys):
    a, b = folders
    assert main(["compare", str(a), str(b)]) == 0
    out = a / "compare-b"
    printed = capsys.readouterr().out
    assert f"procam: compare -> {out / 'compare.csv'}" in printed and str(out / "compare.md") in printed
    assert "4 run(s) matched, 1 only in A, 1 only in B" in printed
    rows = csv_rows(out / "compare.csv")
    assert {r["score"] for r in rows if r["level"] == "group"} == {"psnr", "ssim", "deltae", "cl_psnr",
                                                                   "cl_ssim", "cl_deltae"}
    # tps at point 1: seeds 0 and 1 paired; PSNR per image from per_image.csv in both
    g = _scored(rows, "group", "psnr", method="tps", **{AXIS: "1"})
    a_mean, b_mean = np.mean([21.0, 22.0]), np.mean([21.0 + SHIFT[0], 22.0 + SHIFT[1]])
    assert float(g["a"]) == pytest.approx(a_mean) and float(g["b"]) == pytest.approx(b_mean)
    assert float(g["diff"]) == pytest.approx(np.mean(list(SHIFT.values())))
    samples = [SHIFT[s] for s in (0, 1) for _ in IMAGES]
    assert (g["over"], g["samples"], g["pairs"]) == ("images", "4", "2")
    assert (float(g["lo"]), float(g["hi"])) == pytest.approx(bootstrap_interval(samples), abs=1e-5)
    assert float(g["sampled"]) == pytest.approx(np.mean(samples))
    # SSIM has no per-image scores: its interval is over the paired runs
    s = _scored(rows, "group", "ssim", method="tps", **{AXIS: "0"})
    diffs = [SHIFT[0] / 10, SHIFT[1] / 10]
    assert float(s["diff"]) == pytest.approx(np.mean(diffs)) and (s["over"], s["samples"]) == ("runs", "2")
    assert (float(s["lo"]), float(s["hi"])) == pytest.approx(bootstrap_interval(diffs), abs=1e-5)
    # one run: its own images, B's setup name with its leading folder beside A's
    r = _scored(rows, "run", "cl_psnr", method="tps", seed=1, **{AXIS: "0"})
    assert (r["setup"], r["setup_b"], r["status_a"], r["status_b"]) == ("p0", "data/p0", "ok", "ok")
    assert float(r["diff"]) == pytest.approx(SHIFT[1]) and r["over"] == "images"
    assert float(r["lo"]) == pytest.approx(SHIFT[1]) == pytest.approx(float(r["hi"]))
    md = (out / "compare.md").read_text()
    assert "## Per point and method" in md and "| psnr A | psnr B | psnr B − A |" in md
    assert "+0.75 [0.50, 1.00]" in md  # tps, point 1, PSNR


def test_runs_of_one_folder_only_are_listed(folders):
    a, b = folders
    assert main(["compare", str(a), str(b), "--out", str(a.parent / "cmp")]) == 0
    rows = csv_rows(a.parent / "cmp" / "compare.csv")
    only_a = [r for r in rows if r["level"] == "only A"]
    only_b = [r for r in rows if r["level"] == "only B"]
    assert [(r["method"], r["setup"], r["seed"], r["status_a"]) for r in only_a] == [("nayar", "p0", "0", "ok")]
    assert [(r["method"], r["setup"], r["seed"], r["status_b"]) for r in only_b] == [("tps", "data/p1", "2", "ok")]
    md = (a.parent / "cmp" / "compare.md").read_text()
    assert "1 only in A, 1 only in B" in md and "## Only in A (1)" in md and "## Only in B (1)" in md
    assert "| nayar |" in md.split("## Only in A")[1] and "data/p1" in md.split("## Only in B")[1]


def test_without_per_image_scores_the_intervals_are_over_runs_or_none(tmp_path):
    a = make_folder(tmp_path / "a", [_row(0, "tps", s, 0.0, "p0") for s in (0, 1)], per_image=False)
    b = make_folder(tmp_path / "b", [_row(0, "tps", s, SHIFT[s], "p0") for s in (0, 1)])
    assert main(["compare", str(a), str(b)]) == 0
    rows = csv_rows(a / "compare-b" / "compare.csv")
    g = _scored(rows, "group", "psnr", method="tps")
    assert g["over"] == "runs" and float(g["diff"]) == pytest.approx(0.75)
    r = _scored(rows, "run", "psnr", method="tps", seed=0)
    assert (r["over"], r["lo"], r["hi"]) == ("none", "", "")
    md = (a / "compare-b" / "compare.md").read_text()
    assert "no interval in" in md and "over the paired test images" not in md


@pytest.mark.parametrize("case", ["missing", "no study.json", "same", "no match", "other kind"])
def test_bad_input_exits_2_with_one_line_naming_the_folder(folders, tmp_path, capsys, case):
    a, b = folders
    if case == "missing":
        args, named = [str(a), str(tmp_path / "nowhere")], "nowhere"
    elif case == "no study.json":
        (tmp_path / "empty").mkdir()
        args, named = [str(tmp_path / "empty"), str(b)], "empty"
    elif case == "same":
        args, named = [str(a), str(a.parent / "." / "a")], str(a)
    elif case == "no match":
        other = make_folder(tmp_path / "c", [_row(0, "nayar", 5, 0.0, "q0")])
        args, named = [str(b), str(other)], str(other)
    else:
        other = make_folder(tmp_path / "d", [{**_row(0, "tps", 0, 0.0, "p0"), "table": "1"}], kind="bench")
        args, named = [str(a), str(other)], str(other)
    assert main(["compare", *args]) == 2
    err = capsys.readouterr().err
    assert err.startswith("procam: error: ") and named in err and "expected" in err
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not list(tmp_path.glob("*/compare-*"))


def test_per_image_scores_pair_by_image_number_not_by_line_order(folders):
    """B's per_image.csv with its lines reversed pairs the same images: the same intervals."""
    a, b = folders
    assert main(["compare", str(a), str(b), "--out", str(a.parent / "in-order")]) == 0
    lines = (b / "per_image.csv").read_text().splitlines()
    (b / "per_image.csv").write_text("\n".join([lines[0], *reversed(lines[1:])]) + "\n")
    assert main(["compare", str(a), str(b), "--out", str(a.parent / "reversed")]) == 0
    assert csv_rows(a.parent / "reversed" / "compare.csv") == csv_rows(a.parent / "in-order" / "compare.csv")
    r = _scored(csv_rows(a.parent / "reversed" / "compare.csv"), "run", "psnr", method="tps", seed=1,
                **{AXIS: "0"})
    assert float(r["lo"]) == pytest.approx(SHIFT[1]) == pytest.approx(float(r["hi"]))


@pytest.mark.parametrize("case", ["dropped", "twice", "not a number"])
def test_per_image_runs_with_a_gap_or_a_repeat_are_refused(folders, capsys, case):
    a, b = folders
    lines = (b / "per_image.csv").read_text().splitlines()
    header = lines[0].split(",")
    image = header.index("image")
    if case == "dropped":  # the first run's first image
        body = lines[2:]
    elif case == "twice":
        body = [lines[1], *lines[1:]]
    else:
        cells = lines[1].split(",")
        cells[image] = "first"
        body = [",".join(cells), *lines[2:]]
    (b / "per_image.csv").write_text("\n".join([lines[0], *body]) + "\n")
    assert main(["compare", str(a), str(b)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("procam: error: ") and str(b / "per_image.csv") in err and "Traceback" not in err
    assert {"dropped": "lacks image(s) 1 (expected images 1 to 2)", "twice": "image 1 of run point 0",
            "not a number": "column image: expected a test image number"}[case] in err


def test_the_same_axes_in_another_order_are_matched(tmp_path, capsys):
    """A two-factor study and the same study with its axes listed the other way round: every run
    matched, A's axis order naming the columns."""
    values = {"k1": [0.0, 1.0], "k2": [5.0]}

    def folder(name: str, order: list[str], shift: float) -> Path:
        rows = []
        for p in (0, 1):
            row = _row(p, "tps", 0, shift, f"p{p}")
            del row[AXIS]
            rows.append({**row, "k1": values["k1"][p], "k2": values["k2"][0]})
        path = tmp_path / name
        path.mkdir()
        (path / "study.json").write_text(json.dumps({
            "name": name, "kind": "study", "methods": ["tps"], "seeds": [0],
            "axes": [{"key": k, "values": values[k]} for k in order]}))
        write_results(path, order, rows)
        return path

    a, b = folder("a", ["k1", "k2"], 0.0), folder("b", ["k2", "k1"], 0.5)
    assert main(["compare", str(a), str(b)]) == 0
    assert "2 run(s) matched, 0 only in A, 0 only in B" in capsys.readouterr().out
    rows = csv_rows(a / "compare-b" / "compare.csv")
    assert list(rows[0]).index("k1") < list(rows[0]).index("k2")
    run = _scored(rows, "run", "psnr", k1=1, k2=5)
    assert float(run["diff"]) == pytest.approx(0.5)
