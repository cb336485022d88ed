"""Charts of a study or bench folder (matplotlib, Agg): scores against the factor, and speed against
accuracy.

The data each chart draws comes from small pure functions (:func:`axis_positions`,
:func:`study_lines`, :func:`baseline_line`, :func:`gain_lines`, :func:`bound_gain`,
:func:`speed_points`, :func:`pareto_front`, :func:`heatmap_grid`), tested on
their own; the ``draw_*`` functions only draw it. Files go to ``DIR/charts/`` as PNG and SVG:

``study.png``                  one axis: surrogate and closed-loop panels (PSNR, SSIM, ΔE where
                               scored) against the factor, one line per method and training size
                               with a ± std band, uncompensated, the oracle and the optimum, break points
                               (star and vertical line) and failures (red x)
``study_<key>=<value>.png``    two axes: the same per value of the second axis
``gain.png``                   closed-loop PSNR gain over uncompensated against the factor, one line
                               per method and training size with its bootstrap interval (band), the
                               1 dB line, the oracle's and the optimum's gains, break points (star); below, the
                               share of the targets' pixels the setup can show (reachable fraction)
``gain_<key>=<value>.png``     two axes: the same per value of the second axis
``speed.png``                  fit time, inference ms per frame and the captures the fit needs (log
                               x) against PSNR (closed loop where scored), every method and training
                               size with its ± std bars, the Pareto front; in a study one column of
                               panels per value of the factor (a method's cost and score differ
                               along it)
``speed_<key>=<value>.png``    two axes: the same per value of the second axis
``heatmap_<score>_<method>.png``  two axes: PSNR (``psnr``; ``cl_psnr`` where scored) per cell of the
                               grid of the two factors (x: the first, y: the second), the mean over
                               the cell's runs printed in it (± the std over several), one chart per
                               method (``_n_train=<n>`` added where the study has several training
                               sizes); ``heatmap_gain_<method>.png`` the gain over uncompensated
                               (closed loop where scored) with its bootstrap interval, which reads
                               across a factor that moves the target (a darker wall darkens y′ and
                               raises every PSNR)
"""
from __future__ import annotations

import io
import math
import re
from pathlib import Path

import numpy as np

from compensation.experiments.jobs import cell_identity
from compensation.methods import METHODS
from compensation.reports.summary import (BREAK_GAIN_DB, CONFIDENCE, INTERVALS, is_finite, mean_std,
                                          order_key, closed_loop_gain, n_train_follows)
from sim.io import atomic_write

PANELS = (("psnr", "PSNR (dB)"), ("ssim", "SSIM"), ("deltae", "ΔE (CIEDE2000)"))
"""Metrics drawn, one column each (ΔE only where scored)."""
SCOPES = (("", "surrogate", "unc_", ()), ("cl_", "closed loop", "cl_unc_", ("oracle_", "optimum_")))
"""Panel rows: (column prefix, title, uncompensated prefix, prefixes of the method-free rows drawn
beside: the feedback oracle and the exact optimum)."""
LEGEND_COLUMNS = 4
"""Entries per row of a figure's shared legend (five long labels overflow the figure's width)."""
BOUNDS = {"oracle_": (":", "feedback oracle"), "optimum_": ("-", "exact optimum (physical bound)")}
"""Line style and label of each method-free row of :data:`SCOPES`."""
LOG_SPAN = 8
"""A numeric factor whose positive values span this ratio or more is drawn on a log axis (e.g. 8 …
500 pairs), with a linear stretch down to 0 where 0 is one of its values (a smoothing λ of 0, 1e-4
… 1; an aperture of 0 then doubling four times, whose small values a linear axis crowds into
its first tick); see :func:`x_scale`."""
FAILURE_COLOUR = "#d62728"
DPI = 110


def axis_positions(values: list, listed: list) -> tuple[dict, bool]:
    """Where each axis value goes on the x axis: itself when every value is a number, else its
    rank in the study's order (categorical ticks).

    Returns
    -------
    dict, bool
        Position by value; whether the axis is numeric.

    >>> axis_positions([2.0, 0.5], [0.5, 2.0])
    ({0.5: 0.5, 2.0: 2.0}, True)
    >>> axis_positions(["RGGB", "none"], ["none", "RGGB"])
    ({'none': 0, 'RGGB': 1}, False)
    """
    ordered = sorted(set(values), key=lambda v: order_key(v, listed))
    numeric = all(is_finite(v) for v in ordered)
    return ({v: (float(v) if numeric else i) for i, v in enumerate(ordered)}, numeric)


def x_scale(positions: list[float]) -> tuple[str, float | None]:
    """How to draw a numeric factor's axis: ``"linear"``, ``"log"`` where its values are positive
    and span :data:`LOG_SPAN` or more, or ``"symlog"`` where they also include 0 (linear from 0 to
    the smallest positive value, returned as the threshold, logarithmic above it).

    >>> x_scale([0.0, 0.01, 0.02, 0.04])
    ('linear', None)
    >>> x_scale([0.0, 0.01, 0.02, 0.04, 0.08])
    ('symlog', 0.01)
    >>> x_scale([8.0, 32.0, 500.0])
    ('log', None)
    >>> x_scale([0.0, 1e-4, 1e-2, 1.0])
    ('symlog', 0.0001)
    >>> x_scale([-1.0, 1.0, 100.0])
    ('linear', None)
    """
    positive = [v for v in positions if v > 0]
    if min(positions) < 0 or len(positive) < 2 or max(positive) < LOG_SPAN * min(positive):
        return "linear", None
    return ("log", None) if len(positive) == len(positions) else ("symlog", min(positive))


def study_lines(summary: list[dict], key: str, listed: list, score: str) -> dict[tuple, dict]:
    """One line per (method, n_train): ``x`` (axis positions), ``value`` (axis values), ``mean``,
    ``std`` of ``score`` (a :data:`~compensation.reports.summary.SCORES` name), in axis order.
    Where the factor sets the training size, one line per method (n_train ``""``).

    >>> s = [{"point": p, "f": v, "method": "tps", "n_train": 8, "cl_psnr_mean": m, "cl_psnr_std": 0.5}
    ...      for p, (v, m) in enumerate([(2.0, 18.0), (1.0, 20.0)])]
    >>> study_lines(s, "f", [1.0, 2.0], "cl_psnr")[("tps", 8)]["mean"]
    [20.0, 18.0]
    """
    pos, _ = axis_positions([r[key] for r in summary], listed)
    follows = n_train_follows(summary, key)
    lines: dict[tuple, dict] = {}
    for r in sorted(summary, key=lambda r: order_key(r[key], listed)):
        line = lines.setdefault((r["method"], "" if follows else r["n_train"]),
                                {"x": [], "value": [], "mean": [], "std": []})
        line["x"].append(pos[r[key]])
        line["value"].append(r[key])
        line["mean"].append(r.get(f"{score}_mean", math.nan))
        line["std"].append(r.get(f"{score}_std", math.nan))
    return lines


def baseline_line(summary: list[dict], key: str, listed: list, score: str) -> tuple[list, list]:
    """A method-free score (uncompensated or oracle) against the factor: the mean of ``score_mean``
    over the methods' rows at each axis value (they share it), NaN-free points only.

    >>> s = [{"f": 1.0, "unc_psnr_mean": 12.0}, {"f": 1.0, "unc_psnr_mean": 12.0},
    ...      {"f": 3.0, "unc_psnr_mean": 10.0}]
    >>> baseline_line(s, "f", [1.0, 3.0], "unc_psnr")
    ([1.0, 3.0], [12.0, 10.0])
    """
    pos, _ = axis_positions([r[key] for r in summary], listed)
    xs, ys = [], []
    for v in sorted(pos, key=lambda v: pos[v]):
        vals = [r.get(f"{score}_mean", math.nan) for r in summary if r[key] == v]
        vals = [x for x in vals if is_finite(x)]
        if vals:
            xs.append(pos[v])
            ys.append(float(np.mean(vals)))
    return xs, ys


def gain_lines(summary: list[dict], key: str, listed: list) -> dict[tuple, dict]:
    """One line per (method, n_train), as :func:`study_lines`: ``x``, ``value``, ``mean``
    (``gain_db``), ``lo`` and ``hi`` (its bootstrap interval) of the closed-loop gain, in axis order.

    >>> s = [{"f": v, "method": "tps", "n_train": 8, "gain_db": g, "gain_lo": g - 1, "gain_hi": g + 1}
    ...      for v, g in ((2.0, 3.0), (1.0, 5.0))]
    >>> line = gain_lines(s, "f", [1.0, 2.0])[("tps", 8)]
    >>> line["x"], line["mean"], line["lo"]
    ([1.0, 2.0], [5.0, 3.0], [4.0, 2.0])
    """
    pos, _ = axis_positions([r[key] for r in summary], listed)
    follows = n_train_follows(summary, key)
    lines: dict[tuple, dict] = {}
    for r in sorted(summary, key=lambda r: order_key(r[key], listed)):
        line = lines.setdefault((r["method"], "" if follows else r["n_train"]),
                                {"x": [], "value": [], "mean": [], "lo": [], "hi": []})
        line["x"].append(pos[r[key]])
        line["value"].append(r[key])
        for name, column in (("mean", "gain_db"), ("lo", "gain_lo"), ("hi", "gain_hi")):
            line[name].append(r.get(column, math.nan))
    return lines


def bound_gain(summary: list[dict], key: str, listed: list, prefix: str) -> tuple[list, list]:
    """A method-free row's closed-loop PSNR gain over uncompensated against the factor (the
    :func:`baseline_line` of each), where both are scored; ``prefix`` ``oracle_`` or ``optimum_``.

    >>> s = [{"f": 1.0, "oracle_psnr_mean": 20.0, "cl_unc_psnr_mean": 17.0},
    ...      {"f": 2.0, "oracle_psnr_mean": 19.0, "cl_unc_psnr_mean": float("nan")}]
    >>> bound_gain(s, "f", [1.0, 2.0], "oracle_")
    ([1.0], [3.0])
    """
    unc = dict(zip(*baseline_line(summary, key, listed, "cl_unc_psnr")))
    xs, ys = baseline_line(summary, key, listed, f"{prefix}psnr")
    kept = [(x, y - unc[x]) for x, y in zip(xs, ys) if x in unc]
    return [x for x, _ in kept], [y for _, y in kept]


def speed_points(summary: list[dict], key: str | None = None) -> list[dict]:
    """Speed and accuracy of every (method, n_train), averaged over the folder's points, or per value
    of the factor ``key`` (then each point has its ``value``): ``fit_s``, ``infer_ms`` (per frame),
    ``captures`` (that the fit needs, :meth:`~compensation.methods.base.Method.fit_captures`; NaN
    for a method this version does not know), ``psnr`` and ``score`` (``closed loop`` where scored,
    else ``surrogate``, as :func:`~compensation.reports.summary.closed_loop_gain`), with
    ``fit_s_std`` and ``psnr_std`` (over seeds and setups: the mean of the points' stds).

    >>> s = [{"f": f, "method": "tps", "n_train": 8, "fit_s_mean": f, "infer_ms_mean": 2.0,
    ...       "cl_psnr_mean": p, "cl_psnr_std": 0.5, "cl_unc_psnr_mean": 10.0}
    ...      for f, p in ((1.0, 20.0), (3.0, 22.0))]
    >>> [(p["fit_s"], p["captures"], p["psnr"], p["score"]) for p in speed_points(s)]
    [(2.0, 125, 21.0, 'closed loop')]
    >>> [(p["value"], p["fit_s"], p["psnr"], p["psnr_std"]) for p in speed_points(s, "f")]
    [(1.0, 1.0, 20.0, 0.5), (3.0, 3.0, 22.0, 0.5)]
    """
    groups: dict[tuple, list[dict]] = {}
    for r in summary:
        groups.setdefault((r["method"], r["n_train"], *((cell_identity(r[key]),) if key else ())), []).append(r)

    def mean(vals):
        return mean_std(vals)[0]

    out = []
    for group, rs in groups.items():
        scored = [closed_loop_gain(r) for r in rs]
        prefix = "cl_" if scored[0][2] == "closed loop" else ""
        out.append({"method": group[0], "n_train": group[1], **({"value": rs[0][key]} if key else {}),
                    "fit_s": mean(r.get("fit_s_mean", math.nan) for r in rs),
                    "fit_s_std": mean(r.get("fit_s_std", math.nan) for r in rs),
                    "infer_ms": mean(r.get("infer_ms_mean", math.nan) for r in rs),
                    "captures": _fit_captures(group[0], group[1]),
                    "psnr": mean(s[0] for s in scored),
                    "psnr_std": mean(r.get(f"{prefix}psnr_std", math.nan) for r in rs),
                    "score": scored[0][2]})
    return out


def _fit_captures(method: str, n_train) -> float:
    """The captures a fit of ``method`` with ``n_train`` pairs needs; NaN for an unknown method or
    a size that is not a number.

    >>> _fit_captures("compennet", "125"), _fit_captures("magic", 8)
    (126, nan)
    """
    try:
        return METHODS[method].fit_captures(int(n_train))
    except (KeyError, TypeError, ValueError):
        return math.nan


def pareto_front(points: list[tuple[float, float]]) -> list[int]:
    """Indices of the points no other point beats: cost (x) lower or equal and score (y) higher or
    equal, one of them strictly. Sorted by cost; points with a NaN are never on the front.

    >>> pareto_front([(1.0, 10.0), (2.0, 9.0), (3.0, 12.0), (0.5, 5.0), (3.0, 11.0), (4.0, 12.0)])
    [3, 0, 2]
    >>> pareto_front([(1.0, float("nan")), (2.0, 3.0)])
    [1]
    """
    ok = [i for i, (c, s) in enumerate(points) if is_finite(c) and is_finite(s)]
    front = [i for i in ok if not any(
        points[j][0] <= points[i][0] and points[j][1] >= points[i][1]
        and (points[j][0] < points[i][0] or points[j][1] > points[i][1]) for j in ok)]
    return sorted(front, key=lambda i: (points[i][0], -points[i][1]))


HEATMAP_SCORES = (("psnr", "surrogate PSNR"), ("cl_psnr", "closed-loop PSNR"),
                  ("gain", "gain over uncompensated"))
"""Scores of the heatmaps of a two-axis study (dB): the surrogate always, the closed loop where scored,
and the gain over uncompensated where scored (``summary.csv``'s ``gain_db`` with its interval, of the
closed loop where scored, else of the surrogate)."""


def heatmap_grid(summary: list[dict], axes: list[dict], method: str, n_train: int | None,
                 score: str) -> dict:
    """The cells of one heatmap of a two-axis study: ``x`` and ``y`` (the first and second axis's
    values, in the study's order), and ``mean``, ``std`` (of ``score`` over the cell's ok runs:
    seeds, and setups of a suite), ``lo``, ``hi`` (the bootstrap interval, for a score of
    :data:`~compensation.reports.summary.INTERVALS`, whose mean is ``<score>_db``; NaN otherwise)
    and ``runs`` (their number) as (len(y), len(x)) arrays, NaN (0 runs) where ``method`` has no
    summary row. ``n_train`` None: any training size (an axis sets it).

    >>> axes = [{"key": "a", "values": [1.0, 2.0]}, {"key": "b", "values": ["y", "x"]}]
    >>> s = [{"a": a, "b": b, "method": "tps", "n_train": 8, "psnr_mean": m, "psnr_std": 0.5, "ok": 2}
    ...      for a, b, m in ((2.0, "y", 21.0), (1.0, "y", 20.0), (1.0, "x", 22.0))]
    >>> g = heatmap_grid(s + [{**s[0], "method": "nayar", "psnr_mean": 9.0}], axes, "tps", 8, "psnr")
    >>> g["x"], g["y"], g["mean"].tolist(), g["runs"].tolist()
    ([1.0, 2.0], ['y', 'x'], [[20.0, 21.0], [22.0, nan]], [[2, 2], [2, 0]])
    """
    first, second = axes[0], axes[1]
    ordered = [sorted({r[a["key"]] for r in summary}, key=lambda v, a=a: order_key(v, a["values"]))
               for a in (first, second)]
    mean, std, lo, hi = (np.full((len(ordered[1]), len(ordered[0])), math.nan) for _ in range(4))
    runs = np.zeros(mean.shape, int)
    for r in summary:
        if r["method"] == method and (n_train is None or r["n_train"] == n_train):
            cell = ordered[1].index(r[second["key"]]), ordered[0].index(r[first["key"]])
            if score in INTERVALS:
                mean[cell], lo[cell], hi[cell] = (r.get(f"{score}_{s}", math.nan) for s in ("db", "lo", "hi"))
            else:
                mean[cell], std[cell] = r.get(f"{score}_mean", math.nan), r.get(f"{score}_std", math.nan)
            runs[cell] = r.get("ok", 0)
    return {"x": ordered[0], "y": ordered[1], "mean": mean, "std": std, "lo": lo, "hi": hi, "runs": runs}


def pyplot():
    """matplotlib's pyplot on the Agg backend (files only, no display)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def with_extension(stem: Path, ext: str) -> Path:
    """``stem`` with ``.ext`` appended: a stem holding a key and value such as
    ``study_surface.corner_angle=75`` keeps them (``Path.with_suffix`` would replace
    ``.corner_angle=75``).

    >>> with_extension(Path("charts/study_surface.corner_angle=75"), "png").name
    'study_surface.corner_angle=75.png'
    """
    return stem.with_name(f"{stem.name}.{ext}")


def _save(fig, stem: Path) -> list[Path]:
    paths = []
    for ext in ("png", "svg"):
        buf = io.BytesIO()
        fig.savefig(buf, format=ext, dpi=DPI)
        atomic_write(with_extension(stem, ext), buf.getvalue())
        paths.append(with_extension(stem, ext))
    return paths


def _saved(plt, fig, stem: Path) -> list[Path]:
    """:func:`_save` the figure, then close it (also when saving fails)."""
    try:
        return _save(fig, stem)
    finally:
        plt.close(fig)


def _colours(methods: list[str]) -> dict[str, str]:
    cycle = ["#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd", "#8c564b", "#e377c2", "#17becf", "#bcbd22"]
    return {m: cycle[i % len(cycle)] for i, m in enumerate(sorted(methods))}


MARKERS = ("o", "s", "^", "D", "v", "P")


def draw_study(summary: list[dict], breaks: list[dict], fails: list[dict], axis: dict, stem: Path,
               title: str) -> list[Path]:
    """Draw one study chart (see the module's description) to ``stem.png`` and ``stem.svg``.

    Parameters
    ----------
    summary, breaks, fails : list of dict
        The rows of :func:`~compensation.reports.summary.summarize`,
        :func:`~compensation.reports.summary.breakpoints` and
        :func:`~compensation.reports.summary.failures` for the points drawn.
    axis : dict
        The study's first axis (``key``, ``values``, optional ``label`` and ``unit``).
    """
    plt = pyplot()
    key, listed = axis["key"], axis["values"]
    pos, numeric, scale, xlabel = _x_axis(axis, summary)
    metrics = [(m, label) for m, label in PANELS
               if any(is_finite(r.get(f"{p}{m}_mean", math.nan)) for r in summary for p, *_ in SCOPES)]
    scopes = [s for s in SCOPES if any(is_finite(r.get(f"{s[0]}psnr_mean", math.nan)) for r in summary)] or [SCOPES[0]]
    fig, axes = plt.subplots(len(scopes), len(metrics), figsize=(4.2 * len(metrics), 3.4 * len(scopes)),
                             squeeze=False)
    colours = _colours(list({r["method"] for r in summary}))
    sizes = [""] if n_train_follows(summary, key) else sorted({r["n_train"] for r in summary})
    for row, (prefix, scope, unc, bounds) in enumerate(scopes):
        for col, (metric, label) in enumerate(metrics):
            ax = axes[row][col]
            score = f"{prefix}{metric}"
            ax.set_title(f"{scope}: {label}", fontsize=10)
            if not any(is_finite(r.get(f"{score}_mean", math.nan)) for r in summary):
                ax.text(0.5, 0.5, "not scored", ha="center", va="center", transform=ax.transAxes)
                ax.set_axis_off()
                continue
            for (method, n), line in study_lines(summary, key, listed, score).items():
                mean, std = np.array(line["mean"], float), np.array(line["std"], float)
                name = method + (f", n={n}" if len(sizes) > 1 else "")
                ax.plot(line["x"], mean, color=colours[method], marker=MARKERS[sizes.index(n) % len(MARKERS)],
                        ms=4, label=name)
                ax.fill_between(line["x"], mean - np.nan_to_num(std), mean + np.nan_to_num(std),
                                color=colours[method], alpha=0.18, lw=0)
            for base, (style, name) in ((unc, ("--", "uncompensated")), *((b, BOUNDS[b]) for b in bounds)):
                xs, ys = baseline_line(summary, key, listed, f"{base}{metric}")
                if xs:
                    ax.plot(xs, ys, style, color="black", lw=1.4, label=name)
            for b in breaks:
                if b["kind"] == "none" or b["break_value"] not in pos:
                    continue
                ax.axvline(pos[b["break_value"]], color=colours[b["method"]], lw=0.8, ls="-.", alpha=0.6)
                if metric == "psnr" and prefix == ("cl_" if b["score"] == "closed loop" else "") \
                        and is_finite(b["psnr"]):
                    ax.plot([pos[b["break_value"]]], [b["psnr"]], marker="*", ms=14, mec="black",
                            color=colours[b["method"]], ls="none", zorder=5,
                            label=f"break: {b['method']}" + (f", n={b['n_train']}" if len(sizes) > 1 else ""))
            _draw_failures(ax, fails, key, pos, score)
            _format_x(ax, pos, numeric, scale, xlabel, axis)
    return _finish(plt, fig, axes, stem, title)


def _x_axis(axis: dict, summary: list[dict]) -> tuple[dict, bool, tuple[str, float | None], str]:
    """Positions of the factor's values, whether numeric, its scale (:func:`x_scale`; linear where
    categorical), and its label (with the physical quantity of its ticks' second line, where the
    axis records one)."""
    key = axis["key"]
    pos, numeric = axis_positions([r[key] for r in summary], axis["values"])
    scale = x_scale(list(pos.values())) if numeric else ("linear", None)
    label = (axis.get("label") or key) + (f" ({axis['unit']})" if axis.get("unit") else "")
    if physical := axis.get("physical"):
        label += f"\nbelow it: {physical['label']} ({physical['unit']})"
    return pos, numeric, scale, label


def tick_labels(axis: dict, pos: dict) -> list[str]:
    r"""The factor's tick labels in position order: each value, and below it the physical quantity
    it amounts to where the axis records one (``physical`` of ``study.json``).

    >>> axis = {"values": [0.0, 0.02], "physical": {"label": "blur", "unit": "px", "values": [0.0, 0.639]}}
    >>> tick_labels(axis, {0.0: 0.0, 0.02: 0.02})
    ['0\n0', '0.02\n0.639']

    An RGB value (a list in ``study.json``, its JSON text in the CSVs) finds its quantity too:

    >>> axis = {"values": [[0.1, 0.1, 0.1]], "physical": {"label": "ambient", "unit": "%", "values": [4.2]}}
    >>> tick_labels(axis, {"[0.1, 0.1, 0.1]": 0})
    ['[0.1, 0.1, 0.1]\n4.2']
    """
    physical = {cell_identity(v): p for v, p in zip(axis.get("values", []),
                                                 (axis.get("physical") or {}).get("values", []))}
    labels = []
    for value in sorted(pos, key=pos.get):
        text = f"{value:g}" if isinstance(value, (int, float)) else str(value)
        if physical.get(cell_identity(value)) is not None:
            text += f"\n{physical[cell_identity(value)]:.3g}"
        labels.append(text)
    return labels


def _format_x(ax, pos: dict, numeric: bool, scale: tuple[str, float | None], xlabel: str,
              axis: dict) -> None:
    """Ticks at the factor's values (categorical, or a log axis as :func:`x_scale` draws it, its
    linear stretch from 0 as wide as the first step above it; :func:`tick_labels`), its label and
    a grid."""
    from matplotlib.ticker import NullFormatter

    kind, threshold = scale
    if kind != "linear":
        # symlog: the stretch from 0 to the smallest value as wide as the step after it (matplotlib
        # widens a linear stretch of ``linscale`` decades by 1 / (1 - 1 / base), base 10)
        positive = sorted(v for v in pos.values() if v > 0)
        linear = ({"linthresh": threshold, "linscale": 0.9 * math.log10(positive[1] / positive[0])}
                  if threshold else {})
        ax.set_xscale(kind, **linear)
        ax.xaxis.set_minor_formatter(NullFormatter())
    if kind != "linear" or not numeric or axis.get("physical"):
        ax.set_xticks(sorted(pos.values()), tick_labels(axis, pos))
    ax.set_xlabel(xlabel, fontsize=9)
    ax.grid(alpha=0.3)


def _finish(plt, fig, axes, stem: Path, title: str) -> list[Path]:
    """One legend for every panel under the figure, the title, and the files saved."""
    handles, labels = {}, []
    for ax in axes.flat:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in handles:
                handles[lab] = h
                labels.append(lab)
    fig.legend([handles[lab] for lab in labels], labels, loc="lower center",
               ncol=min(len(labels), LEGEND_COLUMNS), fontsize=8, frameon=False)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout(rect=(0, 0.06 + 0.025 * ((len(labels) - 1) // LEGEND_COLUMNS), 1, 0.95))
    return _saved(plt, fig, stem)


def draw_gain(summary: list[dict], breaks: list[dict], axis: dict, stem: Path, title: str) -> list[Path]:
    """Draw one gain chart (see the module's description) to ``stem.png`` and ``stem.svg``.

    Parameters
    ----------
    summary, breaks : list of dict
        The rows of :func:`~compensation.reports.summary.summarize` and
        :func:`~compensation.reports.summary.breakpoints` for the points drawn.
    axis : dict
        The study's first axis (``key``, ``values``, optional ``label`` and ``unit``).
    """
    plt = pyplot()
    key, listed = axis["key"], axis["values"]
    pos, numeric, scale, xlabel = _x_axis(axis, summary)
    fig, axes = plt.subplots(2, 1, figsize=(7.5, 7.0), squeeze=False, sharex=True,
                             gridspec_kw={"height_ratios": (3, 1.3)})
    ax, reach = axes[0][0], axes[1][0]
    colours = _colours(list({r["method"] for r in summary}))
    sizes = [""] if n_train_follows(summary, key) else sorted({r["n_train"] for r in summary})
    for (method, n), line in gain_lines(summary, key, listed).items():
        name = method + (f", n={n}" if len(sizes) > 1 else "")
        ax.plot(line["x"], line["mean"], color=colours[method], marker=MARKERS[sizes.index(n) % len(MARKERS)],
                ms=4, label=name)
        ax.fill_between(line["x"], line["lo"], line["hi"], color=colours[method], alpha=0.18, lw=0)
    for prefix, (style, name) in BOUNDS.items():
        xs, ys = bound_gain(summary, key, listed, prefix)
        if xs:
            ax.plot(xs, ys, style, color="black", lw=1.4 if style == ":" else 0.9, label=name)
    ax.axhline(BREAK_GAIN_DB, color=FAILURE_COLOUR, lw=1.0, ls="--", label=f"{BREAK_GAIN_DB:g} dB")
    for b in breaks:
        if b["kind"] in ("gain", "optimum") and b["break_value"] in pos and is_finite(b["gain_db"]):
            ax.plot([pos[b["break_value"]]], [b["gain_db"]], marker="*", ms=14, mec="black",
                    color=colours[b["method"]], ls="none", zorder=5,
                    label=f"break: {b['method']}" + (f", n={b['n_train']}" if len(sizes) > 1 else ""))
    ax.set_ylabel("closed-loop PSNR gain (dB)")
    ax.set_title(f"gain over uncompensated, {100 * CONFIDENCE:g} % bootstrap interval (band)", fontsize=10)
    ax.grid(alpha=0.3)
    xs, ys = baseline_line(summary, key, listed, "reachable_fraction")
    reach.plot(xs, ys, "o-", color="black", ms=4, label="reachable fraction")
    if not xs:
        reach.text(0.5, 0.5, "not recorded", ha="center", va="center", transform=reach.transAxes)
    reach.set_ylim(0, 1.02)
    reach.set_ylabel("reachable fraction")
    _format_x(reach, pos, numeric, scale, xlabel, axis)
    return _finish(plt, fig, axes, stem, title)


def _draw_failures(ax, fails: list[dict], key: str, pos: dict, score: str) -> None:
    """Red x at each failed run's score, or at the panel's foot when it has none; a ``worse`` run
    only on the PSNR panel it was judged on (closed loop where scored, else surrogate)."""
    marked = False
    for f in fails:
        judged = "cl_psnr" if is_finite(f.get("cl_psnr", math.nan)) else "psnr"
        if f[key] not in pos or (f["kind"] == "worse" and score != judged):
            continue
        y = f.get(score, math.nan)
        kw = dict(marker="x", color=FAILURE_COLOUR, ms=8, mew=2, ls="none", zorder=6,
                  label=None if marked else "failure (failed, NaN, diverged, worse)")
        if is_finite(y):
            ax.plot([pos[f[key]]], [y], **kw)
        else:
            ax.plot([pos[f[key]]], [0.03], transform=ax.get_xaxis_transform(), clip_on=False, **kw)
        marked = True


SPEED_COSTS = {"fit_s": "fit time (s, log)", "infer_ms": "inference (ms per frame, log)",
               "captures": "captures the fit needs (log)"}
"""The costs :func:`draw_speed` draws PSNR against, one row of panels each, with their axis labels.
The captures are those of the fit (plain colours or training pairs, and the surface image); the
registration's checkerboards, the same for every method, are left out."""


def draw_speed(points: list[dict], stem: Path, title: str, axis: dict | None = None) -> list[Path]:
    """Draw fit time, inference ms per frame and the captures the fit needs (log x) against PSNR for
    every (method, n_train) of :func:`speed_points`, ± std bars, each panel with its Pareto front,
    to ``stem.png`` and ``stem.svg``: one column of the three panels per value of ``axis`` (the
    study's factor) where the points carry one, else one column."""
    plt = pyplot()
    from matplotlib.ticker import NullFormatter

    values = [None]
    if axis is not None:
        values = sorted({cell_identity(p["value"]): p["value"] for p in points}.values(),
                        key=lambda v: order_key(v, axis["values"]))
    fig, axes = plt.subplots(len(SPEED_COSTS), len(values), figsize=(max(5.0, 3.6 * len(values)), 11.0),
                             squeeze=False)
    colours = _colours(list({p["method"] for p in points}))
    score = points[0]["score"] if points else "closed loop"
    for col, value in enumerate(values):
        mine = [p for p in points if value is None or cell_identity(p["value"]) == cell_identity(value)]
        for row, (cost, xlabel) in enumerate(SPEED_COSTS.items()):
            ax = axes[row][col]
            if value is not None and row == 0:
                name = axis.get("label") or axis["key"]
                ax.set_title(f"{name} = {_tick(value)}", fontsize=9)
            _speed_panel(ax, [p for p in mine if is_finite(p[cost]) and p[cost] > 0 and is_finite(p["psnr"])],
                         cost, colours)
            ax.set_xlabel(xlabel, fontsize=9)
            ax.set_ylabel(f"{score} PSNR (dB)", fontsize=9)
            ax.grid(alpha=0.3, which="both")
            ax.xaxis.set_minor_formatter(NullFormatter())
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    return _saved(plt, fig, stem)


def _speed_panel(ax, usable: list[dict], cost: str, colours: dict) -> None:
    """One panel of :func:`draw_speed`: the points with their ± std bars (the cost's bar kept above
    0 on the log axis), labelled, and their Pareto front ringed."""
    if not usable:
        ax.text(0.5, 0.5, f"no {cost} recorded", ha="center", transform=ax.transAxes)
        return
    for p in usable:
        spread = p.get(f"{cost}_std", math.nan)
        spread = min(spread, 0.9 * p[cost]) if is_finite(spread) else 0.0
        ax.errorbar(p[cost], p["psnr"], xerr=spread, yerr=np.nan_to_num(p.get("psnr_std", math.nan)),
                    fmt="o", color=colours[p["method"]], ms=7, capsize=3, label=p["method"])
        ax.annotate(f"{p['method']} n={p['n_train']}", (p[cost], p["psnr"]), fontsize=7,
                    xytext=(4, 4), textcoords="offset points")
    front = [usable[i] for i in pareto_front([(p[cost], p["psnr"]) for p in usable])]
    xs, ys = [p[cost] for p in front], [p["psnr"] for p in front]
    ax.step(xs, ys, where="post", color="black", lw=1.2, alpha=0.7, label="Pareto front")
    ax.plot(xs, ys, "o", ms=12, mfc="none", mec="black", mew=1.2)
    ax.set_xscale("log")
    lo, hi = min(p[cost] for p in usable), max(p[cost] for p in usable)
    ax.set_xlim(10 ** math.floor(math.log10(lo / 2)), 10 ** math.ceil(math.log10(hi * 2)))
    handles = dict(zip(*reversed(ax.get_legend_handles_labels())))
    ax.legend(list(handles.values()), list(handles), fontsize=7)


def _tick(value) -> str:
    """An axis value as a tick label.

    >>> _tick(0.002), _tick(3.0), _tick("RGGB")
    ('0.002', '3', 'RGGB')
    """
    return f"{value:g}" if is_finite(value) else str(value)


def draw_heatmap(grid: dict, axes: list[dict], label: str, stem: Path, title: str) -> list[Path]:
    """Draw one heatmap of :func:`heatmap_grid` to ``stem.png`` and ``stem.svg``: a cell per pair of
    values, its mean printed in it (with its interval where it has one, else ± the std where it has
    several runs), a colour bar of ``label`` in dB; a cell without a score grey."""
    plt = pyplot()
    mean = np.ma.masked_invalid(grid["mean"])
    fig, ax = plt.subplots(figsize=(1.3 * len(grid["x"]) + 3.0, 0.8 * len(grid["y"]) + 2.4))
    cmap = plt.get_cmap("viridis").with_extremes(bad="#d9d9d9")
    image = ax.imshow(mean, cmap=cmap, origin="lower", aspect="auto")
    fig.colorbar(image, ax=ax).set_label(f"{label} (dB)")
    middle = (mean.min() + mean.max()) / 2 if mean.count() else 0.0
    for (i, j), value in np.ndenumerate(grid["mean"]):
        lo, hi = grid["lo"][i, j], grid["hi"][i, j]
        text = "no score" if not is_finite(value) else f"{value:.2f}" + (
            f"\n[{lo:.2f}, {hi:.2f}]" if is_finite(lo) and is_finite(hi) else
            f"\n± {grid['std'][i, j]:.2f}" if grid["runs"][i, j] > 1 and is_finite(grid["std"][i, j]) else "")
        ax.text(j, i, text, ha="center", va="center", fontsize=8,
                color="black" if not is_finite(value) or value > middle else "white")
    for axis, values, set_ticks, set_label in ((axes[0], grid["x"], ax.set_xticks, ax.set_xlabel),
                                              (axes[1], grid["y"], ax.set_yticks, ax.set_ylabel)):
        set_ticks(range(len(values)), [_tick(v) for v in values])
        set_label((axis.get("label") or axis["key"]) + (f" ({axis['unit']})" if axis.get("unit") else ""),
                  fontsize=9)
    ax.set_title(title, fontsize=10)
    fig.tight_layout()
    return _saved(plt, fig, stem)


def write_heatmaps(charts: Path, name: str, axes: list[dict], summary: list[dict]) -> list[Path]:
    """Draw the heatmaps of a two-axis study into ``charts`` (see the module's description): per
    method (and training size, unless an axis sets it) and :data:`HEATMAP_SCORES` entry that any
    cell scored.

    Returns
    -------
    list of Path
        The PNG files written (each has an SVG beside it).
    """
    sized = "n_train" not in (a["key"] for a in axes)
    sizes = sorted({r["n_train"] for r in summary}) if sized else [None]
    out = []
    for method in sorted({r["method"] for r in summary}):
        # the gain is the closed loop's where scored (the rule of summary.csv's gain_db)
        closed = any(closed_loop_gain(r)[2] == "closed loop" for r in summary if r["method"] == method)
        for n in sizes:
            for score, label in HEATMAP_SCORES:
                grid = heatmap_grid(summary, axes, method, n, score)
                if not np.isfinite(grid["mean"]).any():
                    continue
                if score in INTERVALS:
                    label = ("closed-loop " if closed else "surrogate ") + label
                size = f"_n_train={n}" if len(sizes) > 1 else ""
                out.append(draw_heatmap(grid, axes, label, charts / _slug(f"heatmap_{score}_{method}{size}"),
                                        f"{name}: {method}" + (f", n={n}" if size else "") + f", {label}")[0])
    return out


def _slug(text: str) -> str:
    """A file-name-safe form of ``text``.

    >>> _slug("projector.aperture=0.5")
    'projector.aperture=0.5'
    >>> _slug("camera.bayer=RG GB/x")
    'camera.bayer=RG_GB_x'
    """
    return re.sub(r"[^A-Za-z0-9.=+-]+", "_", text)


def _scored(summary: list[dict]) -> bool:
    """Whether any row holds a finite score of a panel the study chart draws."""
    return any(is_finite(r.get(f"{p}{m}_mean", math.nan))
               for r in summary for m, _ in PANELS for p, *_ in SCOPES)


def write_charts(folder: Path, study: dict, summary: list[dict], breaks: list[dict],
                 fails: list[dict]) -> list[Path]:
    """Draw every chart of a folder into ``folder/charts``: the study and gain charts (one each per
    value of a second axis; a gain chart where gains are scored), a two-axis study's heatmaps
    (:func:`write_heatmaps`) and the speed–accuracy chart.

    Returns
    -------
    list of Path
        The PNG files written (each has an SVG beside it).
    """
    charts = Path(folder) / "charts"
    name = study.get("name") or Path(folder).name
    axes = study.get("axes", [])
    out = []
    if axes and summary:
        first, second = axes[0], [a["key"] for a in axes[1:]]
        groups: dict[tuple, list[dict]] = {}
        for r in summary:
            groups.setdefault(tuple(r[k] for k in second), []).append(r)
        for values, group in sorted(groups.items(), key=lambda kv: tuple(
                order_key(v, a["values"]) for v, a in zip(kv[0], axes[1:]))):
            where = ", ".join(f"{k} = {v:g}" if is_finite(v) else f"{k} = {v}" for k, v in zip(second, values))
            stem = "study" + "".join(f"_{k}={v:g}" if is_finite(v) else f"_{k}={v}" for k, v in zip(second, values))
            match = lambda r: all(r.get(k) == v for k, v in zip(second, values))  # noqa: E731
            heading = f"{name}" + (f" ({where})" if where else "")
            out.append(draw_speed(speed_points(group, first["key"]), charts / _slug("speed" + stem[len("study"):]),
                                  f"{heading}: speed against accuracy", first)[0])
            if not _scored(group):  # every run of these points failed: no scores to draw
                continue
            out.append(draw_study(group, [b for b in breaks if match(b)], [f for f in fails if match(f)],
                                  first, charts / _slug(stem), heading)[0])
            if any(is_finite(r.get("gain_db", math.nan)) for r in group):
                out.append(draw_gain(group, [b for b in breaks if match(b)], first,
                                     charts / _slug("gain" + stem[len("study"):]), heading)[0])
    if len(axes) == 2 and summary:
        out += write_heatmaps(charts, name, axes, summary)
    if not axes and (points := speed_points(summary)):
        out.append(draw_speed(points, charts / "speed", f"{name}: speed against accuracy")[0])
    return out
