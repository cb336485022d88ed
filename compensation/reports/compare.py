"""Two study or bench folders side by side (``procam compare A B``): the same runs' scores in each,
and B − A with a bootstrap interval.

The rows of the two ``results.csv`` that describe the same run are matched on
:func:`key_columns` (a study: its axis values, setup, method, n_train, seed; a bench: table, setup,
method, n_train, variant, seed); two setup names that differ only by leading folders
(``data/default`` and ``default``) name the same setup (:func:`match_setups`). Written into
``A/compare-<name of B>/`` (or another folder):

``compare.csv``
    one row per score of each matched group (``level`` ``group``: the pairs whose runs are both
    ``ok``, over seeds and setups, per point, method and n_train), of each matched run (``level``
    ``run``), and one row per run found in one folder only (``level`` ``only A`` / ``only B``):
    the score in A (``a``), in B (``b``), ``diff`` = b − a and its
    :data:`~compensation.reports.summary.CONFIDENCE` percentile bootstrap interval ``lo``, ``hi``
    (:func:`score_difference`; ``over`` says over what, ``samples`` how many, ``sampled`` their mean).
``compare.md``
    the same as Markdown tables, with a note on what was matched and what the intervals are over.
"""
from __future__ import annotations

from pathlib import Path, PurePosixPath

import numpy as np

from compensation.reports.paired import image_differences
from compensation.reports.report import load_folder
from compensation.reports.summary import (CONFIDENCE, axis_keys, bootstrap_interval, cell_text, is_finite,
                                          write_csv)
from sim.errors import ProcamError
from sim.io import check_output_folder, write_text

SURROGATE = ("psnr", "ssim", "deltae")
"""Scores always compared; their ``cl_`` (closed-loop) forms too where both folders have them."""
BENCH_COLUMNS = ("table", "variant")
"""Key columns a bench adds to a study's (:func:`key_columns`)."""
LEVELS = ("group", "run", "only A", "only B")
"""Values of ``compare.csv``'s ``level`` column."""


def key_columns(study_a: dict, study_b: dict, a: str = "A", b: str = "B") -> list[str]:
    """The ``results.csv`` columns that name one run in both folders: the axis keys, ``setup``,
    ``method``, ``n_train``, ``seed``, and a bench's ``table`` and ``variant``.

    Raises
    ------
    ProcamError
        If one folder is a study and the other a bench, or their axes differ (``a``, ``b`` name them;
        the same axes in another order are the same axes).

    >>> key_columns({"kind": "study", "axes": [{"key": "n_train", "values": [8, 16]}]}, {"axes": [
    ...     {"key": "n_train", "values": [16, 32]}]})
    ['n_train', 'setup', 'method', 'seed']
    >>> key_columns({"axes": [{"key": "k1", "values": [1]}, {"key": "k2", "values": [2]}]},
    ...             {"axes": [{"key": "k2", "values": [2]}, {"key": "k1", "values": [1]}]})
    ['k1', 'k2', 'setup', 'method', 'n_train', 'seed']
    >>> key_columns({"kind": "bench", "axes": []}, {"kind": "bench", "axes": []})
    ['table', 'setup', 'method', 'n_train', 'variant', 'seed']
    """
    kinds = [s.get("kind", "study") for s in (study_a, study_b)]
    if kinds[0] != kinds[1]:
        raise ProcamError(f"{a} is a {kinds[0]} folder, {b} a {kinds[1]} folder: expected two studies or "
                          "two benches")
    axes = [axis_keys(s) for s in (study_a, study_b)]
    if sorted(axes[0]) != sorted(axes[1]):  # the same axes in any order: A's order names the columns
        raise ProcamError(f"{a} sweeps {', '.join(axes[0]) or 'no axis'}, {b} sweeps "
                          f"{', '.join(axes[1]) or 'no axis'}: expected studies of the same axes")
    if kinds[0] == "bench":
        return list(dict.fromkeys(["table", *axes[0], "setup", "method", "n_train", "variant", "seed"]))
    return list(dict.fromkeys([*axes[0], "setup", "method", "n_train", "seed"]))


def _ends_with(name: str, tail: str) -> bool:
    """Whether the path ``name`` ends with the path ``tail`` (whole folder names).

    >>> _ends_with("light2/pos1/curves", "pos1/curves"), _ends_with("xcurves", "curves")
    (True, False)
    """
    parts, end = PurePosixPath(name).parts, PurePosixPath(tail).parts
    return len(end) <= len(parts) and parts[len(parts) - len(end):] == end


def match_setups(names_a: list[str], names_b: list[str]) -> dict[str, str]:
    """B's setup names mapped to A's: a name both have to itself; else the one name of A it equals
    once leading folders are dropped from either, where that name is not B's too and no other name
    of B maps there; else to itself (matching nothing of A's).

    >>> match_setups(["default", "other"], ["data/default", "other"])
    {'other': 'other', 'data/default': 'default'}
    >>> match_setups(["light1/pos1/curves", "light2/pos1/curves"], ["pos1/curves", "light2/pos1/curves"])
    {'light2/pos1/curves': 'light2/pos1/curves', 'pos1/curves': 'pos1/curves'}
    """
    both = set(names_a) & set(names_b)
    found = {b: [a for a in dict.fromkeys(names_a) if _ends_with(a, b) or _ends_with(b, a)]
             for b in dict.fromkeys(names_b) if b not in both}
    taken = [c[0] for c in found.values() if len(c) == 1]
    return {**{b: b for b in dict.fromkeys(names_b) if b in both},
            **{b: c[0] if len(c) == 1 and c[0] not in both and taken.count(c[0]) == 1 else b
               for b, c in found.items()}}


def run_key(row: dict, columns: list[str]) -> tuple[str, ...]:
    """The cells of ``columns`` that name ``row``'s run, as text (a number as its exact float text).

    >>> run_key({"f": 0.5, "setup": "s", "method": "tps", "n_train": 8, "seed": 0},
    ...         ["f", "setup", "method", "n_train", "seed"])
    ('0.5', 's', 'tps', '8', '0')
    """
    return tuple(cell_text(row.get(c, ""), None) for c in columns)


def match_rows(rows_a: list[dict], rows_b: list[dict], columns: list[str]
               ) -> tuple[list[tuple[dict, dict]], list[dict], list[dict]]:
    """Pair the rows of A and B that name the same run (:func:`run_key` on ``columns``, B's setups
    renamed by :func:`match_setups`); a key found twice in both pairs in order.

    Returns
    -------
    list of (dict, dict), list of dict, list of dict
        The pairs (row of A, row of B) in A's order; the rows found only in A; only in B (each in
        its folder's order).

    >>> a = [{"setup": "s", "seed": s, "psnr": 20.0 + s} for s in (0, 1)]
    >>> b = [{"setup": "data/s", "seed": s, "psnr": 21.0} for s in (1, 2)]
    >>> pairs, only_a, only_b = match_rows(a, b, ["setup", "seed"])
    >>> [(x["seed"], y["seed"]) for x, y in pairs], [r["seed"] for r in only_a], [r["seed"] for r in only_b]
    ([(1, 1)], [0], [2])
    """
    rename = match_setups([r["setup"] for r in rows_a], [r["setup"] for r in rows_b])
    waiting: dict[tuple, list[dict]] = {}
    for r in rows_b:
        waiting.setdefault(run_key({**r, "setup": rename[r["setup"]]}, columns), []).append(r)
    pairs, only_a = [], []
    for r in rows_a:
        same = waiting.get(run_key(r, columns))
        if same:
            pairs.append((r, same.pop(0)))
        else:
            only_a.append(r)
    left = {id(w) for ws in waiting.values() for w in ws}
    return pairs, only_a, [r for r in rows_b if id(r) in left]


def compared_scores(pairs: list[tuple[dict, dict]]) -> list[str]:
    """The scores compared: :data:`SURROGATE`, and each of their ``cl_`` forms that A and B both
    hold a finite value of in some pair.

    >>> compared_scores([({"cl_psnr": 18.0, "cl_ssim": 0.5}, {"cl_psnr": float("nan"), "cl_ssim": 0.6})])
    ['psnr', 'ssim', 'deltae', 'cl_ssim']
    """
    both = [f"cl_{s}" for s in SURROGATE
            if all(any(is_finite(p[side].get(f"cl_{s}")) for p in pairs) for side in (0, 1))]
    return [*SURROGATE, *both]


def run_image_differences(row_a: dict, row_b: dict, score: str) -> list[float]:
    """B − A of ``score`` test image by test image
    (:func:`~compensation.reports.paired.image_differences` of the rows' ``per_image``); none where
    either run kept no such scores.

    >>> run_image_differences({"per_image": {"psnr": [20.0, 21.0, 22.0]}},
    ...                       {"per_image": {"psnr": [20.5, 20.0, float("nan")]}}, "psnr")
    [0.5, -1.0]
    >>> run_image_differences({"per_image": {"psnr": [20.0]}}, {}, "psnr")
    []
    """
    a, b = ((r.get("per_image") or {}).get(score) or [] for r in (row_a, row_b))
    return image_differences(b, a)


def score_difference(pairs: list[tuple[dict, dict]], score: str) -> dict:
    """B − A of ``score`` over the ``pairs`` (row of A, row of B) that both scored it.

    ``a`` and ``b`` are the means of ``score`` in A and in B over those pairs, ``diff`` = b − a,
    ``pairs`` their number. ``lo`` and ``hi`` bound the :data:`CONFIDENCE` percentile bootstrap
    interval (:func:`~compensation.reports.summary.bootstrap_interval`) of the mean difference over
    ``samples`` samples, which ``over`` names: ``images`` where every pair has paired test images
    (:func:`run_image_differences`: each image of each pair one sample), else ``runs`` with two pairs or
    more (each pair one sample: setups and seeds), else ``none`` (no interval). ``sampled`` is the
    samples' mean: per image for ``images``, where a run's PSNR is over its images' pooled error.

    >>> pairs = [({"psnr": 20.0}, {"psnr": 21.0}), ({"psnr": 22.0}, {"psnr": 22.5}),
    ...          ({"psnr": 23.0}, {"psnr": float("nan")})]
    >>> d = score_difference(pairs, "psnr")
    >>> d["a"], d["b"], d["diff"], d["pairs"], d["over"], d["samples"], d["lo"], d["hi"]
    (21.0, 21.75, 0.75, 2, 'runs', 2, 0.5, 1.0)
    >>> score_difference(pairs[:1], "psnr")["over"]
    'none'
    """
    both = [(a, b) for a, b in pairs if is_finite(a.get(score)) and is_finite(b.get(score))]
    nan = float("nan")
    out = {"a": nan, "b": nan, "diff": nan, "pairs": len(both), "lo": nan, "hi": nan, "over": "none",
           "samples": 0, "sampled": nan}
    if not both:
        return out
    out["a"], out["b"] = (float(np.mean([p[i][score] for p in both])) for i in (0, 1))
    out["diff"] = out["b"] - out["a"]
    images = [run_image_differences(a, b, score) for a, b in both]
    if all(images):
        samples, out["over"] = [x for per in images for x in per], "images"
    elif len(both) > 1:
        samples, out["over"] = [b[score] - a[score] for a, b in both], "runs"
    else:
        return out
    out["lo"], out["hi"] = bootstrap_interval(samples)
    out["samples"], out["sampled"] = len(samples), float(np.mean(samples))
    return out


def groups(pairs: list[tuple[dict, dict]], columns: list[str]) -> list[tuple[dict, list[tuple[dict, dict]]]]:
    """The pairs by the key ``columns`` less ``setup`` and ``seed`` (point, method, n_train, …), in
    A's order: per group its key cells (A's) and the pairs whose runs are both ``ok`` (none kept
    where none are).

    >>> p = [({"m": "tps", "seed": s, "status": "ok"}, {"status": st}) for s, st in ((0, "ok"), (1, "failed"))]
    >>> [(cells, len(ok)) for cells, ok in groups(p, ["m", "seed"])]
    [({'m': 'tps'}, 1)]
    """
    kept = [c for c in columns if c not in ("setup", "seed")]
    out: dict[tuple, tuple[dict, list[tuple[dict, dict]]]] = {}
    for a, b in pairs:
        _, ok = out.setdefault(run_key(a, kept), ({c: a.get(c, "") for c in kept}, []))
        if a.get("status") == "ok" and b.get("status") == "ok":
            ok.append((a, b))
    return list(out.values())


def compare_rows(pairs: list[tuple[dict, dict]], only_a: list[dict], only_b: list[dict],
                 columns: list[str]) -> list[dict]:
    """The rows of ``compare.csv`` (see the module's description): per group and score, per pair
    and score, then each row found in one folder only."""
    scores = compared_scores(pairs)
    out = []
    for cells, group in groups(pairs, columns):
        out += [{"level": "group", **cells, "score": s, **score_difference(group, s)} for s in scores]
    for a, b in pairs:
        cells = {"level": "run", **{c: a.get(c, "") for c in columns}, "setup_b": b["setup"],
                 "status_a": a["status"], "status_b": b["status"]}
        out += [{**cells, "score": s, **score_difference([(a, b)], s)} for s in scores]
    for level, rows, status in (("only A", only_a, "status_a"), ("only B", only_b, "status_b")):
        out += [{"level": level, **{c: r.get(c, "") for c in columns}, status: r["status"]} for r in rows]
    return out


def csv_columns(columns: list[str]) -> list[str]:
    """Columns of ``compare.csv``: ``level``, the key columns, then the cells of
    :func:`compare_rows`."""
    return ["level", *columns, "setup_b", "status_a", "status_b", "score", "pairs", "a", "b", "diff",
            "lo", "hi", "over", "samples", "sampled"]


def _number(score: str, value: float, sign: bool = False) -> str:
    """A score for the Markdown tables: SSIM to 4 decimals, dB and ΔE to 2; ``-`` for none.

    >>> _number("ssim", 0.81234), _number("cl_psnr", 1.5, sign=True), _number("psnr", float("nan"))
    ('0.8123', '+1.50', '-')
    """
    if not is_finite(value):
        return "-"
    return f"{value:{'+' if sign else ''}.{4 if score.endswith('ssim') else 2}f}"


def difference_text(score: str, row: dict) -> str:
    """A ``compare.csv`` row's B − A and its interval, as one Markdown cell.

    >>> difference_text("psnr", {"diff": 0.75, "lo": 0.5, "hi": 1.0, "over": "runs"})
    '+0.75 [0.50, 1.00]'
    >>> difference_text("psnr", {"diff": 0.75, "lo": float("nan"), "hi": float("nan"), "over": "none"})
    '+0.75'
    """
    text = _number(score, row["diff"], sign=True)
    if row["over"] != "none":
        text += f" [{_number(score, row['lo'])}, {_number(score, row['hi'])}]"
    return text


def markdown_table(header: list[str], body: list[list[str]]) -> list[str]:
    """The lines of a Markdown table.

    >>> markdown_table(["a", "b"], [["1", "2"]])
    ['| a | b |', '|---|---|', '| 1 | 2 |']
    """
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header),
            *("| " + " | ".join(row) + " |" for row in body)]


def _wide(rows: list[dict], level: str, key: list[str], scores: list[str]) -> list[str]:
    """The ``level`` rows of ``compare.csv`` as one Markdown table: a line per key, per score its
    value in A, in B and B − A with its interval."""
    lines: dict[tuple, dict] = {}
    for r in rows:
        if r["level"] == level:
            lines.setdefault(tuple(cell_text(r.get(c, "")) for c in key), {})[r["score"]] = r
    header = [*key, "pairs", *(f"{s} {side}" for s in scores for side in ("A", "B", "B − A"))]
    body = [[*k, str(next(iter(by.values()))["pairs"]),
             *(cell for s in scores for cell in (_number(s, by[s]["a"]), _number(s, by[s]["b"]),
                                                 difference_text(s, by[s])))]
            for k, by in lines.items()]
    return markdown_table(header, body)


def interval_note(rows: list[dict]) -> str:
    """What the intervals of ``compare.csv``'s scored rows are over, counted.

    >>> print(interval_note([{"level": "group", "over": "images"}, {"level": "run", "over": "none"}]))
    ... # doctest: +NORMALIZE_WHITESPACE
    B − A with its 95 % percentile bootstrap interval of the mean difference: over the paired test
    images (per_image.csv) in 1 cell(s), no interval in 1 (one run, no per-image scores).
    """
    scored = [r.get("over") for r in rows if r["level"] in LEVELS[:2]]
    count = {o: scored.count(o) for o in ("images", "runs", "none")}
    words = {"images": "over the paired test images (per_image.csv) in {} cell(s)",
             "runs": "over the paired runs (setups and seeds) in {}",
             "none": "no interval in {} (one run, no per-image scores)"}
    said = [words[o].format(n) for o, n in count.items() if n]
    return (f"B − A with its {100 * CONFIDENCE:g} % percentile bootstrap interval of the mean difference: "
            f"{', '.join(said) or 'no score compared'}.")


def write_markdown(path: Path, rows: list[dict], columns: list[str], names: tuple[str, str],
                   counts: tuple[int, int, int]) -> Path:
    """Write ``compare.md``: the note (what was matched, what the intervals are over), the groups,
    the runs, and the runs found in one folder only."""
    scores = list(dict.fromkeys(r["score"] for r in rows if r["level"] == "group"))
    kept = [c for c in columns if c not in ("setup", "seed")]
    matched, only_a, only_b = counts
    md = [f"# {names[1]} against {names[0]}", "",
          f"A: `{names[0]}`; B: `{names[1]}`. {matched} run(s) matched on {', '.join(columns)}; "
          f"{only_a} only in A, {only_b} only in B (listed at the end). Groups average the pairs whose "
          f"runs are both ok over seeds and setups. {interval_note(rows)}", "",
          "## Per point and method", "", *_wide(rows, "group", kept, scores), "",
          "## Per run", "", *_wide(rows, "run", [*columns, "status_a", "status_b"], scores)]
    for level, n in (("only A", only_a), ("only B", only_b)):
        status = "status_a" if level == "only A" else "status_b"
        md += ["", f"## Only in {level[-1]} ({n})", ""]
        md += markdown_table([*columns, "status"], [[cell_text(r.get(c, "")) for c in (*columns, status)]
                                                    for r in rows if r["level"] == level]) if n else ["none"]
    write_text(path, "\n".join(md) + "\n")
    return Path(path)


def _read(folder: Path, name: str) -> tuple[dict, list[dict]]:
    """A study or bench folder's record and results rows, or a one-line error naming it."""
    if not Path(folder).is_dir():
        raise ProcamError(f"{name} {folder}: not a study or bench folder (expected a folder written by "
                          "procam study or procam bench, holding study.json and results.csv)")
    return load_folder(Path(folder))


COMPARE_FILES = ("compare.csv", "compare.md")
"""What :func:`compare_folders` writes into its output folder."""


def compare_folders(a: Path, b: Path, out: Path | None = None) -> dict:
    """Compare the study or bench folders ``a`` and ``b``: write ``compare.csv`` and ``compare.md``
    into ``out`` (default ``a/compare-<name of b>``).

    Returns
    -------
    dict
        ``csv``, ``md`` (their paths), ``rows`` (of ``compare.csv``), ``matched``, ``only_a``,
        ``only_b`` (counts), ``columns`` (:func:`key_columns`).

    Raises
    ------
    ProcamError
        If either is not a study or bench folder, both are the same folder, they are not of one
        kind and axes (:func:`key_columns`), no run of one matches a run of the other, or ``out``
        is a file or holds anything but :data:`COMPARE_FILES`.
    """
    a, b = Path(a), Path(b)
    (study_a, rows_a), (study_b, rows_b) = _read(a, "A"), _read(b, "B")
    if a.resolve() == b.resolve():
        raise ProcamError(f"A and B are the same folder {a}: expected two study or bench folders to compare")
    columns = key_columns(study_a, study_b, f"A {a}", f"B {b}")
    pairs, only_a, only_b = match_rows(rows_a, rows_b, columns)
    if not pairs:
        raise ProcamError(f"{a}, {b}: no run of one matches a run of the other on {', '.join(columns)}: "
                          "expected two folders of the same study or bench")
    out = Path(out) if out is not None else a / f"compare-{b.resolve().name}"
    check_output_folder(out, COMPARE_FILES, "compare")
    rows = compare_rows(pairs, only_a, only_b, columns)
    counts = (len(pairs), len(only_a), len(only_b))
    return {"csv": write_csv(out / COMPARE_FILES[0], csv_columns(columns), rows),
            "md": write_markdown(out / COMPARE_FILES[1], rows, columns, (str(a), str(b)), counts),
            "rows": rows, "matched": counts[0], "only_a": counts[1], "only_b": counts[2],
            "columns": columns}


def summary_lines(result: dict, most: int = 12) -> list[str]:
    """A short account of :func:`compare_folders`' result: the counts, then B − A of PSNR (and
    closed-loop PSNR where compared) per group, at most ``most`` groups.

    >>> rows = [{"level": "group", "method": "tps", "score": "psnr", "diff": 0.5, "lo": 0.1, "hi": 0.9,
    ...          "over": "runs", "pairs": 2}]
    >>> summary_lines({"rows": rows, "matched": 2, "only_a": 1, "only_b": 0, "columns": ["method", "seed"]})
    ['2 run(s) matched, 1 only in A, 0 only in B', '  method tps: psnr B − A +0.50 [0.10, 0.90] dB (2 pairs)']
    """
    kept = [c for c in result["columns"] if c not in ("setup", "seed")]
    lines: dict[str, list[str]] = {}
    for r in result["rows"]:
        if r["level"] == "group" and r["score"] in ("psnr", "cl_psnr"):
            where = ", ".join(f"{c} {cell_text(r.get(c, ''))}" for c in kept)
            lines.setdefault(where, []).append(f"{r['score']} B − A {difference_text(r['score'], r)} dB "
                                               f"({r['pairs']} pairs)")
    out = [f"{result['matched']} run(s) matched, {result['only_a']} only in A, {result['only_b']} only in B"]
    out += [f"  {where}: {'; '.join(parts)}" for where, parts in list(lines.items())[:most]]
    if len(lines) > most:
        out.append(f"  … {len(lines) - most} more group(s) in compare.md")
    return out
