"""`procam study`: every shipped study loads and expands into valid setups and runs; a tiny study
end to end writes study.json and results.csv with the contract's columns and sensible values,
resumes without fitting again, and keeps a failing job as a row."""
from __future__ import annotations

import csv
import json
import math
import re
import shutil
import tomllib
from pathlib import Path

import imageio.v3 as iio
import pytest

from helpers import csv_rows, refuse_renders, run_benchmark, tiny_toml
from compensation.cli import main
from compensation.experiments.jobs import RESULT_COLUMNS, run_status
from compensation.reports.summary import STATUSES
from compensation.experiments.studies import expand, load_study, with_overrides
from compensation.experiments.targets import TargetPolicy
from compensation.methods import METHODS
from sim.errors import ProcamError
from sim.setup.schema import SECTIONS

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = sorted((ROOT / "scenes" / "studies").glob("*.toml"))
BASE = tiny_toml()
STUDY = """
# Does more ambient light cost the per-pixel methods?
name = "tiny"
question = "ambient light vs per-pixel methods"
base = "base.toml"
methods = ["tps", "nayar"]
seeds = [0]
n_train = 8
n_test = 4
size = 32

[[axis]]
key = "ambient.radiance"
values = [0.02, 0.1]
label = "ambient radiance"
unit = ""
"""
SURROGATE_MARGIN_DB = 3.0
"""Surrogate PSNR of tps and nayar above uncompensated, per point (measured +3.7 to +5.4 dB)."""
CLOSED_LOOP_MARGIN_DB = 1.0
"""Closed-loop PSNR of tps, nayar and the oracle above y projected as is, per point (measured +1.7 to
+2.2 dB: most of the noise texture's dark pixels cannot reach the desired images)."""
REACHABLE_MARGIN_DB = 6.0
"""The same on the reachable pixels only (measured +9.6 to +13.3 dB)."""


def _setup_value(setup, section: str, key: str):
    """A setup key's value, in its section or in the surface's own options (``surface.shape``)."""
    table = getattr(setup, section)
    return getattr(table, key) if hasattr(table, key) else getattr(table.shape, key)


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_studies_load_and_expand(path):
    text = path.read_text()
    assert text.startswith("# procam study") and "Question:" in text
    data = tomllib.loads(text)
    if any(a["key"].split(".")[0] not in SECTIONS for a in data["axis"] if "." in a["key"]):
        pytest.skip(f"{path.name}: its setup section is not in this build")
    study = load_study(path)
    assert study.question and study.name == path.stem
    plan = expand(study)
    n_points = math.prod(len(a.values) for a in study.axes)
    assert len(plan.points) == n_points
    per_point = len(study.methods) * len(study.seeds) * (1 if any(a.key == "n_train" for a in study.axes)
                                                        else len(study.n_train))
    bases = len({name.split("__")[0] for name in plan.setups})  # a suite base gives several
    assert len(plan.runs) == n_points * per_point * bases
    setup_axes = [a for a in study.axes if a.on_setup]
    assert len(plan.setups) == (math.prod(len(a.values) for a in setup_axes) if setup_axes else 1) * bases
    for axis in setup_axes:  # every value reached its setup (a number broadcast to an RGB triple)
        section, key = axis.key.split(".")
        seen = {_setup_value(s, section, key) for s in plan.setups.values()}
        assert len(seen) == len(axis.values)
    assert len({r.run for r in plan.runs}) <= len(plan.runs)


MEASURED = sorted((ROOT / "benchmarks" / "studies").glob("*.toml"))


@pytest.mark.parametrize("path", MEASURED, ids=[p.stem for p in MEASURED])
def test_the_benchmark_copies_of_studies_load_and_reach_their_camera(path):
    """The shipped studies as measured on 2 cores (benchmarks/studies/: a 120x80 camera) load,
    expand to one setup per value, and every setup has the 120x80 camera."""
    study = load_study(path)
    plan = expand(study)
    assert study.name == path.stem and len(plan.setups) == len(study.axes[0].values)
    assert {tuple(_setup_value(s, "camera", "resolution")) for s in plan.setups.values()} == {(120, 80)}


def test_overrides_and_only():
    study = load_study(ROOT / "scenes" / "studies" / "train-size.toml")
    small = with_overrides(study, size=(32, 32), n_train=(8, 16), n_test=4, iters=5, seeds=1,
                           methods=("tps", "compennet"))
    plan = expand(small)
    assert [p.values for p in plan.points] == [{"n_train": 8}, {"n_train": 16}]
    assert {(r.method, r.n_train, r.seed) for r in plan.runs} == {
        (m, n, 0) for m in ("tps", "compennet") for n in (8, 16)}
    assert all(r.cfg.n_test == 4 for r in plan.runs)
    assert {r.cfg.options.iters for r in plan.runs if r.method == "compennet"} == {5}
    assert small.overrides["seeds"] == 1 and small.size == (32, 32)
    only = expand(with_overrides(load_study(ROOT / "scenes" / "studies" / "projector-defocus.toml"),
                                 only=("1", "*aperture-0p08")))
    assert sorted({r.point.index for r in only.runs}) == [1, 4]
    with pytest.raises(ProcamError, match="--only 9: matches no point"):
        expand(with_overrides(study, only=("9",)))


def test_profile_override(tmp_path):
    (tmp_path / "base.toml").write_text(BASE)
    head = 'base = "base.toml"\nmethods = ["compennet", "tps"]\n'
    axis = '[[axis]]\nkey = "ambient.radiance"\nvalues = [0.1]\n'
    (tmp_path / "study.toml").write_text(head + "n_test = 7\n" + axis)
    study = load_study(tmp_path / "study.toml", profile="faithful")
    assert (study.profile, study.size, study.n_train, study.n_test) == ("faithful", (256, 256), (125,), 7)
    assert study.overrides == {"profile": "faithful"}
    runs = {r.method: r.cfg for r in expand(study).runs}
    assert (runs["compennet"].options.patch, runs["compennet"].options.iters) == (64, 5000)
    assert runs["tps"].options.scale_invariant and runs["compennet"].profile == "faithful"
    assert load_study(tmp_path / "study.toml").size == (64, 64) and load_study(tmp_path / "study.toml").overrides == {}
    with pytest.raises(ProcamError, match="--profile 'fast': expected one of paper, quick, faithful"):
        load_study(tmp_path / "study.toml", profile="fast")


def test_only_in_the_study_file_selects_setups():
    plan = expand(load_study(ROOT / "scenes" / "studies" / "baseline-smoothing.toml"))
    assert sorted(plan.setups) == sorted(f"light1_{p}" for p in (
        "pos5_curves", "pos1_squares", "pos2_stripes", "pos3_lavender", "pos4_cloud", "pos5_cubes"))
    assert {r.run.rsplit("/", 1)[1] for r in plan.runs if r.method in ("nayar", "compennet")} == {
        "nayar-n125-seed0", "compennet-n125-seed0"}  # reference lines: one fit per setup


def test_a_study_on_a_suite_renders_the_suites_test_frames(tmp_path, monkeypatch):
    """As ``procam render`` and ``procam bench`` do: the base suite's ``test_frames``, else mixed."""
    import compensation.experiments.jobs as jobs
    from compensation.experiments.studies import run_study

    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "suite.toml").write_text('base = "base.toml"\ntest_frames = "photo"\n\n[[setup]]\nname = "a"\n')
    kinds = []

    def refuse(root, setup, spec, *args, **kwargs):
        kinds.append(spec.test_frames)
        raise ProcamError("simulated refusal")

    monkeypatch.setattr(jobs, "write_setup", refuse)
    for base, kind in (("suite.toml", "photo"), ("base.toml", "mixed")):
        study = STUDY.replace('base = "base.toml"', f'base = "{base}"').replace('name = "tiny"', f'name = "{kind}"')
        (tmp_path / f"{kind}.toml").write_text(study)
        run_study(load_study(tmp_path / f"{kind}.toml"), tmp_path / kind, progress=False)
        assert set(kinds) == {kind}, base
        kinds.clear()


def test_bad_only_is_named(tmp_path):
    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "study.toml").write_text(
        'base = "base.toml"\nmethods = ["nayar"]\nonly = "light1"\n[[axis]]\nkey = "ambient.radiance"\nvalues = [0.1]\n')
    with pytest.raises(ProcamError, match=r"study\.toml: only = 'light1': expected a list of setup-name patterns"):
        load_study(tmp_path / "study.toml")


def test_target_policy_key_and_override(tmp_path):
    (tmp_path / "base.toml").write_text(BASE)
    head = 'base = "base.toml"\nmethods = ["nayar"]\n'
    axis = '[[axis]]\nkey = "ambient.radiance"\nvalues = [0.1]\n'
    (tmp_path / "study.toml").write_text(head + 'target_policy = "image"\nout_of_reach = 0.05\n' + axis)
    study = load_study(tmp_path / "study.toml")
    assert study.target == TargetPolicy("image", 0.05)
    assert load_study(ROOT / "scenes" / "studies" / "projector-defocus.toml").target == TargetPolicy()
    changed = with_overrides(study, target_policy="none")
    assert changed.target == TargetPolicy("none", 0.05) and changed.overrides["target_policy"] == "none"
    assert with_overrides(study, out_of_reach=0.2).target == TargetPolicy("image", 0.2)
    (tmp_path / "bad.toml").write_text(head + 'target_policy = "clip"\n' + axis)
    with pytest.raises(ProcamError, match=r"bad\.toml: target policy 'clip': expected one of none, global, image"):
        load_study(tmp_path / "bad.toml")


def test_training_axis_shares_runs_of_methods_without_the_option():
    plan = expand(load_study(ROOT / "scenes" / "studies" / "iterations.toml"))
    tps = [r for r in plan.runs if r.method == "tps"]
    assert {r.run for r in tps} == {"runs/default/tps-n125-seed0"}  # one fit for 6 points, 3 seeds
    assert sorted({r.seed for r in tps}) == [0, 1, 2] and len(tps) == 6 * 3  # a row per point, seed
    assert "runs/default/compennet-n125-seed1-iters250" in {r.run for r in plan.runs}


def test_plain_colour_and_unseeded_fits_are_made_once():
    """TPS and Nayar fit the 125 plain colours, without a seed: one run each for the train-size
    study's 7 sizes and 3 seeds (loading the fewest pairs); the networks one per size and seed."""
    plan = expand(load_study(ROOT / "scenes" / "studies" / "train-size.toml"))
    for method in ("tps", "nayar"):
        runs = [r for r in plan.runs if r.method == method]
        assert {r.run for r in runs} == {f"runs/default/{method}-n125-seed0"} and len(runs) == 7 * 3
        assert {(r.cfg.n_train, r.cfg.seed) for r in runs} == {(8, 0)}
        assert sorted({r.n_train for r in runs}) == [8, 16, 32, 64, 125, 250, 500]
    assert len({r.run for r in plan.runs if r.method == "compennet"}) == 7 * 3
    plan = expand(with_overrides(load_study(ROOT / "scenes" / "studies" / "train-size.toml"),
                                 methods=("tps-textured", "compennet"), n_train=(8, 600)))
    textured = {(r.n_train, r.seed): r.run for r in plan.runs if r.method == "tps-textured"}
    assert textured[(8, 1)] == textured[(8, 2)] == "runs/default/tps-textured-n8-seed0"  # all pairs
    assert textured[(600, 1)] == "runs/default/tps-textured-n600-seed1"  # a seeded subset of 500


@pytest.mark.parametrize("axis, message", [
    ('key = "projector.aperture"\nvalues = [0.0, -0.01]',
     r"study\.toml \(point 1: projector\.aperture = -0\.01\): projector\.aperture = -0\.01: expected a number >= 0"),
    ('key = "projector.apperture"\nvalues = [0.0]', r"study\.toml.*projector\.apperture: unknown key"),
    ('key = "seed"\nvalues = [1, 2]', r"study\.toml: axis\[0\]\.key = 'seed': not a study axis"),
    ('key = "smoothing"\nvalues = [0.1]', r"study\.toml: axis 'smoothing': not an option of any method"),
    ('key = "ambient.radiance"\nvalues = [1, 1.0]', r"axis\[0\]\.values = \[1, 1\.0\]: expected distinct values"),
    # one setup twice: a number on a triple key is its triple; results.csv tells 6 digits apart
    ('key = "ambient.radiance"\nvalues = [[0.1, 0.1, 0.1], 0.1]', r"\.values = .*: expected distinct values"),
    ('key = "projector.aperture"\nvalues = [0.0, -0.0]', r"\.values = \[0\.0, -0\.0\]: expected distinct"),
    ('key = "camera.read_noise"\nvalues = [0.1234567, 0.1234568]', r"6 significant digits"),
])
def test_bad_axes_are_named(tmp_path, capsys, axis, message):
    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "study.toml").write_text(
        'base = "base.toml"\nmethods = ["nayar"]\n[[axis]]\n' + axis + "\n")
    with pytest.raises(ProcamError, match=message):
        expand(load_study(tmp_path / "study.toml"))
    assert main(["study", str(tmp_path / "study.toml"), "--out", str(tmp_path / "out")]) == 2
    assert "Traceback" not in capsys.readouterr().err
    assert not (tmp_path / "out" / "data").exists()  # nothing rendered


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("study")
    (tmp / "base.toml").write_text(BASE)
    (tmp / "tiny.toml").write_text(STUDY)
    assert main(["study", str(tmp / "tiny.toml"), "--out", str(tmp / "out"), "--quiet"]) == 0
    return tmp


@pytest.mark.slow
def test_study_folder(tiny):
    out = tiny / "out"
    record = json.loads((out / "study.json").read_text())
    assert {"name", "question", "kind", "base", "axes", "methods", "seeds", "n_train", "n_test", "size",
            "overrides", "versions", "setups", "created"} <= set(record)
    assert record["kind"] == "study" and record["name"] == "tiny"
    axis = record["axes"][0]
    assert {k: axis[k] for k in ("key", "values", "label", "unit")} == {
        "key": "ambient.radiance", "values": [0.02, 0.1], "label": "ambient radiance", "unit": ""}
    # the room light, measured in each point's renders: linear in the radiance, and near the
    # radiance relative to the projector's white (0.02: 2 %; the projector's falloff moves it)
    share = axis["physical"]
    assert (share["label"], share["unit"]) == ("room light", "% of projector white")
    assert 1.0 < share["values"][0] < 4.0 and share["values"][1] == pytest.approx(5 * share["values"][0], rel=1e-3)
    assert set(record["versions"]) == {"procam", "procam source", "torch", "mitsuba", "python"}
    assert record["versions"]["procam source"].startswith(("git ", "sha256 "))
    assert record["size"] == [32, 32] and record["n_train"] == [8] and record["seeds"] == [0]
    for name, path in record["setups"].items():
        setup = tomllib.loads((out / path).read_text())
        value = 0.02 if name.endswith("0p02") else 0.1
        assert setup["ambient"]["radiance"] == [value] * 3  # the scalar applies to R, G and B
    rows = csv_rows(out / "results.csv")
    with open(out / "results.csv", newline="") as f:
        assert next(csv.reader(f)) == ["point", "ambient.radiance", *RESULT_COLUMNS]
    assert [(r["point"], r["ambient.radiance"], r["method"], r["n_train"], r["seed"]) for r in rows] == [
        (p, v, m, "8", "0") for p, v in (("0", "0.02"), ("1", "0.1")) for m in ("tps", "nayar")]
    for r in rows:
        assert r["status"] == "ok" and r["error"] == "", r
        for key in ("psnr", "rmse", "ssim", "deltae", "cl_psnr", "cl_ssim", "cl_deltae", "unc_psnr",
                    "cl_unc_psnr", "oracle_psnr", "fit_s", "infer_ms"):
            assert math.isfinite(float(r[key])), (key, r)
        assert float(r["psnr"]) > float(r["unc_psnr"]) + SURROGATE_MARGIN_DB, r
        assert float(r["cl_psnr"]) > float(r["cl_unc_psnr"]) + CLOSED_LOOP_MARGIN_DB, r
        assert float(r["oracle_psnr"]) > float(r["cl_unc_psnr"]) + CLOSED_LOOP_MARGIN_DB, r
        assert float(r["cl_psnr_reachable"]) > float(r["cl_unc_psnr_reachable"]) + REACHABLE_MARGIN_DB, r
        assert 0 < float(r["cl_ssim"]) <= 1 and float(r["cl_deltae"]) > 0
        run = out / r["run"]
        assert r["run"] == f"runs/{r['setup']}/{r['method']}-n125-seed0"  # the plain colours
        metrics = json.loads((run / "metrics.json").read_text())
        assert float(r["cl_psnr"]) == pytest.approx(metrics["closed_loop"]["psnr"], rel=1e-5)
        captures = sorted(p.name for p in (run / "closed_loop").iterdir())
        assert captures == [f"img_{i:04d}.png" for i in range(1, 5)]
        assert iio.imread(run / "closed_loop" / "img_0001.png").shape == (32, 32, 3)
        assert r["undertrained"] == "0"  # tps and nayar log no falling loss
        assert float(r["ambient_share"]) == pytest.approx(share["values"][int(r["point"])] / 100, rel=1e-3)
        assert float(r["indirect_share"]) == 0.0  # a plane does not light itself
    # per_image.csv: every run's 4 test images, each score the PSNR of that image alone
    images = csv_rows(out / "per_image.csv")
    assert [(i["point"], i["method"], i["image"]) for i in images] == [
        (p, m, str(k)) for p in ("0", "1") for m in ("tps", "nayar") for k in range(1, 5)]
    for r in rows:
        mine = [i for i in images if (i["point"], i["method"]) == (r["point"], r["method"])]
        for key in ("psnr", "cl_psnr", "cl_unc_psnr", "oracle_psnr"):
            values = [float(i[key]) for i in mine]
            # the PSNR of the mean squared error lies between the images' PSNRs
            assert min(values) - 1e-3 <= float(r[key]) <= max(values) + 1e-3, (key, r, values)
    # the axis reached the renders: the capture of the black frame is lit by the ambient light alone
    black = {r["ambient.radiance"]: iio.imread(out / "data" / r["setup"] / "cam" / "warp" / "ref" / "img_0001.png")
             for r in rows}
    # 5x the radiance, sRGB-encoded (the projector's black level adds to both): measured 2.9x
    assert black["0.1"].mean() > 2 * black["0.02"].mean()


@pytest.mark.slow
def test_attribution_mixes_the_points_stages_and_reproduces_the_study_at_its_corners(tiny, tmp_path):
    """benchmarks/attribute.py: the study's own scores where fit, target and camera come from one
    point; the room light reaches the closed loop through the camera stage."""
    table = tmp_path / "attribution.csv"
    proc = run_benchmark("attribute.py", str(tiny / "out"), "--points", "0,1", "--methods", "tps,nayar",
                         "--csv", str(table))
    assert proc.returncode == 0, proc.stderr
    rows = csv_rows(table)
    study = {(r["point"], r["method"]): float(r["cl_psnr"]) for r in csv_rows(tiny / "out" / "results.csv")}
    assert sorted((r["method"], r["fit"], r["target"], r["camera"]) for r in rows) == sorted(
        (m, f, t, c) for m in ("tps", "nayar") for f in "01" for t in "01" for c in "01")
    score = {(r["method"], r["fit"], r["target"], r["camera"]): float(r["cl_psnr"]) for r in rows}
    for (method, fit, target, camera), psnr in score.items():
        if fit == target == camera:
            assert psnr == pytest.approx(study[(fit, method)], rel=1e-5)
        else:
            assert math.isfinite(psnr)
    # point 1 has 5x the room light: a fit learns its point's room light and takes it away, so a
    # compensation comes out too bright under the other point's camera or too dark
    for method in ("tps", "nayar"):
        for fit, other in ("01", "10"):
            for target in "01":
                assert score[(method, fit, target, other)] < score[(method, fit, target, fit)] - 1, score
    assert "main effects" in proc.stdout
    bad = run_benchmark("attribute.py", str(tiny / "out"), "--points", "0,7", "--methods", "tps")
    assert bad.returncode == 1 and "no finished run of point 7" in bad.stderr and "Traceback" not in bad.stderr


@pytest.mark.slow
def test_resume_fits_nothing_and_a_failure_is_a_row(tiny, monkeypatch, capsys):
    out = tiny / "out"
    args = ["study", str(tiny / "tiny.toml"), "--out", str(out), "--quiet"]
    stamps = {p: p.stat().st_mtime_ns for p in out.rglob("metrics.json")}
    before = csv_rows(out / "results.csv")
    capsys.readouterr()
    assert main(args) == 0
    assert "4 runs (0 trained, 4 reused)" in capsys.readouterr().out
    assert {p: p.stat().st_mtime_ns for p in out.rglob("metrics.json")} == stamps
    after = csv_rows(out / "results.csv")
    drop = ("fit_s", "infer_ms")  # the reused runs keep their own timings: the whole rows are equal
    assert before == after and all(r[k] for r in after for k in drop)

    def broken(self, data, cfg, progress=True, checkpoint=None):
        raise RuntimeError("simulated crash")

    monkeypatch.setattr(METHODS["nayar"], "fit", broken)
    failing = next(p.parent for p in stamps if p.parent.name == "nayar-n125-seed0"
                   and p.parent.parent.name.endswith("0p1"))
    shutil.rmtree(failing)
    assert main(args) == 0
    assert "3 reused), 1 of 4 result rows failed" in capsys.readouterr().out
    rows = csv_rows(out / "results.csv")
    assert [r["status"] for r in rows] == ["ok", "ok", "ok", "failed"]
    assert set(STATUSES) >= {r["status"] for r in rows}
    failed = rows[-1]
    assert "RuntimeError: simulated crash" in failed["error"] and failed["psnr"] == ""
    assert failed["unc_psnr"] and failed["oracle_psnr"]  # the setup's baselines are still there
    assert failed["run"] == f"runs/{failing.parent.name}/nayar-n125-seed0"


def test_run_status(tmp_path):
    ok = {"psnr": 20.0, "rmse": 0.1, "ssim": 0.7, "deltaE": 5.0, "final_loss": 0.1,
          "closed_loop": {"psnr": 18.0, "rmse": 0.12, "ssim": 0.6, "deltaE": 6.0}}
    assert run_status(ok, tmp_path) == ("ok", "")
    assert run_status({**ok, "ssim": float("nan")}, tmp_path) == ("nan", "not finite: ssim")
    assert run_status({**ok, "closed_loop": {**ok["closed_loop"], "psnr": float("nan")}},
                      tmp_path) == ("nan", "not finite: cl_psnr")
    assert run_status({**ok, "final_loss": float("inf")}, tmp_path)[0] == "diverged"
    (tmp_path / "loss.csv").write_text("iteration,loss,lr\n1,0.2,0.001\n2,0.25,0.001\n")
    assert run_status(ok, tmp_path) == ("ok", "")  # a loss up by a quarter: noise, not divergence
    (tmp_path / "loss.csv").write_text("iteration,loss,lr\n1,0.2,0.001\n2,0.9,0.001\n")
    assert run_status(ok, tmp_path) == ("diverged", "training loss grew above 1.5x its first value")


@pytest.mark.slow
def test_a_setup_that_cannot_render_fails_its_rows_only(tiny, monkeypatch, capsys):
    refuse_renders(monkeypatch, "0p1")
    assert main(["study", str(tiny / "tiny.toml"), "--out", str(tiny / "out"), "--quiet"]) == 0
    rows = csv_rows(tiny / "out" / "results.csv")
    assert [r["status"] for r in rows] == ["ok", "ok", "failed", "failed"]
    assert all(r["error"] == "render of base__ambient-radiance-0p1 failed: ProcamError: simulated refusal"
               for r in rows[2:])
    out = capsys.readouterr()
    assert "2 runs (0 trained, 2 reused), 2 of 4 result rows failed, 1 setups" in out.out
    assert "2 of 4 result rows failed" in out.err


def test_render_seeds_give_each_seed_its_dataset(tmp_path):
    (tmp_path / "base.toml").write_text(BASE.replace("[render]", "[render]\nseed = 5"))
    (tmp_path / "s.toml").write_text(STUDY.replace("seeds = [0]", "seeds = [0, 2]\nrender_seeds = true"))
    plan = expand(load_study(tmp_path / "s.toml"))
    assert {name: s.render.seed for name, s in plan.setups.items()} == {
        f"base__ambient-radiance-{v}__seed{k}": 5 + k for v in ("0p02", "0p1") for k in (0, 2)}
    assert all(r.setup.endswith(f"__seed{r.seed}") for r in plan.runs)
    assert {r.cfg.seed for r in plan.runs} == {0}  # TPS and Nayar take no seed: their datasets differ
    assert len(plan.runs) == 2 * 2 * 2  # points x methods x seeds


def test_render_seeds_shift_the_seed_each_point_sets(tmp_path):
    """An axis on render.seed, or [setup]'s render seed, is the seed the study's seeds shift, not
    replaced by the base's (two points of one dataset otherwise)."""
    (tmp_path / "base.toml").write_text(BASE.replace("[render]", "[render]\nseed = 5"))
    axis = STUDY.split("[[axis]]")[0].replace("seeds = [0]", "seeds = [0, 2]\nrender_seeds = true")
    (tmp_path / "s.toml").write_text(axis + '[[axis]]\nkey = "render.seed"\nvalues = [1, 7]\n')
    plan = expand(load_study(tmp_path / "s.toml"))
    assert {name: s.render.seed for name, s in plan.setups.items()} == {
        f"base__render-seed-{v}__seed{k}": v + k for v in (1, 7) for k in (0, 2)}
    (tmp_path / "s.toml").write_text(STUDY.replace("seeds = [0]", "seeds = [0, 2]\nrender_seeds = true")
                                     + "\n[setup]\nrender = { seed = 10 }\n")
    plan = expand(load_study(tmp_path / "s.toml"))
    assert sorted({s.render.seed for s in plan.setups.values()}) == [10, 12]
    (tmp_path / "s.toml").write_text(axis + '[[axis]]\nkey = "render.seed"\nvalues = [1, 3]\n')
    with pytest.raises(ProcamError, match=re.escape("1 + seed 2 and 3 + seed 0 are one render seed")):
        expand(load_study(tmp_path / "s.toml"))


@pytest.mark.slow
def test_provenance_names_the_source_revision(tmp_path):
    """In a git checkout the source is its commit; a copy of the sources outside any checkout is
    identified by their digest, which changes with any source file."""
    import shutil
    import subprocess
    import sys

    from compensation.experiments.runs import source_revision

    assert re.fullmatch(r"git [0-9a-f]{40}( \(modified\))?", source_revision())
    root = Path(__file__).resolve().parents[1]
    for package in ("sim", "compensation"):
        shutil.copytree(root / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__"))
    code = "from compensation.experiments.runs import source_revision; print(source_revision())"

    def revision() -> str:
        return subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env={"PYTHONPATH": str(tmp_path)},
                              capture_output=True, text=True, check=True).stdout.strip()

    first = revision()
    assert re.fullmatch(r"sha256 [0-9a-f]{16}", first)
    (tmp_path / "sim" / "layout.py").write_text((tmp_path / "sim" / "layout.py").read_text() + "\n# edited\n")
    assert revision() != first


@pytest.mark.slow
def test_surrogate_only_study_scores_no_closed_loop(tmp_path, capsys):
    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "s.toml").write_text(STUDY.replace("n_test = 4", "n_test = 4\nclosed_loop = false"))
    study = load_study(tmp_path / "s.toml")
    assert not study.closed_loop and load_study(ROOT / "scenes" / "studies" / "projector-defocus.toml").closed_loop
    assert main(["study", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out"), "--quiet",
                 "--only", "0", "--methods", "nayar"]) == 0
    out = tmp_path / "out"
    assert json.loads((out / "study.json").read_text())["closed_loop"] is False
    [row] = csv_rows(out / "results.csv")
    assert row["status"] == "ok", row
    assert float(row["psnr"]) > float(row["unc_psnr"]) + SURROGATE_MARGIN_DB
    assert row["cl_psnr"] == row["cl_unc_psnr"] == row["oracle_psnr"] == ""  # nothing re-projected
    assert not (out / row["run"] / "closed_loop").exists()
    assert "closed_loop" not in json.loads((out / row["run"] / "metrics.json").read_text())
    assert (out / "report.html").is_file() and "Traceback" not in capsys.readouterr().err
    # the command line turns the closed loop off for a study file that has it on
    assert not with_overrides(load_study(ROOT / "scenes" / "studies" / "projector-defocus.toml"),
                              closed_loop=False).closed_loop


def test_closed_loop_key_must_be_a_bool(tmp_path):
    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "s.toml").write_text(STUDY.replace("n_test = 4", 'n_test = 4\nclosed_loop = "no"'))
    with pytest.raises(ProcamError, match=r"s\.toml: closed_loop = 'no': expected true or false"):
        load_study(tmp_path / "s.toml")


def test_raw_key_is_a_bool_the_command_line_may_set(tmp_path):
    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "s.toml").write_text(STUDY.replace("n_test = 4", "n_test = 4\nraw = true"))
    assert load_study(tmp_path / "s.toml").raw
    shipped = load_study(ROOT / "scenes" / "studies" / "projector-defocus.toml")
    assert not shipped.raw and with_overrides(shipped, raw=True).raw
    (tmp_path / "s.toml").write_text(STUDY.replace("n_test = 4", 'n_test = 4\nraw = 1'))
    with pytest.raises(ProcamError, match=r"s\.toml: raw = 1: expected true or false"):
        load_study(tmp_path / "s.toml")


@pytest.mark.slow
def test_study_keeps_raw_captures_only_when_asked(tmp_path):
    """A study's datasets hold no raw captures unless its file or --raw asks; asked again with
    --raw, the finished setup renders them (its warped captures unchanged)."""
    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "s.toml").write_text(STUDY)
    argv = ["study", str(tmp_path / "s.toml"), "--out", str(tmp_path / "out"), "--quiet", "--only", "0",
            "--methods", "nayar", "--surrogate-only"]
    assert main(argv) == 0
    [setup] = [p.parent for p in (tmp_path / "out" / "data").glob("*/meta.json")]
    assert not (setup / "cam" / "raw").exists()
    assert json.loads((setup / "meta.json").read_text())["raw"] is False
    warped = {p: p.read_bytes() for p in (setup / "cam" / "warp").rglob("*.png")}
    assert main([*argv, "--raw"]) == 0
    assert json.loads((setup / "meta.json").read_text())["raw"] is True
    assert len(list((setup / "cam" / "raw").rglob("*.png"))) == len(warped) == 126 + 8 + 4
    assert {p: p.read_bytes() for p in (setup / "cam" / "warp").rglob("*.png")} == warped


def _study_file(tmp_path: Path, extra: str, size: int = 32) -> Path:
    """A one-axis study of the default setup with ``extra`` lines appended."""
    path = tmp_path / "hostile.toml"
    path.write_text(f'base = "{ROOT / "scenes" / "default.toml"}"\nmethods = ["tps", "compennet"]\n'
                    f'size = {size}\n{extra}\n[[axis]]\nkey = "ambient.radiance"\nvalues = [0.0, 0.1]\n')
    return path


@pytest.mark.parametrize("extra, size, message", [
    ('profile = ["quick"]', 32, "profile = ['quick']: expected one of"),
    ("[options]\ndevice = \"tpu\"", 32, "device 'tpu': expected 'auto', 'cpu' or 'cuda[:N]'"),
    ("[options]\npatch = 128", 64, "option patch = 128: expected at most the images' shorter side, 64"),
    ("[options]\ninit = \"/nowhere/run\"", 32, "option init = '/nowhere/run': no weights there"),
    ("[options]\ninit = 5", 32, "option init = 5: expected the path of a run folder"),
    ("[options]\namp = \"yes\"", 32, "option amp = 'yes': expected true or false"),
    ("[options]\nseed = 5", 32, "options.seed: not a training option of a study"),
    ("[options]\nn_train = 5", 32, "options.n_train: not a training option of a study"),
    ('only = ["0", "typo*"]', 32, "hostile.toml: only = 'typo*': matches no point number or setup"),
    # one value given twice: the axis would replace the other without a word
    ("[setup]\nambient = { radiance = [0.1, 0.1, 0.1] }", 32,
     "hostile.toml: setup.ambient.radiance: also given by the axis on ambient.radiance"),
    ("[setup]\nambient = { intensity = 0.5 }", 32,
     "setup.ambient.intensity: the room light is given as intensity and temperature or as radiance"),
    ('target_policy = "none"\nout_of_reach = 0.05', 32, "out_of_reach: the target policy 'none' maps no target"),
    ("", 18, "size 18x18 (W x H, the study's or --size): expected sides divisible by 4"),
])
def test_a_study_that_cannot_run_is_refused_before_anything_is_rendered(tmp_path, extra, size, message):
    """Each of these used to pass the study's checks and fail only when its runs were fitted,
    after the renders (or with a traceback)."""
    path = _study_file(tmp_path, extra, size)
    with pytest.raises(ProcamError, match=re.escape(message)):
        expand(load_study(path))


@pytest.mark.parametrize("axis, top, tail, where", [
    ("iters", "", "[options]\niters = 5", "options.iters"), ("n_train", "n_train = [8, 16]", "", "n_train")])
def test_a_training_value_given_as_an_axis_and_again_is_refused(tmp_path, axis, top, tail, where):
    path = tmp_path / "twice.toml"
    path.write_text(f'base = "{ROOT / "scenes" / "default.toml"}"\nmethods = ["compennet"]\n'
                    f'{top}\n[[axis]]\nkey = "{axis}"\nvalues = [8, 16]\n{tail}\n')
    with pytest.raises(ProcamError, match=re.escape(f"twice.toml: {where}: also given by the axis on {axis}")):
        load_study(path)


def test_a_study_file_saved_with_a_byte_order_mark_loads(tmp_path):
    path = _study_file(tmp_path, "")
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    assert load_study(path).axes[0].key == "ambient.radiance"


def test_whole_numbers_are_told_apart_in_full(tmp_path):
    """results.csv writes whole numbers in full (only decimals to 6 digits): two 8-digit seeds are
    two points."""
    path = tmp_path / "seeds.toml"
    path.write_text(f'base = "{ROOT / "scenes" / "default.toml"}"\nmethods = ["tps"]\n'
                    '[[axis]]\nkey = "render.seed"\nvalues = [20240101, 20240102]\n')
    assert len(expand(load_study(path)).setups) == 2


def test_an_option_no_method_takes_is_named_where_it_was_given(tmp_path):
    """--iters on a study of TPS alone names the flag; [options] iters left without the network by
    --methods names the file's key and the flag that chose the methods."""
    path = _study_file(tmp_path, "")
    with pytest.raises(ProcamError, match=re.escape("--iters 5: not an option of any method of the study "
                                                    "(tps, as --methods gives them)")):
        expand(with_overrides(load_study(path), iters=5, methods=("tps",)))
    path.write_text(path.read_text() + "[options]\niters = 5\n")
    with pytest.raises(ProcamError, match=re.escape("options.iters: not an option of any method of the "
                                                    "study (tps, as --methods gives them)")):
        expand(with_overrides(load_study(path), methods=("tps",)))


def test_a_study_whose_frames_cannot_be_held_names_its_file_and_writes_nothing(tmp_path, capsys):
    path = _study_file(tmp_path, "n_test = 1000000000")
    assert main(["study", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert f"{path}: projector frames:" in err and "n_test / --n-test 1000000000" in err
    assert "GiB in memory" in err and not (tmp_path / "out").exists()


def test_only_selects_each_point_of_a_training_axis():
    """Points on a training axis share one setup: each is still selected by its number."""
    study = load_study(ROOT / "scenes" / "studies" / "iterations.toml")
    for point in range(6):
        plan = expand(with_overrides(study, only=(str(point),)))
        assert {r.point.index for r in plan.runs if r.method == "compennet"} == {point}
    with pytest.raises(ProcamError, match=re.escape("iterations.toml: --only 6: matches no point number")):
        expand(with_overrides(study, only=("0", "6")))


def test_a_pix2pix_study_at_a_size_its_u_net_cannot_take_is_refused(tmp_path):
    path = _study_file(tmp_path, "", size=36).read_text().replace('"compennet"', '"pix2pix"')
    (tmp_path / "pix.toml").write_text(path)
    with pytest.raises(ProcamError, match=re.escape("36x36 pixels: pix2pix's U-Net needs width and height")):
        expand(load_study(tmp_path / "pix.toml"))
