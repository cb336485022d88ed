"""The one planner of studies and benches: points, runs, run folders, and carrying a plan out.

A *plan* is what a study file or a bench configuration expands to: the grid of points (a bench
has one, point 0), the setups to render and the runs — one method fitted with one seed on one
setup of one point, in the run folder ``runs/<setup>/<name>`` named by :func:`run_name`. Both
commands then go through :func:`execute` (render, fit, score, baselines, by the executor's
jobs of :mod:`compensation.experiments.jobs`) and :func:`result_rows` (one ``results.csv`` row per
run), so they name folders, reuse runs and record failures the same way.
"""
from __future__ import annotations

import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from compensation.experiments.jobs import (BaselineJob, FitJob, RenderJob, baselines, fit, render,
                                          result_row, tasks)
from compensation.experiments.targets import TargetPolicy
from compensation.training.config import TrainConfig
from sim.dataset import FrameSpec
from sim.errors import ProcamError
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


def execute(plan: Plan, out: Path, data_root: Path, spec: FrameSpec, scoring: Scoring, executor,
            setups: list[str], progress: bool = True) -> Outcome:
    """Carry out ``plan`` into ``out``: render its setups into ``data_root`` (finished ones are
    kept), fit its runs (a run whose folder holds the same configuration is reused; runs sharing a
    folder are fitted once; a run with ``after`` waits for that run and is not tried when it
    failed), score each setup of ``setups`` once.

    Every job runs whatever the others do: failures are records with ``ok`` false and the error.
    Each setup's baseline scores are kept in ``out/baselines/<setup>.json`` for reuse.

    Raises
    ------
    ProcamError
        With ``scoring.renders_required``, if a setup cannot be rendered.
    """
    out, data_root = Path(out), Path(data_root)
    gpus = executor.gpus()
    renders = [RenderJob(data_root, s, spec, progress) for s in plan.setups.values()]
    rendered = dict(zip(plan.setups, executor.run(tasks(render, renders, gpus))))
    if scoring.renders_required and (failed := [s for s, d in rendered.items() if not d["ok"]]):
        raise ProcamError(f"render {failed[0]}: {rendered[failed[0]]['error']}")
    ready = [s for s in setups if rendered.get(s, {"ok": True})["ok"]]

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
        bases = []
        if stage is stages[-1]:
            bases = [BaselineJob(data_root / s, scoring.n_test, scoring.closed_loop,
                                 out / "reachable" if scoring.masks else None, out / "baselines" / f"{s}.json",
                                 scoring.target)
                     for s in ready]
        done = executor.run(tasks(fit, list(unique.values()), gpus) + tasks(baselines, bases, gpus))
        fitted.update({run: {"run": str(j.run_dir), **d} for (run, j), d in zip(unique.items(), done)})
    return Outcome(rendered, fitted, dict(zip(ready, done[len(unique):])))


def result_rows(plan: Plan, outcome: Outcome, out: Path) -> list[dict]:
    """One ``results.csv`` row per run of ``plan``: ``point``, the point's axis values, ``setup``,
    ``method``, ``n_train``, ``seed``, the run's scores (:func:`~compensation.experiments.jobs.result_row`)
    and its labels."""
    return [{"point": r.point.index, **r.point.values, "setup": r.setup, "method": r.method,
             "n_train": r.n_train, "seed": r.seed,
             **result_row(outcome.fitted[r.run], outcome.base.get(r.setup), Path(out)), **r.labels}
            for r in plan.runs]
