"""End to end: `procam render` writes the full layout, resumes without rewriting, fails cleanly."""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from compensation.cli import main
from helpers import TINY_RENDER, tiny_setup_file, tiny_toml
from sim.dataset import read_raw
from sim.errors import DatasetError
from sim.io import read_png


def _files(root: Path) -> dict[Path, int]:
    return {p: p.stat().st_mtime_ns for p in sorted(root.rglob("*")) if p.is_file()}


def _copy(tiny_render: Path, tmp_path: Path) -> Path:
    """A copy of the tiny rendered dataset's root, to write into."""
    return Path(shutil.copytree(tiny_render / "data", tmp_path / "data"))


def test_layout(tiny_render):
    data = tiny_render / "data"
    for split, n in (("ref", 126), ("train", 2), ("test", 1)):
        assert len(list((data / split).glob("img_*.png"))) == n
        files = sorted((data / "tiny" / "cam" / "warp" / split).glob("img_*.png"))
        assert [f.name for f in files] == [f"img_{i:04d}.png" for i in range(1, n + 1)]
        assert read_png(files[0]).shape == (32, 32, 3)
    assert not (data / "tiny" / "cam" / "raw").exists()  # kept only with --raw
    assert read_png(data / "train" / "img_0001.png").shape == (32, 32, 3)
    assert read_png(data / "ref" / "img_0001.png").max() == 0
    assert read_png(data / "ref" / "img_0125.png").min() == 255
    meta = json.loads((data / "tiny" / "meta.json").read_text())
    assert meta["spp"] == 4 and meta["fidelity"] == "direct"
    assert meta["counts"] == {"ref": 126, "train": 2, "test": 1} and meta["raw"] is False
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


@pytest.fixture(scope="module")
def raw_render(tiny_render, tmp_path_factory) -> Path:
    """The tiny setup rendered with --raw: its root folder."""
    root = tmp_path_factory.mktemp("raw") / "data"
    assert main(["render", str(tiny_render / "tiny.toml"), "--out", str(root), *TINY_RENDER, "--raw"]) == 0
    return root


def test_raw_keeps_the_camera_captures_and_changes_nothing_else(tiny_render, raw_render):
    """--raw adds cam/raw at camera resolution, records it, and every other file holds the same
    bytes as without it (the warped captures too)."""
    plain = tiny_render / "data"
    for split, n in (("ref", 126), ("train", 2), ("test", 1)):
        files = sorted((raw_render / "tiny" / "cam" / "raw" / split).glob("img_*.png"))
        assert [f.name for f in files] == [f"img_{i:04d}.png" for i in range(1, n + 1)]
        assert read_png(files[0]).shape == (64, 64, 3)
        assert np.array_equal(read_raw(raw_render / "tiny", split, n), read_png(files[-1]))
    assert json.loads((raw_render / "tiny" / "meta.json").read_text())["raw"] is True
    with_raw = {p.relative_to(raw_render): p for p in raw_render.rglob("*") if p.is_file()}
    without = {p.relative_to(plain): p for p in plain.rglob("*") if p.is_file()}
    assert {r for r in with_raw if r.parts[:3] != ("tiny", "cam", "raw")} == set(without)
    warped = [r for r in without if r.parts[:3] == ("tiny", "cam", "warp")]
    assert len(warped) == 126 + 2 + 1
    for rel in without:
        if rel.name not in ("meta.json", ".lock"):
            assert with_raw[rel].read_bytes() == without[rel].read_bytes(), rel


@pytest.mark.slow
def test_raw_is_not_what_makes_a_dataset_different(tiny_render, raw_render, tmp_path):
    """A setup finished with its raw captures is finished without --raw (nothing rendered, nothing
    written); one finished without them renders its captures again for --raw, the warped ones to
    the same bytes."""
    root = Path(shutil.copytree(raw_render, tmp_path / "with"))
    before = _files(root)
    assert main(["render", str(tiny_render / "tiny.toml"), "--out", str(root), *TINY_RENDER]) == 0
    assert _files(root) == before
    root = _copy(tiny_render, tmp_path)
    assert main(["render", str(tiny_render / "tiny.toml"), "--out", str(root), *TINY_RENDER, "--raw"]) == 0
    meta = json.loads((root / "tiny" / "meta.json").read_text())
    assert meta["raw"] is True and meta["captures_this_run"] == 126 + 2 + 1
    for path in sorted(raw_render.rglob("*.png")):
        assert (root / path.relative_to(raw_render)).read_bytes() == path.read_bytes(), path


def test_raw_captures_asked_of_a_setup_without_them_are_refused_by_name(tiny_render, raw_render):
    folder = tiny_render / "data" / "tiny"
    with pytest.raises(DatasetError) as info:
        read_raw(folder, "test", 1)
    message = str(info.value)
    assert str(folder / "cam" / "raw" / "test") in message and "--raw" in message
    assert "rendered without its raw captures" in message
    with pytest.raises(DatasetError, match="no such file.*--raw"):
        read_raw(raw_render / "tiny", "test", 2)


def test_resume_rewrites_nothing_and_finishes_interrupted(tiny_render, tmp_path):
    data = _copy(tiny_render, tmp_path)
    before = _files(data)
    assert main(["render", str(tiny_render / "tiny.toml"), "--out", str(data), *TINY_RENDER]) == 0
    assert _files(data) == before
    # simulate a run killed mid-way: meta.json gone, a capture missing, a stray temp file
    victim = data / "tiny" / "cam" / "warp" / "train" / "img_0002.png"
    content = victim.read_bytes()
    victim.unlink()
    (data / "tiny" / "meta.json").unlink()
    (victim.parent / ".img_0002.png.abc.tmp").write_bytes(b"truncated")
    assert main(["render", str(tiny_render / "tiny.toml"), "--out", str(data), *TINY_RENDER]) == 0
    assert victim.read_bytes() == content  # same seed: bit-identical capture
    after = _files(data)
    changed = {p for p in before if p in after and after[p] != before[p]}
    assert changed <= {victim, data / "tiny" / "meta.json"}  # nothing else rewritten


def test_resume_compares_setups_not_their_formatting(tiny_render, tmp_path, capsys):
    """A setup.toml written differently (by hand, or by an older procam) that reads back to the
    same setup resumes; one of another setup is refused."""
    data = _copy(tiny_render, tmp_path)
    (data / "tiny" / "setup.toml").write_text(tiny_toml("tiny", 64, render={"seed": 0}))
    before = _files(data)
    assert main(["render", str(tiny_render / "tiny.toml"), "--out", str(data), *TINY_RENDER]) == 0
    assert _files(data) == before
    other = tiny_setup_file(tmp_path, render={"seed": 1})
    assert main(["render", str(other), "--out", str(data), *TINY_RENDER]) == 2
    assert "different setup" in capsys.readouterr().err
    assert _files(data) == before


def test_sizes_are_recorded_as_width_and_height_and_older_records_read(tiny_render, tmp_path):
    from sim.dataset import canonical_size

    data = _copy(tiny_render, tmp_path)
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
    assert main(["render", str(tiny_render / "tiny.toml"), "--out", str(data), *TINY_RENDER]) == 0
    assert {p: t for p, t in _files(data).items() if p != marker} == before
    assert json.loads(marker.read_text())["source"]["width"] == 32  # upgraded in place


@pytest.mark.slow
def test_same_seed_same_bytes_other_seed_other_noise(tiny_render, tmp_path):
    for file, seed, out in (("a.toml", 0, "a"), ("b.toml", 1, "b")):
        setup = tiny_setup_file(tmp_path, file, render={"seed": seed})
        assert main(["render", str(setup), "--out", str(tmp_path / out), *TINY_RENDER]) == 0
    rel = Path("tiny/cam/warp/test/img_0001.png")
    assert (tmp_path / "a" / rel).read_bytes() == (tiny_render / "data" / rel).read_bytes()
    a, b = read_png(tmp_path / "a" / rel), read_png(tmp_path / "b" / rel)
    assert 0 < np.abs(a.astype(int) - b.astype(int)).mean() < 10


@pytest.mark.slow
def test_output_does_not_depend_on_the_worker_threads(tiny_render, tmp_path, monkeypatch):
    """The camera model, warp and PNG writes run on worker threads; one worker gives the same
    bytes as the default pool, capture for capture."""
    import sim.dataset

    monkeypatch.setattr(sim.dataset, "capture_workers", lambda: 1)
    assert main(["render", str(tiny_setup_file(tmp_path)), "--out", str(tmp_path / "one"),
                 *TINY_RENDER]) == 0
    assert json.loads((tmp_path / "one" / "tiny" / "meta.json").read_text())["capture_workers"] == 1
    pngs = sorted((tiny_render / "data" / "tiny" / "cam").rglob("*.png"))
    assert len(pngs) == 126 + 2 + 1
    for p in pngs:
        twin = tmp_path / "one" / p.relative_to(tiny_render / "data")
        assert twin.read_bytes() == p.read_bytes(), twin


def test_bad_setup_writes_nothing(tmp_path, capsys):
    bad = tiny_setup_file(tmp_path, "bad.toml", render={"spp": -4})
    assert main(["render", str(bad), "--out", str(tmp_path / "data"), *TINY_RENDER]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "render.spp" in err
    assert not (tmp_path / "data").exists()


@pytest.mark.slow
def test_console_script_help():
    exe = Path(sys.executable).with_name("procam")
    out = subprocess.run([str(exe), "render", "--help"], capture_output=True, text=True,
                         env={**os.environ}, check=True).stdout
    assert "--n-train" in out and "--size" in out


@pytest.mark.slow
def test_photo_test_frames_change_the_test_split_only(tiny_render, tmp_path, capsys):
    """--test-frames photo: the same training frames, natural test frames, recorded in frames.json;
    a root of mixed test frames refuses them (its frames are made otherwise)."""
    root = tmp_path / "photo"
    argv = ["render", str(tiny_render / "tiny.toml"), "--out", str(root), *TINY_RENDER]
    assert main([*argv, "--test-frames", "photo"]) == 0
    mixed = tiny_render / "data"
    for split, same in (("ref", True), ("train", True), ("test", False)):
        for a in sorted((mixed / split).glob("img_*.png")):
            assert np.array_equal(read_png(a), read_png(root / split / a.name)) == same, (split, a.name)
    assert json.loads((root / "frames.json").read_text())["source"]["test_frames"] == "photo"
    assert "test_frames" not in json.loads((mixed / "frames.json").read_text())["source"]
    copy = _copy(tiny_render, tmp_path)
    assert main(["render", str(tiny_render / "tiny.toml"), "--out", str(copy), *TINY_RENDER,
                 "--test-frames", "photo"]) == 2
    assert "frames.json" in capsys.readouterr().err


@pytest.mark.slow
def test_a_suites_test_frames_are_the_default_of_the_flag(tiny_render, tmp_path):
    """A suite's ``test_frames`` is what ``--test-frames`` takes when not given; the flag overrides it."""
    (tmp_path / "tiny.toml").write_bytes((tiny_render / "tiny.toml").read_bytes())
    suite = tmp_path / "suite.toml"
    suite.write_text('base = "tiny.toml"\ntest_frames = "photo"\n\n[[setup]]\nname = "tiny"\n')
    for out, flag, kind in (("suite", [], "photo"), ("flag", ["--test-frames", "mixed"], None)):
        assert main(["render", str(suite), "--out", str(tmp_path / out), *TINY_RENDER, *flag]) == 0
        assert json.loads((tmp_path / out / "frames.json").read_text())["source"].get("test_frames") == kind
    mixed = read_png(tiny_render / "data" / "test" / "img_0001.png")
    assert np.array_equal(read_png(tmp_path / "flag" / "test" / "img_0001.png"), mixed)
    assert not np.array_equal(read_png(tmp_path / "suite" / "test" / "img_0001.png"), mixed)


def test_every_command_prints_its_help():
    """Each subcommand's help is formatted without error: help built from docstrings may hold a
    ``%``, which argparse would read as a format directive."""
    from compensation.cli import build_parser

    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    assert {"render", "train", "bench", "study"} <= set(commands.choices)
    for name, sub in commands.choices.items():
        text = sub.format_help()
        assert text.startswith("usage: procam " + name), name
    assert "80 % of iters" in " ".join(commands.choices["train"].format_help().split())
