"""`procam bench` end to end on a tiny 2-setup suite: all three tables, resumable, failures kept apart."""
from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import imageio.v3 as iio
import pytest

from compensation.cli import main
from compensation.methods import METHODS

BASE = """
name = "base"
[surface]
texture = "{texture}"
texture_resolution = 64
[projector]
resolution = [64, 64]
[camera]
resolution = [64, 64]
[render]
fidelity = "direct"
spp = 4
ambient_spp = 16
"""
SUITE = """
base = "base.toml"
[[setup]]
name = "s1"
surface = { texture = "noise", texture_seed = 1 }
[[setup]]
name = "s2"
surface = { texture = "stripes", texture_seed = 2 }
ambient = { radiance = [0.08, 0.08, 0.08] }
"""
METHOD_LIST = "compennet,compennet-nosurf,tps,tps-textured,nayar,pix2pix"
ARGS = ["--size", "32", "--sizes", "4,8", "--n-test", "2", "--iters", "3", "--batch", "2", "--quiet"]


def _bench(tmp: Path, *extra: str) -> int:
    return main(["bench", str(tmp / "suite.toml"), "--out", str(tmp / "bench"), "--white",
                 str(tmp / "white.toml"), "--methods", METHOD_LIST, *ARGS, *extra])


@pytest.fixture(scope="module")
def bench(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("bench")
    (tmp / "base.toml").write_text(BASE.format(texture="noise"))
    (tmp / "white.toml").write_text(BASE.format(texture="uniform").replace('"base"', '"white"'))
    (tmp / "suite.toml").write_text(SUITE)
    assert _bench(tmp, "--closed-loop") == 0
    return tmp


def _rows(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


def test_all_tables_and_methods(bench):
    out = bench / "bench"
    t1 = _rows(out / "table1.csv")
    names = {r["method"] for r in t1}
    assert {"uncompensated", *METHOD_LIST.split(",")} <= names
    assert any(n.startswith("iterative refinement (8 it.") for n in names)
    for r in t1:
        if r["method"] in METHOD_LIST.split(","):
            assert r["setups"] == "2" and float(r["PSNR"]) > 0 and float(r["CL PSNR"]) > 0
            assert float(r["CL PSNR reachable"]) > 0
    unc = next(r for r in t1 if r["method"] == "uncompensated")  # y projected as is: closed loop too
    assert float(unc["CL PSNR"]) > 0 and unc["infer ms/frame"] == "-"
    for s in ("s1", "s2"):  # the reachable masks, the (2) test images side by side
        assert iio.imread(out / "reachable" / f"{s}.png").shape == (32, 2 * 32, 3)
    assert len(_rows(out / "table2.csv")) == 2
    assert [r["method"] for r in _rows(out / "table3.csv")] == [
        f"CompenNet, loss {loss}" for loss in ("l1", "l2", "ssim", "l1+ssim")]
    for name in ("table1", "table2", "table3"):
        assert (out / f"{name}.md").read_text().startswith(f"# Table {name[-1]}")
    per = _rows(out / "per_setup.csv")
    assert {r["setup"] for r in per} == {"s1", "s2"}
    assert json.loads((out / "failures.json").read_text())["failures"] == []
    assert "correlation" in (out / "table1.md").read_text()


def test_resume_trains_nothing_and_failures_are_isolated(bench, monkeypatch):
    metrics = sorted((bench / "bench" / "runs").rglob("metrics.json"))
    before = {p: p.stat().st_mtime_ns for p in metrics}
    assert _bench(bench) == 0
    assert {p: p.stat().st_mtime_ns for p in metrics} == before

    def broken(self, data, cfg, progress=True):
        raise RuntimeError("simulated crash")

    monkeypatch.setattr(METHODS["compennet-nosurf"], "fit", broken)
    for run in (bench / "bench" / "runs").glob("s1/compennet-nosurf-*"):
        shutil.rmtree(run)
    assert _bench(bench) == 0
    failures = json.loads((bench / "bench" / "failures.json").read_text())["failures"]
    assert {(f["setup"], f["method"]) for f in failures} == {("s1", "compennet-nosurf")}
    assert all("simulated crash" in f["error"] for f in failures)
    nosurf = [r for r in _rows(bench / "bench" / "table1.csv") if r["method"] == "compennet-nosurf"]
    assert {r["setups"] for r in nosurf} == {"1"}  # s2 still counted
