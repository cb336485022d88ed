"""Progress of a plan: the time left from the jobs done so far (reused jobs left out, unknown while
a kind has none done), the overall line's counts, per-job bars naming their setup, method and
seed, and the baselines' bars (the oracle's corrections, the exact optimum) naming their setup."""
from __future__ import annotations

import json
import re

import pytest

from helpers import refuse_renders
from test_studies import BASE, STUDY
from compensation.cli import main
from compensation.experiments.executors import LocalExecutor, Task
from compensation.experiments.jobs import BaselineJob, FitJob
from compensation.experiments.plans import JobCount, eta, fit_group
from compensation.methods import make_config


def test_eta_leaves_out_what_is_not_known():
    assert eta({"tps fit": [10.0, 30.0], "render": []}, {"tps fit": 2, "render": 0}) == 40.0
    assert eta({"tps fit": [10.0]}, {"tps fit": 1, "score": 1}) is None  # no score done yet
    assert eta({}, {"render": 0, "tps fit": 0}) == 0.0


class _Timed:
    """A stand-in executor: each task "took" the seconds its run folder's name says."""

    def run(self, tasks, on_done):
        for i, task in enumerate(tasks):
            on_done(i, {"ok": True, "reused": False}, float(task.job.run_dir.name))
        return [{"ok": True}] * len(tasks)


def test_each_method_times_its_own_fits(tmp_path):
    """A network's fits are not estimated from a spline's: the time left stays unknown until a
    fit of every method with fits left has run, then adds each method's own mean."""
    tps, net = make_config("quick", "tps"), make_config("quick", "compennet")
    count = JobCount({"fit": {fit_group("tps"): 2, fit_group("compennet"): 2}})
    count.run(_Timed(), [Task(None, FitJob(tmp_path, tps, tmp_path / "2"))])
    assert count.line().endswith("fits 1/4 (0 reused, 0 failed); time left unknown "
                                 "(no compennet fit run yet)")
    count.run(_Timed(), [Task(None, FitJob(tmp_path, net, tmp_path / "300"))])
    assert count.seconds == {"tps fit": [2.0], "compennet fit": [300.0]}
    assert count.line().endswith("fits 2/4 (0 reused, 0 failed); time left about 5 min")  # 2 s + 300 s
    count.not_tried([fit_group("compennet")])
    assert count.left == {"tps fit": 1, "compennet fit": 0} and count.done == {"fit": 3}
    assert count.line().endswith("fits 3/4 (0 reused, 1 failed); time left about 2 s")


def _write_record(job: BaselineJob) -> dict:
    """A stand-in job: writes its record unless it is there (then it says it reused it), fails on
    n_test 0."""
    if job.n_test == 0:
        raise RuntimeError("no test pairs")
    if job.record.exists():
        return {"reused": True}
    job.record.write_text(json.dumps({"done": True}))
    return {"reused": False}


def test_reused_jobs_do_not_pull_the_estimate_down(tmp_path, capsys):
    kept = tmp_path / "kept.json"
    kept.write_text("{}")
    jobs = [BaselineJob(tmp_path, 4, record=kept), BaselineJob(tmp_path, 4, record=tmp_path / "new.json"),
            BaselineJob(tmp_path, 0, record=tmp_path / "bad.json")]
    count = JobCount({"score": {"score": 5}, "fit": {"tps fit": 1}})
    count.run(LocalExecutor(), [Task(_write_record, job) for job in jobs])
    assert count.done == {"score": 3, "fit": 0} and (count.reused, count.failed) == (1, 1)
    assert len(count.seconds["score"]) == 1  # the one job that did work
    assert count.seconds["tps fit"] == []
    lines = capsys.readouterr().err.splitlines()
    assert lines[-1].startswith("procam: jobs done: scores 3/5, fits 0/1 (1 reused, 1 failed); time left unknown")
    count.not_tried(["tps fit"])
    assert count.line().startswith("procam: jobs done: scores 3/5, fits 1/1 (1 reused, 2 failed); time left about ")
    assert eta(count.seconds, {"score": 2, "tps fit": 0}) == pytest.approx(2 * count.seconds["score"][0])


@pytest.mark.slow
def test_a_study_shows_its_jobs_and_names_each_bar(tmp_path, capfd, monkeypatch):
    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "tiny.toml").write_text(STUDY)
    args = ["study", str(tmp_path / "tiny.toml"), "--out", str(tmp_path / "out")]
    assert main(args) == 0
    err = capfd.readouterr().err
    lines = [line for line in err.splitlines() if line.startswith("procam: jobs done:")]
    assert lines[0] == ("procam: jobs done: renders 0/2, fits 0/4, scores 0/2 (0 reused, 0 failed); "
                        "time left unknown (no render or tps fit or nayar fit or score run yet)")
    assert lines[-1] == ("procam: jobs done: renders 2/2, fits 4/4, scores 2/2 (0 reused, 0 failed); "
                         "time left about 0 s")
    assert len(lines) == 1 + 2 + 2 + 4  # the start, then each job
    # renders and scores timed; then each method's fits from their own
    assert any(line.endswith("(no tps fit or nayar fit run yet)") for line in lines)
    assert re.search(r"fits 1/4, scores 2/2 .*; time left unknown \(no nayar fit run yet\)", err)
    assert re.search(r"fits 2/4, scores 2/2 .*; time left about \d+", err)
    setups = sorted(p.name for p in (tmp_path / "out" / "data").glob("base__*"))
    assert len(setups) == 2
    for setup in setups:
        assert f"{setup} · render" in err
        assert f"{setup} · tps · 125 pairs · seed 0 · fit" in err  # the plain colours; nayar: no bar
        # the baselines: the oracle's corrections and the exact optimum's evaluations
        assert re.search(rf"{setup} · oracle: 100%.*\| 8/8 ", err)
        assert f"{setup} · exact optimum" in err
    assert main(args) == 0  # again: every job reused, none timed
    lines = [line for line in capfd.readouterr().err.splitlines() if line.startswith("procam: jobs done:")]
    assert lines[-1] == ("procam: jobs done: renders 2/2, fits 4/4, scores 2/2 (8 reused, 0 failed); "
                         "time left about 0 s")
    assert all(line.endswith("run yet)") for line in lines[:-1])

    refuse_renders(monkeypatch, "0p2")
    (tmp_path / "tiny.toml").write_text(STUDY.replace("[0.02, 0.1]", "[0.02, 0.1, 0.2]"))
    assert main(args) == 0  # a third setup that cannot render: its render, fits and score failed
    lines = [line for line in capfd.readouterr().err.splitlines() if line.startswith("procam: jobs done:")]
    assert lines[-1].startswith("procam: jobs done: renders 3/3, fits 6/6, scores 3/3 (8 reused, 4 failed)")
