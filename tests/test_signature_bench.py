"""benchmarks/signature.py on a tiny two-setup suite: one bench per variant in its own folder, the
variant's values in the rendered setups, the table's means and paired differences recomputed
from the benches' own result files, and a finished variant kept from its result files alone."""
from __future__ import annotations

import csv
import json
import statistics
from pathlib import Path

import pytest
from helpers import run_benchmark, tiny_toml


def _rows(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


@pytest.mark.slow
def test_signature_per_variant(tmp_path):
    (tmp_path / "base.toml").write_text(tiny_toml("base", 16))
    suite = tmp_path / "two.toml"
    suite.write_text('base = "base.toml"\n\n[[setup]]\nname = "a"\nsurface = { texture_seed = 1 }\n\n'
                     '[[setup]]\nname = "b"\nsurface = { texture_seed = 2 }\n')
    out = tmp_path / "out"
    args = ["--suite", str(suite), "--setups", "a,b", "--variants", "default,white_boost", "--methods",
            "tps,tps-textured", "--profile", "quick", "--size", "16", "--n-train", "8", "--n-test", "3"]
    proc = run_benchmark("signature.py", "--out", str(out), *args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    # the variant's value reached the renderer, and only there
    for setup in ("a", "b"):
        assert "white_boost = 0.7" in (out / "white_boost" / "data" / setup / "setup.toml").read_text()
        assert "white_boost = 0.7" not in (out / "default" / "data" / setup / "setup.toml").read_text()
    table = {r["variant"]: r for r in _rows(out / "signature.csv")}
    assert list(table) == ["default", "white_boost"]
    for variant, row in table.items():
        results = [r for r in _rows(out / variant / "results.csv") if r["status"] == "ok"]
        assert row["setups"] == "2"
        for method in ("tps", "tps-textured"):
            mean = statistics.fmean(float(r["psnr"]) for r in results if r["method"] == method)
            assert float(row[f"PSNR {method}"]) == pytest.approx(mean, abs=0.006)
        images = _rows(out / variant / "per_image.csv")
        score = {(r["method"], r["setup"], r["image"]): float(r["psnr"]) for r in images}
        diffs = [score["tps-textured", s, i] - score["tps", s, i] for s in "ab" for i in ("1", "2", "3")]
        assert float(row["tps-textured − tps mean"]) == pytest.approx(statistics.fmean(diffs), abs=6e-4)
        assert float(row["tps-textured − tps lo"]) <= float(row["tps-textured − tps mean"]) \
            <= float(row["tps-textured − tps hi"])
        assert float(row["tps-textured − tps share"]) == pytest.approx(sum(d > 0 for d in diffs) / 6, abs=6e-4)
        assert row["compennet − tps-textured mean"] == ""  # not run: left blank
    # the white segment changes the captures, so the scores
    assert table["white_boost"]["PSNR tps"] != table["default"]["PSNR tps"]
    md = (out / "signature.md").read_text()
    assert "tps-textured − tps (paper +1.68)" in md and "compennet − tps-textured (paper +1.74)" in md
    assert "--variants default,white_boost" in md

    # a finished variant is its three result files: without its datasets and runs it is kept, not
    # rendered again, and the table comes out the same
    kept = tmp_path / "kept"
    for variant in table:
        (kept / variant).mkdir(parents=True)
        for name in ("study.json", "results.csv", "per_image.csv"):
            (kept / variant / name).write_bytes((out / variant / name).read_bytes())
    proc = run_benchmark("signature.py", "--out", str(kept), *args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    for variant in table:
        assert f"{variant}: finished in {kept / variant}, not run again" in proc.stdout
        assert not (kept / variant / "data").exists()
    assert _rows(kept / "signature.csv") == _rows(out / "signature.csv")

    # a variant made with other method options (a profile whose budget changed since) is not
    # finished: it is run again at the options the profile gives now
    record = json.loads((kept / "default" / "study.json").read_text())
    assert record["options"]["tps"]["smoothing"] > 0
    record["options"]["tps"]["smoothing"] *= 2
    (kept / "default" / "study.json").write_text(json.dumps(record))
    proc = run_benchmark("signature.py", "--out", str(kept), *args, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert "white_boost: finished" in proc.stdout and "default: finished" not in proc.stdout
    assert (kept / "default" / "data").is_dir() and not (kept / "white_boost" / "data").exists()
    assert json.loads((kept / "default" / "study.json").read_text())["options"] == \
        json.loads((out / "default" / "study.json").read_text())["options"]


@pytest.mark.slow
def test_unknown_variant_or_setup_is_refused_by_name(tmp_path):
    proc = run_benchmark("signature.py", "--out", str(tmp_path), "--variants", "default,glow")
    assert proc.returncode == 2 and "--variants: glow unknown; expected some of default, dynamic_lamp" in proc.stderr
    proc = run_benchmark("signature.py", "--out", str(tmp_path), "--setups", "light9_pos1_nowhere")
    assert proc.returncode == 2 and "--setups: light9_pos1_nowhere not in the suite paper" in proc.stderr
    assert not any(tmp_path.iterdir())  # nothing written


@pytest.mark.slow
def test_a_variant_folder_of_another_bench_is_refused_without_traceback(tmp_path):
    (tmp_path / "default").mkdir()
    (tmp_path / "default" / "study.json").write_text('{"name": "other", "kind": "bench"}')
    proc = run_benchmark("signature.py", "--out", str(tmp_path), "--variants", "default", "--setups",
                         "light1_pos1_squares")
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "signature: " in proc.stderr and "holds the bench 'other'" in proc.stderr
    assert sorted(p.name for p in tmp_path.rglob("*")) == ["default", "study.json"]


@pytest.mark.parametrize("args, message", [
    (["--suite", "nosuch"], "signature: nosuch: no such setup file"),
    (["--profile", "nonsense"], "signature: profile 'nonsense': choose one of"),
    (["--methods", ","], "signature: --methods ',': expected some of"),
    (["--methods", "tps,magic"], "signature: unknown method 'magic'"),
    (["--variants", ","], "--variants ',': expected some of default"),
    (["--setups", ","], "--setups ',': expected setups of the suite paper"),
])
def test_bad_arguments_exit_2_with_one_line(tmp_path, args, message):
    proc = run_benchmark("signature.py", "--out", str(tmp_path / "out"), *args, cwd=tmp_path)
    assert proc.returncode == 2 and message in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "out").exists()
