"""The one planner of studies and benches: points, runs, run folders, and carrying a plan out.

A *plan* is what a study file or a bench configuration expands to: the grid of points (a bench
has one, point 0), the setups to render and the runs — one method fitted with one seed on one
setup of one point, in the run folder ``runs/<setup>/<name>`` named by :func:`run_name`. Both
commands then go through :func:`execute` (render, fit, score, baselines, by the executor's
jobs of :mod:`compensation.experiments.jobs`) and :func:`result_rows` (one ``results.csv`` row per
run), so they name folders, reuse runs and record failures the same way. With progress on,
:class:`JobCount` prints one line each time a job finishes: the jobs of each kind done, reused and
failed, and the time left (:func:`eta`).
"""
from __future__ import annotations

import re
import sys
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from tqdm import tqdm

from compensation.experiments.executors import Task
from compensation.experiments.jobs import (BaselineJob, FitJob, RenderJob, baselines, fit, render,
                                          result_row, tasks)
from compensation.experiments.targets import TargetPolicy
from compensation.methods import get_method
from compensation.training.config import TrainConfig
from sim.dataset import FrameSpec
from sim.errors import ProcamError
from sim.layout import N_PLAIN
from sim.setup import Setup


def slug(value) -> str:
    """A value in a setup or run name (letters, digits, ``_`` and ``-``): ``0.005`` → ``0p005``,
    ``-2`` → ``m2``, ``[1, 0.5]`` → ``1x0p5``.

    >>> slug(0.005), slug(-2), slug([1.0, 0.5, 0.5]), slug("RGGB"), slug("l1+ssim")
    ('0p005', 'm2', '1p0x0p5x0p5', 'RGGB', 'l1ssim')
    """
    if isinstance(value, (list, tuple)):
        return "x".join(slug(v) for v in value)
    text = str(value).lower() if isinstance(value, bool) else str(value)
    text = text.replace(".", "p").replace("+", "")
    text = re.sub(r"^-", "m", text)
    return re.sub(r"[^A-Za-z0-9_-]", "", text)


def run_name(method: str, n_train: int, seed: int, varied: Mapping) -> str:
    """The folder name of a run: ``<method>-n<n_train>-seed<seed>``, then ``-<option><value>`` for
    each training value the run varies (in the mapping's order).

    >>> run_name("compennet", 125, 0, {"iters": 500, "loss": "l1+ssim"})
    'compennet-n125-seed0-iters500-lossl1ssim'
    """
    return f"{method}-n{n_train}-seed{seed}" + "".join(f"-{k}{slug(v)}" for k, v in varied.items())


def fit_sizes(method: str, n_train: int, fewest: int) -> tuple[int, int]:
    """The training pairs a run of ``method`` loads and the number its folder is named for, for a
    row of ``n_train`` pairs: a method on the plain colours fits the same 125 captures whatever
    the row's size, so every size shares one run, which loads the ``fewest`` pairs of the plan and
    is named for the 125 it fits.

    >>> fit_sizes("tps", 500, 125), fit_sizes("tps-textured", 500, 125)
    ((125, 125), (500, 500))
    """
    return (fewest, N_PLAIN) if get_method(method).plain_colours else (n_train, n_train)


@dataclass(frozen=True)
class Point:
    """One combination of axis values, numbered from 0 in the grid's order (the last axis fastest);
    a bench has one point without values."""

    index: int
    values: dict = field(default_factory=dict)
    """Axis key → value."""


@dataclass(frozen=True)
class Run:
    """One row of ``results.csv``: a method fitted with one seed on one setup of one point."""

    point: Point
    setup: str
    method: str
    n_train: int
    seed: int
    cfg: TrainConfig
    run: str
    """The run folder relative to the study or bench folder, ``runs/<setup>/<name>``."""
    labels: dict = field(default_factory=dict)
    """Extra ``results.csv`` cells of the run (a bench: its ``table`` and ``variant``)."""
    after: str | None = None
    """The run folder (relative) this run starts from, trained before it (a pre-training)."""
    scored: bool = True
    """Score it in closed loop and write its official outputs (a pre-training is not)."""


@dataclass(frozen=True)
class Plan:
    """The jobs of a study or bench: the points, the setups to render (by name, in order; a
    bench on found datasets renders none) and the runs."""

    points: tuple[Point, ...]
    setups: dict[str, Setup]
    runs: tuple[Run, ...]


@dataclass(frozen=True)
class Scoring:
    """How a plan's runs and setups are scored."""

    n_test: int
    """Held-out pairs per setup."""
    closed_loop: bool = True
    """Also project every compensation back through its (simulated) setup, and score the
    uncompensated projection and the feedback oracle."""
    official: bool = False
    """Write the official code's outputs of every run under ``official/<setup>``."""
    masks: bool = False
    """Write each setup's reachable-pixel strip under ``reachable/``."""
    renders_required: bool = False
    """A setup that cannot be rendered stops everything before the first fit (a bench needs all
    its setups); otherwise its runs become failed rows."""
    target: TargetPolicy = TargetPolicy()
    """What the closed loop scores against (:mod:`~compensation.experiments.targets`)."""


@dataclass(frozen=True)
class Outcome:
    """What :func:`execute` did: the renders, the fits and the baselines, each an executor record
    (``ok``, ``error`` and the job's result)."""

    rendered: dict[str, dict]
    """Setup name → render record."""
    fitted: dict[str, dict]
    """Run folder (relative) → fit record (with ``run``, the absolute folder; ``skipped`` where
    the run was not tried because its setup or the run it starts from failed)."""
    base: dict[str, dict]
    """Setup name → baseline record (setups whose data exists)."""


KINDS = {RenderJob: "render", FitJob: "fit", BaselineJob: "score"}
"""The kind of each job of a plan, as the progress line counts them."""


def fit_group(method: str) -> str:
    """The timing group of a fit of ``method`` (:func:`timing_group`).

    >>> fit_group("compennet")
    'compennet fit'
    """
    return f"{method} fit"


def timing_group(job: RenderJob | FitJob | BaselineJob) -> str:
    """The jobs whose durations predict ``job``'s: its kind (:data:`KINDS`), and for a fit its method
    too (a spline fit takes seconds, a network's training minutes)."""
    return fit_group(job.cfg.method) if isinstance(job, FitJob) else KINDS[type(job)]


def eta(done: Mapping[str, Sequence[float]], remaining: Mapping[str, int], workers: int = 1) -> float | None:
    """Seconds left: each timing group's remaining jobs times the mean duration of the jobs of
    that group that did work so far (``done``: durations by group, reused jobs left out), over
    ``workers`` jobs running side by side; None while a group with jobs left has none done.

    >>> eta({"render": [10.0, 20.0], "tps fit": [60.0]}, {"render": 1, "tps fit": 2, "score": 0})
    135.0
    >>> eta({"render": [10.0, 20.0], "tps fit": [60.0]}, {"render": 1, "tps fit": 2}, workers=3)
    45.0
    >>> eta({"render": [10.0], "tps fit": [1.0]}, {"render": 1, "tps fit": 1, "compennet fit": 1}) is None
    True
    """
    if any(n > 0 and not done.get(group) for group, n in remaining.items()):
        return None
    return sum(n * sum(done[group]) / len(done[group]) for group, n in remaining.items() if n > 0) / workers


def duration(seconds: float | None) -> str:
    """A time left in words, rounded to what matters: seconds under a minute, then minutes, then
    hours and minutes.

    >>> duration(None), duration(0.4), duration(42.6), duration(601), duration(7385)
    ('unknown', '0 s', '43 s', '10 min', '2 h 3 min')
    """
    if seconds is None:
        return "unknown"
    if seconds < 59.5:
        return f"{seconds:.0f} s"
    minutes = round(seconds / 60)
    return f"{minutes} min" if minutes < 60 else f"{minutes // 60} h {minutes % 60} min"


class JobCount:
    """The overall progress of a plan: at the start and after each job, one line on stderr with the jobs of each
    kind (:data:`KINDS`) done of all, how many were reused (finished earlier: no work) and failed
    (or not tried because one they need failed), and the time left (:func:`eta` over the timing
    groups of :func:`timing_group`).

    Parameters
    ----------
    totals : dict
        Kind → timing group → the plan's jobs of that group, e.g. ``{"render": {"render": 2},
        "fit": {"tps fit": 2, "compennet fit": 2}, "score": {"score": 2}}``.
    workers : int
        Jobs running side by side.
    show : bool
        Print the line (else only count).
    """

    def __init__(self, totals: Mapping[str, Mapping[str, int]], workers: int = 1, show: bool = True):
        self.workers, self.show = workers, show
        self.totals = {kind: sum(groups.values()) for kind, groups in totals.items()}
        self.kind_of = {group: kind for kind, groups in totals.items() for group in groups}
        self.left = {group: n for groups in totals.values() for group, n in groups.items()}
        self.done = dict.fromkeys(totals, 0)
        self.seconds: dict[str, list[float]] = {group: [] for group in self.left}
        self.reused = self.failed = 0

    def line(self) -> str:
        """The progress line, e.g. ``procam: jobs done: renders 2/2, fits 1/4, scores 2/2
        (1 reused, 0 failed); time left about 3 min``, or ``time left unknown (no compennet fit
        run yet)`` while a timing group with jobs left has none that did work."""
        counts = ", ".join(f"{kind}s {self.done[kind]}/{n}" for kind, n in self.totals.items())
        left = eta(self.seconds, self.left, self.workers)
        if left is None:
            untimed = [group for group, n in self.left.items() if n > 0 and not self.seconds[group]]
            when = f"unknown (no {' or '.join(untimed)} run yet)"
        else:
            when = f"about {duration(left)}"
        return f"procam: jobs done: {counts} ({self.reused} reused, {self.failed} failed); time left {when}"

    def report(self) -> None:
        """Print :meth:`line` (with ``show``)."""
        if self.show:
            tqdm.write(self.line(), file=sys.stderr)

    def not_tried(self, groups: Sequence[str]) -> None:
        """Count one job of each timing group of ``groups`` that cannot run (one it needs failed)
        as failed."""
        for group in groups:
            self.done[self.kind_of[group]] += 1
            self.left[group] -= 1
            self.failed += 1
        if groups:
            self.report()

    def run(self, executor, batch: Sequence[Task]) -> list[dict]:
        """``executor.run(batch)``, counting each job as it finishes."""
        def finished(i: int, record: dict, seconds: float) -> None:
            job = batch[i].job
            group = timing_group(job)
            self.done[KINDS[type(job)]] += 1
            self.left[group] -= 1
            if not record["ok"]:
                self.failed += 1
            elif record.get("reused"):  # the job's own word: it found its work finished
                self.reused += 1
            else:
                self.seconds[group].append(seconds)
            self.report()

        return executor.run(batch, on_done=finished)


def execute(plan: Plan, out: Path, data_root: Path, spec: FrameSpec, scoring: Scoring, executor,
            setups: list[str], progress: bool = True, raw: bool = False) -> Outcome:
    """Carry out ``plan`` into ``out``: render its setups into ``data_root`` (finished ones are
    kept), fit its runs (a run whose folder holds the same configuration is reused; runs sharing a
    folder are fitted once; a run with ``after`` waits for that run and is not tried when it
    failed), score each setup of ``setups`` once.

    Every job runs whatever the others do: failures are records with ``ok`` false and the error.
    Each setup's baseline scores are kept in ``out/baselines/<setup>.json`` for reuse. With
    ``progress``, the jobs show their progress bars and :class:`JobCount` its line, on stderr. With
    ``raw``, the renders keep the captures at camera resolution too.

    Raises
    ------
    ProcamError
        With ``scoring.renders_required``, if a setup cannot be rendered.
    """
    out, data_root = Path(out), Path(data_root)
    gpus = executor.gpus()
    methods: dict[str, str] = {}  # run folder → the method of its first run, the one fitted there
    for r in plan.runs:
        methods.setdefault(r.run, r.cfg.method)
    fits = Counter(fit_group(method) for method in methods.values())
    count = JobCount({"render": {"render": len(plan.setups)}, "fit": fits, "score": {"score": len(setups)}},
                     getattr(executor, "workers", 1), progress)
    count.report()
    renders = [RenderJob(data_root, s, spec, progress, raw) for s in plan.setups.values()]
    rendered = dict(zip(plan.setups, count.run(executor, tasks(render, renders, gpus))))
    if scoring.renders_required and (failed := [s for s, d in rendered.items() if not d["ok"]]):
        raise ProcamError(f"render {failed[0]}: {rendered[failed[0]]['error']}")
    ready = [s for s in setups if rendered.get(s, {"ok": True})["ok"]]
    count.not_tried(["score"] * (len(setups) - len(ready)))

    def job(r: Run) -> FitJob:
        return FitJob(data_root / r.setup, r.cfg, out / r.run, closed_loop=scoring.closed_loop and r.scored,
                      official=out / "official" / r.setup if scoring.official and r.scored else None,
                      pretrained=r.after is not None, progress=progress, target=scoring.target)

    fitted: dict[str, dict] = {}
    first = {r.after for r in plan.runs if r.after is not None}  # runs others start from
    stages = [[r for r in plan.runs if r.run in first], [r for r in plan.runs if r.run not in first]]
    for stage in stages:
        unique: dict[str, FitJob] = {}
        for r in stage:
            if not rendered.get(r.setup, {"ok": True})["ok"]:
                fitted[r.run] = {"ok": False, "run": str(out / r.run), "skipped": True,
                                 "error": f"render of {r.setup} failed: {rendered[r.setup]['error']}"}
            elif r.after is not None and not fitted.get(r.after, {}).get("ok"):
                fitted[r.run] = {"ok": False, "run": str(out / r.run), "skipped": True,
                                 "error": f"{r.after} failed: {fitted.get(r.after, {}).get('error')}"}
            else:
                unique.setdefault(r.run, job(r))
        skipped = {r.run: r.cfg.method for r in stage if fitted.get(r.run, {}).get("skipped")}
        count.not_tried([fit_group(method) for method in skipped.values()])
        bases = []
        if stage is stages[-1]:
            bases = [BaselineJob(data_root / s, scoring.n_test, scoring.closed_loop,
                                 out / "reachable" if scoring.masks else None, out / "baselines" / f"{s}.json",
                                 scoring.target, progress=progress)
                     for s in ready]
        # the baselines first: their duration is known early, for the time left
        done = count.run(executor, tasks(baselines, bases, gpus) + tasks(fit, list(unique.values()), gpus))
        fitted.update({run: {"run": str(j.run_dir), **d} for (run, j), d in zip(unique.items(), done[len(bases):])})
    return Outcome(rendered, fitted, dict(zip(ready, done[:len(bases)])))


def result_rows(plan: Plan, outcome: Outcome, out: Path) -> list[dict]:
    """One ``results.csv`` row per run of ``plan``: ``point``, the point's axis values, ``setup``,
    ``method``, ``n_train``, ``seed``, the run's scores (:func:`~compensation.experiments.jobs.result_row`)
    and its labels."""
    return [{"point": r.point.index, **r.point.values, "setup": r.setup, "method": r.method,
             "n_train": r.n_train, "seed": r.seed,
             **result_row(outcome.fitted[r.run], outcome.base.get(r.setup), Path(out)), **r.labels}
            for r in plan.runs]
