"""`procam bench --data ROOT` without a suite on a dataset in the official benchmark's layout (nested
setups, only cam/warp, img_gray.png, no metadata): the setups are found, nothing is written into the
dataset, the closed loop is left out with the reason, the official outputs are written."""
from __future__ import annotations

import os

import numpy as np
import pytest

from compensation.cli import main
from compensation.data import load_setup_data
from compensation.experiments.runs import load_run
from helpers import csv_rows
from sim.io import read_png, to_uint8
from synthetic import make_dataset

SETUPS = ("light1/pos1/curves", "light1/pos2/squares")
ARGS = ["--methods", "compennet,tps", "--sizes", "8", "--tables", "1,2", "--n-test", "2",
        "--iters", "2", "--batch", "2", "--closed-loop", "--quiet"]

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def _files(root) -> set[str]:
    return {os.path.relpath(os.path.join(d, f), root) for d, _, fs in os.walk(root) for f in fs}


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("official")
    for name in SETUPS:  # Table 2 trains on 32 pairs
        make_dataset(tmp / "root", name=name, n_train=32, n_test=2, official=True)
    before = _files(tmp / "root")
    assert main(["bench", "--data", str(tmp / "root"), "--out", str(tmp / "out"), *ARGS]) == 0
    assert _files(tmp / "root") == before  # the dataset may be read-only: nothing is written there
    return tmp


@pytest.mark.slow
def test_found_setups_and_tables(bench):
    out = bench / "out"
    per = csv_rows(out / "per_setup.csv")
    assert sorted({r["setup"] for r in per}) == list(SETUPS)
    t1 = csv_rows(out / "table1.csv")
    assert [(r["method"], r["n_train"], r["setups"]) for r in t1] == [
        ("uncompensated", "-", "2"), ("compennet", "8", "2"), ("tps (λ = 0.01)", "8", "2")]
    # the paper's figures beside procam's: the uncompensated row has them, 8 pairs do not
    assert (t1[0]["paper PSNR"], t1[0]["paper RMSE"], t1[0]["paper SSIM"]) == ("12.1673", "0.4342", "0.4875")
    assert t1[1]["paper PSNR"] == "-" and float(t1[2]["PSNR"]) > float(t1[0]["PSNR"])
    assert all(float(r["deltaE"]) > 0 for r in t1)
    assert not any(k.startswith("CL ") for k in t1[0])  # no setup was simulated
    md = (out / "table1.md").read_text()
    assert "32² px" in md
    assert ("Closed loop left out for 2 setup(s) that procam did not simulate (no setup.toml, nothing to "
            f"project through): {', '.join(SETUPS)}.") in md
    t2 = csv_rows(out / "table2.csv")
    assert [(r["setups"], r["paper PSNR"]) for r in t2] == [("2", "19.6767"), ("0", "20.3423")]
    assert "No pre-trained run finished" in (out / "table2.md").read_text()


@pytest.mark.slow
def test_official_outputs(bench):
    """π†(x̃) of the test captures in cam/cmp/<tag>, π†(y) of the test images in prj/cmp/<tag>."""
    out = bench / "out"
    data = load_setup_data(bench / "root" / SETUPS[0], n_train=1, n_test=2)
    method, _ = load_run(out / "runs" / SETUPS[0] / "compennet-n8-seed0")
    for kind, inputs in (("cam", data.test.captures), ("prj", data.test.frames)):
        folder = out / "official" / SETUPS[0] / kind / "cmp" / "CompenNet_l1+ssim_8_2_2"
        assert sorted(os.listdir(folder)) == ["img_0001.png", "img_0002.png"]
        predicted = method.predict(inputs, data.surface).permute(0, 2, 3, 1).numpy()
        written = np.stack([read_png(folder / f) for f in sorted(os.listdir(folder))])
        assert np.array_equal(written, np.uint8(predicted * 255))  # the official code's conversion
        assert not np.array_equal(written, to_uint8(predicted))  # truncated, not rounded
    for setup in SETUPS:
        tags = {p.name for p in (out / "official" / setup / "prj" / "cmp").iterdir()}
        assert tags == {"CompenNet_l1+ssim_8_2_2", "TPS_125_lambda0.01", "CompenNet_l1+ssim_32_2_2"}  # TPS: 125 colours


def test_bench_without_suite_needs_the_data(tmp_path, capsys):
    assert main(["bench", "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert "bench without a suite: give the dataset root" in capsys.readouterr().err
    (tmp_path / "empty").mkdir()
    assert main(["bench", "--data", str(tmp_path / "empty"), "--out", str(tmp_path / "out"), "--quiet"]) == 2
    assert "no setup found (a setup is a folder holding cam/warp/)" in capsys.readouterr().err
