"""Fault injection on the learning side: bad arguments and outputs give a clear error (exit 2, the
file, key or value named, no traceback, nothing written); killed benches resume to the same tables;
stale runs are not reused; files respect the umask."""
from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
import typing
from pathlib import Path

import numpy as np
import pytest

from helpers import csv_rows, failing_study_file, interrupted_render, tiny_toml
from compensation.cli import main
from compensation.methods import METHODS, make_config
from compensation.methods.tps import fit_splines
from compensation.experiments.runs import partial_dir, train_run
from sim.io import write_png

ROOT = Path(__file__).resolve().parents[1]
TRAIN = ["--n-train", "8", "--n-test", "4", "--quiet"]


def _fails(capsys, argv: list[str], *expected: str) -> str:
    """Run the CLI: exit 2, every ``expected`` text in the message, no traceback."""
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.startswith("procam: error:"), err
    for text in expected:
        assert text in err, (text, err)
    return err


def _tree(folder: Path) -> set[Path]:
    return {p.relative_to(folder) for p in folder.rglob("*")} if folder.exists() else set()


# -- class 4: stale work and unknown names are refused before any work --------------------------

def test_unknown_method_in_bench_is_refused_before_any_work(tmp_path, capsys):
    _fails(capsys, ["bench", "ideal", "--out", str(tmp_path / "b"), "--methods", "tps,bogus"],
           "unknown method 'bogus'", "tps")
    assert not (tmp_path / "b").exists()


def test_bench_option_no_method_uses_is_refused(tmp_path, capsys):
    _fails(capsys, ["bench", "ideal", "--out", str(tmp_path / "b"), "--methods", "tps",
                    "--tables", "1", "--l1-weight", "5"], "'l1_weight'", "tps")
    assert not (tmp_path / "b").exists()


def test_train_option_of_another_method_is_refused(setup_dir, tmp_path, capsys):
    _fails(capsys, ["train", str(setup_dir), "--method", "tps", "--loss", "ssim", "--out",
                    str(tmp_path / "run"), *TRAIN], "method 'tps' does not use option 'loss'")
    assert _tree(tmp_path) == set()


# -- class 5: output paths ----------------------------------------------------------------------

def test_train_out_at_an_existing_file(setup_dir, tmp_path, capsys):
    target = tmp_path / "run"
    target.write_text("not a run")
    _fails(capsys, ["train", str(setup_dir), "--method", "nayar", "--out", str(target), *TRAIN],
           str(target), "is a file")
    assert target.read_text() == "not a run"


@pytest.mark.slow
def test_train_overwrite_never_deletes_files_a_run_did_not_write(setup_dir, tmp_path, capsys):
    """--overwrite replaces a run, not a folder of the user's that happens to hold a metrics.json;
    a real run (with its closed-loop captures) is still replaced."""
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "metrics.json").write_text("{}")
    (mine / "thesis.tex").write_text("years of work")
    _fails(capsys, ["train", str(setup_dir), "--method", "nayar", "--out", str(mine), "--overwrite", *TRAIN],
           str(mine), "thesis.tex", "which no run writes")
    assert (mine / "thesis.tex").read_text() == "years of work"
    run = tmp_path / "run"
    assert main(["train", str(setup_dir), "--method", "nayar", "--out", str(run), *TRAIN]) == 0
    (run / "closed_loop").mkdir()
    assert main(["train", str(setup_dir), "--method", "tps", "--out", str(run), "--overwrite", *TRAIN]) == 0
    assert (run / "tps.npz").is_file() and not (run / "nayar.npz").exists()


@pytest.mark.slow
def test_train_out_at_a_symbolic_link_is_refused_and_leaves_nothing_behind(setup_dir, tmp_path, capsys):
    """--out naming a symbolic link to a run (or a dangling one) is refused before training; the run
    it points to stays as it was, nothing is left beside the link, and the folder itself is taken."""
    run = tmp_path / "runs" / "nayar"
    assert main(["train", str(setup_dir), "--method", "nayar", "--out", str(run), *TRAIN]) == 0
    before = {p.name: p.read_bytes() for p in run.iterdir()}
    link = tmp_path / "link"
    link.symlink_to(run, target_is_directory=True)
    dangling = tmp_path / "dangling"
    dangling.symlink_to(tmp_path / "nowhere", target_is_directory=True)
    for out in (link, dangling):
        _fails(capsys, ["train", str(setup_dir), "--method", "tps", "--out", str(out), "--overwrite", *TRAIN],
               str(out), "is a symbolic link", "give the folder itself")
    assert {p.name: p.read_bytes() for p in run.iterdir()} == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dangling", "link", "runs"]
    assert main(["train", str(setup_dir), "--method", "tps", "--out", str(run), "--overwrite", *TRAIN]) == 0
    assert (run / "tps.npz").is_file()


def test_train_out_that_cannot_be_created_fails_before_training(setup_dir, tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    _fails(capsys, ["train", str(setup_dir), "--method", "compennet", "--iters", "500", "--out",
                    str(blocker / "run"), *TRAIN], str(blocker), "cannot write the run there")


def test_compensate_refuses_two_inputs_with_one_output_name(setup_dir, tmp_path, capsys):
    run = tmp_path / "run"
    assert main(["train", str(setup_dir), "--method", "nayar", "--out", str(run), *TRAIN]) == 0
    image = np.full((32, 32, 3), 100, np.uint8)
    write_png(tmp_path / "a" / "x.png", image)
    write_png(tmp_path / "b" / "x.png", image)
    out = tmp_path / "frames"
    _fails(capsys, ["compensate", str(run), str(tmp_path / "a" / "x.png"), str(tmp_path / "b" / "x.png"),
                    "--out", str(out)], "x.png")
    assert not out.exists()
    # one input and --out NAME.png writes that file, not a folder
    assert main(["compensate", str(run), str(tmp_path / "a" / "x.png"), "--out", str(tmp_path / "y.png")]) == 0
    assert (tmp_path / "y.png").is_file()


def test_compensate_never_writes_over_its_inputs(setup_dir, tmp_path, capsys):
    """Every way --out could land on an input is refused before anything is written: the desired
    image itself, a folder of desired images, the surface image, a file inside the run."""
    run = tmp_path / "run"
    assert main(["train", str(setup_dir), "--method", "nayar", "--out", str(run), *TRAIN]) == 0
    inputs = tmp_path / "inputs"
    images = {name: np.full((32, 32, 3), v, np.uint8) for name, v in (("a.png", 60), ("b.png", 160))}
    for name, image in images.items():
        write_png(inputs / name, image)
    surface = tmp_path / "surface.png"
    write_png(surface, np.full((32, 32, 3), 90, np.uint8))
    model = run / "nayar.npz"
    before = {p: p.read_bytes() for p in (*inputs.iterdir(), surface, model)}
    a, b = str(inputs / "a.png"), str(inputs / "b.png")
    for argv, named in (([a, "--out", a], a),                                     # the image itself
                        ([a, b, "--out", str(inputs)], a),                         # their folder
                        ([a, "--surface", str(surface), "--out", str(surface)], str(surface)),
                        ([a, "--out", str(run / "frame.png")], str(run))):          # inside the run
        _fails(capsys, ["compensate", str(run), *argv], named, "would")
    assert {p: p.read_bytes() for p in before} == before
    # one image to a name of another image type is refused, not turned into a folder
    _fails(capsys, ["compensate", str(run), a, "--out", str(tmp_path / "res.jpg")], "res.jpg", "name it .png")
    assert not (tmp_path / "res.jpg").exists()
    # several images to an existing file
    (tmp_path / "file").write_text("mine")
    _fails(capsys, ["compensate", str(run), a, b, "--out", str(tmp_path / "file")], "existing file")
    assert (tmp_path / "file").read_text() == "mine"


# -- class 6: damaged run records ---------------------------------------------------------------

@pytest.mark.parametrize("damage,expected", [
    (lambda c: c.write_text("{not json"), "cannot read run configuration"),
    (lambda c: c.write_text(json.dumps({k: v for k, v in json.loads(c.read_text()).items()
                                        if k != "image_size"})), "'image_size'"),
    (lambda c: c.write_text(json.dumps({**json.loads(c.read_text()), "train": {"method": "bogus"}})),
     "unknown method 'bogus'"),
])
def test_damaged_config_json_names_file_and_key(setup_dir, tmp_path, capsys, damage, expected):
    run = tmp_path / "run"
    assert main(["train", str(setup_dir), "--method", "nayar", "--out", str(run), *TRAIN]) == 0
    damage(run / "config.json")
    write_png(tmp_path / "y.png", np.full((32, 32, 3), 100, np.uint8))
    _fails(capsys, ["compensate", str(run), str(tmp_path / "y.png"), "--out", str(tmp_path / "f.png")],
           "config.json", expected)
    assert not (tmp_path / "f.png").exists()


# -- class 7: permissions and leftovers ---------------------------------------------------------

def test_run_files_respect_the_umask_and_leave_nothing_behind(setup_dir, tmp_path):
    old = os.umask(0o022)
    try:
        run = tmp_path / "run"
        train_run(setup_dir, make_config("quick", "compennet", iters=3, batch=4, n_train=8, n_test=4),
                  run, progress=False)
    finally:
        os.umask(old)
    assert stat.S_IMODE(run.stat().st_mode) == 0o755
    for path in run.iterdir():
        assert stat.S_IMODE(path.stat().st_mode) == 0o644, path
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]  # no partial or temporary folder


# -- classes 4 and 8: a killed bench resumes to the same tables; a changed option retrains -------

BENCH_SETUP = tiny_toml("tinybench")
BENCH_ARGS = ["--methods", "compennet,tps", "--tables", "1", "--sizes", "8", "--size", "32",
              "--n-test", "2", "--iters", "80", "--batch", "4", "--quiet"]


def _bench(tmp: Path, out: str, *extra: str) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "compensation.cli", "bench", str(tmp / "setup.toml"), "--out",
           str(tmp / out), "--data", str(tmp / "data"), *BENCH_ARGS, *extra]
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"}
    return subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _scores(table: Path) -> list[list[str]]:
    """Table 1's rows without the timing column."""
    rows = [[c.strip(" |") for c in line.split(" | ")] for line in table.read_text().splitlines()
            if line.startswith("| ")]
    timing = rows[0].index("train s")
    return [[c for i, c in enumerate(r) if i != timing] for r in rows]


@pytest.mark.slow
def test_killed_bench_resumes_to_the_same_table(tmp_path):
    (tmp_path / "setup.toml").write_text(BENCH_SETUP)
    whole = _bench(tmp_path, "whole")
    assert whole.wait() == 0, whole.communicate()
    proc = _bench(tmp_path, "killed")
    checkpoint = partial_dir(tmp_path / "killed" / "runs" / "tinybench" / "compennet-n8-seed0") / "checkpoint.pt"
    end = time.monotonic() + 300
    while not checkpoint.exists():
        assert proc.poll() is None and time.monotonic() < end, proc.communicate()
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    resumed = _bench(tmp_path, "killed")
    assert resumed.wait() == 0, resumed.communicate()
    assert _scores(tmp_path / "whole" / "table1.md") == _scores(tmp_path / "killed" / "table1.md")
    # another --seed is another run, in a folder of its own: nothing stale is reused
    reseeded = _bench(tmp_path, "killed", "--seed", "1")
    assert reseeded.wait() == 0, reseeded.communicate()
    runs = tmp_path / "killed" / "runs" / "tinybench"
    seeds = [json.loads((runs / f"compennet-n8-seed{s}" / "config.json").read_text())["train"]["seed"]
             for s in (0, 1)]
    assert seeds == [0, 1]
    shutil.rmtree(tmp_path / "data")


@pytest.mark.slow
def test_file_system_errors_are_reported_without_traceback(tmp_path, capsys):
    """bench-sim into a folder under a file: the OSError is named, exit 2."""
    blocker = tmp_path / "file"
    blocker.write_text("")
    _fails(capsys, ["bench-sim", "ideal", "--out", str(blocker / "out"), "--spp", "1", "--repeats", "1",
                    "--ref-spp", "4", "--window", "8", "--classes", "smooth", "--quiet"], str(blocker))


def test_too_few_pairs_for_a_spline_is_a_clear_error(setup_dir, tmp_path, capsys):
    _fails(capsys, ["train", str(setup_dir), "--method", "tps-textured", "--n-train", "3", "--n-test", "4",
                    "--out", str(tmp_path / "run"), "--quiet"], "tps-textured", "at least 4")


def test_bench_option_values_are_checked_before_any_work(tmp_path, capsys):
    _fails(capsys, ["bench", "ideal", "--out", str(tmp_path / "b"), "--methods", "compennet",
                    "--tables", "1", "--lr", "-1"], "option lr = -1.0")
    assert not (tmp_path / "b").exists()


# -- class sweeps: every training option, every limit, every record a report reads -------------

def _float_options() -> dict[str, tuple[str, str]]:
    """Every training option holding a float, once per options class: name -> (a method, option)."""
    found = {}
    for method, cls in METHODS.items():
        for option, hint in typing.get_type_hints(cls.options).items():
            if hint is float:
                found.setdefault(f"{cls.options.__name__}.{option}", (method, option))
    return found


FLOAT_OPTION_TRIES = {f"{method} --{option.replace('_', '-')} {value}": (method, option, value)
                      for method, option in _float_options().values()
                      for value in ("1e39", "1e300", "inf", "1e-300")}
"""Every float option at values float32, in which training computes, cannot hold (or rounds to 0)."""


@pytest.mark.parametrize("case", FLOAT_OPTION_TRIES)
def test_every_float_option_refuses_what_float32_cannot_hold(setup_dir, tmp_path, capsys, case):
    method, option, value = FLOAT_OPTION_TRIES[case]
    _fails(capsys, ["train", str(setup_dir), "--method", method, f"--{option.replace('_', '-')}", value,
                    "--out", str(tmp_path / "run"), *TRAIN], f"option {option} = ", "training computes in float32")
    assert _tree(tmp_path) == set()


COUNT_TRIES = {
    "compennet --iters 2**70": (["--method", "compennet", "--iters", str(2 ** 70)], "at most 1000000"),
    "pix2pix --iters 2**63": (["--method", "pix2pix", "--iters", str(2 ** 63)], "at most 1000000"),
    "tps --seed 2**32": (["--method", "tps", "--seed", str(2 ** 32)], "from 0 to 4294967295"),
    "compennet --seed 2**70": (["--method", "compennet", "--seed", str(2 ** 70)], "from 0 to 4294967295"),
}
"""Counts that would allocate (the loss log holds a row per iteration) or overflow (a seed)."""


@pytest.mark.parametrize("case", COUNT_TRIES)
def test_huge_training_counts_are_refused_before_any_work(setup_dir, tmp_path, capsys, case):
    options, expected = COUNT_TRIES[case]
    _fails(capsys, ["train", str(setup_dir), *options, "--out", str(tmp_path / "run"), *TRAIN], expected)
    assert _tree(tmp_path) == set()


def test_a_spline_fit_starts_no_more_workers_than_it_has_tasks():
    rng = np.random.default_rng(0)
    centres, values = rng.random((3, 6, 3)), rng.random((3, 6, 3))
    many, _, _ = fit_splines(centres, values, workers=2 ** 62)  # was an OverflowError
    assert np.array_equal(many, fit_splines(centres, values, workers=1)[0])


@pytest.mark.parametrize("size", [{"width": 100000, "height": 100000}, {"width": 0, "height": 32},
                                  {"width": -4, "height": 32}, {"width": "abc", "height": 32},
                                  {"width": 1e300, "height": 32}, {"width": True, "height": 32}, [32, 32], None],
                         ids=["100000", "0", "-4", "text", "1e300", "true", "a list", "null"])
def test_a_run_size_is_checked_before_an_image_is_resized_to_it(runs, tmp_path, capsys, size):
    run = tmp_path / "run"
    shutil.copytree(runs / "nayar", run)
    config = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**config, "image_size": size}))
    write_png(tmp_path / "y.png", np.full((32, 32, 3), 100, np.uint8))
    _fails(capsys, ["compensate", str(run), str(tmp_path / "y.png"), "--out", str(tmp_path / "f.png")],
           str(run / "config.json"), "image_size = ", "integer from 1 to 4096")
    assert not (tmp_path / "f.png").exists()


STUDY_TRIES = {
    "--seeds 2**70": (["--seeds", str(2 ** 70)], ["--seeds", "at most 10000"]),
    "--seeds 10**9": (["--seeds", str(10 ** 9)], ["--seeds 1000000000", "at most 10000"]),
    "--size 100000": (["--size", "100000"], ["--size", "100000", "<= 4096"]),
    "--size 4": (["--size", "4"], ["--size 4x4: expected sides of at least 8 pixels"]),
    "--out-of-reach for no target": (["--target-policy", "none", "--out-of-reach", "0.1"],
                                     ["--out-of-reach 0.1: the target policy 'none'"]),
    "--n-test 2**40": (["--n-test", str(2 ** 40)], [f"--n-test {2 ** 40}", "GiB in memory"]),
    "--n-train 2**40": (["--n-train", str(2 ** 40)], [f"--n-train {2 ** 40}", "GiB in memory"]),
    "--iters 2**70": (["--methods", "compennet", "--iters", str(2 ** 70)], ["option iters", "at most 1000000"]),
    "--methods tps,tps": (["--methods", "tps,tps"], ["--methods 'tps,tps': tps given twice"]),
    "--only 0,0": (["--only", "0,0"], ["--only '0,0': 0 given twice"]),
    "seeds = [0, 0]": (["seeds = [0, 0]"], ["seeds = [0, 0]: expected distinct values"]),
    "seeds = [2**32]": ([f"seeds = [{2 ** 32}]"], ["seeds", "integers from 0 to 4294967295"]),
    "methods twice": (['methods = ["tps", "tps"]'], ["methods = ['tps', 'tps']: expected distinct values"]),
    "n_train twice": (["n_train = [4, 4]"], ["n_train = [4, 4]: expected distinct values"]),
    "only twice": (['only = ["0", "0"]'], ["only = ['0', '0']: expected distinct values"]),
    "12000 runs": ([f"[[axis]]\nkey = \"camera.read_noise\"\nvalues = {[i / 1e4 for i in range(6000)]}"],
                   ["12000 runs", "expected at most 10000"]),
}
"""Per try: command-line options (``--…``) or lines added to the study file, and what the refusal
says; each is refused before anything is written."""


@pytest.mark.parametrize("case", STUDY_TRIES)
def test_study_counts_and_selections_are_refused_before_anything_is_written(tmp_path, capsys, case):
    extra, expected = STUDY_TRIES[case]
    study = failing_study_file(tmp_path)
    options = extra if extra[0].startswith("--") else []
    if not options:  # a key replaced at the top, or one more [[axis]] at the end
        key = extra[0].split(" = ", 1)[0]
        kept = [line for line in study.read_text().splitlines() if not line.startswith(f"{key} = ")]
        study.write_text("\n".join([*kept, *extra] if key.startswith("[[") else [*extra, *kept]) + "\n")
    _fails(capsys, ["study", str(study), "--out", str(tmp_path / "out"), "--quiet", *options], *expected)
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("argv", [["study", "S", "--n-train", "4,4"], ["bench", "ideal", "--sizes", "4,4"]],
                         ids=["study --n-train 4,4", "bench --sizes 4,4"])
def test_a_repeated_count_is_an_argument_error(tmp_path, capsys, argv):
    argv = [str(failing_study_file(tmp_path)) if a == "S" else a for a in argv]
    with pytest.raises(SystemExit) as exit_:  # an argparse type: usage and the value
        main([*argv, "--out", str(tmp_path / "out")])
    assert exit_.value.code == 2 and "'4,4': 4 given twice" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("option, expected", [(["--methods", "tps,tps"], "tps given twice"),
                                              (["--tables", "1,1"], "--tables '1,1': 1 given twice"),
                                              (["--only", "ideal,ideal"], "--only ideal,ideal: ideal given twice")],
                         ids=["--methods tps,tps", "--tables 1,1", "--only ideal,ideal"])
def test_bench_selections_given_twice_are_refused(tmp_path, capsys, option, expected):
    _fails(capsys, ["bench", "ideal", "--out", str(tmp_path / "b"), "--methods", "tps", "--tables", "1",
                    *option], expected)
    assert not (tmp_path / "b").exists()


@pytest.fixture(scope="module")
def failed_study(tmp_path_factory) -> Path:
    """The folder of a study whose every render was refused (:func:`helpers.failing_study_file`):
    the report is written, and the command says it holds no result with a non-zero exit."""
    tmp = tmp_path_factory.mktemp("failed")
    assert main(["study", str(failing_study_file(tmp)), "--out", str(tmp / "out"), "--quiet"]) == 2
    assert (tmp / "out" / "report.html").is_file()
    return tmp / "out"


def test_a_study_whose_every_job_failed_reports_and_compares(failed_study, tmp_path, capsys):
    a, b = tmp_path / "a", tmp_path / "b"
    shutil.copytree(failed_study, a)
    shutil.copytree(failed_study, b)
    rows = csv_rows(a / "results.csv")
    assert len(rows) == 2 and all(r["status"] == "failed" and "do not respond" in r["error"] for r in rows)
    assert main(["report", str(a)]) == 0
    assert "do not respond to the projector" in (a / "report.html").read_text()
    assert len(csv_rows(a / "failures.csv")) == 2 and (a / "charts").is_dir()
    assert main(["compare", str(a), str(b)]) == 0
    assert sorted(p.name for p in (a / "compare-b").iterdir()) == ["compare.csv", "compare.md"]
    assert "Traceback" not in capsys.readouterr().err


DAMAGES = {"not UTF-8": "caf\xe9,\xff\n".encode("latin-1"), "cut short": None, "empty": b"",
           "binary": bytes(range(256))}
"""Ways a record is damaged: another encoding, cut half-way, emptied, overwritten with bytes."""


@pytest.mark.parametrize("command", ["report", "compare A B", "compare B A"])
@pytest.mark.parametrize("damage", DAMAGES)
@pytest.mark.parametrize("name", ["results.csv", "per_image.csv", "study.json"])
def test_a_damaged_record_is_named(failed_study, tmp_path, capsys, name, damage, command):
    a, b = tmp_path / "a", tmp_path / "b"
    shutil.copytree(failed_study, a)
    shutil.copytree(failed_study, b)
    data = (a / name).read_bytes()
    (a / name).write_bytes(data[:len(data) // 2] if DAMAGES[damage] is None else DAMAGES[damage])
    argv = {"report": ["report", str(a)], "compare A B": ["compare", str(a), str(b)],
            "compare B A": ["compare", str(b), str(a)]}[command]
    _fails(capsys, argv, str(a / name))


@pytest.mark.parametrize("key, value", [("name", [1]), ("question", [1]), ("kind", 3), ("target", "x"),
                                        ("setups", [1]), ("versions", "x")], ids=lambda v: json.dumps(v))
def test_a_study_record_of_the_wrong_shape_is_named(failed_study, tmp_path, capsys, key, value):
    out = tmp_path / "out"
    shutil.copytree(failed_study, out)
    record = json.loads((out / "study.json").read_text())
    (out / "study.json").write_text(json.dumps({**record, key: value}))
    _fails(capsys, ["report", str(out)], str(out / "study.json"), f"'{key}' = ")


def test_a_score_that_is_not_a_number_is_named(failed_study, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(failed_study, out)
    rows = csv_rows(out / "results.csv")
    rows[0]["psnr"] = "abc"
    with open(out / "results.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    _fails(capsys, ["report", str(out)], str(out / "results.csv"), "line 2: column psnr: expected a number")


GOOD_PER_SETUP = "table,setup,method,n_train,PSNR,RMSE,SSIM,deltaE,train s\n1,synth,tps,8,20,0.1,0.7,5,1.0\n"
BENCH_DAMAGES = {
    "per_setup.csv not UTF-8": ("{}", "table,setup\n1,caf\xe9\n", None, "per_setup.csv"),
    "per_setup.csv cut short": ("{}", GOOD_PER_SETUP[:-20], None, "per_setup.csv"),
    "per_setup.csv without columns": ("{}", "table\n1\n", None, "per_setup.csv"),
    "per_setup.csv n_train text": ("{}", GOOD_PER_SETUP.replace(",8,", ",x,"), None, "bench"),
    "bench.json a list": ("[]", GOOD_PER_SETUP, None, "bench.json"),
    "bench.json config a list": ('{"config": []}', GOOD_PER_SETUP, None, "bench"),
    "failures.json without setup": ("{}", GOOD_PER_SETUP, '{"failures": [{"table": "1"}]}', "bench"),
    "failures.json a number": ("{}", GOOD_PER_SETUP, '{"failures": 3}', "bench"),
    "per_setup.csv header only": ("{}", GOOD_PER_SETUP.splitlines()[0] + "\n", None, "per_setup.csv"),
    "per_setup.csv a row twice": ("{}", GOOD_PER_SETUP + GOOD_PER_SETUP.splitlines()[1] + "\n", None,
                                  "per_setup.csv"),
    **{f"failures.json {key} {value}": ("{}", GOOD_PER_SETUP, json.dumps({"failures": [
        {"table": "1", "setup": "synth", "method": "compennet", "n_train": 8, key: value}]}), "bench")
       for key, value in (("n_train", "eight"), ("n_train", [8]), ("setup", 5), ("method", None))},
    "failures.json not UTF-8": ("{}", GOOD_PER_SETUP, '{"failures": "caf\xe9"}', "failures.json"),
}
"""Damaged records of a bench folder written before results.csv: bench.json, per_setup.csv and
failures.json, and what the refusal names."""


def test_a_bench_whose_table_1_runs_all_failed_is_reported(tmp_path):
    """per_setup.csv holds the runs that finished; a bench whose every Table 1 run failed has its
    header only, and its failures in failures.json: a folder procam wrote, not a damaged one."""
    from compensation.reports.report import load_folder

    folder = tmp_path / "bench"
    folder.mkdir()
    (folder / "bench.json").write_text("{}")
    (folder / "per_setup.csv").write_text(GOOD_PER_SETUP.splitlines()[0] + "\n")
    (folder / "failures.json").write_text(json.dumps({"failures": [
        {"table": "1", "setup": "synth", "method": "tps", "n_train": 8, "error": "no light"}]}))
    _, rows = load_folder(folder)
    assert [(r["method"], r["status"], r["error"]) for r in rows] == [("tps", "failed", "no light")]


@pytest.mark.parametrize("case", BENCH_DAMAGES)
def test_a_damaged_bench_record_is_named(tmp_path, capsys, case):
    bench, per_setup, failures, named = BENCH_DAMAGES[case]
    folder = tmp_path / "bench"
    folder.mkdir()
    (folder / "bench.json").write_bytes(bench.encode("latin-1"))
    (folder / "per_setup.csv").write_bytes(per_setup.encode("latin-1"))
    if failures is not None:
        (folder / "failures.json").write_bytes(failures.encode("latin-1"))
    _fails(capsys, ["report", str(folder)], str(folder) if named == "bench" else str(folder / named))


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Path:
    """Runs of nayar, tps and CompenNet (2 iterations) on a synthetic dataset of their own."""
    from synthetic import make_dataset

    tmp = tmp_path_factory.mktemp("runs")
    setup = make_dataset(tmp / "data")
    for method, extra in (("nayar", []), ("tps", []), ("compennet", ["--iters", "2", "--batch", "4"])):
        assert main(["train", str(setup), "--method", method, *extra, "--out", str(tmp / method), *TRAIN]) == 0
    return tmp


@pytest.mark.parametrize("damage", ["text", "cut short", "empty"])
@pytest.mark.parametrize("file", ["nayar/nayar.npz", "tps/tps.npz", "compennet/model.pt", "tps/config.json"])
def test_a_damaged_run_file_is_named(runs, tmp_path, capsys, file, damage):
    run = tmp_path / file.split("/")[0]
    shutil.copytree(runs / run.name, run)
    data = (tmp_path / file).read_bytes()
    (tmp_path / file).write_bytes({"text": b"garbage", "cut short": data[:len(data) // 2], "empty": b""}[damage])
    write_png(tmp_path / "y.png", np.full((32, 32, 3), 100, np.uint8))
    _fails(capsys, ["compensate", str(run), str(tmp_path / "y.png"), "--out", str(tmp_path / "f.png")],
           str(tmp_path / file))
    assert not (tmp_path / "f.png").exists()


def test_ctrl_c_inside_a_render_job_stops_the_study(tmp_path, capsys, monkeypatch):
    """Dr.Jit reports Ctrl-C inside a render as a RuntimeError: the study stops (status 130) instead
    of recording a failed render and going on."""
    import mitsuba as mi

    study = failing_study_file(tmp_path)
    (tmp_path / "base.toml").write_text(tiny_toml("base", 16, registration={"method": "exact"}))
    monkeypatch.setattr(mi, "render", interrupted_render)
    assert main(["study", str(study), "--out", str(tmp_path / "out"), "--quiet"]) == 130
    err = capsys.readouterr().err
    assert "procam: interrupted" in err and "Traceback" not in err
    assert not (tmp_path / "out" / "results.csv").exists()


def test_a_study_folder_holds_one_study(failed_study, tmp_path, capsys):
    out = tmp_path / "out"
    shutil.copytree(failed_study, out)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    other = failing_study_file(tmp_path / "files", "other")
    _fails(capsys, ["study", str(other), "--out", str(out), "--quiet"], str(out / "study.json"),
           "holds the study 'allfail'", "choose another --out for the study 'other'")
    assert {p: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    # the study itself goes on in its folder
    assert main(["study", str(failing_study_file(tmp_path / "files")), "--out", str(out), "--quiet"]) == 2


@pytest.mark.slow
def test_the_corrected_study_renders_where_the_failed_one_left_off(failed_study, tmp_path, capsys):
    """A study whose renders were refused, its base corrected, runs in the same folder."""
    out = tmp_path / "out"
    shutil.copytree(failed_study, out)
    study = failing_study_file(tmp_path / "files")
    (tmp_path / "files" / "base.toml").write_text(tiny_toml("base", 16, registration={"method": "exact"}))
    assert main(["study", str(study), "--out", str(out), "--quiet"]) == 0
    assert {r["status"] for r in csv_rows(out / "results.csv")} == {"ok"}


def test_an_unreachable_ray_cluster_is_refused_before_anything_is_written(tmp_path, capsys):
    pytest.importorskip("ray")
    _fails(capsys, ["study", str(failing_study_file(tmp_path)), "--out", str(tmp_path / "out"),
                    "--executor", "ray", "--address", "bogus.invalid:1234"], "--address bogus.invalid:1234")
    assert not (tmp_path / "out").exists()
