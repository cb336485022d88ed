"""Speed against accuracy of every fidelity level of a setup: ``procam bench-sim``.

For each level × spp, the probe frames of every class (:data:`sim.fidelity.PROBE_CLASSES`) are
rendered through the whole camera and compared with a path-traced reference of ``reference_spp``
samples per pixel (its own Monte-Carlo variance removed, :func:`sim.fidelity.unbiased_rmse`).
Written to the output folder:

- ``bench_sim_<setup>.csv``: one row per level × spp × class — time per capture, error (RMS and
  PSNR, linear signal and after the camera curve), the camera's noise floor, speed-up against the
  reference, whether the error is below the floor, whether ``auto`` picks it;
- ``bench_sim_<setup>.png``: time per capture (log) against PSNR, linear and after the camera
  curve, one colour per class, one marker per level, the noise floors as dashed lines and the
  ``auto`` choice ringed.

Times are the median wall-clock seconds of a capture's radiance (projector emission, render,
ambient added; camera model, registration and PNG writing excluded; :func:`time_per_capture`);
``transport`` adds its calibration divided by ``n_captures`` (a dataset's 826 by default). The
reference's time is that of its two renders per frame. PSNR is ``10 log10(1 / MSE)`` with the full well
(linear) or the top code (encoded) as peak 1.
"""
from __future__ import annotations

import csv
import io
import textwrap
import time
from pathlib import Path

import numpy as np

from sim import seeds
from sim.errors import ProcamError
from sim.fidelity import (DATASET_CAPTURES, FLOOR_FRACTION, LEVELS, PROBE_CLASSES, SPP_LADDER, Probe,
                          check_level, choose, psnr_from_rmse)
from sim.io import atomic_write
from sim.render import Renderer
from sim.setup import Setup
from sim.setup.schema import MAX_SPP
from sim.transport import TransportRenderer

MARKERS = {"path": "o", "direct": "s", "transport": "^"}
MAX_REPEATS = 1000
"""Most timed captures per level × spp (``--repeats``): their median settles long before."""
_PSNR_CAP = 99.0
"""dB shown for an error indistinguishable from the reference's own noise."""


def psnr(rmse: float) -> float:
    """PSNR in dB for a peak of 1 (:func:`sim.fidelity.psnr_from_rmse`), to 3 decimals, capped
    at 99 dB.

    Examples
    --------
    >>> psnr(0.01), psnr(0.0)
    (40.0, 99.0)
    """
    return min(_PSNR_CAP, round(psnr_from_rmse(rmse), 3))


def _renderer(setup: Setup, level: str, spp: int) -> tuple[Renderer | None, str]:
    """A renderer of the level, or None and why the level declines the setup.

    ``direct`` on a setup with inter-reflection is still charted (labelled as dropping it): it
    shows what path tracing buys.
    """
    try:
        check_level(setup, level)
    except ProcamError as exc:
        if level != "direct":
            return None, str(exc)
    try:
        if level == "transport":
            return TransportRenderer(setup, spp), ""
    except ProcamError as exc:
        return None, str(exc)
    return Renderer(setup, level, spp), ""


def time_per_capture(renderer: Renderer, frame: np.ndarray, repeats: int = 3) -> float:
    """Median wall time (seconds) of a capture's radiance (emission, render, ambient added), after
    one untimed capture that compiles the kernels; each repeat uses another seed."""
    times = []
    for i in range(repeats + 1):
        t0 = time.perf_counter()
        renderer.radiance(frame, seed=seeds.BENCH_TIMING + i)
        times.append(time.perf_counter() - t0)
    return float(np.median(times[1:]))


def measure(setup: Setup, reference_spp: int = 1024, classes=PROBE_CLASSES,
            window: int | None = None, n_captures: int = DATASET_CAPTURES, levels=LEVELS,
            spp=SPP_LADDER, repeats: int = 3, progress: bool = True) -> tuple[list[dict], dict]:
    """Error and time of every level × spp of a setup (see the module docstring).

    Parameters
    ----------
    setup : Setup
        The setup.
    reference_spp : int
        Samples per pixel of the path-traced reference.
    classes : sequence of str
        Probe classes.
    window : int, optional
        Render only a central camera window of this side (pixels) instead of the whole image.
    n_captures : int
        Captures a ``transport`` calibration is amortised over.
    levels : sequence of str
        Levels to chart.
    spp : sequence of int
        Samples per pixel charted for every level (``transport``: of its calibration).
    repeats : int
        Timed captures per level × spp (:func:`time_per_capture`).
    progress : bool
        Print a line per level × spp.

    Returns
    -------
    rows : list of dict
        One per level × spp × class (see :func:`write_csv` for the columns); declined levels give
        one row with the reason and no numbers.
    summary : dict
        ``reference_seconds``, ``auto`` (the :class:`~sim.fidelity.Choice` as a dict) and
        ``sentence``, the read-off of the ``auto`` choice.

    Raises
    ------
    ProcamError
        If ``reference_spp``, ``window``, ``repeats`` or an ``spp`` is below 1, an spp above
        :data:`~sim.setup.schema.MAX_SPP` or ``repeats`` above :data:`MAX_REPEATS` (named with its
        ``procam bench-sim`` option).
    """
    for name, value, most in (("ref-spp", reference_spp, MAX_SPP), ("window", window, None),
                              ("repeats", repeats, MAX_REPEATS), *(("spp", n, MAX_SPP) for n in spp)):
        if value is not None and (value < 1 or most is not None and value > most):
            raise ProcamError(f"bench-sim --{name} {value}: expected an integer >= 1"
                              + (f" and <= {most}" if most is not None else ""))
    probe = Probe(setup, classes, reference_spp, window)
    auto = choose(setup)
    rows = []
    for level in levels:
        for n in spp:
            r, why = _renderer(probe.setup, level, n)
            if r is None:
                rows.append({"setup": setup.name, "level": level, "spp": n, "declined": why})
                if progress:
                    print(f"bench-sim {setup.name}: {level} declined: {why}")
                break
            calibration = r.operator.info.seconds if level == "transport" else 0.0
            render_seconds = time_per_capture(r, probe.frames[classes[-1]], repeats)
            errs = probe.errors(r)
            seconds = render_seconds + calibration / n_captures
            for k, e in errs.items():
                rows.append({
                    "setup": setup.name, "level": level, "spp": n, "class": k,
                    "seconds_per_capture": seconds, "render_seconds": render_seconds,
                    "calibration_seconds": calibration, "rmse": e["rmse"], "psnr": psnr(e["rmse"]),
                    "rmse_encoded": e["rmse_encoded"], "psnr_encoded": psnr(e["rmse_encoded"]),
                    "noise_floor": probe.floors[k], "noise_floor_psnr": psnr(probe.floors[k]),
                    "noise_floor_encoded": probe.floors_encoded[k],
                    "noise_floor_encoded_psnr": psnr(probe.floors_encoded[k]),
                    "speedup": probe.reference_seconds / seconds,
                    "below_floor": e["rmse"] <= FLOOR_FRACTION * probe.floors[k],
                    "auto": level == auto.level and n == auto.spp, "declined": ""})
            if progress:
                worst = max(e["rmse"] / probe.floors[k] for k, e in errs.items())
                print(f"bench-sim {setup.name}: {level:9s} {n:4d} spp  {render_seconds:8.4f} s/capture"
                      f"{f' (+{calibration:.1f} s calibration)' if calibration else ''}  "
                      f"worst error {worst:.2f} x noise floor")
    picked = [row for row in rows if row.get("auto")]
    sentence = (f"for {setup.name}, {auto.level} at {auto.spp} spp is "
                f"{np.mean([row['speedup'] for row in picked]):.0f}x faster than the path-traced "
                f"reference ({reference_spp} spp) and its error is "
                + ("below what the camera adds anyway" if all(row["below_floor"] for row in picked)
                   else "above the camera noise for some class (no level tried reaches it)")
                if picked else f"for {setup.name}, auto picks {auto.level} at {auto.spp} spp "
                               "(not among the charted points)")
    return rows, {"reference_seconds": probe.reference_seconds, "reference_spp": reference_spp,
                  "auto": auto.as_dict(), "sentence": sentence}


COLUMNS = ("setup", "level", "spp", "class", "seconds_per_capture", "render_seconds",
           "calibration_seconds", "rmse", "psnr", "rmse_encoded", "psnr_encoded", "noise_floor",
           "noise_floor_psnr", "noise_floor_encoded", "noise_floor_encoded_psnr", "speedup",
           "below_floor", "auto", "declined")
"""Columns of the CSV: seconds; RMS errors in linear signal units (``rmse``) and encoded values
(``rmse_encoded``); PSNR in dB; ``speedup`` = reference seconds / seconds."""


def write_csv(rows: list[dict], path: Path) -> None:
    """Write the rows of :func:`measure` (missing cells empty), atomically."""
    text = io.StringIO(newline="")
    w = csv.DictWriter(text, COLUMNS)
    w.writeheader()
    for row in rows:
        w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    atomic_write(path, text.getvalue())


def plot(rows: list[dict], summary: dict, path: Path) -> None:
    """The chart: time per capture (log x) against PSNR, linear (top) and after the camera (bottom)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = [r for r in rows if not r.get("declined")]
    classes = list(dict.fromkeys(r["class"] for r in data))
    colours = dict(zip(classes, plt.rcParams["axes.prop_cycle"].by_key()["color"]))
    fig, axes = plt.subplots(2, 1, figsize=(9, 10), sharex=True)
    for ax, key, floor, title in ((axes[0], "psnr", "noise_floor_psnr", "linear signal"),
                                  (axes[1], "psnr_encoded", "noise_floor_encoded_psnr",
                                   "after the camera curve (encoded, noiseless)")):
        for k in classes:
            for level in MARKERS:
                pts = sorted((r for r in data if r["class"] == k and r["level"] == level),
                             key=lambda r: r["spp"])
                if not pts:
                    continue
                x, y = [p["seconds_per_capture"] for p in pts], [p[key] for p in pts]
                ax.plot(x, y, marker=MARKERS[level], color=colours[k], lw=1, ms=5,
                        ls="-" if level != "direct" else "--", alpha=0.85)
                if k == classes[0]:
                    for p in pts:
                        ax.annotate(str(p["spp"]), (p["seconds_per_capture"], p[key]), fontsize=7,
                                    xytext=(3, 3), textcoords="offset points")
            ax.axhline(next(r[floor] for r in data if r["class"] == k), color=colours[k], ls=":", lw=1.2)
            for p in (r for r in data if r["class"] == k and r["auto"]):
                ax.plot(p["seconds_per_capture"], p[key], marker="o", ms=14, mfc="none",
                        mec="black", mew=1.5)
        ax.axvline(summary["reference_seconds"], color="grey", ls="-.", lw=1)
        ax.set_xscale("log")
        ax.set_ylabel(f"PSNR (dB), {title}")
        ax.grid(True, which="both", alpha=0.3)
    axes[1].set_xlabel("seconds per capture (radiance; transport: apply + calibration / "
                       f"{DATASET_CAPTURES})")
    handles = [plt.Line2D([], [], color=colours[k], label=k) for k in classes]
    handles += [plt.Line2D([], [], color="black", marker=m, ls="-" if lv != "direct" else "--", label=lv)
                for lv, m in MARKERS.items() if any(r["level"] == lv for r in data)]
    handles += [plt.Line2D([], [], color="black", ls=":", label="camera noise floor (per class)"),
                plt.Line2D([], [], color="grey", ls="-.",
                           label=f"reference: path {summary['reference_spp']} spp"),
                plt.Line2D([], [], marker="o", ms=12, mfc="none", mec="black", ls="",
                           label="auto choice")]
    axes[0].legend(handles=handles, fontsize=8, loc="lower right", ncol=2)
    setup = data[0]["setup"] if data else "?"
    axes[0].set_title(f"{setup}: speed vs accuracy of each fidelity level (numbers: spp)\n"
                      + textwrap.fill(summary["sentence"], 100), fontsize=9)
    fig.tight_layout()
    image = io.BytesIO()
    fig.savefig(image, format="png", dpi=120)
    plt.close(fig)
    atomic_write(path, image.getvalue())


def bench_sim(setup: Setup, out: Path, **options) -> dict[str, Path]:
    """Measure a setup (:func:`measure`, with ``options``) and write its CSV and chart.

    Returns
    -------
    dict
        ``{"csv": path, "chart": path}`` plus ``"sentence"``: the read-off of the ``auto`` choice.

    Raises
    ------
    ProcamError
        If ``out`` is a file, or an option is refused (:func:`measure`).
    """
    out = Path(out)
    if out.exists() and not out.is_dir():  # before the minutes of measuring
        raise ProcamError(f"--out {out}: exists and is a file; bench-sim writes into a folder")
    rows, summary = measure(setup, **options)
    csv_path, png_path = out / f"bench_sim_{setup.name}.csv", out / f"bench_sim_{setup.name}.png"
    write_csv(rows, csv_path)
    plot(rows, summary, png_path)
    return {"csv": csv_path, "chart": png_path, "sentence": summary["sentence"]}
