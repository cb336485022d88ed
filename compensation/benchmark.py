"""The surrogate benchmark of the CompenNet paper over a suite of simulated setups.

suite → (render what is missing) → train each method × training size × setup → evaluate →
Table 1 (methods × training-set sizes, averaged over setups, with the uncompensated row),
Table 2 (pre-trained vs He-initialised CompenNet: 32 pairs, 500 iterations, batch 32),
Table 3 (training losses ℓ1, ℓ2, SSIM, ℓ1+SSIM), as Markdown and CSV, plus per-setup rows.
With ``closed_loop`` every run is also scored by projecting its compensation back through the
setup, next to the iterative-refinement oracle.

Resumable: a run whose ``metrics.json`` exists is not redone; a failing run is recorded in
``failures.json`` and does not lose the others.
"""
from __future__ import annotations

import csv
import json
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from compensation.data import load_setup_data
from compensation.methods import METHODS
from compensation.metrics import evaluate
from compensation.train import PROFILES, make_config, train_run
from sim.dataset import FrameSpec, write_json, write_setup, write_text
from sim.io import to_uint8, write_png

METRICS = ("psnr", "rmse", "ssim")
CL_COLUMNS = (*METRICS, "psnr_reachable", "infer_ms_per_frame")
"""Closed-loop keys shown in the tables (the last only for methods)."""
N_MASK_FIGURE = 4
"""Test images per setup in ``reachable/<setup>.png``."""
TABLE2 = dict(n_train=32, iters=500, batch=32)
"""The paper's fine-tuning setting for Table 2."""
LOSSES = ("l1", "l2", "ssim", "l1+ssim")


@dataclass(frozen=True)
class BenchConfig:
    """What ``procam bench`` runs.

    Attributes
    ----------
    profile : str
        Training profile (``quick`` or ``paper``); also gives the canonical size and test count.
    methods : tuple of str
        Methods of Table 1 (registry names).
    sizes : tuple of int
        Training-set sizes of Table 1.
    tables : tuple of str
        Which tables to produce ("1", "2", "3").
    size : int or None
        Canonical size override (pixels); None takes the profile's.
    n_test : int or None
        Test pairs override; None takes the profile's.
    overrides : dict
        TrainConfig overrides applied to every run (e.g. ``iters``, ``batch``, ``device``).
    closed_loop : bool
        Also score every run in closed loop and add the iterative-refinement oracle.
    """

    profile: str = "quick"
    methods: tuple[str, ...] = ("compennet", "compennet-nosurf")
    sizes: tuple[int, ...] = (125, 250, 500)
    tables: tuple[str, ...] = ("1", "2", "3")
    size: int | None = None
    n_test: int | None = None
    overrides: dict = field(default_factory=dict)
    closed_loop: bool = False

    @property
    def canonical(self) -> int:
        return self.size or PROFILES[self.profile]["size"]

    @property
    def tests(self) -> int:
        return self.n_test or PROFILES[self.profile]["n_test"]


@dataclass(frozen=True)
class Job:
    """One training run of the benchmark."""

    table: str
    setup: str
    method: str
    n_train: int
    loss: str = "l1+ssim"
    init: str | None = None
    extra: tuple = ()

    @property
    def run_name(self) -> str:
        tag = f"{self.method}-n{self.n_train}-{self.loss}"
        tag += "-pretrained" if self.init else ""
        return tag + "".join(f"-{k}{v}" for k, v in self.extra)


def _jobs(cfg: BenchConfig, setups: list[str], pretrain_run: Path | None) -> list[Job]:
    jobs = []
    if "1" in cfg.tables:
        jobs += [Job("1", s, m, n) for s in setups for m in cfg.methods for n in cfg.sizes]
    if "2" in cfg.tables:
        extra = tuple((k, v) for k, v in TABLE2.items() if k != "n_train")
        for s in setups:
            jobs.append(Job("2", s, "compennet", TABLE2["n_train"], extra=extra))
            if pretrain_run is not None:
                jobs.append(Job("2", s, "compennet", TABLE2["n_train"], init=str(pretrain_run),
                                extra=extra))
    if "3" in cfg.tables:
        jobs += [Job("3", s, "compennet", max(cfg.sizes), loss) for s in setups for loss in LOSSES]
    return jobs


def _train_config(cfg: BenchConfig, job: Job):
    values = {**cfg.overrides, "method": job.method, "n_train": job.n_train, "n_test": cfg.tests,
              "loss": job.loss, "init": job.init}
    values.update({k: v for k, v in job.extra if k not in cfg.overrides})  # the user's word wins
    return make_config(cfg.profile, **values)


def run_bench(suite: list, out: Path, cfg: BenchConfig, data_root: Path | None = None,
              white=None, progress: bool = True) -> dict[str, Path]:
    """Run the benchmark and write its tables.

    Parameters
    ----------
    suite : list of Setup
        The setups (e.g. ``load_suite("scenes/suite.toml")``).
    out : Path
        Output folder: ``runs/``, ``table{1,2,3}.{md,csv}``, ``per_setup.csv``, ``failures.json``.
    cfg : BenchConfig
        What to run.
    data_root : Path, optional
        Where datasets are rendered (default ``out/data``); existing ones are reused.
    white : Setup, optional
        The white-surface setup used for pre-training (Table 2).

    Returns
    -------
    dict
        Paths of the files written, by name.
    """
    out = Path(out)
    data_root = Path(data_root or out / "data")
    spec = FrameSpec(max(max(cfg.sizes), TABLE2["n_train"]), cfg.tests, (cfg.canonical,) * 2)
    setups = [s.name for s in suite]
    for s in suite:
        write_setup(data_root, s, spec, progress=progress)
    pretrain = None
    if "2" in cfg.tables and white is not None:
        write_setup(data_root, white, spec, progress=progress)
        pretrain = out / "runs" / white.name / "compennet-pretrain"
        if not (pretrain / "metrics.json").exists():
            train_run(data_root / white.name, make_config(cfg.profile, **{**cfg.overrides,
                      "n_train": max(cfg.sizes), "n_test": cfg.tests}), pretrain, progress, True)

    rows, failures = [], []
    for job in _jobs(cfg, setups, pretrain):
        run_dir = out / "runs" / job.setup / job.run_name
        try:
            if (run_dir / "metrics.json").exists():
                metrics = json.loads((run_dir / "metrics.json").read_text())
            else:
                metrics = train_run(data_root / job.setup, _train_config(cfg, job), run_dir, progress,
                                    overwrite=True)
            if cfg.closed_loop and "psnr_reachable" not in metrics.get("closed_loop", {}):
                metrics = _add_closed_loop(run_dir, data_root / job.setup, cfg.tests)
        except Exception as exc:  # one failure must not lose the others' results
            failures.append({**asdict(job), "error": f"{type(exc).__name__}: {exc}",
                             "traceback": traceback.format_exc(limit=3)})
            continue
        rows.append({**asdict(job), "extra": dict(job.extra), "run": str(run_dir), **metrics})

    masks = out / "reachable" if cfg.closed_loop else None
    uncompensated, oracle = {}, {}
    for s in setups:
        uncompensated[s], oracle_rows = _setup_baselines(data_root / s, cfg.tests, masks)
        if oracle_rows is not None:
            oracle[s] = oracle_rows
    return _write_tables(out, cfg, rows, failures, uncompensated, oracle)


def _setup_baselines(setup_dir: Path, n_test: int, masks: Path | None) -> tuple[dict, list[dict] | None]:
    """The method-free rows of one setup: scores of the test captures x̃ against x, and the oracle.

    With a ``masks`` folder (closed loop), the uncompensated scores also get the closed-loop scores
    of y projected as is (its captures are the test captures), ``masks/<setup>.png`` shows the
    first test images with their physically unreachable pixels tinted magenta, and the iterative
    refinement rows are returned (``None`` otherwise).
    """
    data = load_setup_data(setup_dir, n_train=1, n_test=n_test)
    captures, y = data.test.captures, data.test.frames
    scores = evaluate(captures, y)
    if masks is None:
        return scores, None
    from compensation.closed_loop import (closed_loop_scores, iterative_refinement, reachable_mask,
                                          reachable_overlay, simulator_for)

    mask = reachable_mask(data, y)
    scores["closed_loop"] = closed_loop_scores(captures, y, mask)
    k = min(N_MASK_FIGURE, y.shape[0])
    strip = reachable_overlay(y[:k], mask[:k]).permute(2, 0, 3, 1).reshape(y.shape[2], -1, 3)
    write_png(masks / f"{setup_dir.name}.png", to_uint8(strip.numpy()))
    return scores, iterative_refinement(data, simulator_for(setup_dir))


def _add_closed_loop(run_dir: Path, setup_dir: Path, n_test: int) -> dict:
    from compensation.closed_loop import closed_loop, simulator_for
    from compensation.train import load_run

    method, _ = load_run(run_dir)
    data = load_setup_data(setup_dir, n_train=1, n_test=n_test)
    t0 = time.perf_counter()
    scores = closed_loop(method, data, simulator_for(setup_dir))
    scores["seconds"] = round(time.perf_counter() - t0, 3)
    metrics = json.loads((run_dir / "metrics.json").read_text())
    metrics["closed_loop"] = scores
    write_json(run_dir / "metrics.json", metrics)
    return metrics


def _mean(rows: list[dict], key: str, sub: str | None = None) -> float:
    vals = [(r[sub] if sub else r)[key] for r in rows if (sub is None or sub in r)]
    return float(np.mean(vals)) if vals else float("nan")


def _table(path: Path, title: str, header: list[str], body: list[list], note: str = "") -> None:
    fmt = lambda v: f"{v:.4f}" if isinstance(v, float) else str(v)  # noqa: E731
    md = [f"# {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    md += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in body]
    md += ["", note] if note else []
    write_text(path.with_suffix(".md"), "\n".join(md) + "\n")
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_suffix(".csv"), "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows([[fmt(v) for v in row] for row in body])


def _correlation_note(rows: list[dict]) -> str:
    """Pearson correlation of surrogate and closed-loop scores over all runs (methods × setups)."""
    pairs = [r for r in rows if "closed_loop" in r]
    if len(pairs) < 3:
        return "Surrogate vs closed-loop correlation: too few runs."
    parts = []
    for m, cl_m in (*zip(METRICS, METRICS), ("psnr", "psnr_reachable")):
        a = np.array([r[m] for r in pairs], float)
        b = np.array([r["closed_loop"].get(cl_m, np.nan) for r in pairs], float)
        ok = np.isfinite(a) & np.isfinite(b)
        r = np.corrcoef(a[ok], b[ok])[0, 1] if ok.sum() > 2 else float("nan")
        parts.append(f"{m.upper()} r = {r:.3f}" if m == cl_m else f"PSNR vs CL PSNR reachable r = {r:.3f}")
    return (f"Surrogate (π†(x̃) vs x) vs closed-loop (capture of π†(y) vs y) correlation over "
            f"{len(pairs)} runs: " + ", ".join(parts) + ". CL columns: closed loop.")


def _write_tables(out: Path, cfg: BenchConfig, rows, failures, uncompensated, oracle) -> dict:
    files = {}
    cl = cfg.closed_loop
    head = ["method", "n_train", "PSNR", "RMSE", "SSIM", "train s", "setups"]
    if cl:
        head += ["CL PSNR", "CL RMSE", "CL SSIM", "CL PSNR reachable", "infer ms/frame"]

    def line(name, n, group):
        row = [name, n] + [_mean(group, m) for m in METRICS] + [_mean(group, "train_seconds"), len(group)]
        return row + ([_mean(group, m, "closed_loop") for m in CL_COLUMNS] if cl else [])

    unc = list(uncompensated.values())
    unc_row = ["uncompensated", "-"] + [_mean(unc, m) for m in METRICS] + ["-", len(unc)]
    unc_row += [_mean(unc, m, "closed_loop") for m in CL_COLUMNS[:-1]] + ["-"] if cl else []
    if "1" in cfg.tables:
        t1 = [r for r in rows if r["table"] == "1"]
        body = [unc_row] + [line(m, n, [r for r in t1 if r["method"] == m and r["n_train"] == n])
                            for m in cfg.methods for n in cfg.sizes]
        for k in sorted({row["iterations"] for rs in oracle.values() for row in rs}):
            group = [row for rs in oracle.values() for row in rs if row["iterations"] == k]
            body.append([f"iterative refinement ({k} it., {group[0]['projections']} proj.)", "-", "-", "-", "-",
                         "-", len(group)] + [_mean(group, m) for m in CL_COLUMNS[:-1]] + ["-"])
        note = ""
        if cl:
            reach = 100 * _mean(unc, "reachable_fraction", "closed_loop")
            note = (_correlation_note(rows) + f" {reach:.1f} % of the desired pixels are physically "
                    "reachable (mean over setups); CL PSNR reachable scores those pixels only.")
        _table(out / "table1", f"Table 1: methods x training-set size, mean over {len(unc)} setups "
               f"({cfg.profile} profile, {cfg.canonical}² px, {cfg.tests} test pairs each)", head, body, note)
        files["table1"] = out / "table1.md"
    if "2" in cfg.tables:
        t2 = [r for r in rows if r["table"] == "2"]
        body = [line("CompenNet, He init" if init is None else "CompenNet, pre-trained on white", TABLE2["n_train"],
                     [r for r in t2 if (r["init"] is None) == (init is None)]) for init in (None, "white")]
        _table(out / "table2", "Table 2: pre-trained vs He-initialised CompenNet (32 pairs, "
               f"{cfg.overrides.get('iters', TABLE2['iters'])} iterations, batch "
               f"{cfg.overrides.get('batch', TABLE2['batch'])})", head, body)
        files["table2"] = out / "table2.md"
    if "3" in cfg.tables:
        t3 = [r for r in rows if r["table"] == "3"]
        body = [line(f"CompenNet, loss {loss}", max(cfg.sizes), [r for r in t3 if r["loss"] == loss])
                for loss in LOSSES]
        _table(out / "table3", "Table 3: CompenNet trained with different losses", head, body)
        files["table3"] = out / "table3.md"
    per = [[r["table"], r["setup"], r["method"], r["n_train"], r["loss"], "pretrained" if r["init"] else "he",
            cfg.overrides.get("seed", 0)] + [r[m] for m in METRICS]
           + [r["uncompensated"][m] for m in METRICS] + [r["train_seconds"]]
           + ([r.get("closed_loop", {}).get(m, float("nan")) for m in CL_COLUMNS[:-1]] if cl else [])
           for r in rows]
    _table(out / "per_setup", "Per-setup results", ["table", "setup", "method", "n_train", "loss", "init", "seed",
           "PSNR", "RMSE", "SSIM", "unc PSNR", "unc RMSE", "unc SSIM", "train s"]
           + (["CL PSNR", "CL RMSE", "CL SSIM", "CL PSNR reachable"] if cl else []), per)
    files["per_setup"] = out / "per_setup.csv"
    write_json(out / "failures.json", {"failures": failures})
    write_json(out / "bench.json", {"config": {**asdict(cfg), "methods": list(cfg.methods)},
                                    "registered_methods": sorted(METHODS), "oracle": oracle,
                                    "uncompensated": uncompensated})
    files["failures"] = out / "failures.json"
    return files
