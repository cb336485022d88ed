"""The benchmark's tables: Tables 1-3, Table 1's paired comparisons and per-setup rows as Markdown,
CSV and LaTeX, and ``bench.json``.

Each table is written from the rows of finished runs (one dict per run, its ``metrics.json`` plus
the job that made it), the uncompensated scores per setup and, with the closed loop, the
iterative-refinement oracle. Tables 1-3 put the CompenNet paper's PSNR, RMSE and SSIM in a
``paper`` column beside each of procam's, on the same rows, so the gap reads at once; the CSV keeps
them as separate columns (``paper PSNR`` …, ``-`` where the paper has no such row). The paired
table compares every two methods of Table 1 at one training size, test image by test image
(:mod:`~compensation.reports.paired`). The LaTeX of each table (:func:`latex_table`) is a
``booktabs`` table float.
"""
from __future__ import annotations

import csv
import io
from dataclasses import asdict
from pathlib import Path

import numpy as np

from compensation.experiments.bench import LOSSES, TABLE2, BenchConfig, BenchResult
from compensation.methods import METHODS, applicable, make_config
from compensation.reports.paired import (EXACT_SETUPS, FLIP_SAMPLES, paired_comparison,
                                         paired_differences)
from compensation.reports.summary import BOOTSTRAP_SAMPLES, BOOTSTRAP_SEED, CONFIDENCE
from sim.io import atomic_write, write_json, write_text

METRICS = ("psnr", "rmse", "ssim", "deltaE")
"""Surrogate metrics, in table order."""
LABELS = {"psnr": "PSNR", "rmse": "RMSE", "ssim": "SSIM", "deltaE": "deltaE"}
"""Column names of the metrics."""
PAPER_METRICS = ("psnr", "rmse", "ssim")
"""The metrics the paper reports: each gets a ``paper`` column beside procam's."""
CL_COLUMNS = (*METRICS, "psnr_reachable", "infer_ms_per_frame")
"""Closed-loop keys shown in the tables (the last only for methods)."""

PAPER_TABLE1: dict[tuple[str, int | None], tuple[float, float, float]] = {
    ("uncompensated", None): (12.1673, 0.4342, 0.4875),
    ("TPS", 125): (17.6399, 0.2299, 0.6042),
    ("TPS_textured", 125): (19.3156, 0.1898, 0.6518),
    ("pix2pix", 125): (17.9358, 0.2347, 0.6439),
    ("CompenNet_wo_surf", 125): (19.8227, 0.1786, 0.7003),
    ("CompenNet", 125): (21.0542, 0.1574, 0.7314),
    ("TPS_textured", 250): (19.2764, 0.1907, 0.6590),
    ("pix2pix", 250): (16.2939, 0.2842, 0.6393),
    ("CompenNet_wo_surf", 250): (20.0857, 0.1733, 0.7146),
    ("CompenNet", 250): (21.2991, 0.1536, 0.7420),
    ("TPS_textured", 500): (19.2264, 0.1917, 0.6615),
    ("pix2pix", 500): (18.0923, 0.2350, 0.6523),
    ("CompenNet_wo_surf", 500): (20.2618, 0.1698, 0.7209),
    ("CompenNet", 500): (21.7998, 0.1425, 0.7523),
}
"""The CompenNet paper's Table 1 (PSNR, RMSE, SSIM; real data, mean over 24 setups) by the method's
``official_name`` and the number of training pairs (None for the uncompensated row)."""
PAPER_TABLE2 = {"he": (19.6767, 0.1863, 0.6788), "pretrained": (20.3423, 0.1688, 0.7165)}
"""The paper's Table 2: CompenNet He-initialised and pre-trained (32 pairs, 500 iterations, batch 32)."""
PAPER_TABLE3 = {"l1": (21.1782, 0.1527, 0.6727), "l2": (20.7927, 0.1594, 0.6453),
                "ssim": (21.0134, 0.1566, 0.7591), "l1+ssim": (21.7998, 0.1425, 0.7523)}
"""The paper's Table 3: CompenNet by training loss (500 pairs)."""
PAPER_NOTE = ("paper columns: the CompenNet paper's figures on real captures (mean over 24 setups, "
              "256² px, 200 test pairs); '-' where the paper has no such row.")


def _mean(rows: list[dict], key: str, sub: str | None = None) -> float:
    vals = [(r[sub] if sub else r)[key] for r in rows if (sub is None or sub in r)]
    return float(np.mean(vals)) if vals else float("nan")


def _with_paper(ours: list, paper: tuple[float, float, float] | None) -> list:
    """procam's metric values (in :data:`METRICS` order) with the paper's beside each of
    :data:`PAPER_METRICS` ("-" without a paper figure).

    >>> _with_paper([20.0, 0.2, 0.7, 9.0], (21.0, 0.15, 0.75))
    [20.0, 21.0, 0.2, 0.15, 0.7, 0.75, 9.0]
    >>> _with_paper([20.0, 0.2, 0.7, 9.0], None)
    [20.0, '-', 0.2, '-', 0.7, '-', 9.0]
    """
    cells = []
    for m, value in zip(METRICS, ours):
        cells.append(value)
        if m in PAPER_METRICS:
            cells.append("-" if paper is None else paper[PAPER_METRICS.index(m)])
    return cells


def _cell(value) -> str:
    """A table cell as the Markdown, CSV and LaTeX show it: floats to 4 decimals.

    >>> _cell(21.05423), _cell(125), _cell("-")
    ('21.0542', '125', '-')
    """
    return f"{value:.4f}" if isinstance(value, float) else str(value)


LATEX_TEXT = {"&": r"\&", "%": r"\%", "$": r"\$", "#": r"\#", "_": r"\_", "{": r"\{", "}": r"\}",
              "~": r"\textasciitilde{}", "^": r"\textasciicircum{}", "\\": r"\textbackslash{}",
              "<": r"\textless{}", ">": r"\textgreater{}", "…": r"\ldots{}"}
"""Characters LaTeX reads as commands (or prints as others), escaped in text mode."""
LATEX_MATH = {"λ": r"\lambda", "α": r"\alpha", "π": r"\pi", "Δ": r"\Delta", "ℓ": r"\ell", "μ": r"\mu",
              "²": "^{2}", "³": "^{3}", "†": r"^{\dagger}", "°": r"^{\circ}", "·": r"\cdot", "−": "-",
              "×": r"\times", "±": r"\pm", "≤": r"\leq", "≥": r"\geq", "→": r"\rightarrow"}
"""Unicode characters of the tables' labels and notes, by their math-mode equivalents."""
COMBINING_TILDE = "\u0303"
"""The combining tilde of x̃, set as ``\\tilde`` over the character before it."""


def latex_text(text: str) -> str:
    r"""``text`` for LaTeX's text mode: :data:`LATEX_TEXT` escaped, :data:`LATEX_MATH` (and a
    character under :data:`COMBINING_TILDE`) in math mode, adjacent ones in one ``$…$``; any
    other character as it is.

    >>> print(latex_text("tps (λ = 0.0347·α²), 50 % of x̃_1"))
    tps ($\lambda$ = 0.0347$\cdot\alpha^{2}$), 50 \% of $\tilde{x}$\_1
    """
    parts: list[tuple[str, bool]] = []  # (LaTeX, in math mode)
    for i, char in enumerate(text):
        if char == COMBINING_TILDE:
            continue
        if text[i + 1:i + 2] == COMBINING_TILDE:
            parts.append((rf"\tilde{{{LATEX_MATH.get(char, char)}}}", True))
        elif char in LATEX_MATH:
            parts.append((LATEX_MATH[char], True))
        else:
            parts.append((LATEX_TEXT.get(char, char), False))
    out, math_run = [], []
    for latex, math in parts + [("", False)]:
        if math:
            math_run.append(latex)
            continue
        if math_run:
            out.append("$" + "".join(math_run) + "$")
            math_run.clear()
        out.append(latex)
    return "".join(out)


def latex_table(title: str, header: list[str], rows: list[list], note: str = "") -> str:
    r"""A ``booktabs`` table float: ``title`` as its caption, the ``header`` and ``rows`` in a
    tabular (a column right-aligned where its cells are numbers or ``-``, else left-aligned), the
    ``note`` as a footnote-size paragraph under it; cells formatted as in the Markdown, every
    text through :func:`latex_text`.

    >>> print(latex_table("T_1", ["method", "PSNR"], [["tps (λ = 0.01)", 20.5], ["uncompensated", "-"]],
    ...                   "50 %"), end="")
    % needs \usepackage{booktabs}
    \begin{table}[htbp]
    \centering
    \caption{T\_1}
    \begin{tabular}{lr}
    \toprule
    method & PSNR \\
    \midrule
    tps ($\lambda$ = 0.01) & 20.5000 \\
    uncompensated & - \\
    \bottomrule
    \end{tabular}
    \par\smallskip
    {\footnotesize 50 \%\par}
    \end{table}
    """
    def numeric(column: int) -> bool:
        cells = [row[column] for row in rows]
        return any(isinstance(v, (int, float)) for v in cells) and all(
            isinstance(v, (int, float)) or v == "-" for v in cells)

    line = lambda cells: " & ".join(latex_text(_cell(v)) for v in cells) + r" \\"  # noqa: E731
    align = "".join("r" if numeric(i) else "l" for i in range(len(header)))
    tex = [r"% needs \usepackage{booktabs}", r"\begin{table}[htbp]", r"\centering",
           rf"\caption{{{latex_text(title)}}}", rf"\begin{{tabular}}{{{align}}}", r"\toprule", line(header),
           r"\midrule", *(line(row) for row in rows), r"\bottomrule", r"\end{tabular}"]
    if note:
        tex += [r"\par\smallskip", rf"{{\footnotesize {latex_text(note)}\par}}"]
    return "\n".join([*tex, r"\end{table}"]) + "\n"


def _table(path: Path, title: str, header: list[str], body: list[list], note: str = "") -> None:
    """Write ``path`` with the suffixes ``.md``, ``.csv`` and ``.tex`` (:func:`latex_table`)."""
    md = [f"# {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    md += ["| " + " | ".join(_cell(v) for v in row) + " |" for row in body]
    md += ["", note] if note else []
    write_text(path.with_suffix(".md"), "\n".join(md) + "\n")
    text = io.StringIO(newline="")
    w = csv.writer(text)
    w.writerow(header)
    w.writerows([[_cell(v) for v in row] for row in body])
    atomic_write(path.with_suffix(".csv"), text.getvalue())
    write_text(path.with_suffix(".tex"), latex_table(title, header, body, note))


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
        parts.append(f"{LABELS[m]} r = {r:.3f}" if m == cl_m else f"PSNR vs CL PSNR reachable r = {r:.3f}")
    return (f"Surrogate (π†(x̃) vs x) vs closed-loop (capture of π†(y) vs y) correlation over "
            f"{len(pairs)} runs: " + ", ".join(parts) + ". CL columns: closed loop.")


def _target_note(cfg: BenchConfig, unc: list[dict]) -> str:
    """What the closed-loop columns compare with: the target policy and its map (mean over setups)."""
    if cfg.target.name == "none":
        return "Closed loop (CL columns) against the desired images themselves (target policy none)."
    targets = [u["closed_loop"]["target"] for u in unc if "target" in u.get("closed_loop", {})]
    a, b = (float(np.mean([t[k] for t in targets])) if targets else float("nan") for k in ("a", "b"))
    used = max((t.get("out_of_reach_used", 0.0) for t in targets), default=0.0)
    return (f"Closed loop (CL columns) against the target y' = a·y + b of the target policy "
            f"{cfg.target.name} (at most {100 * cfg.target.out_of_reach:g} % of the pixels out of reach "
            f"asked, {100 * used:.3g} % used where no less leaves any contrast; a = {a:.4f}, b = {b:.4f}, "
            "mean over the simulated setups); compensation aims at y'.")


def _named(cfg: BenchConfig, method: str) -> str:
    """A method's row name: its registry name, with what its options say of themselves
    (:meth:`~compensation.training.config.Options.label`, e.g. ``tps (λ = 0.01)``)."""
    label = make_config(cfg.profile, method, **applicable(method, cfg.overrides)).options.label()
    return f"{method} ({label})" if label else method


PAIRED_HEADER = ["A", "B", "n_train", "score", "mean diff dB", "CI low", "CI high", "share A better",
                 "setups", "images", "p"]
"""Columns of ``table1_paired``: one row per two methods of Table 1, training size and score."""
PAIRED_NOTE = ("Each row compares two methods A and B of Table 1 trained on the same number of "
               "pairs, test image by test image (same setup, same image), pooled across setups. mean "
               "diff dB: the mean of the per-image PSNR differences A − B (surrogate: π†(x̃) vs x; "
               "closed loop: the capture vs the target, where scored); CI low, CI high: its "
               f"{100 * CONFIDENCE:g} % percentile interval from a hierarchical bootstrap "
               f"({BOOTSTRAP_SAMPLES} resamples of the setups, then of the test images within each drawn "
               f"setup; seed {BOOTSTRAP_SEED}); share A better: the share of the images where A scores "
               "higher; p: the two-sided p-value of a paired sign-flip permutation test of the per-setup "
               f"mean differences (every sign pattern up to {EXACT_SETUPS} setups, else {FLIP_SAMPLES} "
               f"random ones; seed {BOOTSTRAP_SEED}): the chance of a mean at least this far from 0 were "
               "A and B interchangeable. With 2 setups p is at least 0.5, with 5 at least 0.0625: p < 0.05 "
               "needs 6 setups or more.")
"""The paired table's note: what each column and the test are."""


def _per_image(row: dict, score: str) -> list[float]:
    """A run's per-test-image PSNR of ``score`` (``surrogate`` or ``closed loop``), empty where its
    ``metrics.json`` kept none.

    >>> _per_image({"psnr_per_image": [20.0], "closed_loop": {"psnr_per_image": [18.0]}}, "closed loop")
    [18.0]
    """
    return (row if score == "surrogate" else row.get("closed_loop", {})).get("psnr_per_image") or []


def _paired_body(cfg: BenchConfig, t1: list[dict]) -> list[list]:
    """The rows of ``table1_paired`` (:data:`PAIRED_HEADER`) from Table 1's runs: per training size,
    every two methods in Table 1's order and each score both hold per image
    (:func:`~compensation.reports.paired.paired_comparison`)."""
    body = []
    for n in cfg.sizes:
        for i, a in enumerate(cfg.methods):
            for b in cfg.methods[i + 1:]:
                for score in ("surrogate", "closed loop"):
                    a_scores, b_scores = ({r["setup"]: _per_image(r, score) for r in t1
                                           if r["method"] == m and r["n_train"] == n} for m in (a, b))
                    groups = paired_differences(a_scores, b_scores)
                    if groups:
                        c = paired_comparison(groups)
                        body.append([_named(cfg, a), _named(cfg, b), n, score, c["mean"], c["lo"], c["hi"],
                                     c["share"], c["setups"], c["images"], c["p"]])
    return body


def write_tables(out: Path, cfg: BenchConfig, result: BenchResult) -> dict:
    """Write ``table{1,2,3}``, ``table1_paired`` and ``per_setup`` (each ``.md``, ``.csv`` and
    ``.tex``), ``failures.json`` and ``bench.json``.

    Tables 1-3 carry the paper's figures in ``paper`` columns beside procam's (:data:`PAPER_TABLE1`
    and the others). With ``cfg.closed_loop`` the closed-loop columns average the setups that were
    simulated; the others (no ``setup.toml``, no closed-loop scores) are named in Table 1's note, and
    without any simulated setup the columns are left out. ``table1_paired`` compares every two
    methods of Table 1 at each training size on the paired test images (:data:`PAIRED_NOTE`).

    Returns
    -------
    dict
        Paths of the files written, by name.
    """
    files = {}
    rows, failures, uncompensated, oracle = result.rows, result.failures, result.uncompensated, result.oracle
    image_size = result.image_size
    cl = cfg.closed_loop and any("closed_loop" in u for u in uncompensated.values())
    cl_head = [f"CL {LABELS[m]}" for m in METRICS] + ["CL PSNR reachable"]
    head = ["method", "n_train"] + _with_paper([LABELS[m] for m in METRICS],
                                               tuple(f"paper {LABELS[m]}" for m in PAPER_METRICS))
    head += ["train s", "setups"] + (cl_head + ["infer ms/frame"] if cl else [])

    def line(name, n, group, paper):
        row = [name, n] + _with_paper([_mean(group, m) for m in METRICS], paper)
        row += [_mean(group, "train_seconds"), len(group)]
        return row + ([_mean(group, m, "closed_loop") for m in CL_COLUMNS] if cl else [])

    unc = list(uncompensated.values())
    unc_row = ["uncompensated", "-"] + _with_paper([_mean(unc, m) for m in METRICS],
                                                   PAPER_TABLE1[("uncompensated", None)]) + ["-", len(unc)]
    unc_row += [_mean(unc, m, "closed_loop") for m in CL_COLUMNS[:-1]] + ["-"] if cl else []
    not_simulated = sorted(s for s, u in uncompensated.items() if "closed_loop" not in u)
    if "1" in cfg.tables:
        t1 = [r for r in rows if r["table"] == "1"]
        body = [unc_row] + [line(_named(cfg, m), n, [r for r in t1 if r["method"] == m and r["n_train"] == n],
                                 PAPER_TABLE1.get((METHODS[m].official_name, n)))
                            for m in cfg.methods for n in cfg.sizes]
        def closed_loop_row(name: str, group: list[dict]) -> list:  # a method-free row: closed loop only
            return ([name, "-"] + ["-"] * (len(METRICS) + len(PAPER_METRICS)) + ["-", len(group)]
                    + [_mean(group, m) for m in CL_COLUMNS[:-1]] + ["-"])

        for k in sorted({row["iterations"] for rs in oracle.values() for row in rs}):
            group = [row for rs in oracle.values() for row in rs if row["iterations"] == k]
            body.append(closed_loop_row(f"iterative refinement ({k} it., {group[0]['projections']} proj.)", group))
        if result.optimum:
            body.append(closed_loop_row("exact optimum", list(result.optimum.values())))
        notes = [PAPER_NOTE]
        if cl:
            notes.append(_target_note(cfg, unc))
            reach = 100 * _mean(unc, "reachable_fraction", "closed_loop")
            notes.append(_correlation_note(rows) + f" {reach:.1f} % of the desired pixels are physically "
                         "reachable (mean over simulated setups); CL PSNR reachable scores those pixels only.")
            if result.optimum:
                evaluations = _mean(list(result.optimum.values()), "evaluations")
                notes.append("Exact optimum: per setup, the projector frames whose captures come closest to "
                             "the target through the simulator's noise-free model, projected as a "
                             "method's compensation is; no method can do better but by noise "
                             f"({evaluations:.1f} noise-free evaluations per test image on average).")
        if cfg.closed_loop and not_simulated:
            notes.append(f"Closed loop left out for {len(not_simulated)} setup(s) that procam did not "
                         f"simulate (no setup.toml, nothing to project through): {', '.join(not_simulated)}.")
        _table(out / "table1", f"Table 1: methods x training-set size, mean over {len(unc)} setups "
               f"({cfg.profile} profile, {image_size}, {cfg.tests} test pairs each)", head, body,
               "\n\n".join(notes))
        files["table1"] = out / "table1.md"
        _table(out / "table1_paired", "Table 1, paired: method A against method B on the same test images",
               PAIRED_HEADER, _paired_body(cfg, t1), PAIRED_NOTE)
        files["table1_paired"] = out / "table1_paired.md"
    if "2" in cfg.tables:
        t2 = [r for r in rows if r["table"] == "2"]
        body = [line("CompenNet, He init" if init is None else "CompenNet, pre-trained on white", TABLE2["n_train"],
                     [r for r in t2 if (r["init"] is None) == (init is None)], PAPER_TABLE2[init or "he"])
                for init in (None, "pretrained")]
        note = PAPER_NOTE
        if not any(r["init"] for r in t2):
            note += (" No pre-trained run finished: pre-training needs the white setup that "
                     "`procam bench` renders with a suite.")
        _table(out / "table2", "Table 2: pre-trained vs He-initialised CompenNet (32 pairs, "
               f"{cfg.overrides.get('iters', TABLE2['iters'])} iterations, batch "
               f"{cfg.overrides.get('batch', TABLE2['batch'])})", head, body, note)
        files["table2"] = out / "table2.md"
    if "3" in cfg.tables:
        t3 = [r for r in rows if r["table"] == "3"]
        body = [line(f"CompenNet, loss {loss}", max(cfg.sizes), [r for r in t3 if r["loss"] == loss],
                     PAPER_TABLE3[loss]) for loss in LOSSES]
        _table(out / "table3", "Table 3: CompenNet trained with different losses", head, body,
               PAPER_NOTE + " The paper's losses are trained on 500 pairs.")
        files["table3"] = out / "table3.md"
    per = [[r["table"], r["setup"], r["method"], r["n_train"], r["loss"], "pretrained" if r["init"] else "he",
            cfg.overrides.get("seed", 0), r["official_tag"]] + [r[m] for m in METRICS]
           + [r["uncompensated"][m] for m in METRICS] + [r["train_seconds"]]
           + ([r.get("closed_loop", {}).get(m, float("nan")) for m in CL_COLUMNS[:-1]] if cl else [])
           for r in rows]
    _table(out / "per_setup", "Per-setup results", ["table", "setup", "method", "n_train", "loss", "init", "seed",
           "official tag"] + [LABELS[m] for m in METRICS] + [f"unc {LABELS[m]}" for m in METRICS]
           + ["train s"] + (cl_head if cl else []), per)
    files["per_setup"] = out / "per_setup.csv"
    write_json(out / "failures.json", {"failures": failures})
    write_json(out / "bench.json", {"config": {**asdict(cfg), "methods": list(cfg.methods)},
                                    "registered_methods": sorted(METHODS), "oracle": oracle,
                                    "optimum": result.optimum,
                                    "uncompensated": uncompensated})
    files["failures"] = out / "failures.json"
    return files
