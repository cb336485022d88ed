"""Every command's output aimed at its own inputs and at a folder of the user's files: no file that
was there is written over, changed or deleted; the command either refuses at once (exit 2, one
line naming the path and what was expected, no traceback, nothing written) or writes only its own
new files where it should."""
from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pytest

from compensation.cli import build_parser, main
from helpers import failing_study_file, tiny_toml
from sim.io import write_png
from synthetic import make_dataset

TRAIN = ["--n-train", "8", "--n-test", "4", "--quiet"]
def _image(path: Path, value: int) -> Path:
    write_png(path, np.full((32, 32, 3), value, np.uint8))
    return path


@pytest.fixture(scope="module")
def workspace(tmp_path_factory) -> Path:
    """The inputs of every command and a folder of the user's files (built once, copied per test):

    - ``inputs/``: a setup file, one beside a setup folder of its name, two studies
      (:func:`helpers.failing_study_file`) and their base, a folder of the user's projector frames
      named as a dataset's ``ref`` folder;
    - ``data/synth``: a synthetic dataset (its root without ``frames.json``, as a dataset made
      elsewhere); ``nayar`` and ``compennet``: runs trained on it;
    - ``study`` and ``study2``: the folder of a study (all its renders refused) and a copy;
    - ``mine/``: the user's files, among them names procam writes (``results.csv``,
      ``report.html``) and a dataset's frames (``train/img_0001.png``);
    - ``official/tiny/cam``: captures made elsewhere, in a setup folder named as a setup.
    """
    ws = tmp_path_factory.mktemp("outputs")
    inputs = ws / "inputs"
    inputs.mkdir()
    (inputs / "tiny.toml").write_text(tiny_toml("tiny", 16, registration={"method": "exact"}))
    (inputs / "tiny").mkdir()
    (inputs / "tiny" / "setup.toml").write_text(tiny_toml("tiny", 16, registration={"method": "exact"}))
    failing_study_file(inputs, "other")
    study = failing_study_file(inputs)
    for i, value in enumerate((40, 90, 140, 190), start=1):
        _image(inputs / "ref" / f"frame{i}.png", value)
    setup = make_dataset(ws / "data")
    assert main(["train", str(setup), "--method", "nayar", "--out", str(ws / "nayar"), *TRAIN]) == 0
    assert main(["train", str(setup), "--method", "compennet", "--iters", "2", "--batch", "4",
                 "--out", str(ws / "compennet"), *TRAIN]) == 0
    assert main(["study", str(study), "--out", str(ws / "study"), "--quiet"]) == 2
    shutil.copytree(ws / "study", ws / "study2")
    mine = ws / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("meeting at 10")
    (mine / "thesis.tex").write_text("years of work")
    (mine / "results.csv").write_text("trial,score\n1,0.5\n")
    (mine / "report.html").write_text("<p>my report</p>")
    _image(mine / "photo.png", 120)
    _image(mine / "train" / "img_0001.png", 60)
    _image(ws / "official" / "tiny" / "cam" / "warp" / "train" / "img_0001.png", 70)
    return ws


def _hashes(root: Path) -> dict[str, str]:
    """Every file under ``root``: relative path -> SHA-256 of its bytes."""
    return {p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


S = "@data/synth"
Y = "@data/test/img_0001.png"
R = ["--size", "16", "--n-train", "2", "--n-test", "1", "--quiet"]
CASES = {
    # command: render (--out: the dataset root)
    "render into the user's folder": (["render", "@inputs/tiny.toml", "--out", "@mine", *R], "mine/train"),
    "render into the setup file": (["render", "@inputs/tiny.toml", "--out", "@inputs/tiny.toml", *R],
                                   "inputs/tiny.toml"),
    "render over its setup folder's setup.toml": (["render", "@inputs/tiny/setup.toml", "--out", "@inputs",
                                                   *R],
                                                  "inputs/tiny/setup.toml"),
    "render into the folder of --images": (["render", "@inputs/tiny.toml", "--images", "@inputs/ref", "--out",
                                            "@inputs", *R], "inputs/ref"),
    "render into a dataset made elsewhere": (["render", "@inputs/tiny.toml", "--out", "@data", *R],
                                             "data/ref"),
    "render --overwrite over captures made elsewhere": (["render", "@inputs/tiny.toml", "--out", "@official",
                                                         "--overwrite", *R], "official/tiny/cam"),
    # bench-sim (--out: a folder for its CSV and chart)
    "bench-sim into the setup file": (["bench-sim", "@inputs/tiny.toml", "--out", "@inputs/tiny.toml"],
                                      "inputs/tiny.toml"),
    # train (--out: the run directory)
    "train --overwrite into the user's folder": (["train", S, "--method", "nayar", "--out", "@mine",
                                                  "--overwrite", *TRAIN], "mine"),
    "train --overwrite into its dataset": (["train", S, "--method", "nayar", "--out", S, "--overwrite",
                                            *TRAIN], "data/synth"),
    "train --overwrite into the dataset root": (["train", S, "--method", "nayar", "--out", "@data",
                                                 "--overwrite", *TRAIN], "data"),
    "train --overwrite into the run of --init": (["train", S, "--method", "compennet", "--init", "@compennet",
                                                  "--iters", "2", "--out", "@compennet", "--overwrite", *TRAIN],
                                                 "compennet"),
    "train into the setup file": (["train", S, "--method", "nayar", "--out", "@inputs/tiny.toml", *TRAIN],
                                  "inputs/tiny.toml"),
    # compensate (--out: a PNG for one image, else a folder)
    "compensate into the folder of its image": (["compensate", "@nayar", "@mine/photo.png", "--out", "@mine"],
                                                "mine/photo.png"),
    "compensate over its image, --overwrite": (["compensate", "@nayar", "@mine/photo.png", "--out",
                                                "@mine/photo.png", "--overwrite"], "mine/photo.png"),
    "compensate over a user's text file": (["compensate", "@nayar", Y, "--out", "@mine/notes.txt"],
                                           "mine/notes.txt"),
    "compensate over a user's image": (["compensate", "@nayar", Y, "--out", "@mine/photo.png"], "mine/photo.png"),
    "compensate into the run's dataset": (["compensate", "@nayar", Y, "--out", "@data/synth/cam/warp/ref"],
                                          "data/synth"),
    "compensate into the run": (["compensate", "@nayar", Y, "--out", "@nayar"], "nayar"),
    "compensate into the user's folder": (["compensate", "@nayar", Y, "--out", "@mine"], ["mine/img_0001.png"]),
    # bench (--out: its folder)
    "bench into the user's folder": (["bench", "@inputs/tiny.toml", "--out", "@mine", "--methods", "tps",
                                      "--tables", "1", "--sizes", "8", "--size", "16", "--n-test", "2"], "mine"),
    "bench into its dataset root": (["bench", "--data", "@data", "--out", "@data", "--methods", "tps",
                                     "--tables", "1", "--sizes", "8"], "data"),
    "bench into a study's folder": (["bench", "@inputs/tiny.toml", "--out", "@study", "--methods", "tps",
                                     "--tables", "1", "--sizes", "8", "--size", "16", "--n-test", "2"],
                                    "study/study.json"),
    # study (--out: its folder)
    "study into the user's folder": (["study", "@inputs/allfail.toml", "--out", "@mine"], "mine"),
    "study into the folder of its file": (["study", "@inputs/allfail.toml", "--out", "@inputs"], "inputs"),
    "study into its file": (["study", "@inputs/allfail.toml", "--out", "@inputs/allfail.toml"],
                            "inputs/allfail.toml"),
    "study into another study's folder": (["study", "@inputs/other.toml", "--out", "@study"],
                                          "study/study.json"),
    # demo (--out: its folder)
    "demo into the user's folder": (["demo", "--out", "@mine"], "mine"),
    "demo into a study's folder": (["demo", "--out", "@study"], "study/study.json"),
    # report (writes into the folder it reads)
    "report on the user's folder": (["report", "@mine"], "mine"),
    "report on the inputs": (["report", "@inputs"], "inputs"),
    # compare (--out: a folder for compare.csv and compare.md)
    "compare into the user's folder": (["compare", "@study", "@study2", "--out", "@mine"], "mine"),
    "compare into folder A": (["compare", "@study", "@study2", "--out", "@study"], "study"),
    "compare into A's results": (["compare", "@study", "@study2", "--out", "@study/results.csv"],
                                 "study/results.csv"),
    "compare a folder with itself": (["compare", "@study", "@study"], "study"),
    "compare into A's compare folder": (["compare", "@study", "@study2"],
                                        ["study/compare-study2/compare.csv", "study/compare-study2/compare.md"]),
}
"""Per try: the command line (``@``: a path relative to the workspace; ``--method compennet`` is
not the run ``@compennet``) and either the path its one-line refusal names, or (a list) the only
files it may write."""
SLOW_CASES = {
    "bench-sim into the user's folder": (["bench-sim", "@inputs/tiny.toml", "--out", "@mine", "--quiet",
                                          "--classes", "smooth", "--ref-spp", "4", "--spp", "1",
                                          "--window", "8", "--repeats", "1"],
                                         ["mine/bench_sim_tiny.csv", "mine/bench_sim_tiny.png"]),
}
"""Tries that run for seconds before they write."""
OPTIONS = {"render": "--out", "bench-sim": "--out", "train": "--out", "compensate": "--out", "bench": "--out",
           "study": "--out", "demo": "--out", "compare": "--out", "report": None}
"""Each command and its output option (None: it writes into the folder it reads)."""


def test_the_walk_covers_every_command():
    commands = set(build_parser()._subparsers._group_actions[0].choices)
    assert set(OPTIONS) == commands
    assert {argv[0] for argv, _ in (*CASES.values(), *SLOW_CASES.values())} == commands


def _walk(workspace: Path, tmp_path: Path, capsys, argv: list[str], outcome) -> None:
    ws = tmp_path / "ws"
    shutil.copytree(workspace, ws, symlinks=True)
    for config in ws.glob("*/config.json"):  # the runs' dataset: the copy's
        config.write_text(config.read_text().replace(str(workspace), str(ws)))
    before = _hashes(ws)
    code = main([str(ws / a[1:]) if a.startswith("@") else a for a in argv])
    err = capsys.readouterr().err
    after = _hashes(ws)
    assert {k: after.get(k) for k in before} == before, "a file that was there was changed or deleted"
    assert "Traceback" not in err, err
    if isinstance(outcome, str):
        assert code == 2, err
        assert err.startswith("procam: error: ") and err.count("\n") == 1, err  # one line
        assert str(ws / outcome) in err or str((ws / outcome).resolve()) in err, err
        assert set(after) == set(before), "a refused command wrote a file"
    else:
        assert code == 0, err
        assert sorted(set(after) - set(before)) == sorted(outcome)


@pytest.mark.parametrize("case", CASES)
def test_no_output_overwrites_an_input_or_a_user_file(workspace, tmp_path, capsys, case):
    _walk(workspace, tmp_path, capsys, *CASES[case])


@pytest.mark.slow
@pytest.mark.parametrize("case", SLOW_CASES)
def test_no_output_overwrites_a_user_file_slow(workspace, tmp_path, capsys, case):
    _walk(workspace, tmp_path, capsys, *SLOW_CASES[case])
