"""The jobs a study or benchmark is made of, and the records of its folder.

Each job is a module-level function of one frozen dataclass, so that any executor of
:mod:`compensation.experiments.executors` runs it, in this process or on another machine sharing the folder:

- :func:`render` (:class:`RenderJob`): one setup into the dataset root;
- :func:`fit` (:class:`FitJob`): train one method, or reuse a finished run of exactly the same
  configuration (:func:`reusable`), score it on the held-out pairs, and in closed loop (its
  compensation projected back through the setup, the captures of the first test images saved);
- :func:`baselines` (:class:`BaselineJob`): a setup's method-free scores: the test captures
  against the desired images and, in closed loop, the iterative-refinement oracle.

Records: ``results.csv`` and ``per_image.csv`` (:func:`result_row`, :func:`write_results`) and ``study.json``
(:func:`write_study_record`).
"""
from __future__ import annotations

import csv
import fcntl
import hashlib
import io
import json
import math
import os
import platform
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timezone
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

from compensation.data import load_setup_data
from compensation.experiments.closed_loop import CAPTURES_DIR, N_CAPTURES
from compensation.experiments.targets import TargetPolicy
from compensation.experiments.official import official_complete, official_tag, write_official_outputs
from compensation.training.config import NOT_IDENTITY, TrainConfig
from compensation.experiments.runs import (load_run, package_version, scores_are_current,
                                          source_revision, train_run, uncompensated_scores)
from sim.dataset import FrameSpec, write_setup
from sim.errors import ProcamError
from sim.io import atomic_write, check_output_folder, read_json, to_uint8, write_json, write_png
from sim.layout import META_FILE, SETUP_FILE, image_name
from sim.setup import Setup

DIVERGED_RATIO = 1.5
"""A run whose last logged training loss exceeds this multiple of its first has diverged."""
UNDERTRAINED_WINDOW = 0.1
"""Share of a run's logged training iterations in each of the two last windows that
:func:`still_falling` compares."""
UNDERTRAINED_TOLERANCE = 0.01
"""A run is undertrained where its mean training loss over the last :data:`UNDERTRAINED_WINDOW`
of the logged iterations is below the mean over the window before by more than this share of it
(:func:`still_falling`)."""
RATE_TOLERANCE = 0.01
""":func:`still_falling` judges a curve only where the learning rate over its two last windows
stays within this share of its largest value there: under a falling rate (a one-cycle or cosine
schedule annealing to its end, a step between the windows) the loss falls as the rate's noise
fades, whether or not more iterations would lower it."""
SCORES = ("psnr", "rmse", "ssim", "deltaE")
"""Scores of a run (:func:`~compensation.scores.metrics.evaluate`), in column order."""


def _column(score: str) -> str:
    return score.lower()


RESULT_COLUMNS = (
    "setup", "method", "n_train", "seed", "status", "error",
    *(_column(s) for s in SCORES), *(f"cl_{_column(s)}" for s in SCORES),
    *(f"unc_{_column(s)}" for s in SCORES), "cl_unc_psnr", "cl_unc_ssim", "cl_unc_deltae",
    "oracle_psnr", "oracle_ssim", "oracle_deltae", "optimum_psnr", "optimum_ssim", "optimum_deltae",
    "fit_s", "infer_ms", "run",
    "cl_psnr_reachable", "cl_unc_psnr_reachable", "reachable_fraction", "target_policy",
    "target_out_of_reach", "target_out_of_reach_used", "target_a", "target_b", "undertrained",
    "ambient_share", "indirect_share")
"""Columns of ``results.csv`` after ``point`` and the axis columns (an axis on ``n_train`` is the
``n_train`` column itself); a bench adds ``table`` and ``variant``. ``undertrained`` is 1 where the
run's training loss was still falling at its end (:func:`still_falling`), 0 where it was not, empty
where the learning rate fell over the windows compared (not judged). The ``optimum_``
scores are those of the exact optimum's frames (:mod:`~compensation.experiments.optimum`) projected
as a method's are. The ``cl_``, ``oracle_`` and ``optimum_`` scores compare with the target y' of
``target_policy`` (map y' = ``target_a`` · y + ``target_b``,
the mean over the images for the ``image`` policy; ``target_out_of_reach_used``: the share of pixels
the map was allowed to leave out, above the policy's where that admits no contrast);
``reachable_fraction`` is the share of y''s pixels the setup can show. ``ambient_share`` and
``indirect_share`` are the setup's room light and inter-reflected light as shares of the
projector's white and of its direct light (:func:`~sim.light.light_shares`)."""


@dataclass(frozen=True)
class RenderJob:
    """Render ``setup`` into ``root`` (what is finished is kept)."""

    root: Path
    setup: Setup
    spec: FrameSpec
    progress: bool = False
    raw: bool = False
    """Also keep the captures at camera resolution (:func:`sim.dataset.write_setup`)."""


@contextmanager
def _render_turn(root: Path) -> Iterator[None]:
    """Wait for this process's turn to write the dataset root ``root`` (``root/.queue``, an
    exclusive ``flock``): renders into one root run one after the other, whoever started them."""
    root.mkdir(parents=True, exist_ok=True)
    fd = os.open(root / ".queue", os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)


def _stamp(path: Path) -> tuple[int, int] | None:
    """The identity of a file as written (inode, modification time), None where there is none."""
    if not path.exists():
        return None
    stat = path.stat()
    return stat.st_ino, stat.st_mtime_ns


def render(job: RenderJob) -> dict:
    """Run a :class:`RenderJob`; returns ``setup``, ``seconds`` (waiting included) and ``reused``
    (the dataset was finished before: its ``meta.json``, written last, is the one that was there)."""
    t0 = time.perf_counter()
    meta = Path(job.root) / job.setup.name / META_FILE
    before = _stamp(meta)
    with _render_turn(Path(job.root)):
        write_setup(Path(job.root), job.setup, job.spec, progress=job.progress, raw=job.raw)
    return {"setup": job.setup.name, "seconds": round(time.perf_counter() - t0, 3),
            "reused": before is not None and _stamp(meta) == before}


@dataclass(frozen=True)
class FitJob:
    """Train ``cfg`` on the dataset ``setup_dir`` into ``run_dir`` (or reuse it), then score it.

    Attributes
    ----------
    closed_loop : bool
        Also project its compensation back through the setup (simulated setups only: those with a
        ``setup.toml``) and save the first :data:`N_CAPTURES` captures.
    official : Path or None
        Write the official code's outputs under this folder (:mod:`~compensation.experiments.official`).
    pretrained : bool
        The run starts from a pre-trained one (its official tag says so).
    target : TargetPolicy
        The target policy of the closed loop; a run scored under another is scored again.
    """

    setup_dir: Path
    cfg: TrainConfig
    run_dir: Path
    closed_loop: bool = True
    official: Path | None = None
    pretrained: bool = False
    progress: bool = False
    target: TargetPolicy = TargetPolicy()


def reusable(run_dir: Path, train_cfg: TrainConfig, setup_dir: Path) -> dict | None:
    """The metrics of a finished run made with exactly ``train_cfg`` (``NOT_IDENTITY`` aside) on the dataset
    ``setup_dir`` by this procam version and scored with today's metrics
    (:func:`~compensation.experiments.runs.scores_are_current`), else None."""
    if not (run_dir / "metrics.json").exists():
        return None
    try:
        config = read_json(run_dir / "config.json", "run configuration")
        done = config["train"]
    except (ProcamError, KeyError, TypeError):
        return None
    wanted = train_cfg.to_dict()
    if (config.get("dataset") != str(Path(setup_dir).resolve())
            or config.get("procam_version") != package_version()
            or not all(done.get(k) == v for k, v in wanted.items() if k not in NOT_IDENTITY)):
        return None
    metrics = read_json(run_dir / "metrics.json", "run metrics")
    return metrics if scores_are_current(metrics) else None


def simulated(setup_dir: Path) -> bool:
    """Whether procam rendered the setup (its ``setup.toml`` makes a closed loop possible)."""
    return (Path(setup_dir) / SETUP_FILE).exists()


def scored_under(scores: dict, policy: TargetPolicy) -> bool:
    """Whether closed-loop scores (with their ``target`` record) were made under ``policy``.

    >>> scored_under({"target": {"policy": "global", "out_of_reach": 0.01}}, TargetPolicy())
    True
    >>> scored_under({}, TargetPolicy("none"))
    False
    """
    target = scores.get("target") or {}
    return all(target.get(k) == v for k, v in policy.record().items())


def _closed_loop_done(run_dir: Path, metrics: dict, policy: TargetPolicy) -> bool:
    scores = metrics.get("closed_loop", {})
    shown = min(N_CAPTURES, metrics.get("n_test", 0))
    return (all(k in scores for k in (*SCORES, "psnr_reachable", "psnr_per_image"))
            and scored_under(scores, policy)
            and all((run_dir / CAPTURES_DIR / image_name(i)).exists() for i in range(1, shown + 1)))


def add_closed_loop(run_dir: Path, setup_dir: Path, n_test: int, policy: TargetPolicy = TargetPolicy()) -> dict:
    """Score a finished run in closed loop under the target ``policy``: ``closed_loop`` added to
    its ``metrics.json`` (scores of :func:`~compensation.experiments.closed_loop.closed_loop`, with
    their ``target``, and ``seconds``), the captures of the first :data:`N_CAPTURES` test images
    written to ``run_dir/closed_loop/img_XXXX.png`` (canonical view). Returns the metrics."""
    from compensation.experiments.closed_loop import closed_loop, simulator_for, write_captures

    method, _ = load_run(run_dir)
    data = load_setup_data(setup_dir, n_train=1, n_test=n_test)
    t0 = time.perf_counter()
    scores, captured = closed_loop(method, data, simulator_for(setup_dir), return_captures=True,
                                   policy=policy)
    scores["seconds"] = round(time.perf_counter() - t0, 3)
    write_captures(run_dir, captured)
    metrics = read_json(run_dir / "metrics.json", "run metrics")
    metrics["closed_loop"] = scores
    write_json(run_dir / "metrics.json", metrics)
    return metrics


def fit(job: FitJob) -> dict:
    """Run a :class:`FitJob`; returns ``metrics`` (the run's ``metrics.json``), ``trained``
    (False when a finished run was reused), ``reused`` (nothing was done: neither training nor
    closed loop nor official outputs), the ``official_tag`` of its outputs and ``run`` (its
    folder)."""
    setup_dir, run_dir = Path(job.setup_dir), Path(job.run_dir)
    metrics = reusable(run_dir, job.cfg, setup_dir)
    trained = metrics is None
    predicted = None
    if trained:
        metrics, predicted = train_run(setup_dir, job.cfg, run_dir, job.progress, overwrite=True,
                                       return_predicted=True)
    tag = official_tag(job.cfg, job.pretrained)
    worked = trained
    if job.official is not None and (trained or not official_complete(job.official, tag, metrics["n_test"])):
        data = load_setup_data(setup_dir, 1, metrics["n_test"])
        write_official_outputs(run_dir, data, Path(job.official), tag, cam=predicted)
        worked = True
    if job.closed_loop and simulated(setup_dir) and (trained or not _closed_loop_done(run_dir, metrics, job.target)):
        metrics = add_closed_loop(run_dir, setup_dir, metrics["n_test"], job.target)
        worked = True
    return {"metrics": metrics, "trained": trained, "reused": not worked, "official_tag": tag,
            "run": str(run_dir)}


ORACLE_ROUNDS = (1, 2, 4, 8)
"""The feedback rounds after which a bench scores the oracle."""


@dataclass(frozen=True)
class BaselineJob:
    """The method-free scores of the dataset ``setup_dir`` on its first ``n_test`` test pairs.

    Attributes
    ----------
    closed_loop : bool
        Also the closed-loop scores of y projected as is, the iterative-refinement oracle and the
        exact optimum (simulated setups only).
    masks : Path or None
        Write ``masks/<setup>.png``: the first test images with their physically unreachable
        pixels tinted magenta (closed loop only).
    record : Path or None
        A JSON file keeping the result: reused while the dataset, ``n_test``, the target policy,
        the oracle's rounds and the procam version are the same.
    target : TargetPolicy
        The target policy of the closed loop.
    oracle_rounds : tuple of int
        The feedback rounds after which the oracle is scored (one row each); the exact optimum
        starts from the frames of the last.
    progress : bool
        Show the oracle's and the exact optimum's progress bars.
    """

    setup_dir: Path
    n_test: int
    closed_loop: bool = True
    masks: Path | None = None
    record: Path | None = None
    target: TargetPolicy = TargetPolicy()
    oracle_rounds: tuple[int, ...] = ORACLE_ROUNDS
    progress: bool = False


def _baseline_key(job: BaselineJob, closed: bool) -> dict:
    meta = Path(job.setup_dir) / META_FILE
    digest = hashlib.sha1(meta.read_bytes()).hexdigest() if meta.exists() else None
    return {"dataset": str(Path(job.setup_dir).resolve()), "meta_sha1": digest, "n_test": job.n_test,
            "closed_loop": closed, "procam_version": package_version(),
            "target": job.target.record() if closed else None,
            "rows": ["uncompensated", "oracle", "optimum"] if closed else ["uncompensated"],
            # the rounds only where they are not a bench's, so that records kept before they
            # were part of the key stay valid
            **({"oracle_rounds": list(job.oracle_rounds)} if closed and job.oracle_rounds != ORACLE_ROUNDS else {})}


def baselines(job: BaselineJob) -> dict:
    """Run a :class:`BaselineJob`; returns ``uncompensated`` (scores of the test captures x̃
    against y, with ``closed_loop`` scores of the target y' projected as is when simulated:
    :func:`~compensation.experiments.closed_loop.uncompensated`), ``oracle`` (the rows of
    :func:`~compensation.experiments.closed_loop.iterative_refinement`, or None), ``optimum`` (the
    scores of :func:`~compensation.experiments.optimum.optimum` started from the oracle's last
    frames, or None), ``light`` (:func:`~sim.light.light_shares` through the closed loop's simulator,
    or None), ``size`` ([height, width]) and ``reused`` (the kept record was returned)."""
    from compensation.experiments.closed_loop import simulator_for
    from sim.light import light_shares

    setup_dir = Path(job.setup_dir)
    closed = job.closed_loop and simulated(setup_dir)
    key = _baseline_key(job, closed)
    if job.record is not None and Path(job.record).exists() and job.masks is None:
        try:
            kept = read_json(job.record, "baseline record")
        except ProcamError:
            kept = {}
        if kept.get("key") == key:
            result = kept["result"]
            if result.get("light") is None and closed:  # kept before the light was measured
                result["light"] = light_shares(simulator_for(setup_dir))
                write_json(job.record, {"key": key, "result": result})
            return {**result, "reused": True}
    data = load_setup_data(setup_dir, n_train=1, n_test=job.n_test)
    captures, y = data.test.captures, data.test.frames
    scores, oracle, best, light = uncompensated_scores(captures, y), None, None, None
    if closed:
        from compensation.experiments.closed_loop import (closed_loop_target, iterative_refinement,
                                                         reachable_mask, reachable_overlay,
                                                         uncompensated)
        from compensation.experiments.optimum import optimum

        sim = simulator_for(setup_dir)
        light = light_shares(sim)
        scores["closed_loop"], _ = uncompensated(data, sim, policy=job.target)
        if job.masks is not None:
            k = min(N_CAPTURES, y.shape[0])
            target, _ = closed_loop_target(data, y[:k], job.target)
            strip = reachable_overlay(target, reachable_mask(data, target))
            strip = strip.permute(2, 0, 3, 1).reshape(y.shape[2], -1, 3)
            write_png(Path(job.masks) / f"{data.name}.png", to_uint8(strip.numpy()))
        oracle, frames = iterative_refinement(data, sim, report=job.oracle_rounds, policy=job.target,
                                              return_frames=True, progress=job.progress)
        best, _ = optimum(data, sim, policy=job.target, starts=(frames,), progress=job.progress)
    result = {"uncompensated": scores, "oracle": oracle, "optimum": best, "light": light,
              "size": list(data.size)}
    if job.record is not None:
        write_json(job.record, {"key": key, "result": result})
    return {**result, "reused": False}


def _loss_grew(run_dir: Path) -> bool:
    """Whether the run's logged training loss ended above :data:`DIVERGED_RATIO` times its start."""
    losses, _ = _curve(run_dir)
    return len(losses) > 1 and losses[-1] > DIVERGED_RATIO * losses[0]


PER_IMAGE_SCORES = ("psnr", "cl_psnr", "cl_unc_psnr", "oracle_psnr", "optimum_psnr")
"""Per test image scores of ``per_image.csv`` (dB): surrogate, closed loop, uncompensated closed loop
the oracle's (its most corrections) and the exact optimum's, each against the same image as in
``results.csv``."""


def still_falling(losses: Sequence[float], rates: Sequence[float] | None = None,
                  window: float = UNDERTRAINED_WINDOW, tolerance: float = UNDERTRAINED_TOLERANCE) -> bool | None:
    """Whether a training loss curve was still falling at its end: the mean of its last ``window``
    share of values (at least one) is below the mean of the ``window`` before it by more than
    ``tolerance`` times that mean. Curves of fewer than two values never are. None (not judged)
    where the learning rates logged beside the losses (``rates``) vary over the two windows by more
    than :data:`RATE_TOLERANCE` of their largest value: an annealed rate lowers the loss by itself.

    >>> still_falling([1.0] * 10 + [0.9] * 10)
    False
    >>> still_falling([1.0 - 0.01 * i for i in range(20)])
    True
    >>> still_falling([1.0, 0.5, 0.3] + [0.2] * 17)
    False
    >>> still_falling([1.0 - 0.01 * i for i in range(20)], rates=[1e-3] * 20)
    True
    >>> print(still_falling([1.0 - 0.01 * i for i in range(20)], rates=[1e-3 * (20 - i) / 20 for i in range(20)]))
    None
    """
    n = max(1, int(len(losses) * window))
    if len(losses) < 2 * n:
        return False
    if rates is not None and len(rates) == len(losses):
        compared = rates[-2 * n:]
        if max(compared) - min(compared) > RATE_TOLERANCE * max(compared):
            return None
    last, before = sum(losses[-n:]) / n, sum(losses[-2 * n:-n]) / n
    return last < before * (1 - tolerance)


def _curve(run_dir: Path) -> tuple[list[float], list[float] | None]:
    """The run's logged training losses and learning rates (``loss.csv``; rates None where it logs
    none), empty where it has no loss log or it is unreadable."""
    try:
        with open(run_dir / "loss.csv", newline="") as f:
            rows = list(csv.DictReader(f))
        losses = [float(r["loss"]) for r in rows]
        rates = [float(r["lr"]) for r in rows] if rows and "lr" in rows[0] else None
        return losses, rates
    except (OSError, KeyError, ValueError, TypeError):
        return [], None


def run_status(metrics: dict, run_dir: Path) -> tuple[str, str]:
    """The ``status`` of a finished run (:data:`~compensation.reports.summary.STATUSES`, never
    ``failed``) and why."""
    loss = metrics.get("final_loss")
    if loss is not None and not math.isfinite(loss):
        return "diverged", f"final training loss {loss}"
    if _loss_grew(run_dir):
        return "diverged", f"training loss grew above {DIVERGED_RATIO}x its first value"
    cl = metrics.get("closed_loop", {})
    bad = [k for k in SCORES if not math.isfinite(metrics.get(k, 0.0))]
    bad += [f"cl_{k}" for k in SCORES if not math.isfinite(cl.get(k, 0.0))]
    if bad:
        return "nan", f"not finite: {', '.join(_column(k) for k in bad)}"
    return "ok", ""


def target_cells(closed: dict) -> dict:
    """The ``results.csv`` cells of closed-loop scores' target and reach (empty without them).

    >>> target_cells({"reachable_fraction": 0.9, "target": {"policy": "global", "out_of_reach": 0.01,
    ...                                                      "out_of_reach_used": 0.2, "a": 0.5, "b": 0.1}})
    {'reachable_fraction': 0.9, 'target_policy': 'global', 'target_out_of_reach': 0.01, 'target_out_of_reach_used': 0.2, 'target_a': 0.5, 'target_b': 0.1}
    """
    target = closed.get("target") or {}
    return {"reachable_fraction": closed.get("reachable_fraction"), "target_policy": target.get("policy"),
            "target_out_of_reach": target.get("out_of_reach"),
            "target_out_of_reach_used": target.get("out_of_reach_used"), "target_a": target.get("a"),
            "target_b": target.get("b")}


def bound_cells(prefix: str, scores: dict) -> dict:
    """A method-free closed-loop row's cells of ``results.csv`` (the uncompensated projection, the
    oracle, the optimum): ``<prefix>psnr``, ``<prefix>ssim`` and ``<prefix>deltae``.

    >>> bound_cells("oracle_", {"psnr": 20.0, "ssim": 0.5, "deltaE": 9.0, "rmse": 0.1})
    {'oracle_psnr': 20.0, 'oracle_ssim': 0.5, 'oracle_deltae': 9.0}
    """
    return {f"{prefix}{_column(k)}": scores[k] for k in ("psnr", "ssim", "deltaE")}


def result_row(fitted: dict, base: dict | None, out: Path) -> dict:
    """The ``results.csv`` cells of one run (all but ``point``, the axes, ``setup``, ``method``,
    ``n_train`` and ``seed``, which the caller knows).

    ``per_image`` holds the per-image scores the run and its baselines kept, by name of
    :data:`PER_IMAGE_SCORES` (:func:`per_image_rows`; not a ``results.csv`` column).

    Parameters
    ----------
    fitted : dict
        The :func:`~compensation.experiments.executors.attempt` record of its :func:`fit` job, or of the job
        that kept it from running (``error`` then names that one).
    base : dict or None
        The record of its setup's :func:`baselines` job (None: not run).
    out : Path
        The study folder (``run`` is written relative to it).
    """
    row: dict = {}
    per_image: dict = {}
    if fitted.get("ok"):
        metrics, run_dir = fitted["metrics"], Path(fitted["run"])
        row["status"], row["error"] = run_status(metrics, run_dir)
        cl = metrics.get("closed_loop", {})
        row.update({_column(k): metrics[k] for k in SCORES})
        row.update({f"cl_{_column(k)}": cl.get(k) for k in SCORES})
        row.update(fit_s=metrics.get("train_seconds"), infer_ms=cl.get("infer_ms_per_frame"),
                   cl_psnr_reachable=cl.get("psnr_reachable"), **target_cells(cl))
        row.update({f"unc_{_column(k)}": metrics["uncompensated"][k] for k in SCORES})
        row["run"] = os.path.relpath(run_dir, out)
        falling = still_falling(*_curve(run_dir))
        row["undertrained"] = "" if falling is None else int(falling)
        per_image.update(psnr=metrics.get("psnr_per_image"), cl_psnr=cl.get("psnr_per_image"))
    else:
        row["status"], row["error"] = "failed", fitted.get("error", "not run")
        if "run" in fitted:
            row["run"] = os.path.relpath(fitted["run"], out)
    if base and base.get("ok"):
        unc = base["uncompensated"]
        row.update({f"unc_{_column(k)}": unc[k] for k in SCORES})
        cl = unc.get("closed_loop", {})
        row.update({f"cl_unc_{_column(k)}": cl.get(k) for k in ("psnr", "ssim", "deltaE")},
                   cl_unc_psnr_reachable=cl.get("psnr_reachable"))
        per_image["cl_unc_psnr"] = cl.get("psnr_per_image")
        if cl:
            row.update({k: v for k, v in target_cells(cl).items() if row.get(k) is None})
        if base.get("oracle"):
            best = max(base["oracle"], key=lambda r: r["iterations"])
            row.update(bound_cells("oracle_", best))
            per_image["oracle_psnr"] = best.get("psnr_per_image")
        if base.get("optimum"):
            row.update(bound_cells("optimum_", base["optimum"]))
            per_image["optimum_psnr"] = base["optimum"].get("psnr_per_image")
        if base.get("light"):
            row.update(ambient_share=base["light"]["ambient"], indirect_share=base["light"]["indirect"])
    row["per_image"] = {k: v for k, v in per_image.items() if v}
    return row


def _cell(value) -> str:
    """A CSV cell: empty for a missing value, floats with 6 significant digits, lists as JSON."""
    if value is None:
        return ""
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, (list, tuple)):
        return json.dumps(list(value))
    return str(value)


def cell_identity(value) -> str:
    """What an axis value is once :func:`_cell` has written it to ``results.csv``: two values of one
    identity are one cell. Whole numbers in full, decimals to the cell's 6 significant digits
    (0 and -0 one), the entries of a list in full (its cell is JSON), anything else as text; the
    cell's own text has the identity of the value it was written from.

    >>> cell_identity(1) == cell_identity(1.0), cell_identity(True) == cell_identity(1)
    (True, False)
    >>> cell_identity(0.1234567) == cell_identity("0.123457"), cell_identity(-0.0) == cell_identity("0")
    (True, True)
    >>> cell_identity(20240101) == cell_identity("20240102"), cell_identity(20240101.0) == cell_identity(20240102.0)
    (False, True)
    >>> cell_identity([0.1, 1]) == cell_identity("[0.1, 1.0]"), cell_identity("RGGB")
    (True, 'RGGB')
    """
    if isinstance(value, str):
        text = value.strip()
        for parse in (int, float, json.loads):
            try:
                parsed = parse(text)
            except ValueError:
                continue
            if isinstance(parsed, (int, float, list)):
                return cell_identity(parsed)
        return text
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_number_identity(v, rounded=False) for v in value) + "]"
    return _number_identity(value, rounded=True)


def _number_identity(value, rounded: bool) -> str:
    """A number's part of :func:`cell_identity` (rounded to 6 significant digits, or in full);
    anything else as text."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value)
    if isinstance(value, float):
        value = (float(f"{value:.6g}") if rounded else value) + 0.0
        return repr(int(value)) if value.is_integer() and abs(value) < 2 ** 53 else repr(value)
    return repr(value)


def per_image_rows(rows: Sequence[dict], keys: Sequence[str]) -> list[dict]:
    """One row per run and test image: the run's ``keys`` cells, ``image`` (1-based) and its
    :data:`PER_IMAGE_SCORES` (None where not kept), from each row's ``per_image``
    (:func:`result_row`); runs without per-image scores give none.

    >>> per_image_rows([{"point": 0, "per_image": {"cl_psnr": [20.0, 21.0], "oracle_psnr": [22.0]}},
    ...                 {"point": 1}], ["point"])[1]["cl_psnr"]
    21.0
    """
    out = []
    for row in rows:
        scores = row.get("per_image") or {}
        for i in range(max((len(v) for v in scores.values()), default=0)):
            out.append({**{k: row.get(k) for k in keys}, "image": i + 1,
                        **{k: scores[k][i] if i < len(scores.get(k) or ()) else None
                           for k in PER_IMAGE_SCORES}})
    return out


def _write_table(path: Path, header: Sequence[str], rows: Sequence[dict]) -> Path:
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(header)
    writer.writerows([_cell(row.get(k)) for k in header] for row in rows)
    atomic_write(path, text.getvalue())
    return path


def write_results(out: Path, axis_keys: Sequence[str], rows: Sequence[dict],
                  extra: Sequence[str] = ()) -> Path:
    """Write ``out/results.csv``: ``point``, one column per axis key (but ``n_train``, which has
    its own), :data:`RESULT_COLUMNS`, then ``extra``; missing values are empty cells. Beside it
    ``out/per_image.csv`` (:func:`per_image_rows`): ``point``, the axis columns, ``setup``,
    ``method``, ``n_train``, ``seed``, ``extra``, ``image`` and :data:`PER_IMAGE_SCORES`."""
    axes = [k for k in axis_keys if k not in RESULT_COLUMNS]
    keys = ["point", *axes, "setup", "method", "n_train", "seed", *extra]
    _write_table(out / "per_image.csv", [*keys, "image", *PER_IMAGE_SCORES], per_image_rows(rows, keys))
    return _write_table(out / "results.csv", ["point", *axes, *RESULT_COLUMNS, *extra], rows)


def versions() -> dict:
    """Versions of procam (its number and :func:`~compensation.experiments.runs.source_revision`),
    torch, Mitsuba and Python."""
    import torch

    try:
        mitsuba = version("mitsuba")
    except PackageNotFoundError:
        mitsuba = "unknown"
    return {"procam": package_version(), "procam source": source_revision(), "torch": torch.__version__,
            "mitsuba": mitsuba, "python": platform.python_version()}


FOLDER_ENTRIES = ("study.json", "results.csv", "per_image.csv", "summary.csv", "breakpoints.csv",
                  "failures.csv", "failures.json", "bench.json", "report.html", "charts", "data", "runs",
                  "baselines", "reachable", "official", "table[123]*", "per_setup.*", "demo.png", "demo.json",
                  "compare-*")
"""What a study, bench or demo folder holds (:mod:`fnmatch` patterns): its records, tables, report
and charts (``procam report``), datasets, runs, baselines and comparisons."""


def check_study_folder(out: Path, name: str, kind: str) -> None:
    """Refuse to write the study (or bench) ``name`` into ``out`` where that holds another study
    or bench (its ``study.json`` of another ``name`` or ``kind``), or, without a ``study.json``, is
    a file or holds an entry none of them writes (:data:`FOLDER_ENTRIES`: the user's own files);
    nothing is written then. In its own folder a study writes only those entries, whatever else
    is put there.

    Raises
    ------
    ProcamError
        Naming the folder, and the study it holds.
    """
    record = Path(out) / "study.json"
    if not record.exists():
        check_output_folder(out, FOLDER_ENTRIES, "study, bench or demo")
        return
    held = read_json(record, "study record")
    if (held.get("kind", "study"), held.get("name")) != (kind, name):
        raise ProcamError(f"{record}: this folder holds the {held.get('kind', 'study')} "
                          f"{held.get('name')!r}; choose another --out for the {kind} {name!r}")


def write_study_record(out: Path, record: dict, created: str | None = None) -> dict:
    """Write ``out/study.json``: ``record`` plus ``versions`` and ``created`` (ISO time, UTC; now
    unless given). Returns what it wrote."""
    written = {**record, "versions": versions(),
               "created": created or datetime.now(timezone.utc).isoformat(timespec="seconds")}
    write_json(out / "study.json", written)
    return written


def tasks(fn, jobs: Sequence, gpus: float) -> list:
    """One :class:`~compensation.experiments.executors.Task` per job: one CPU core each, and one GPU where the
    machine or cluster has GPUs (``gpus``) and the job uses them: a render or a baseline (Mitsuba's
    CUDA variant is chosen when a GPU is present) or a fit whose device is ``auto`` or ``cuda[:N]``."""
    from compensation.experiments.executors import Task

    def needs_gpu(job) -> bool:
        wanted = job.cfg.device if isinstance(job, FitJob) else "auto"
        return gpus > 0 and (wanted == "auto" or wanted.startswith("cuda"))

    return [Task(fn, job, num_cpus=1.0, num_gpus=1.0 if needs_gpu(job) else 0.0) for job in jobs]
