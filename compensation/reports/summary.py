"""What a study or bench folder's ``results.csv`` says, in three CSV files: pure functions over rows.

``results.csv`` holds one row per (point, setup, method, n_train, seed): the point's axis values,
the run's ``status`` and its scores (surrogate, closed loop, uncompensated, oracle, optimum) and timings
(:data:`compensation.experiments.jobs.RESULT_COLUMNS`; missing values are empty cells). From it:

``summary.csv``
    mean and standard deviation over seeds (and setups) per (point, method, n_train), ``ok`` runs
    only (:func:`summarize`).
``breakpoints.csv``
    per method and n_train (and value of a second axis): the first value of the factor where the
    method's closed-loop PSNR gain over uncompensated is below :data:`BREAK_GAIN_DB`, or its PSNR
    more than :data:`OPTIMUM_MARGIN_DB` below the exact optimum's, with :data:`CONFIDENCE`
    (:func:`bootstrap_interval` over the point's test images and seeds, from ``per_image.csv``);
    a point whose runs were still training (``undertrained``) is not a break (:func:`breakpoints`).
``failures.csv``
    every run that failed, gave NaN, diverged, or scored below uncompensated (:func:`failures`).
"""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np

from compensation.experiments.jobs import cell_identity
from compensation.experiments.targets import TargetPolicy
from sim.errors import ProcamError
from sim.io import atomic_write, read_json
from sim.layout import SETUP_FILE

METRICS = ("psnr", "rmse", "ssim", "deltae")
"""Surrogate metrics (π†(x̃) against x on held-out pairs); ``cl_``, ``unc_`` prefixed: the same in
closed loop and for the uncompensated captures."""
SCORES = (*METRICS, *(f"cl_{m}" for m in METRICS), *(f"unc_{m}" for m in METRICS),
          "cl_unc_psnr", "cl_unc_ssim", "cl_unc_deltae", "oracle_psnr", "oracle_ssim", "oracle_deltae",
          "optimum_psnr", "optimum_ssim", "optimum_deltae",
          "fit_s", "infer_ms", "reachable_fraction", "target_out_of_reach", "target_out_of_reach_used",
          "target_a", "target_b", "ambient_share", "indirect_share")
"""The numeric columns of ``results.csv`` (empty cells read as NaN); closed-loop scores compare with
the target y' = ``target_a`` · y + ``target_b`` of the row's ``target_policy``; ``ambient_share`` and
``indirect_share`` are the setup's measured light (:func:`~sim.light.light_shares`)."""
STATUSES = ("ok", "failed", "nan", "diverged")
"""Values of the ``status`` column: finished; raised an error (``error`` says which); a score is not
finite; the training loss grew (:data:`compensation.experiments.jobs.DIVERGED_RATIO`) or is not
finite."""
BREAK_GAIN_DB = 1.0
"""A method breaks where its closed-loop PSNR gain over uncompensated is below this (dB): the
whole confidence interval of the gain lies below it."""
OPTIMUM_MARGIN_DB = 3.0
"""A method breaks where its closed-loop PSNR is more than this below the exact optimum's (dB): the
whole confidence interval of the optimum's lead lies above it. The optimum is what the setup can
show at best (:mod:`compensation.experiments.optimum`); a method this far below it fails at
compensation, not at the setup's reach."""
CONFIDENCE = 0.95
"""Confidence of the break-point intervals: the central percentile bootstrap interval holding this
share of the resampled means (a break needs the whole interval past its line)."""
BOOTSTRAP_SAMPLES = 2000
"""Resamples of each percentile bootstrap interval."""
BOOTSTRAP_SEED = 0
"""Seed of the bootstrap's generator: the same results give the same intervals."""
INTERVALS = ("gain", "optimum_gap")
"""The intervals of ``summary.csv`` and ``breakpoints.csv`` (dB; each as ``<name>_db``, ``_lo``,
``_hi``): the closed-loop PSNR gain over uncompensated, and the exact optimum's lead over the method
(surrogate gain over the uncompensated captures, and no lead, where the folder has no closed loop)."""


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


STUDY_TYPES = {"name": str, "question": str, "kind": str, "target": dict, "setups": dict,
                "versions": dict}
"""Keys of ``study.json`` the readers use besides ``axes``, and the type each holds where given."""


def read_study(folder: Path) -> dict:
    """``folder/study.json``, checked for what the readers use (``axes`` with ``key`` and ``values``).

    Raises
    ------
    ProcamError
        If the file is missing or unreadable, an axis lacks its key or values, a key of
        :data:`STUDY_TYPES` holds another type, the target is not a
        :class:`~compensation.experiments.targets.TargetPolicy`, or a setup's path does not name a
        ``setup.toml``.
    """
    path = Path(folder) / "study.json"
    study = read_json(path, "study description")
    if not isinstance(study, dict):
        raise ProcamError(f"{path}: expected a JSON object")
    axes = study.get("axes", [])
    if not isinstance(axes, list) or not all(isinstance(a, dict) and isinstance(a.get("key"), str)
                                             and isinstance(a.get("values"), list) for a in axes):
        raise ProcamError(f"{path}: 'axes' must be a list of {{key, values, ...}} tables, each key "
                          "a string and its values a list")
    for a in axes:
        for text in ("label", "unit"):
            if a.get(text) is not None and not isinstance(a[text], str):
                raise ProcamError(f"{path}: axis {a['key']!r}: {text} = {a[text]!r}: expected a string")
        physical = a.get("physical")
        if physical is not None and not (
                isinstance(physical, dict) and isinstance(physical.get("label"), str)
                and isinstance(physical.get("unit"), str) and isinstance(physical.get("values"), list)
                and len(physical["values"]) == len(a["values"])
                and all(v is None or is_finite(v) for v in physical["values"])):
            raise ProcamError(f"{path}: axis {a['key']!r}: 'physical' must be {{label, unit, values}} with "
                              "one number (or null) per axis value")
    for key, kind in STUDY_TYPES.items():
        if study.get(key) is not None and not isinstance(study[key], kind):
            raise ProcamError(f"{path}: {key!r} = {study[key]!r}: expected a JSON "
                              f"{'object' if kind is dict else 'string'}")
    if target := study.get("target"):
        try:
            TargetPolicy(target.get("policy"), target.get("out_of_reach"))
        except (ProcamError, TypeError) as exc:
            raise ProcamError(f"{path}: target {target}: {exc}") from None
    for name, where in (study.get("setups") or {}).items():
        if not isinstance(where, str) or Path(where).name != SETUP_FILE:
            raise ProcamError(f"{path}: setups.{name} = {where!r}: expected the path of a setup "
                              f"file named {SETUP_FILE}")
    return study


def table_text(path: Path, what: str) -> str:
    """The text of a CSV table procam wrote (``what`` names it in messages).

    Raises
    ------
    ProcamError
        If the file is missing, not UTF-8 or cut short (its last line unfinished).
    """
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ProcamError(f"{path}: {what} not found") from None
    except UnicodeDecodeError as exc:
        raise ProcamError(f"{path}: not a {what} (not UTF-8 text: byte {exc.start})") from None
    if text and not text.endswith("\n"):  # every row procam writes ends its line
        raise ProcamError(f"{path}: cut short (its last line is unfinished); run the study or bench "
                          "again to write it whole")
    return text


def read_results(path: Path, axes: list[str], listed: dict[str, list] | None = None) -> list[dict]:
    """Read ``results.csv``: ``point``, ``n_train`` and ``seed`` as int, scores as float (NaN for
    an empty cell), axis values as float where numeric, every other cell as text.

    ``listed``: the values ``study.json`` gives each axis, where the rows' values are checked
    against them.

    Raises
    ------
    ProcamError
        If the file is missing, not UTF-8 or cut short (its last line unfinished), or a required
        column or axis column is absent, or a row has more or fewer cells than the header, or a cell of
        ``point``, ``n_train``, ``seed`` is not an integer, of a score not a number or of an axis
        empty or not finite (or not one of ``listed``), or a ``status`` is unknown, or a run
        (:data:`RUN_COLUMNS`) is given twice, or an ``ok`` run has an infinite score of its own or no
        PSNR (surrogate or closed loop), or
        one point has two sets of axis values or two points one; the message names the file, the
        row and the column.
    """
    path = Path(path)
    reader = csv.DictReader(io.StringIO(table_text(path, "results table")))
    header = reader.fieldnames or []
    missing = [c for c in ("point", *axes, "setup", "method", "n_train", "seed", "status", "psnr", "ssim",
                           "deltae") if c not in header]
    if missing:
        raise ProcamError(f"{path}: missing column(s) {', '.join(missing)}")
    rows, seen, points = [], {}, {}
    for line, raw in enumerate(reader, start=2):
        if None in raw or None in raw.values():
            raise ProcamError(f"{path}, line {line}: {len(header)} columns in the header, another number "
                              "in this row")
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
        for key in SCORES:
            row[key] = _number(raw.get(key) or "")
            if isinstance(row[key], str):
                raise ProcamError(f"{path}, line {line}: column {key}: expected a number, found {row[key]!r}")
        for key in (a for a in axes if a not in ("point", "n_train", "seed", *SCORES)):
            row[key] = _number(raw.get(key) or "")
            if isinstance(row[key], float) and not math.isfinite(row[key]):
                raise ProcamError(f"{path}, line {line}: column {key}: expected the run's axis value, "
                                  f"found {raw.get(key)!r}")
        for key in ("error", "run", "table", "variant", "target_policy"):
            row[key] = raw.get(key) or ""
        row["undertrained"] = raw.get("undertrained") == "1"
        if (run_id := _run_key(row)) in seen:
            raise ProcamError(f"{path}, line {line}: run {_run_text(row)} is given twice (first on "
                              f"line {seen[run_id]})")
        seen[run_id] = line
        if row["status"] == "ok" and (bad := _missing_scores(row)):
            raise ProcamError(f"{path}, line {line}: status ok but column {bad} holds no finite number "
                              f"({raw.get(bad)!r}); a run without its scores is failed or nan")
        _check_point(path, line, row, axes, listed or {}, points)
        rows.append(row)
    return rows


def _missing_scores(row: dict) -> str:
    """The score column that makes an ``ok`` row's scores incomplete: one of the run's own that is
    infinite (a run with one is ``nan``; a baseline's, such as ``unc_psnr``, may be), or the PSNR
    where neither the surrogate nor the closed loop has one; empty where none.

    >>> _missing_scores({"psnr": float("nan"), "cl_psnr": 20.0}), _missing_scores({"psnr": float("inf")})
    ('', 'psnr')
    >>> _missing_scores({"psnr": 20.0, "unc_psnr": float("inf")})
    ''
    """
    own = (*METRICS, *(f"cl_{m}" for m in METRICS))
    if inf := [k for k in own if isinstance(row.get(k), float) and math.isinf(row[k])]:
        return inf[0]
    return "" if any(is_finite(row.get(k)) for k in ("psnr", "cl_psnr")) else "psnr"


def _check_point(path: Path, line: int, row: dict, axes: list[str], listed: dict[str, list],
                 points: dict) -> None:
    """Refuse a row whose axis values are not the study's, or disagree with its point's: one
    point, one set of values (``points``: what each point and each set of values was first
    given as, updated)."""
    for key in axes:
        if key in listed and cell_identity(row[key]) not in {cell_identity(v) for v in listed[key]}:
            raise ProcamError(f"{path}, line {line}: column {key}: {row[key]!r} is not one of the "
                              f"study's values ({', '.join(map(str, listed[key]))}; study.json)")
    values = tuple(cell_identity(row[key]) for key in axes)
    shown = f"point {row['point']} ({', '.join(f'{k} = {row[k]}' for k in axes) or 'no axis'})"
    if points.setdefault(("point", row["point"]), (values, line))[0] != values:
        raise ProcamError(f"{path}, line {line}: {shown}: line {points[('point', row['point'])][1]} "
                          "gives this point other axis values")
    if points.setdefault(("values", values), (row["point"], line))[0] != row["point"]:
        first, at = points[("values", values)]
        raise ProcamError(f"{path}, line {line}: {shown}: line {at} gives these axis values as point {first}")


RUN_COLUMNS = ("point", "setup", "method", "n_train", "seed", "table", "variant")
"""The columns that name one run of a folder in ``results.csv`` and ``per_image.csv`` alike."""


def _run_key(row: dict) -> tuple:
    """What names one run of a folder in ``results.csv`` and ``per_image.csv`` alike."""
    return tuple(str(row.get(k, "")) for k in RUN_COLUMNS)


def _run_text(row: dict) -> str:
    """A run's name in a message: its non-empty :data:`RUN_COLUMNS`.

    >>> _run_text({"point": 0, "setup": "default", "method": "tps", "seed": 0, "table": ""})
    'point 0, setup default, method tps, seed 0'
    """
    return ", ".join(f"{k} {row[k]}" for k in RUN_COLUMNS if row.get(k) not in (None, ""))


def attach_per_image(rows: list[dict], path: Path) -> list[dict]:
    """``rows`` of :func:`read_results`, each with ``per_image``: its run's per-image scores of
    ``per_image.csv`` at ``path`` by column (lists in image order, by the ``image`` column and not
    by the order of the lines, NaN for an empty cell); the rows unchanged where the file is absent
    (a folder written before it existed).

    Raises
    ------
    ProcamError
        If the file is not UTF-8 or cut short, lacks a column it is joined by, a row has more or
        fewer cells than the header, names a run ``rows`` do not hold, a score cell is not a
        number, or a run's images are not numbered 1 to N each once.
    """
    path = Path(path)
    if not path.is_file():
        return rows
    reader = csv.DictReader(io.StringIO(table_text(path, "per-image table")))
    missing = [c for c in ("point", "setup", "method", "n_train", "seed", "image")
               if c not in (reader.fieldnames or [])]
    if missing:
        raise ProcamError(f"{path}: missing column(s) {', '.join(missing)}")
    scores = [c for c in reader.fieldnames if c.endswith("psnr")]
    images: dict[tuple, dict[int, dict]] = {}
    known = {_run_key(r) for r in rows}
    for line, raw in enumerate(reader, start=2):
        if None in raw or None in raw.values():
            raise ProcamError(f"{path}, line {line}: {len(reader.fieldnames)} columns in the header, "
                              "another number in this row")
        if _run_key(raw) not in known:
            raise ProcamError(f"{path}, line {line}: run {_run_text(raw)} is not a run of results.csv")
        try:
            image = int(raw["image"] or "")
        except ValueError:
            image = 0
        if image < 1:
            raise ProcamError(f"{path}, line {line}: column image: expected a test image number "
                              f"from 1, found {raw['image']!r}")
        run = images.setdefault(_run_key(raw), {})
        if image in run:
            raise ProcamError(f"{path}, line {line}: image {image} of run {_run_text(raw)} is given "
                              "twice")
        run[image] = {}
        for c in scores:
            value = _number(raw[c] or "")
            if isinstance(value, str):
                raise ProcamError(f"{path}, line {line}: column {c}: expected a number, found {value!r}")
            run[image][c] = value
    found: dict[tuple, dict] = {}
    for key, run in images.items():
        absent = sorted(set(range(1, max(run) + 1)) - set(run))
        if absent:
            raise ProcamError(f"{path}: run {_run_text(dict(zip(RUN_COLUMNS, key)))} lacks image(s) "
                              f"{', '.join(map(str, absent[:5]))}{' …' if len(absent) > 5 else ''} "
                              f"(expected images 1 to {max(run)})")
        found[key] = {c: [run[i][c] for i in range(1, len(run) + 1)] for c in scores}
    return [{**r, "per_image": found.get(_run_key(r), {})} for r in rows]


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


def bootstrap_interval(values, confidence: float = CONFIDENCE, samples: int = BOOTSTRAP_SAMPLES,
                       seed: int = BOOTSTRAP_SEED) -> tuple[float, float]:
    """Percentile bootstrap interval of the mean of the finite ``values``: the central
    ``confidence`` share of the means of ``samples`` resamples (with replacement, of the same
    size), drawn by a generator seeded with ``seed``. NaN without values.

    >>> bootstrap_interval([2.0, 2.0, float("nan")])
    (2.0, 2.0)
    >>> bootstrap_interval([0.0, 1.0])  # resampled means 0, 0.5, 1 with chances 1/4, 1/2, 1/4
    (0.0, 1.0)
    """
    v = np.array([x for x in values if is_finite(x)], float)
    if v.size == 0:
        return float("nan"), float("nan")
    means = v[np.random.default_rng(seed).integers(0, v.size, (samples, v.size))].mean(axis=1)
    lo, hi = np.quantile(means, [(1 - confidence) / 2, (1 + confidence) / 2])
    return float(lo), float(hi)


def run_samples(row: dict) -> tuple[list[float], list[float]]:
    """A run's samples of :data:`INTERVALS`: per test image (``per_image``: closed loop against
    uncompensated and the optimum, image by image) where kept, else the run's own means (its
    :func:`closed_loop_gain`, the optimum's lead in closed loop only).

    >>> run_samples({"per_image": {"cl_psnr": [20.0, 22.0], "cl_unc_psnr": [18.0, 18.5],
    ...                            "optimum_psnr": [24.0, 23.0]}})
    ([2.0, 3.5], [4.0, 1.0])
    >>> run_samples({"cl_psnr": 20.0, "cl_unc_psnr": 18.0, "optimum_psnr": float("nan")})
    ([2.0], [nan])
    """
    per = row.get("per_image") or {}
    cl, unc, bound = (np.array(per.get(k) or [], float) for k in ("cl_psnr", "cl_unc_psnr", "optimum_psnr"))
    if cl.size and unc.size == cl.size:
        return (cl - unc).tolist(), (bound - cl).tolist() if bound.size == cl.size else []
    nan = float("nan")
    score, gain, which = closed_loop_gain({f"{k}_mean": row.get(k, nan)
                                           for k in ("cl_psnr", "cl_unc_psnr", "psnr", "unc_psnr")})
    return [gain], [row.get("optimum_psnr", nan) - score if which == "closed loop" else nan]


def summarize(rows: list[dict], axes: list[str]) -> list[dict]:
    """Mean and std over seeds and setups per (point, method, n_train), of the ``ok`` runs.

    Each summary row has ``point``, the axis values, ``method``, ``n_train``, ``runs`` (all rows),
    ``ok`` (rows with status ok), ``undertrained`` (ok rows flagged so), ``<score>_mean``,
    ``<score>_std`` for every :data:`SCORES`, and for every :data:`INTERVALS` name its mean over
    the samples of the ok runs (:func:`run_samples`) ``<name>_db`` and :func:`bootstrap_interval`
    ``<name>_lo``, ``<name>_hi``: each (run, test image) pair is one sample, so the resamples vary
    both the seeds (and setups) and the test images.

    >>> rows = [dict(point=0, a=1.0, method="m", n_train=8, seed=s, status="ok", cl_psnr=p)
    ...         for s, p in enumerate([20.0, 22.0])]
    >>> rows.append(dict(point=0, a=1.0, method="m", n_train=8, seed=2, status="failed", cl_psnr=5.0))
    >>> s = summarize(rows, ["a"])[0]
    >>> s["runs"], s["ok"], s["cl_psnr_mean"], round(s["cl_psnr_std"], 3), s["psnr_mean"]
    (3, 2, 21.0, 1.414, nan)
    >>> s["gain_db"], s["gain_lo"], s["gain_hi"], s["undertrained"]
    (nan, nan, nan, 0)
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
        row["undertrained"] = sum(bool(r.get("undertrained")) for r in ok)
        samples = [run_samples(r) for r in ok]
        for i, name in enumerate(INTERVALS):
            values = [x for pair in samples for x in pair[i]]
            row[f"{name}_db"] = mean_std(values)[0]
            row[f"{name}_lo"], row[f"{name}_hi"] = bootstrap_interval(values)
        out.append(row)
    return out


def summary_columns(axes: list[str]) -> list[str]:
    """Columns of ``summary.csv``."""
    return list(dict.fromkeys(["point", *axes, "method", "n_train", "runs", "ok", "undertrained",
                               *(f"{k}_{s}" for k in SCORES for s in ("mean", "std")),
                               *(f"{k}_{s}" for k in INTERVALS for s in ("db", "lo", "hi"))]))


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


BREAK_COLUMNS = ("method", "n_train", "axis", "break_value", "point", "kind", "gain_db", "gain_lo",
                 "gain_hi", "optimum_gap_db", "optimum_gap_lo", "optimum_gap_hi", "psnr", "score",
                 "undertrained", "reason")
"""Columns of ``breakpoints.csv`` (the second axis's key comes after ``n_train`` with two axes)."""
BREAK_KINDS = ("none", "gain", "optimum", "failed", "undertrained")
"""Values of ``kind`` in ``breakpoints.csv`` (:func:`breakpoints`)."""


def break_test(row: dict, threshold: float = BREAK_GAIN_DB, margin: float = OPTIMUM_MARGIN_DB) -> tuple[str, str]:
    """Whether a summary row (:func:`summarize`) is a break, by its intervals: ``gain`` where the
    gain's whole interval is below ``threshold`` dB, else ``optimum`` where the optimum's lead's whole
    interval is above ``margin`` dB, else no break (``""``); and the reason in words.

    >>> break_test({"gain_db": 0.6, "gain_lo": 0.2, "gain_hi": 0.9, "optimum_gap_lo": float("nan")})[0]
    'gain'
    >>> break_test({"gain_db": 0.6, "gain_lo": 0.2, "gain_hi": 1.1, "optimum_gap_db": 5.0,
    ...             "optimum_gap_lo": 3.5, "optimum_gap_hi": 6.0})
    ('optimum', "PSNR 5.00 dB below the optimum's (95 % interval 3.50 to 6.00) > 3 dB")
    """
    level = f"{100 * CONFIDENCE:g} % interval"
    if row["gain_hi"] < threshold:
        return "gain", (f"PSNR gain over uncompensated {row['gain_db']:.2f} dB ({level} {row['gain_lo']:.2f} "
                        f"to {row['gain_hi']:.2f}) < {threshold:g} dB")
    if row["optimum_gap_lo"] > margin:
        return "optimum", (f"PSNR {row['optimum_gap_db']:.2f} dB below the optimum's ({level} "
                           f"{row['optimum_gap_lo']:.2f} to {row['optimum_gap_hi']:.2f}) > {margin:g} dB")
    return "", ""


def breakpoints(summary: list[dict], study: dict, threshold: float = BREAK_GAIN_DB,
                margin: float = OPTIMUM_MARGIN_DB) -> list[dict]:
    """Each method's break point along the study's first axis, per n_train and value of a second axis.

    Along the first axis's values (in the study's order), a method breaks at the first value where
    it has no score (every run failed: ``kind`` ``failed``) or :func:`break_test` holds with
    :data:`CONFIDENCE` (``gain``: gain over uncompensated below ``threshold`` dB; ``optimum``: more
    than ``margin`` dB below the exact optimum). A value where the test holds but a run was still
    training at its end (``undertrained`` runs in the summary row) is no break: it is listed in
    ``undertrained`` and the search goes on. A method that never breaks gets ``kind`` ``none``, or
    ``undertrained`` where only such values held, and an empty ``break_value``. Without an axis (a
    bench) there is nothing to break along: no rows. Where the factor sets the training size
    (:func:`n_train_follows`), the line runs across sizes and ``n_train`` is left empty.

    >>> study = {"axes": [{"key": "blur", "values": [0, 1, 2]}]}
    >>> def row(p, m, gain, gap, undertrained=0):
    ...     return {"point": p, "blur": float(p), "method": m, "n_train": 8, "cl_psnr_mean": 20.0,
    ...             "cl_unc_psnr_mean": 20.0 - gain, "undertrained": undertrained,
    ...             "gain_db": gain, "gain_lo": gain - 0.3, "gain_hi": gain + 0.3,
    ...             "optimum_gap_db": gap, "optimum_gap_lo": gap - 0.5, "optimum_gap_hi": gap + 0.5}
    >>> s = [row(0, "a", 5, 1), row(1, "a", 3, 4), row(2, "a", 0.5, 6)]
    >>> s += [row(0, "b", 4, 2), row(1, "b", 0.5, 2, undertrained=1), row(2, "b", 0.6, 3.2)]
    >>> [(b["method"], b["break_value"], b["kind"], b["undertrained"]) for b in breakpoints(s, study)]
    [('a', 1.0, 'optimum', ''), ('b', 2.0, 'gain', '1')]
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
        for method, line in by_method.items():
            found, held = None, []
            for r in line:
                score, _, which = closed_loop_gain(r)
                if not is_finite(score):
                    found = (r, "failed", f"no {which} score at {key} = {cell_text(r[key])}: every run failed")
                    break
                kind, reason = break_test(r, threshold, margin)
                if kind and r.get("undertrained"):
                    held.append(r)
                elif kind:
                    found = (r, kind, f"{which} {reason}")
                    break
            first = line[0]
            row = {"method": method, "n_train": group_key[0], **dict(zip(second, group_key[1:])),
                   "axis": key, "score": closed_loop_gain(first)[2],
                   "undertrained": "; ".join(cell_text(r[key]) for r in held)}
            if found is None:
                kind = "undertrained" if held else "none"
                reason = (f"{len(held)} value(s) would break but runs there were still training at their end: "
                          "undertrained, not broken" if held else
                          f"no break: gain >= {threshold:g} dB or within {margin:g} dB of the optimum "
                          f"with {100 * CONFIDENCE:g} % confidence")
                row.update(break_value="", point="", kind=kind, psnr=float("nan"), reason=reason,
                           **{f"{n}_{s}": float("nan") for n in INTERVALS for s in ("db", "lo", "hi")})
            else:
                hit, kind, reason = found
                row.update(break_value=hit[key], point=hit["point"], kind=kind, psnr=closed_loop_gain(hit)[0],
                           reason=reason, **{f"{n}_{s}": hit.get(f"{n}_{s}", float("nan"))
                                             for n in INTERVALS for s in ("db", "lo", "hi")})
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
