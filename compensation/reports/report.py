"""``procam report DIR``: one self-contained HTML page for a study or bench folder.

The page holds, in order: the question and each method's break point, a figure grid in the style of
the CompenNet paper's Fig. 4 (rows: test images; columns: surface s̃, uncompensated capture, each
method's closed-loop capture, desired image; two zoomed patches under each), every chart of
:mod:`~compensation.reports.charts`, the tables (a bench's Tables 1-3 with the paper's columns and
Table 1's paired comparisons of the methods, the summary), the failures, and the provenance (setup
files, seeds, versions, timings). Images are inlined as base64 ``data:`` URIs and the style sheet
is inline: the page needs no network and no other file. It is written atomically to
``DIR/report.html``, beside the files it is made from: ``summary.csv``, ``breakpoints.csv``,
``failures.csv`` and ``charts/`` (written again each time).

A folder is read from ``study.json`` and ``results.csv`` (with ``per_image.csv``, the per-image
scores of the break points' intervals, where it has one); a bench folder written before those
existed (``per_setup.csv`` and ``bench.json``) is read from its Table 1 rows and run folders.
"""
from __future__ import annotations

import base64
import csv
import html
import io
import json
import math
from pathlib import Path

import cv2
import numpy as np

from compensation.data import frames_root, read_png_like, surface_path
from compensation.reports import charts as ch
from compensation.experiments.closed_loop import CAPTURES_DIR
from compensation.reports.summary import (CONFIDENCE, BREAK_GAIN_DB, OPTIMUM_MARGIN_DB, is_finite, cell_text,
                                             order_key, axis_keys, attach_per_image, break_columns,
                                             breakpoints, failure_columns, failures, read_results,
                                             main_rows, read_study, summarize, table_text,
                                             write_summaries)
from sim.errors import DatasetError, ProcamError
from sim.io import atomic_write, read_json, read_png, write_text
from sim.layout import SETUP_FILE, TEST, capture_dir, image_name

N_ROWS = 3
"""Test images (rows) per figure grid."""
N_GRIDS = 3
"""Figure grids per study at most: the first, middle and last value of the first axis."""
CELL = 160
"""Display size of a grid cell's image (pixels, its longer side); the zoomed patches go below it."""
PATCH_COLOURS = ((255, 200, 0), (0, 190, 255))
"""Outline colours of the two zoomed patches (RGB)."""


# --------------------------------------------------------------------------- reading a folder

def _bench_rows(folder: Path) -> tuple[dict, list[dict]]:
    """A bench folder without ``results.csv``: its Table 1 rows of ``per_setup.csv`` as results
    rows (one point, no axis), the timings and run folders from ``runs/<setup>/<method>-n<N>``,
    the uncompensated closed loop, the oracle and the optimum from ``bench.json``."""
    bench = read_json(folder / "bench.json", "bench record")
    table = list(csv.DictReader(io.StringIO(table_text(folder / "per_setup.csv", "bench table"))))
    if table and (missing := [c for c in ("table", "setup", "method", "n_train") if c not in table[0]]):
        raise ProcamError(f"{folder / 'per_setup.csv'}: missing column(s) {', '.join(missing)}")
    seen: dict[tuple, int] = {}
    for line, r in enumerate(table, start=2):
        run = tuple(r.get(k) for k in ("table", "setup", "method", "n_train", "loss", "init", "seed"))
        if seen.setdefault(run, line) != line:
            raise ProcamError(f"{folder / 'per_setup.csv'}, line {line}: table {r['table']}, setup "
                              f"{r['setup']}, method {r['method']}, n_train {r['n_train']} is given twice "
                              f"(first on line {seen[run]})")
    try:
        study, rows = _bench_record(folder, bench, table)
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise ProcamError(f"{folder}: bench.json, per_setup.csv or failures.json is not as procam writes "
                          f"it ({type(exc).__name__}: {exc})") from None
    if not rows:
        raise ProcamError(f"{folder / 'per_setup.csv'}: holds no run of Table 1 (nor does failures.json): "
                          "nothing to report")
    return study, rows


def _bench_record(folder: Path, bench: dict, table: list[dict]) -> tuple[dict, list[dict]]:
    """The study and rows of :func:`_bench_rows` from its bench record and ``per_setup.csv`` rows."""
    cfg = bench.get("config", {})
    rows = []
    for r in table:
        if r.get("table") != "1":
            continue
        run = Path("runs") / r["setup"] / f"{r['method']}-n{r['n_train']}"
        metrics = {}
        if (folder / run / "metrics.json").is_file():
            metrics = read_json(folder / run / "metrics.json", "run metrics")
        unc_cl = bench.get("uncompensated", {}).get(r["setup"], {}).get("closed_loop", {})
        oracle = (bench.get("oracle", {}).get(r["setup"]) or [{}])[-1]
        best = bench.get("optimum", {}).get(r["setup"]) or {}
        cl = metrics.get("closed_loop", {})
        num = lambda d, k: float(d[k]) if k in d and d[k] not in ("", None, "nan") else math.nan  # noqa: E731
        row = {"point": 0, "setup": r["setup"], "method": r["method"], "n_train": int(r["n_train"]),
               "seed": int(r.get("seed") or 0), "status": "ok", "error": "", "run": run.as_posix(),
               "fit_s": num(r, "train s"), "infer_ms": num(cl, "infer_ms_per_frame")}
        for m, label in (("psnr", "PSNR"), ("rmse", "RMSE"), ("ssim", "SSIM"), ("deltae", "deltaE")):
            row[m] = num(r, label)
            row[f"unc_{m}"] = num(r, f"unc {label}")
            row[f"cl_{m}"] = num(r, f"CL {label}")
            row[f"cl_unc_{m}"] = num(unc_cl, "deltaE" if m == "deltae" else m)
            row[f"oracle_{m}"] = num(oracle, "deltaE" if m == "deltae" else m)
            row[f"optimum_{m}"] = num(best, "deltaE" if m == "deltae" else m)
        rows.append(row)
    for failure in read_json(folder / "failures.json", "bench failures").get("failures", []) \
            if (folder / "failures.json").is_file() else []:
        if failure.get("table") == "1":
            if not all(isinstance(failure.get(k), str) for k in ("setup", "method")):
                raise TypeError(f"a failure's setup and method are not text: {failure}")
            rows.append({"point": 0, "setup": failure["setup"], "method": failure["method"],
                         "n_train": int(failure["n_train"]), "seed": 0, "status": "failed",
                         "error": failure.get("error", ""), "run": ""})
    study = {"name": folder.name, "kind": "bench", "axes": [], "methods": cfg.get("methods", []),
             "seeds": [cfg.get("overrides", {}).get("seed", 0)], "n_train": cfg.get("sizes"),
             "n_test": cfg.get("n_test"), "profile": cfg.get("profile"), "overrides": cfg.get("overrides", {}),
             "question": "The CompenNet paper's benchmark (Tables 1-3) on simulated setups."}
    return study, rows


def load_folder(folder: Path) -> tuple[dict, list[dict]]:
    """The resolved study and the results rows of a study or bench folder.

    Raises
    ------
    ProcamError
        If the folder holds neither ``study.json`` with ``results.csv`` nor a bench's
        ``per_setup.csv`` with ``bench.json``.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ProcamError(f"{folder}: " + ("a file, not a study or bench folder" if folder.exists()
                                           else "folder not found"))
    if (folder / "study.json").is_file():
        study = read_study(folder)
        listed = {a["key"]: a["values"] for a in study["axes"]}
        return study, attach_per_image(read_results(folder / "results.csv", axis_keys(study), listed),
                                       folder / "per_image.csv")
    if (folder / "per_setup.csv").is_file() and (folder / "bench.json").is_file():
        return _bench_rows(folder)
    raise ProcamError(f"{folder}: not a study or bench folder (expected study.json and results.csv, "
                      "or a bench's per_setup.csv and bench.json)")


# --------------------------------------------------------------------------- the figure grid

def zoom_windows(error: np.ndarray, size: int, n: int = 2) -> list[tuple[int, int]]:
    """Top-left corners (row, column) of ``n`` non-overlapping ``size`` × ``size`` windows with the
    largest total ``error`` (H, W), chosen greedily: where compensation has the most to do.

    >>> e = np.zeros((8, 8)); e[5:7, 1:3] = 1.0; e[0:2, 6:8] = 0.5
    >>> zoom_windows(e, 2)
    [(5, 1), (0, 6)]
    """
    h, w = error.shape
    size = min(size, h, w)
    c = np.pad(np.cumsum(np.cumsum(error.astype(np.float64), 0), 1), ((1, 0), (1, 0)))
    sums = c[size:, size:] - c[:-size, size:] - c[size:, :-size] + c[:-size, :-size]
    chosen = []
    for _ in range(n):
        y, x = np.unravel_index(int(np.argmax(sums)), sums.shape)
        chosen.append((int(y), int(x)))
        sums[max(0, y - size + 1):y + size, max(0, x - size + 1):x + size] = -np.inf
        if not np.isfinite(sums).any():
            break
    return chosen


def grid_cell(image: np.ndarray, windows: list[tuple[int, int]], size: int, cell: int = CELL) -> np.ndarray:
    """One grid cell: ``image`` (H, W, 3 uint8) scaled to ``cell`` pixels on its longer side
    (nearest when enlarged, area-averaged when reduced) with the zoom windows (``size`` pixels of
    ``image``) outlined, above the windows' contents enlarged side by side at full resolution, each
    framed in its colour (:data:`PATCH_COLOURS`).

    >>> img = np.zeros((16, 16, 3), np.uint8)
    >>> out = grid_cell(img, [(0, 0), (8, 8)], 4, cell=64)
    >>> out.shape, out[0, 0].tolist(), out[-1, -1].tolist()
    ((96, 64, 3), [255, 200, 0], [0, 190, 255])
    """
    h, w = image.shape[:2]
    k = cell / max(h, w)
    big = cv2.resize(image, (max(1, round(w * k)), max(1, round(h * k))),
                     interpolation=cv2.INTER_NEAREST if k >= 1 else cv2.INTER_AREA)
    t = max(1, round(cell / 80))  # outline width
    half = big.shape[1] // len(windows)
    patches = []
    for (y, x), colour in zip(windows, PATCH_COLOURS):
        y0, x0 = round(y * k), round(x * k)
        y1, x1 = min(round((y + size) * k), big.shape[0]), min(round((x + size) * k), big.shape[1])
        for sl in ((slice(y0, y0 + t), slice(x0, x1)), (slice(y1 - t, y1), slice(x0, x1)),
                   (slice(y0, y1), slice(x0, x0 + t)), (slice(y0, y1), slice(x1 - t, x1))):
            big[sl] = colour
        inner = half - 2 * t
        framed = np.empty((half, half, 3), np.uint8)
        framed[:] = colour
        framed[t:t + inner, t:t + inner] = cv2.resize(image[y:y + size, x:x + size], (inner, inner),
                                                      interpolation=cv2.INTER_NEAREST)
        patches.append(framed)
    strip = np.concatenate(patches, axis=1)
    strip = np.pad(strip, ((0, 0), (0, big.shape[1] - strip.shape[1]), (0, 0)), constant_values=255)
    return np.concatenate([big, strip], axis=0)


def _placeholder(shape: tuple[int, int]) -> np.ndarray:
    """A light gray hatched image for a missing capture."""
    h, w = shape
    y, x = np.mgrid[0:h, 0:w]
    img = np.full((h, w, 3), 225, np.uint8)
    img[((x + y) // max(1, h // 8)) % 2 == 0] = 200
    return img


def _png_uri(path_or_array) -> str:
    if isinstance(path_or_array, np.ndarray):
        import imageio.v3 as iio

        data = iio.imwrite("<bytes>", path_or_array, extension=".png")
    else:
        data = Path(path_or_array).read_bytes()
    return "data:image/png;base64," + base64.b64encode(data).decode("ascii")


def _setup_dir(folder: Path, row: dict) -> Path:
    """The dataset of a results row: its run's ``config.json`` ``dataset``, else ``DIR/data/<setup>``."""
    config = folder / row.get("run", "") / "config.json"
    if row.get("run") and config.is_file():
        try:
            dataset = read_json(config, "run configuration").get("dataset")
        except ProcamError:
            dataset = None
        if dataset and Path(dataset).is_dir():
            return Path(dataset)
    return folder / "data" / row["setup"]


def grid_points(rows: list[dict], study: dict) -> list[int]:
    """The points whose figure grid the page shows: along the first axis, its first, middle and last
    value (at the first value of any second axis); a bench's single point.

    >>> study = {"axes": [{"key": "a", "values": [1, 2, 3, 4, 5]}]}
    >>> grid_points([{"point": p, "a": float(p + 1)} for p in range(5)], study)
    [0, 2, 4]
    """
    axes = study.get("axes", [])
    if not axes:
        return sorted({r["point"] for r in rows})[:1]
    key, listed = axes[0]["key"], axes[0]["values"]
    keep = [r for r in rows if all(r[a["key"]] == min((x[a["key"]] for x in rows),
                                                       key=lambda v: order_key(v, a["values"]))
                                   for a in axes[1:])]
    values = sorted({r[key] for r in keep}, key=lambda v: order_key(v, listed))
    picks = sorted({0, len(values) // 2, len(values) - 1})[:N_GRIDS] if values else []
    return [min(r["point"] for r in keep if r[key] == values[i]) for i in picks]


def figure_grid(folder: Path, rows: list[dict], point: int, stem: Path) -> tuple[Path, str] | None:
    """Draw the Fig. 4-style grid of one point to ``stem.png``: rows = the first test images that
    have a desired image; columns = surface s̃, uncompensated capture, each method's closed-loop
    capture (its ok run with the most training pairs and the lowest seed; hatched where the run
    left none), desired image. Returns the file and the setup shown, or None without a dataset."""
    at = [r for r in rows if r["point"] == point]
    if not at:
        return None
    setup = sorted({r["setup"] for r in at})[0]
    at = [r for r in at if r["setup"] == setup]
    setup_dir = _setup_dir(folder, at[0])
    try:
        surface = surface_path(setup_dir)
        desired_dir = frames_root(setup_dir) / TEST
    except (DatasetError, OSError):
        return None
    runs = {}
    for r in sorted(at, key=lambda r: (-r["n_train"], r["seed"])):
        if r["status"] == "ok" and r.get("run") and r["method"] not in runs:
            runs[r["method"]] = (folder / r["run"] / CAPTURES_DIR, r["n_train"])
    indices = [i for i in range(1, N_ROWS + 1) if (desired_dir / image_name(i)).is_file()
               and (capture_dir(setup_dir, TEST) / image_name(i)).is_file()]
    if not indices:
        return None
    columns = ["surface s̃", "uncompensated"] + [f"{m} (n={n})" for m, (_, n) in runs.items()] + ["desired y"]
    cells = []
    desired_files = [desired_dir / image_name(i) for i in indices]
    desireds = [read_png(f) for f in desired_files]
    surface_image = read_png_like(surface, desired_files[0], desireds[0].shape)
    for i, desired_file, desired in zip(indices, desired_files, desireds):
        unc = read_png_like(capture_dir(setup_dir, TEST) / image_name(i), desired_file, desired.shape)
        size = max(4, min(desired.shape[:2]) // 4)
        err = np.abs(unc.astype(np.float32) - desired.astype(np.float32)).sum(-1)
        windows = zoom_windows(err, size)
        images = [surface_image, unc]
        for run_captures, _ in runs.values():
            file = run_captures / image_name(i)
            images.append(read_png_like(file, desired_file, desired.shape) if file.is_file()
                          else _placeholder(desired.shape[:2]))
        images.append(desired)
        cells.append([grid_cell(img, windows, size) for img in images])
    plt = ch.pyplot()
    h, w = cells[0][0].shape[:2]
    fig, axes = plt.subplots(len(cells), len(columns), squeeze=False,
                             figsize=(len(columns) * w / 100 * 1.08, len(cells) * h / 100 * 1.12), dpi=100)
    for r, row in enumerate(cells):
        for c, cell in enumerate(row):
            ax = axes[r][c]
            ax.imshow(cell, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(columns[c], fontsize=8)
            if c == 0:
                ax.set_ylabel(image_name(indices[r]), fontsize=7)
    fig.tight_layout(pad=0.4)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    atomic_write(ch.with_extension(stem, "png"), buf.getvalue())
    return ch.with_extension(stem, "png"), setup


# --------------------------------------------------------------------------- HTML

STYLE = """
body{font-family:system-ui,-apple-system,'Segoe UI',sans-serif;margin:24px auto;max-width:1280px;
color:#222;background:#fff;line-height:1.4}
h1{font-size:1.6em;margin-bottom:.2em}h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:1.6em}
table{border-collapse:collapse;font-size:.82em;margin:.6em 0}
td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}th{background:#f2f2f2;text-align:left}
td.t{text-align:left}img{max-width:100%;height:auto;display:block;margin:.5em 0}
pre{background:#f7f7f7;padding:8px;overflow-x:auto;font-size:.8em}.note{color:#555;font-size:.9em}
.fail{color:#b00}figure{margin:0 0 1.2em 0}figcaption{font-size:.85em;color:#444}
"""


def _e(value) -> str:
    return html.escape(cell_text(value) if isinstance(value, float) else str(value))


def _is_number(value) -> bool:
    if isinstance(value, (int, float)):
        return True
    try:
        float(str(value).split(" ± ")[0])
        return True
    except ValueError:
        return False


def html_table(columns: list[str], rows: list[list]) -> str:
    """An HTML table, cells escaped; numbers right-aligned, text left-aligned (class ``t``).

    >>> html_table(["a", "b"], [["x<y", 1.5]])
    '<table><tr><th>a</th><th>b</th></tr><tr><td class="t">x&lt;y</td><td>1.5</td></tr></table>'
    """
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    cell = lambda v: f"<td>{_e(v)}</td>" if _is_number(v) else f'<td class="t">{_e(v)}</td>'  # noqa: E731
    body = "".join("<tr>" + "".join(cell(v) for v in r) + "</tr>" for r in rows)
    return f"<table><tr>{head}</tr>{body}</table>"


def markdown_html(text: str) -> str:
    """A Markdown file of :mod:`~compensation.reports.tables` (a ``#`` title, one pipe table,
    notes) as HTML.

    >>> markdown_html("# T\\n\\n| a | b |\\n|---|---|\\n| x | 1 |\\n\\nnote")
    '<h3>T</h3><table><tr><th>a</th><th>b</th></tr><tr><td class="t">x</td><td>1</td></tr></table><p class="note">note</p>'
    """
    out, table = [], []

    def flush():
        if table:
            cells = [[c.strip() for c in line.strip().strip("|").split("|")] for line in table]
            body = [r for r in cells[1:] if not all(set(c) <= set("-: ") for c in r)]
            out.append(html_table(cells[0], body))
            table.clear()

    for line in text.splitlines():
        if line.startswith("|"):
            table.append(line)
            continue
        flush()
        if line.startswith("#"):
            out.append(f"<h3>{html.escape(line.lstrip('#').strip())}</h3>")
        elif line.strip():
            out.append(f'<p class="note">{html.escape(line.strip())}</p>')
    flush()
    return "".join(out)


def _pm(row: dict, key: str) -> str:
    m, s = row.get(f"{key}_mean", math.nan), row.get(f"{key}_std", math.nan)
    if not is_finite(m):
        return ""
    return f"{m:.3g} ± {s:.2g}" if is_finite(s) and s > 0 else f"{m:.4g}"


def _provenance(folder: Path, study: dict, rows: list[dict]) -> str:
    parts = [html_table(["key", "value"], [[k, json.dumps(v) if isinstance(v, (dict, list)) else v]
                                           for k, v in study.items()
                                           if k not in ("axes", "versions", "setups", "question")])]
    if study.get("axes"):
        parts.append("<h3>Axes</h3>" + html_table(["key", "label", "unit", "values"], [
            [a["key"], a.get("label") or "", a.get("unit") or "", ", ".join(map(str, a["values"]))]
            for a in study["axes"]]))
    if study.get("versions"):
        parts.append("<h3>Versions</h3>" + html_table(["package", "version"],
                                                      list(study["versions"].items())))
    fit = [r["fit_s"] for r in rows if is_finite(r.get("fit_s", math.nan))]
    timing = []
    for method in sorted({r["method"] for r in rows}):
        mine = [r for r in rows if r["method"] == method]
        f = [r["fit_s"] for r in mine if is_finite(r.get("fit_s", math.nan))]
        i = [r["infer_ms"] for r in mine if is_finite(r.get("infer_ms", math.nan))]
        timing.append([method, len(mine), sum(f) if f else math.nan, float(np.mean(f)) if f else math.nan,
                       float(np.mean(i)) if i else math.nan])
    parts.append(f"<h3>Timings</h3><p>{len(rows)} runs, {sum(fit):.1f} s of fitting in all.</p>"
                 + html_table(["method", "runs", "fit s (total)", "fit s (mean)", "infer ms/frame (mean)"],
                              timing))
    setups = dict(study.get("setups") or {})
    if not setups:
        for r in rows:
            if r["setup"] not in setups:
                setups[r["setup"]] = _setup_dir(folder, r) / SETUP_FILE
    shown = []
    for name, path in setups.items():
        path = Path(path) if Path(path).is_absolute() else folder / path
        try:
            body = html.escape(path.read_text(encoding="utf-8"))
        except UnicodeDecodeError:
            body = "(not UTF-8 text)"
        except OSError:
            body = "(no setup.toml: a dataset made elsewhere)"
        shown.append(f"<details><summary>{html.escape(str(name))}: {html.escape(str(path))}</summary>"
                     f"<pre>{body}</pre></details>")
    parts.append(f"<h3>Setup files ({len(setups)})</h3>" + "".join(shown))
    return "".join(parts)


def target_sentence(study: dict, rows: list[dict]) -> str:
    """What the folder's closed-loop scores compare with: its target policy and map.

    >>> target_sentence({"target": {"policy": "global", "out_of_reach": 0.01}},
    ...                 [{"target_a": 0.5, "target_b": 0.1}, {"target_a": 0.7, "target_b": 0.1}])
    "Closed-loop scores compare each capture with the target y' = a·y + b of the target policy global (at most 1 % of the pixels out of reach; a = 0.6000, b = 0.1000, mean over the rows)."
    """
    target = study.get("target") or {}
    if not target or target.get("policy") == "none":
        return "Closed-loop scores compare each capture with the desired image itself (target policy none)."
    a = [r["target_a"] for r in rows if is_finite(r.get("target_a", math.nan))]
    b = [r["target_b"] for r in rows if is_finite(r.get("target_b", math.nan))]
    used = [r["target_out_of_reach_used"] for r in rows if is_finite(r.get("target_out_of_reach_used", math.nan))]
    shown = f"; a = {np.mean(a):.4f}, b = {np.mean(b):.4f}, mean over the rows" if a and b else ""
    if used and max(used) > target["out_of_reach"] + 1e-9:
        shown += f"; up to {100 * max(used):.3g} % used where no less leaves any contrast"
    return (f"Closed-loop scores compare each capture with the target y' = a·y + b of the target policy "
            f"{target['policy']} (at most {100 * target['out_of_reach']:g} % of the pixels out of reach"
            f"{shown}).")


def break_sentence(breaks: list[dict]) -> str:
    """The break-point rule in words, and which methods were undertrained rather than broken.

    >>> break_sentence([{"method": "compennet", "n_train": 8, "undertrained": "0.5; 1"}]).split("breaks: ")[1]
    'compennet (n=8) at 0.5; 1: its training loss was still falling at the end there, so it is undertrained, not broken.'
    """
    level = f"{100 * CONFIDENCE:g} %"
    text = (f"A method breaks at the first value where, with {level} confidence (percentile bootstrap over "
            f"the test images and seeds), its closed-loop PSNR gain over uncompensated is below "
            f"{BREAK_GAIN_DB:g} dB or its PSNR is more than {OPTIMUM_MARGIN_DB:g} dB below the exact "
            "optimum's (the best projector frames through the noise-free model).")
    held = [f"{b['method']} (n={b['n_train']}) at {b['undertrained']}" if b["n_train"] != "" else
            f"{b['method']} at {b['undertrained']}" for b in breaks if b.get("undertrained")]
    if held:
        text += (f" Not counted as breaks: {', '.join(held)}: its training loss was still falling at the end "
                 "there, so it is undertrained, not broken.")
    return text


def build_report(folder: Path) -> Path:
    """Write ``folder/report.html`` (and the summaries and charts it shows) for a study or bench
    folder; see the module's description.

    Returns
    -------
    Path
        The page.

    Raises
    ------
    ProcamError
        If the folder is not a study or bench folder, or its files are malformed (named).
    """
    folder = Path(folder)
    study, rows = load_folder(folder)
    axes = axis_keys(study)
    write_summaries(folder, study, rows)
    shown = main_rows(rows)
    summary = summarize(shown, axes)
    breaks = breakpoints(summary, study)
    fails = failures(rows, axes)
    chart_files = ch.write_charts(folder, study, summary, breaks, fails)
    name = study.get("name") or folder.name
    body = [f"<h1>{html.escape(str(name))}</h1>"]
    if study.get("question"):
        body.append(f"<p><b>Question:</b> {html.escape(str(study['question']))}</p>")
    body.append(f"<p>{html.escape(target_sentence(study, rows))}</p>")
    body.append(f'<p class="note">{study.get("kind", "study")} folder {html.escape(str(folder.resolve()))}; '
                f"{len(rows)} runs, {len({r['point'] for r in rows})} point(s), "
                f"{len({r['method'] for r in rows})} method(s); {len(fails)} failure(s).</p>")
    if axes:
        cols = [c for c in break_columns(axes) if c not in ("axis", "point", "psnr", "score")]
        body.append("<h2>Break points</h2>" + f'<p class="note">{html.escape(break_sentence(breaks))}</p>'
                    + html_table(cols, [[b.get(c, "") for c in cols] for b in breaks]))
    body.append("<h2>Figure grid</h2>")
    grids = 0
    for point in grid_points(shown, study):
        made = figure_grid(folder, shown, point, folder / "charts" / f"grid_point{point}")
        if made is None:
            continue
        grids += 1
        at = next(r for r in shown if r["point"] == point)
        where = ", ".join(f"{k} = {cell_text(at[k])}" for k in axes)
        body.append(f'<figure><img alt="figure grid, point {point}" src="{_png_uri(made[0])}">'
                    f"<figcaption>Point {point}{': ' + html.escape(where) if where else ''}, setup "
                    f"{html.escape(made[1])}. Columns: surface s̃ (capture of the gray frame), "
                    "uncompensated (the desired image projected as is), each method's closed-loop capture "
                    "(its compensation projected through the setup), desired y. Under each image: the "
                    "two patches outlined on it, enlarged (where the uncompensated error is largest)."
                    "</figcaption></figure>")
    if not grids:
        body.append('<p class="note">No figure grid: the datasets of this folder are not there.</p>')
    body.append("<h2>Charts</h2>")
    for path in chart_files:
        body.append(f'<figure><img alt="{html.escape(path.stem)}" src="{_png_uri(path)}">'
                    f"<figcaption>{html.escape(path.name)} (SVG beside it in charts/)</figcaption></figure>")
    body.append("<h2>Tables</h2>")
    for table in ("table1", "table1_paired", "table2", "table3"):
        if (folder / f"{table}.md").is_file():
            body.append(markdown_html((folder / f"{table}.md").read_text()))
    cols = [*dict.fromkeys(["point", *axes, "method", "n_train"]), "ok/runs", "PSNR", "SSIM", "CL PSNR", "CL SSIM",
            "unc PSNR", "CL unc PSNR", "oracle PSNR", "optimum PSNR", "fit s", "infer ms"]
    keys = ("psnr", "ssim", "cl_psnr", "cl_ssim", "unc_psnr", "cl_unc_psnr", "oracle_psnr", "optimum_psnr",
            "fit_s", "infer_ms")
    body.append("<h3>Summary: mean ± std over seeds and setups (summary.csv)</h3>" + html_table(
        cols, [[*(s[c] for c in cols[:-len(keys) - 1]), f"{s['ok']}/{s['runs']}",
                *(_pm(s, k) for k in keys)] for s in summary]))
    body.append(f'<h2 class="fail">Failures ({len(fails)})</h2>')
    if fails:
        fcols = failure_columns(axes)
        body.append(html_table(fcols, [[f.get(c, "") for c in fcols] for f in fails]))
    else:
        body.append("<p>None: every run finished and beat uncompensated.</p>")
    body.append("<h2>Provenance</h2>" + _provenance(folder, study, rows))
    page = ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>procam report: {html.escape(str(name))}</title><style>{STYLE}</style></head>"
            "<body>" + "\n".join(body) + "</body></html>\n")
    out = folder / "report.html"
    write_text(out, page)
    return out

