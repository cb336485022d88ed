"""What a study or bench folder's ``results.csv`` says, in three CSV files: pure functions over rows.

``results.csv`` holds one row per (point, setup, method, n_train, seed): the point's axis values,
the run's ``status`` and its scores (surrogate, closed loop, uncompensated, oracle) and timings
(:data:`compensation.experiments.jobs.RESULT_COLUMNS`; missing values are empty cells). From it:

``summary.csv``
    mean and standard deviation over seeds (and setups) per (point, method, n_train), ``ok`` runs
    only (:func:`summarize`).
``breakpoints.csv``
    per method and n_train (and value of a second axis): the first value of the factor where the
    method's closed-loop PSNR gain over uncompensated falls below :data:`BREAK_GAIN_DB`, or where
    it falls below a method it was at least as good as at the previous value (:func:`breakpoints`).
``failures.csv``
    every run that failed, gave NaN, diverged, or scored below uncompensated (:func:`failures`).
"""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from sim.errors import ProcamError
from sim.io import atomic_write, read_json

METRICS = ("psnr", "rmse", "ssim", "deltae")
"""Surrogate metrics (π†(x̃) against x on held-out pairs); ``cl_``, ``unc_`` prefixed: the same in
closed loop and for the uncompensated captures."""
SCORES = (*METRICS, *(f"cl_{m}" for m in METRICS), *(f"unc_{m}" for m in METRICS),
          "cl_unc_psnr", "cl_unc_ssim", "cl_unc_deltae", "oracle_psnr", "oracle_ssim", "oracle_deltae",
          "fit_s", "infer_ms", "reachable_fraction", "target_out_of_reach", "target_out_of_reach_used",
          "target_a", "target_b")
"""The numeric columns of ``results.csv`` (empty cells read as NaN); closed-loop scores compare with
the target y' = ``target_a`` · y + ``target_b`` of the row's ``target_policy``."""
STATUSES = ("ok", "failed", "nan", "diverged")
"""Values of the ``status`` column: finished; raised an error (``error`` says which); a score is not
finite; the training loss grew (:data:`compensation.experiments.jobs.DIVERGED_RATIO`) or is not
finite."""
BREAK_GAIN_DB = 1.0
"""A method breaks where its closed-loop PSNR gain over uncompensated falls below this (dB)."""
OVERTAKE_MARGIN_DB = 0.1
"""A method is overtaken where it falls below another method by more than this (dB): closer
crossings are within a single run's spread (two methods 0.02 dB apart swapped places along the
inter-reflection study's flat lines, ``benchmarks/results/studies/``)."""


def _number(text: str) -> float | str:
    """A cell as a float, or the text itself where it is not a number.

    >>> _number("0.5"), _number(""), _number("RGGB")
    (0.5, nan, 'RGGB')
    """
    if text.strip() == "":
        return float("nan")
    try:
        return float(text)
    except ValueError:
        return text


def is_finite(value) -> bool:
    """Whether ``value`` is a finite number (a text cell or NaN is not).

    >>> is_finite(2), is_finite(float("nan")), is_finite("RGGB")
    (True, False, False)
    """
    return isinstance(value, (int, float)) and math.isfinite(value)


def axis_keys(study: dict) -> list[str]:
    """The axis keys of a resolved ``study.json`` (empty for a bench).

    >>> axis_keys({"axes": [{"key": "projector.aperture", "values": [1, 2]}]})
    ['projector.aperture']
    """
    return [a["key"] for a in study.get("axes", [])]


def read_study(folder: Path) -> dict:
    """``folder/study.json``, checked for what the readers use (``axes`` with ``key`` and ``values``).

    Raises
    ------
    ProcamError
        If the file is missing or unreadable, or an axis lacks its key or values.
    """
    path = Path(folder) / "study.json"
    study = read_json(path, "study description")
    axes = study.get("axes", [])
    if not isinstance(axes, list) or not all(isinstance(a, dict) and "key" in a and isinstance(
            a.get("values"), list) for a in axes):
        raise ProcamError(f"{path}: 'axes' must be a list of {{key, values, ...}} tables")
    return study


def read_results(path: Path, axes: list[str]) -> list[dict]:
    """Read ``results.csv``: ``point``, ``n_train`` and ``seed`` as int, scores as float (NaN for
    an empty cell), axis values as float where numeric, every other cell as text.

    Raises
    ------
    ProcamError
        If the file is missing, or a required column or axis column is absent, or a cell of
        ``point``, ``n_train``, ``seed`` is not an integer, or a ``status`` is unknown; the message
        names the file, the row and the column.
    """
    path = Path(path)
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise ProcamError(f"{path}: results table not found") from None
    reader = csv.DictReader(io.StringIO(text))
    header = reader.fieldnames or []
    missing = [c for c in ("point", *axes, "setup", "method", "n_train", "seed", "status") if c not in header]
    if missing:
        raise ProcamError(f"{path}: missing column(s) {', '.join(missing)}")
    rows = []
    for line, raw in enumerate(reader, start=2):
        row = dict(raw)
        for key in ("point", "n_train", "seed"):
            try:
                row[key] = int(raw[key])
            except (TypeError, ValueError):
                raise ProcamError(f"{path}, line {line}: column {key}: expected an integer, "
                                  f"found {raw[key]!r}") from None
        if row["status"] not in STATUSES:
            raise ProcamError(f"{path}, line {line}: status {row['status']!r}: expected one of "
                              f"{', '.join(STATUSES)}")
        for key in (*SCORES, *(a for a in axes if a not in ("point", "n_train", "seed"))):
            row[key] = _number(raw.get(key) or "")
        for key in ("error", "run", "table", "variant", "target_policy"):
            row[key] = raw.get(key) or ""
        rows.append(row)
    return rows


def cell_text(value, digits: int | None = 6) -> str:
    """A CSV cell: NaN empty, a float to ``digits`` significant digits (None: exact, the shortest
    text that reads back as the same float).

    >>> cell_text(float("nan")), cell_text(13.85700900195572), cell_text(13.85700900195572, None), cell_text("a")
    ('', '13.857', '13.85700900195572', 'a')
    """
    if isinstance(value, float):
        return "" if math.isnan(value) else repr(value) if digits is None else f"{value:.{digits}g}"
    return str(value)


def write_csv(path: Path, columns: list[str], rows: list[dict], digits: int | None = 6) -> Path:
    """Write ``rows`` (dicts) under ``columns`` atomically; NaN as an empty cell, floats to
    ``digits`` significant digits (None: exact)."""
    text = io.StringIO(newline="")
    w = csv.writer(text)
    w.writerow(columns)
    w.writerows([[cell_text(r.get(c, ""), digits) for c in columns] for r in rows])
    atomic_write(path, text.getvalue())
    return Path(path)


def mean_std(values) -> tuple[float, float, int]:
    """Mean, sample standard deviation (0 for a single value) and count of the finite values.

    >>> mean_std([1.0, 3.0, float("nan")])
    (2.0, 1.4142135623730951, 2)
    >>> mean_std([float("nan")])
    (nan, nan, 0)
    """
    v = np.array([x for x in values if is_finite(x)], float)
    if v.size == 0:
        return float("nan"), float("nan"), 0
    return float(v.mean()), float(v.std(ddof=1)) if v.size > 1 else 0.0, int(v.size)


def main_rows(rows: list[dict]) -> list[dict]:
    """The rows that summaries, break points and charts compare: a bench's Table 1 rows (methods ×
    training sizes) where the rows name their ``table``; Tables 2 and 3 compare variants of one
    method (initialisation, loss) and have their own tables. A bench without Table 1 keeps every
    row, each under its ``variant`` (run name) as the method. Rows without a table: all of them.

    >>> rows = [{"table": "1", "method": "tps"}, {"table": "3", "method": "compennet", "variant": "v"}]
    >>> main_rows(rows)
    [{'table': '1', 'method': 'tps'}]
    >>> main_rows(rows[1:])
    [{'table': '3', 'method': 'v', 'variant': 'v'}]
    """
    if not any(r.get("table") for r in rows):
        return rows
    first = [r for r in rows if str(r.get("table")) == "1"]
    return first or [{**r, "method": r.get("variant") or r["method"]} for r in rows]


def summarize(rows: list[dict], axes: list[str]) -> list[dict]:
    """Mean and std over seeds and setups per (point, method, n_train), of the ``ok`` runs.

    Each summary row has ``point``, the axis values, ``method``, ``n_train``, ``runs`` (all rows),
    ``ok`` (rows with status ok) and ``<score>_mean``, ``<score>_std`` for every :data:`SCORES`.

    >>> rows = [dict(point=0, a=1.0, method="m", n_train=8, seed=s, status="ok", cl_psnr=p)
    ...         for s, p in enumerate([20.0, 22.0])]
    >>> rows.append(dict(point=0, a=1.0, method="m", n_train=8, seed=2, status="failed", cl_psnr=5.0))
    >>> s = summarize(rows, ["a"])[0]
    >>> s["runs"], s["ok"], s["cl_psnr_mean"], round(s["cl_psnr_std"], 3), s["psnr_mean"]
    (3, 2, 21.0, 1.414, nan)
    """
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        groups.setdefault((r["point"], r["method"], r["n_train"]), []).append(r)
    out = []
    for (point, method, n_train), group in sorted(groups.items(), key=lambda kv: (kv[0][0], kv[0][2], kv[0][1])):
        ok = [r for r in group if r["status"] == "ok"]
        row = {"point": point, **{a: group[0][a] for a in axes}, "method": method, "n_train": n_train,
               "runs": len(group), "ok": len(ok)}
        for key in SCORES:
            row[f"{key}_mean"], row[f"{key}_std"], _ = mean_std(r.get(key, float("nan")) for r in ok)
        out.append(row)
    return out


def summary_columns(axes: list[str]) -> list[str]:
    """Columns of ``summary.csv``."""
    return list(dict.fromkeys(["point", *axes, "method", "n_train", "runs", "ok",
                               *(f"{k}_{s}" for k in SCORES for s in ("mean", "std"))]))


def order_key(value, listed: list) -> tuple:
    """Sort key of an axis value: its place in the study's list of values, else its own order.

    >>> sorted([3.0, 1.0, 2.0], key=lambda v: order_key(v, [2, 3]))
    [2.0, 3.0, 1.0]
    """
    for i, v in enumerate(listed):
        if v == value or str(v) == str(value):
            return (0, i, "")
    return (1, value if is_finite(value) else 0.0, str(value))


def closed_loop_gain(row: dict) -> tuple[float, float, str]:
    """A summary row's PSNR, its gain over uncompensated (dB) and which score they are: the closed
    loop where the row has one (against ``cl_unc_psnr``, else ``unc_psnr``), else the surrogate.

    >>> closed_loop_gain({"cl_psnr_mean": 20.0, "cl_unc_psnr_mean": 17.5, "psnr_mean": 25.0})
    (20.0, 2.5, 'closed loop')
    >>> closed_loop_gain({"cl_psnr_mean": float("nan"), "psnr_mean": 25.0, "unc_psnr_mean": 15.0})
    (25.0, 10.0, 'surrogate')
    """
    nan = float("nan")
    if is_finite(row.get("cl_psnr_mean", nan)) or is_finite(row.get("cl_unc_psnr_mean", nan)):
        base = row.get("cl_unc_psnr_mean", nan)
        base = base if is_finite(base) else row.get("unc_psnr_mean", nan)
        return row.get("cl_psnr_mean", nan), row.get("cl_psnr_mean", nan) - base, "closed loop"
    return row.get("psnr_mean", nan), row.get("psnr_mean", nan) - row.get("unc_psnr_mean", nan), "surrogate"


def n_train_follows(summary: list[dict], key: str) -> bool:
    """Whether the factor ``key`` sets the training size (a training-size study): ``n_train`` takes
    more than one value, and one per value of the factor. Its lines then run across sizes.

    >>> n_train_follows([{"f": 1, "n_train": 8}, {"f": 2, "n_train": 16}], "f")
    True
    >>> n_train_follows([{"f": 1, "n_train": 8}, {"f": 1, "n_train": 16}], "f")
    False
    """
    pairs = {(str(r[key]), r["n_train"]) for r in summary}
    return len({n for _, n in pairs}) > 1 and len(pairs) == len({v for v, _ in pairs})


BREAK_COLUMNS = ("method", "n_train", "axis", "break_value", "point", "kind", "other", "gain_db",
                 "psnr", "score", "reason")
"""Columns of ``breakpoints.csv`` (the second axis's key comes after ``n_train`` with two axes)."""


def breakpoints(summary: list[dict], study: dict, threshold: float = BREAK_GAIN_DB) -> list[dict]:
    """Each method's break point along the study's first axis, per n_train and value of a second axis.

    Along the first axis's values (in the study's order), a method breaks at the first value where

    - its PSNR gain over uncompensated (:func:`closed_loop_gain`) is below ``threshold`` dB, or it
      has no score there (every run failed): ``kind`` ``gain`` or ``failed``;
    - it falls more than :data:`OVERTAKE_MARGIN_DB` below another method (same n_train) that it
      matched or beat at the previous value: ``kind`` ``overtaken``, ``other`` names that method.

    A method that never breaks gets ``kind`` ``none`` and an empty ``break_value``. Without an axis
    (a bench) there is nothing to break along: no rows. Where the factor sets the training size
    (:func:`n_train_follows`), the line runs across sizes and ``n_train`` is left empty.

    >>> study = {"axes": [{"key": "blur", "values": [0, 1, 2, 3]}]}
    >>> def row(p, m, cl):
    ...     return {"point": p, "blur": float(p), "method": m, "n_train": 8,
    ...             "cl_psnr_mean": cl, "cl_unc_psnr_mean": 15.0}
    >>> s = [row(p, "a", cl) for p, cl in enumerate([25, 22, 19, 15.5])]
    >>> s += [row(p, "b", cl) for p, cl in enumerate([24, 23, 21, 20])]
    >>> [(b["method"], b["break_value"], b["kind"], b["other"]) for b in breakpoints(s, study)]
    [('a', 1.0, 'overtaken', 'b'), ('b', '', 'none', '')]
    >>> [b["break_value"] for b in breakpoints([r for r in s if r["method"] == "a"], study)]
    [3.0]
    >>> close = [row(p, "c", cl) for p, cl in enumerate([24.02, 22.95, 20.97, 19.96])]  # crosses b
    >>> [(b["method"], b["kind"]) for b in breakpoints(close + s[4:], study)]  # by 0.05 dB: noise
    [('c', 'none'), ('b', 'none')]
    """
    axes = study.get("axes", [])
    if not axes:
        return []
    key, listed = axes[0]["key"], axes[0]["values"]
    second = [a["key"] for a in axes[1:]]
    follows = n_train_follows(summary, key)
    lines: dict[tuple, list[dict]] = {}
    for r in summary:
        lines.setdefault(("" if follows else r["n_train"], *(r[k] for k in second)), []).append(r)
    out = []
    for group_key, group in sorted(lines.items(), key=lambda kv: tuple(map(str, kv[0]))):
        by_method: dict[str, list[dict]] = {}
        for r in sorted(group, key=lambda r: order_key(r[key], listed)):
            by_method.setdefault(r["method"], []).append(r)
        values = sorted({r[key] for r in group}, key=lambda v: order_key(v, listed))
        psnr = {m: {r[key]: closed_loop_gain(r) for r in rs} for m, rs in by_method.items()}
        for method in by_method:
            found = None
            for i, v in enumerate(values):
                if v not in psnr[method]:
                    continue
                score, gain, which = psnr[method][v]
                if not is_finite(score):
                    found = (i, "failed", "", f"no {which} score at {key} = {cell_text(v)}: every run failed")
                elif not gain >= threshold:
                    found = (i, "gain", "", f"{which} PSNR gain over uncompensated {gain:.2f} dB < "
                                            f"{threshold:g} dB")
                elif i > 0:
                    prev = values[i - 1]
                    for other in by_method:
                        if other == method or v not in psnr[other] or prev not in psnr[other] \
                                or prev not in psnr[method]:
                            continue
                        o_now, o_prev = psnr[other][v][0], psnr[other][prev][0]
                        if score < o_now - OVERTAKE_MARGIN_DB and psnr[method][prev][0] >= o_prev:
                            found = (i, "overtaken", other, f"{which} PSNR {score:.2f} dB falls below "
                                                            f"{other}'s {o_now:.2f} dB")
                            break
                if found:
                    break
            row = {"method": method, "n_train": group_key[0], **dict(zip(second, group_key[1:])),
                   "axis": key, "score": psnr[method][values[0]][2] if values[0] in psnr[method] else ""}
            if found is None:
                row.update(break_value="", point="", kind="none", other="", gain_db=float("nan"),
                           psnr=float("nan"), reason=f"gain >= {threshold:g} dB over the whole range")
            else:
                i, kind, other, reason = found
                hit = next(r for r in by_method[method] if r[key] == values[i])
                score, gain, _ = psnr[method][values[i]]
                row.update(break_value=values[i], point=hit["point"], kind=kind, other=other,
                           gain_db=gain, psnr=score, reason=reason)
            out.append(row)
    return out


FAILURE_COLUMNS = ("point", "setup", "method", "n_train", "seed", "kind", "detail", "psnr", "cl_psnr",
                   "cl_unc_psnr", "run")
"""Columns of ``failures.csv`` (the axis columns come after ``point``); each failure row also keeps
every score of :data:`SCORES` for the charts."""


def failures(rows: list[dict], axes: list[str]) -> list[dict]:
    """Every run that did not compensate: ``kind`` is its status (``failed``: an exception, e.g. a
    crash; ``nan``; ``diverged``), or ``nan`` for an ``ok`` row without a PSNR, or ``worse`` when
    its PSNR is below uncompensated (closed loop where scored, else surrogate).

    >>> rows = [dict(point=0, setup="s", method="m", n_train=8, seed=0, status="ok", cl_psnr=14.0,
    ...              cl_unc_psnr=15.0, psnr=20.0, unc_psnr=12.0, error="", run="runs/x"),
    ...         dict(point=1, setup="s", method="m", n_train=8, seed=0, status="diverged",
    ...              error="loss inf at iteration 3", run="")]
    >>> [(f["kind"], f["detail"]) for f in failures(rows, [])]
    [('worse', 'closed loop PSNR 14.00 dB < uncompensated 15.00 dB'), ('diverged', 'loss inf at iteration 3')]
    """
    out = []
    nan = float("nan")
    for r in rows:
        base = {"point": r["point"], **{a: r[a] for a in axes}, "setup": r["setup"], "method": r["method"],
                "n_train": r["n_train"], "seed": r["seed"], "run": r.get("run", ""),
                **{k: r.get(k, nan) for k in SCORES}}
        if r["status"] != "ok":
            out.append({**base, "kind": r["status"], "detail": r.get("error") or r["status"]})
            continue
        cl, psnr = r.get("cl_psnr", nan), r.get("psnr", nan)
        cl_unc = r.get("cl_unc_psnr", nan)
        cl_unc = cl_unc if is_finite(cl_unc) else r.get("unc_psnr", nan)
        if not is_finite(cl) and not is_finite(psnr):
            out.append({**base, "kind": "nan", "detail": "no finite PSNR"})
        elif is_finite(cl) and is_finite(cl_unc) and cl < cl_unc:
            out.append({**base, "kind": "worse",
                        "detail": f"closed loop PSNR {cl:.2f} dB < uncompensated {cl_unc:.2f} dB"})
        elif not is_finite(cl) and is_finite(r.get("unc_psnr", nan)) and psnr < r["unc_psnr"]:
            out.append({**base, "kind": "worse",
                        "detail": f"surrogate PSNR {psnr:.2f} dB < uncompensated {r['unc_psnr']:.2f} dB"})
    return out


def write_summaries(folder: Path, study: dict, rows: list[dict]) -> dict[str, Path]:
    """Write ``summary.csv`` and ``breakpoints.csv`` (of :func:`main_rows`) and ``failures.csv``
    (of every row) into ``folder``.

    Returns
    -------
    dict
        Their paths by name (``summary``, ``breakpoints``, ``failures``).
    """
    folder = Path(folder)
    axes = axis_keys(study)
    summary = summarize(main_rows(rows), axes)
    return {"summary": write_csv(folder / "summary.csv", summary_columns(axes), summary),
            "breakpoints": write_csv(folder / "breakpoints.csv", break_columns(axes),
                                     breakpoints(summary, study)),
            "failures": write_csv(folder / "failures.csv", failure_columns(axes), failures(rows, axes))}


def break_columns(axes: list[str]) -> list[str]:
    """Columns of ``breakpoints.csv``: a second axis's key after ``n_train``."""
    return list(dict.fromkeys([*BREAK_COLUMNS[:2], *axes[1:], *BREAK_COLUMNS[2:]]))


def failure_columns(axes: list[str]) -> list[str]:
    """Columns of ``failures.csv``: the axis keys after ``point``."""
    return list(dict.fromkeys([FAILURE_COLUMNS[0], *axes, *FAILURE_COLUMNS[1:]]))
