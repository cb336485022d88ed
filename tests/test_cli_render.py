"""End to end: `procam render` writes the full layout, resumes without rewriting, fails cleanly."""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from compensation.cli import main
from sim.io import read_png

SETUP = """
name = "tiny"
[surface]
texture = "noise"
texture_resolution = 64
[projector]
resolution = [64, 64]
[camera]
resolution = [64, 64]
[render]
fidelity = "direct"
spp = 4
ambient_spp = 16
seed = {seed}
"""
ARGS = ["--size", "32", "--n-train", "4", "--n-test", "2", "--quiet"]


def _setup_file(tmp_path: Path, seed: int = 0, name: str = "tiny.toml") -> Path:
    path = tmp_path / name
    path.write_text(SETUP.format(seed=seed))
    return path


def _files(root: Path) -> dict[Path, int]:
    return {p: p.stat().st_mtime_ns for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def rendered(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("render")
    assert main(["render", str(_setup_file(tmp)), "--out", str(tmp / "data"), *ARGS]) == 0
    return tmp


def test_layout(rendered):
    data = rendered / "data"
    for split, n in (("ref", 126), ("train", 4), ("test", 2)):
        assert len(list((data / split).glob("img_*.png"))) == n
        for kind, shape in (("raw", (64, 64, 3)), ("warp", (32, 32, 3))):
            files = sorted((data / "tiny" / "cam" / kind / split).glob("img_*.png"))
            assert [f.name for f in files] == [f"img_{i:04d}.png" for i in range(1, n + 1)]
            assert read_png(files[0]).shape == shape
    assert read_png(data / "train" / "img_0001.png").shape == (32, 32, 3)
    assert read_png(data / "ref" / "img_0001.png").max() == 0
    assert read_png(data / "ref" / "img_0125.png").min() == 255
    meta = json.loads((data / "tiny" / "meta.json").read_text())
    assert meta["spp"] == 4 and meta["fidelity"] == "direct"
    assert meta["counts"] == {"ref": 126, "train": 4, "test": 2}
    assert set(meta["timings_s"]) >= {"render", "camera", "registration", "png"}
    # auto on a plane: the homography, unless the 32² view is too small for the checkerboard
    reg = meta["registration"]
    assert (reg["method"], reg["homography"]["status"]) in {
        ("homography", "ok"), ("exact", "checkerboard corners not found: exact map used")}
    assert reg == {**json.loads((data / "tiny" / "registration" / "registration.json").read_text()),
                   "ground_truth": "registration/exact_map.npz"}
    assert "seed = 0" in (data / "tiny" / "setup.toml").read_text()
    # a brighter projector frame gives a brighter capture (white ref vs black ref)
    white = read_png(data / "tiny" / "cam" / "warp" / "ref" / "img_0125.png").mean()
    black = read_png(data / "tiny" / "cam" / "warp" / "ref" / "img_0001.png").mean()
    assert white > black + 50


def test_resume_rewrites_nothing_and_finishes_interrupted(rendered):
    data = rendered / "data"
    before = _files(data)
    assert main(["render", str(rendered / "tiny.toml"), "--out", str(data), *ARGS]) == 0
    assert _files(data) == before
    # simulate a run killed mid-way: meta.json gone, a capture missing, a stray temp file
    victim = data / "tiny" / "cam" / "warp" / "train" / "img_0003.png"
    content = victim.read_bytes()
    victim.unlink()
    (data / "tiny" / "meta.json").unlink()
    (victim.parent / ".img_0004.png.abc.tmp").write_bytes(b"truncated")
    assert main(["render", str(rendered / "tiny.toml"), "--out", str(data), *ARGS]) == 0
    assert victim.read_bytes() == content  # same seed: bit-identical capture
    after = _files(data)
    changed = {p for p in before if p in after and after[p] != before[p]}
    assert changed <= {victim, data / "tiny" / "meta.json"}  # nothing else rewritten


def test_resume_compares_setups_not_their_formatting(rendered, tmp_path, capsys):
    """A setup.toml written differently (by hand, or by an older procam) that reads back to the
    same setup resumes; one of another setup is refused."""
    data = tmp_path / "data"
    shutil.copytree(rendered / "data", data)
    (data / "tiny" / "setup.toml").write_text(SETUP.format(seed=0))
    before = _files(data)
    assert main(["render", str(rendered / "tiny.toml"), "--out", str(data), *ARGS]) == 0
    assert _files(data) == before
    assert main(["render", str(_setup_file(tmp_path, seed=1)), "--out", str(data), *ARGS]) == 2
    assert "different setup" in capsys.readouterr().err
    assert _files(data) == before


def test_sizes_are_recorded_as_width_and_height_and_older_records_read(rendered):
    from sim.dataset import canonical_size

    data = rendered / "data"
    meta_file, marker = data / "tiny" / "meta.json", data / "frames.json"
    meta, frames = json.loads(meta_file.read_text()), json.loads(marker.read_text())
    assert (meta["width"], meta["height"]) == (32, 32) and "size" not in meta
    assert (frames["source"]["width"], frames["source"]["height"]) == (32, 32)
    assert canonical_size({"width": 64, "height": 48}) == (64, 48)
    assert canonical_size({"size": [64, 48]}) == (64, 48)  # older files: [width, height]
    assert canonical_size({}) is None
    # a root written before width/height were recorded resumes without re-rendering anything
    for path, record in ((meta_file, meta), (marker, frames["source"])):
        record["size"] = [record.pop("width"), record.pop("height")]
    meta_file.write_text(json.dumps(meta))
    marker.write_text(json.dumps(frames))
    before = {p: t for p, t in _files(data).items() if p != marker}
    assert main(["render", str(rendered / "tiny.toml"), "--out", str(data), *ARGS]) == 0
    assert {p: t for p, t in _files(data).items() if p != marker} == before
    assert json.loads(marker.read_text())["source"]["width"] == 32  # upgraded in place


def test_same_seed_same_bytes_other_seed_other_noise(rendered, tmp_path):
    assert main(["render", str(_setup_file(tmp_path, seed=0)), "--out", str(tmp_path / "a"), *ARGS]) == 0
    assert main(["render", str(_setup_file(tmp_path, seed=1, name="b.toml")), "--out",
                 str(tmp_path / "b"), *ARGS]) == 0
    rel = Path("tiny/cam/raw/test/img_0002.png")
    assert (tmp_path / "a" / rel).read_bytes() == (rendered / "data" / rel).read_bytes()
    a, b = read_png(tmp_path / "a" / rel), read_png(tmp_path / "b" / rel)
    assert 0 < np.abs(a.astype(int) - b.astype(int)).mean() < 10


def test_output_does_not_depend_on_the_worker_threads(rendered, tmp_path, monkeypatch):
    """The camera model, warp and PNG writes run on worker threads; one worker gives the same
    bytes as the default pool, capture for capture."""
    import sim.dataset

    monkeypatch.setattr(sim.dataset, "capture_workers", lambda: 1)
    assert main(["render", str(_setup_file(tmp_path)), "--out", str(tmp_path / "one"), *ARGS]) == 0
    assert json.loads((tmp_path / "one" / "tiny" / "meta.json").read_text())["capture_workers"] == 1
    pngs = sorted((rendered / "data" / "tiny" / "cam").rglob("*.png"))
    assert len(pngs) == 2 * (126 + 4 + 2)
    for p in pngs:
        twin = tmp_path / "one" / p.relative_to(rendered / "data")
        assert twin.read_bytes() == p.read_bytes(), twin


def test_bad_setup_writes_nothing(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text(SETUP.format(seed=0).replace("spp = 4", "spp = -4"))
    assert main(["render", str(bad), "--out", str(tmp_path / "data"), *ARGS]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "render.spp" in err
    assert not (tmp_path / "data").exists()


def test_console_script_help():
    exe = Path(sys.executable).with_name("procam")
    out = subprocess.run([str(exe), "render", "--help"], capture_output=True, text=True,
                         env={**os.environ}, check=True).stdout
    assert "--n-train" in out and "--size" in out
