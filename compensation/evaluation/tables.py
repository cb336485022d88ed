"""The benchmark's tables: Tables 1-3 and per-setup rows as Markdown and CSV, and ``bench.json``.

Each table is written from the rows of finished runs (one dict per run, its ``metrics.json`` plus
the job that made it), the uncompensated scores per setup and, with the closed loop, the
iterative-refinement oracle.
"""
from __future__ import annotations

import csv
import io
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from compensation.methods import METHODS
from sim.io import atomic_write, write_json, write_text

if TYPE_CHECKING:
    from compensation.evaluation.bench import BenchConfig

METRICS = ("psnr", "rmse", "ssim")
"""Surrogate metrics, in table order."""
CL_COLUMNS = (*METRICS, "psnr_reachable", "infer_ms_per_frame")
"""Closed-loop keys shown in the tables (the last only for methods)."""
LOSSES = ("l1", "l2", "ssim", "l1+ssim")
"""The training losses Table 3 compares."""
TABLE2 = dict(n_train=32, iters=500, batch=32)
"""The paper's fine-tuning setting for Table 2."""


def _mean(rows: list[dict], key: str, sub: str | None = None) -> float:
    vals = [(r[sub] if sub else r)[key] for r in rows if (sub is None or sub in r)]
    return float(np.mean(vals)) if vals else float("nan")


def _table(path: Path, title: str, header: list[str], body: list[list], note: str = "") -> None:
    fmt = lambda v: f"{v:.4f}" if isinstance(v, float) else str(v)  # noqa: E731
    md = [f"# {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    md += ["| " + " | ".join(fmt(v) for v in row) + " |" for row in body]
    md += ["", note] if note else []
    write_text(path.with_suffix(".md"), "\n".join(md) + "\n")
    text = io.StringIO(newline="")
    w = csv.writer(text)
    w.writerow(header)
    w.writerows([[fmt(v) for v in row] for row in body])
    atomic_write(path.with_suffix(".csv"), text.getvalue())


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


def write_tables(out: Path, cfg: BenchConfig, rows, failures, uncompensated, oracle) -> dict:
    """Write ``table{1,2,3}.{md,csv}``, ``per_setup.{md,csv}``, ``failures.json`` and ``bench.json``.

    Returns
    -------
    dict
        Paths of the files written, by name.
    """
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
