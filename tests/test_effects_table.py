"""benchmarks/effects.py's table from result rows: changes against the base row, runs of earlier calls
kept, and the residual misregistration of each row's dataset."""
from __future__ import annotations

import csv
import importlib.util
import json
import math
import re
import sys
from pathlib import Path

import pytest
from helpers import BENCHMARKS, run_benchmark

SCRIPT = BENCHMARKS / "effects.py"


@pytest.fixture(scope="module")
def effects():
    spec = importlib.util.spec_from_file_location("effects_script", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _write_results(path: Path, rows: list[dict]) -> None:
    cols = list(dict.fromkeys(k for r in rows for k in r))
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, cols)
        writer.writeheader()
        writer.writerows(rows)


def _row(setup: str, method: str, psnr: float, cl: str = "") -> dict:
    return {"setup": setup, "method": method, "status": "ok", "psnr": psnr, "cl_psnr": cl,
            "unc_psnr": 9.0 if setup == "effects_base" else 8.5, "cl_unc_psnr": "", "table": "1",
            "n_train": 125}


def _made_at(effects, **options):
    """A call's settings (:func:`made_at` at 16², 125 / 4 pairs)."""
    return lambda method: effects.made_at(method, 16, 125, 4, options)


def _kept(effects, setup: str, method: str, psnr: float, **options) -> dict:
    """A run an earlier call kept, with the settings it was made at."""
    return {**_row(setup, method, psnr), **_made_at(effects, **options)(method)}


def _meta(out: Path, setup: str, registration: dict) -> None:
    (out / "data" / setup).mkdir(parents=True)
    (out / "data" / setup / "meta.json").write_text(json.dumps({"registration": registration}))


def test_rows_are_changes_against_the_base_with_their_misregistration(effects, tmp_path):
    # an earlier call's runs (relief row, TPS only), kept in effects_runs.csv
    _write_results(tmp_path / "effects_runs.csv", [_kept(effects, "effects_01", "tps", 25.0)])
    # this call: the base and the relief row again with CompenNet, their datasets on disk
    _write_results(tmp_path / "results.csv", [_row("effects_base", "tps", 26.5, "26.0"),
                                              _row("effects_base", "compennet", 24.0, "25.5"),
                                              _row("effects_01", "compennet", 23.2, "24.9")])
    _meta(tmp_path, "effects_base", {"method": "exact", "homography": {"status": "not estimated"}})
    _meta(tmp_path, "effects_01", {"method": "homography", "homography": {
        "status": "estimated", "canonical_px": {"mean": 0.46, "p95": 1.13, "max": 2.9}}})
    rows = effects.merge_runs(tmp_path, _made_at(effects))
    assert {(r["setup"], r["method"]) for r in rows} == {
        ("effects_base", "tps"), ("effects_base", "compennet"), ("effects_01", "compennet"), ("effects_01", "tps")}
    lines = {line["setup"]: line for line in effects.table(rows)}
    base, relief = lines["effects_base"], lines["effects_01"]
    assert (base["misreg_mean"], base["misreg_p95"]) == (0.0, 0.0)  # registered by the exact map
    assert (relief["misreg_mean"], relief["misreg_p95"]) == (0.46, 1.13)
    assert base["tps"] == 26.5 and base["compennet CL"] == 25.5  # absolute in the base row
    assert relief["tps"] == pytest.approx(-1.5) and relief["compennet"] == pytest.approx(-0.8)
    assert relief["compennet CL"] == pytest.approx(-0.6) and math.isnan(relief["tps CL"])
    assert relief["uncompensated"] == pytest.approx(-0.5)
    # the kept store now holds the merged runs with the misregistration of this call's datasets
    stored = {(r["setup"], r["method"]): r for r in csv.DictReader(open(tmp_path / "effects_runs.csv"))}
    assert stored["effects_01", "compennet"]["misreg_p95"] == "1.13" and stored["effects_01", "tps"]["misreg_p95"] == ""
    effects.write(tmp_path, list(lines.values()), "how")
    md = (tmp_path / "effects.md").read_text()
    assert "| surface relief, registered by one homography | 0.46 / 1.13 | -0.50 / – | -1.50 / – |" in md
    assert md.count("| base (all effects off) | 0.00 / 0.00 | 9.00 / – | 26.50 / 26.00 |") == 1


def test_a_row_without_its_dataset_has_no_misregistration(effects, tmp_path):
    assert effects.misregistration(tmp_path, "effects_05") == {}
    _meta(tmp_path, "effects_05", {"method": "homography", "homography": {"status": "failed"}})
    assert effects.misregistration(tmp_path, "effects_05") == {}


def test_runs_kept_elsewhere_fill_the_rows_this_folder_lacks(effects, tmp_path):
    kept = tmp_path / "kept.csv"
    _write_results(kept, [_kept(effects, "effects_base", "tps", 26.0), _kept(effects, "effects_05", "tps", 25.5),
                          _kept(effects, "effects_05", "nayar", 24.0)])
    out = tmp_path / "out"
    out.mkdir()
    _write_results(out / "effects_runs.csv", [_kept(effects, "effects_05", "nayar", 24.4)])  # the folder's own
    _write_results(out / "results.csv", [_row("effects_base", "tps", 26.5), _row("effects_base", "nayar", 25.0)])
    made_at = _made_at(effects)
    for path in (kept, out / "effects_runs.csv"):
        effects.check_kept(path, made_at)
    merged = effects.merge_runs(out, made_at, kept)
    rows = {(r["setup"], r["method"]): r["psnr"] for r in merged}
    assert rows == {("effects_base", "tps"): "26.5", ("effects_base", "nayar"): "25.0",  # this call's
                    ("effects_05", "nayar"): "24.4", ("effects_05", "tps"): "25.5"}  # its folder's, then kept
    assert {(r["size"], r["n_test"]) for r in merged} == {("16", "4")}  # this call's runs carry their settings


def test_runs_made_at_other_settings_are_refused_by_name(effects, tmp_path):
    kept = tmp_path / "effects_runs.csv"
    _write_results(kept, [_kept(effects, "effects_base", "tps", 26.0),
                          _kept(effects, "effects_base", "compennet", 24.0, iters=2000, patch=64)])
    effects.check_kept(kept, _made_at(effects, iters=2000, patch=64))
    with pytest.raises(effects.ProcamError, match=r"effects_runs.csv: run effects_base/compennet was made at "
                                                  r"iters 2000 \(this call: 300\)"):
        effects.check_kept(kept, _made_at(effects, iters=300, patch=64))  # TPS takes no iterations: not refused
    with pytest.raises(effects.ProcamError, match=r"run effects_base/tps was made at size 16 \(this call: 256\)"):
        effects.check_kept(kept, lambda m: effects.made_at(m, 256, 125, 4, {}))
    _write_results(kept, [_row("effects_base", "tps", 26.0)])  # written before runs carried their settings
    with pytest.raises(effects.ProcamError, match="carries no record of the settings"):
        effects.check_kept(kept, _made_at(effects))


@pytest.mark.slow
def test_a_folder_the_bench_refuses_is_named_without_traceback(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    proc = run_benchmark("effects.py", "--out", str(tmp_path), "--size", "16", "--methods", "tps",
                         "--only", "effects_01")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert proc.stderr.startswith(f"effects: {tmp_path}: holds notes.txt")
    proc = run_benchmark("effects.py", "--out", str(tmp_path / "new"), "--keep", str(tmp_path / "none.csv"))
    assert proc.returncode == 2 and f"--keep {tmp_path / 'none.csv'}: no such file" in proc.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_a_kept_base_is_not_run_again_unless_a_method_lacks_it(effects, tmp_path):
    kept, out = tmp_path / "kept.csv", tmp_path / "out"
    out.mkdir()
    failed = {**_row("effects_base", "nayar", 0.0), "status": "failed"}
    _write_results(kept, [_row("effects_base", "tps", 26.5), _row("effects_base", "compennet", 24.0),
                          _row("effects_01", "nayar", 25.0), failed])
    assert effects.base_kept(out, kept, ("tps", "compennet"))
    assert not effects.base_kept(out, kept, ("tps", "nayar"))  # nayar's base run failed: run it again
    assert not effects.base_kept(out, kept, ("tps-textured",))
    assert not effects.base_kept(out, None, ("tps",))
    # the folder's own runs win over the kept ones, in the table as here
    _write_results(out / "effects_runs.csv", [{**_row("effects_base", "tps", 0.0), "status": "failed"},
                                              _row("effects_base", "nayar", 25.0)])
    assert not effects.base_kept(out, kept, ("tps",)) and effects.base_kept(out, kept, ("nayar", "compennet"))


def test_the_script_refuses_kept_runs_before_running_anything(effects, tmp_path, monkeypatch, capsys):
    kept, out = tmp_path / "kept.csv", tmp_path / "out"
    _write_results(kept, [_kept(effects, "effects_base", "tps", 26.0)])  # made at 16²
    ran = []
    monkeypatch.setattr(effects, "run_bench", lambda *a: ran.append(a))
    for rows, expected in (([], "was made at size 16 (this call: 32)"),
                           ([{"setup": "effects_base", "status": "ok"}], "a run without method"),
                           ([{**_row("effects_base", "foo", 1.0), "size": "32"}], "run effects_base/foo: unknown method")):
        if rows:
            _write_results(kept, rows)
        monkeypatch.setattr(sys, "argv", ["effects.py", "--out", str(out), "--size", "32", "--n-test", "4",
                                          "--keep", str(kept), "--only", "effects_05"])
        with pytest.raises(SystemExit) as exit_:
            effects.main()
        err = capsys.readouterr().err
        assert exit_.value.code == 1 and err.startswith(f"effects: {kept}: ") and expected in err, err
    assert ran == [] and not out.exists()


def test_a_setup_that_does_not_load_is_named_without_traceback(effects, tmp_path, monkeypatch, capsys):
    bad = tmp_path / "mine.toml"
    bad.write_text('name = "mine"\n[surface]\nink = 0.5\n')
    monkeypatch.setattr(sys, "argv", ["effects.py", "--out", str(tmp_path / "out"), "--size", "16",
                                      "--setup", str(bad)])
    with pytest.raises(SystemExit) as exit_:
        effects.main()
    err = capsys.readouterr().err
    assert exit_.value.code == 1 and err.startswith(f"effects: {bad}: ") and "surface.ink" in err, err
    assert "Traceback" not in err and not (tmp_path / "out").exists()


def test_runs_are_kept_only_beside_the_setup_they_were_made_from(effects, tmp_path, monkeypatch, capsys):
    out = tmp_path / "out"
    ran = []
    monkeypatch.setattr(effects, "run_bench", lambda suite, *a: ran.append([s.name for s in suite]))
    lighter = tmp_path / "lighter.toml"  # the default setup, printed lighter
    text = effects.scene_path("default").read_text()
    lighter.write_text(text.replace("ink_density = 0.75", "ink_density = 0.5").replace('name = "default"',
                                                                                     'name = "lighter"'))
    assert lighter.read_text() != text
    argv = ["effects.py", "--out", str(out), "--size", "16", "--n-test", "4", "--methods", "tps", "--only", "effects_05"]
    monkeypatch.setattr(sys, "argv", argv + ["--setup", str(lighter)])
    effects.main()
    capsys.readouterr()
    assert ran == [["effects_base", "effects_05"]]
    kept = effects.load_setup(lighter)
    assert effects.load_setup(out / effects.SETUP_FILE) == kept  # the resolved setup, beside the runs
    base = [s for s in effects.setups(kept) if s.name == "effects_base"][0]
    assert base.surface.ink_density == 0.5 and base.surface.shape.relief == 0.0  # its print, effects off
    _write_results(out / "effects_runs.csv", [_kept(effects, "effects_05", "tps", 25.0)])
    effects.check_setup(out / "effects_runs.csv", kept)
    monkeypatch.setattr(sys, "argv", argv)  # the default setup: the folder's runs are not its
    with pytest.raises(SystemExit) as exit_:
        effects.main()
    err = capsys.readouterr().err
    assert exit_.value.code == 1 and err.startswith(f"effects: {out / 'effects_runs.csv'}: its runs were made "
                                                     "from another setup")
    assert "surface.ink_density = 0.5 (this call: 0.75)" in err and "name" not in err.split("):")[1]
    assert len(ran) == 1
    (out / effects.SETUP_FILE).write_text("[surface\n")
    with pytest.raises(effects.ProcamError, match=f"{effects.SETUP_FILE}: not valid TOML"):
        effects.check_setup(out / "effects_runs.csv", kept)
    (out / effects.SETUP_FILE).unlink()  # runs without a record of their setup
    with pytest.raises(effects.ProcamError, match=f"no {effects.SETUP_FILE} beside it"):
        effects.check_setup(out / "effects_runs.csv", kept)


def test_every_effect_is_off_in_the_base_of_a_setup_that_turns_them_on(effects, tmp_path):
    mine = tmp_path / "processed.toml"
    text = effects.scene_path("default").read_text()
    for key, value in (("dynamic_lamp", "0.55"), ("adaptive_tone", "0.5")):
        text, n = re.subn(rf"^{key} = [0-9.]+", f"{key} = {value}", text, flags=re.M)
        assert n == 1, key
    mine.write_text(text)
    rows = {s.name: s for s in effects.setups(effects.load_setup(mine))}
    base = rows["effects_base"]
    assert base.projector.dynamic_lamp == 0 and base.camera.adaptive_tone == 0
    assert base.projector.flare == 0 and base.surface.shape.relief == 0
    assert rows["effects_17"].projector.dynamic_lamp == 0.55 and rows["effects_17"].camera.adaptive_tone == 0
    assert rows["effects_all"].camera.adaptive_tone == 0.5  # the setup itself


def test_a_setup_without_a_plane_is_refused_by_name(effects, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["effects.py", "--out", str(tmp_path / "out"), "--setup",
                                      str(effects.scene_path("corner"))])
    with pytest.raises(SystemExit) as exit_:
        effects.main()
    err = capsys.readouterr().err
    assert exit_.value.code == 1 and "surface.geometry = 'corner'" in err and "needs a plane surface" in err, err
    assert not (tmp_path / "out").exists()


def _images(setup: str, method: str, psnrs) -> list[dict]:
    return [{"setup": setup, "method": method, "image": i, "psnr": v, "cl_psnr": "", "table": "1",
             "n_train": 125} for i, v in enumerate(psnrs, start=1)]


def test_paired_differences_per_row_from_the_images_of_every_call(effects, tmp_path):
    kept, out = tmp_path / "kept" / "effects_runs.csv", tmp_path / "out"
    kept.parent.mkdir()
    out.mkdir()
    # kept: the base of both methods, and a TPS row the folder will run again
    _write_results(kept.with_name("effects_per_image.csv"),
                   _images("effects_base", "compennet", [26.0, 27.0, 25.0])
                   + _images("effects_base", "tps-textured", [26.5, 26.5, 26.5])
                   + _images("effects_17", "tps-textured", [1.0, 1.0, 1.0]))
    # this call: the dynamic-lamp row, CompenNet 1 dB ahead on two images of three, 2 dB behind on one
    _write_results(out / "per_image.csv", _images("effects_17", "compennet", [25.0, 25.0, 22.0])
                   + _images("effects_17", "tps-textured", [24.0, 24.0, 24.0]))
    images = effects.merge_images(out, kept)
    assert len(images) == 12 and {r["psnr"] for r in images if r["setup"] == "effects_17"
                                  and r["method"] == "tps-textured"} == {"24.0"}  # this call's replace the kept
    assert (out / "effects_per_image.csv").read_text().splitlines()[0] == ",".join(effects.IMAGE_COLUMNS)
    pairs = {(p["setup"], p["a"], p["b"]): p for p in effects.paired(images)}
    assert set(pairs) == {("effects_base", "compennet", "tps-textured"), ("effects_17", "compennet", "tps-textured")}
    lamp = pairs["effects_17", "compennet", "tps-textured"]
    assert lamp["mean"] == pytest.approx(0.0) and lamp["share"] == pytest.approx(2 / 3) and lamp["images"] == 3
    assert lamp["lo"] <= -0.9 and lamp["hi"] >= 0.9  # three images: the interval spans their spread
    assert pairs["effects_base", "compennet", "tps-textured"]["mean"] == pytest.approx(-0.5)
    effects.write(out, [], "how", list(pairs.values()))
    md = (out / "effects.md").read_text()
    assert "| projector dynamic lamp (depth 0.55, the measured one) | +0.00 (" in md and "67 %) | – | – |" in md
    assert (out / "effects_paired.csv").read_text().count("\n") == 3
