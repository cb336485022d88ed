"""Per-effect table: what each hardware effect of the default setup costs each method, alone.

The base is ``scenes/default.toml`` (the paper's hardware) with every hardware effect turned off
(pinhole projector lens, steady lamp, perfect box-filtered RGB camera, manual exposure, exact
registration); each row turns ONE effect back on at the default setup's own magnitude (those of
``scenes/paper.toml``, with their sources in the file), then the content-dependent processing the
default leaves off at the magnitudes its comments give (:data:`CONTENT`); the last rows are the
default setup itself and the default with all of that processing on.
Every setup is rendered and benchmarked by ``procam bench`` (Table 1 jobs at one training size,
closed loop on); this script then writes, per method, the change in dB against the base, surrogate
(π†(x̃) against x) and closed loop (the compensation projected back through the setup)::

    .venv/bin/python benchmarks/effects.py --out OUT [--setup FILE] [--size 64 --n-train 125 --n-test 50 --iters 300]

``--setup`` makes the table of another setup file than ``scenes/default.toml`` (its effects turned
off and on as the default's are); the resolved setup is kept as ``OUT/effects_setup.toml``.

Writes ``OUT/effects.md``, ``OUT/effects.csv`` and, where runs kept per-image scores
(``OUT/effects_per_image.csv``), the paired differences of CompenNet, TPS textured and TPS per row
(``OUT/effects_paired.csv``) beside the bench's own files (``OUT/results.csv``,
``OUT/table1.md``, ``OUT/report.html`` after ``procam report OUT``). Resumable like the bench;
``--methods`` runs some methods only (e.g. CompenNet on a few rows, ``--only``), and the table
keeps the runs of earlier calls (``OUT/effects_runs.csv``, and with ``--keep CSV`` those of calls
into another folder, such as the runs kept in ``benchmarks/results/effects/256/``; each run keeps
the size, pair counts and CompenNet budget it was made at, and runs made at others, or from
another setup than the ``effects_setup.toml`` beside them, are refused).
"""
from __future__ import annotations

import argparse
import csv
import dataclasses
import math
from pathlib import Path

from compensation.experiments.bench import BenchConfig, run_bench
from compensation.methods import get_method
from compensation.reports.paired import image_differences, paired_comparison
from compensation.reports.summary import write_csv
from sim.errors import ProcamError
from sim.io import read_json, write_text
from sim.layout import META_FILE
from sim.options import flat_items
from sim.setup import load_setup, scene_path
from sim.setup.schema import SECTIONS
from sim.setup.toml import dump_setup

METHODS = ("tps", "tps-textured", "nayar", "compennet")
CONTENT = {  # row name -> values: content-dependent processing, off in the default setup; the
    # magnitudes its comments give (scenes/default.toml)
    "projector dynamic lamp (depth 0.55, the measured one)": {("projector", "dynamic_lamp"): 0.55},
    "DLP white segment (boost 0.7, assumed: colour light 59 % of white)": {("projector", "white_boost"): 0.7},
    "camera adaptive tone (0.5, assumed)": {("camera", "adaptive_tone"): 0.5},
    "camera picture style (Standard-like, assumed)": {("camera", "style_contrast"): 0.3,
                                                      ("camera", "style_saturation"): 1.2,
                                                      ("camera", "sharpen_amount"): 0.5},
}
"""Rows of effects the default setup leaves off, with their values; also added, all together, to
the default setup in the table's last row."""
EFFECTS = {  # row name -> (section, key) pairs taken from the default setup
    "surface relief, registered by one homography": (("surface", "relief"), ("registration", "method")),
    "projector lens PSF": (("projector", "psf_sigma"),),
    "projector defocus": (("projector", "aperture"),),
    "projector lens distortion": (("projector", "distortion_k1"), ("projector", "distortion_k2"),
                                  ("projector", "lens_offset")),
    "surface translucency": (("projector", "translucency_mfp"), ("projector", "translucency_fraction")),
    "projector flare": (("projector", "flare"), ("projector", "flare_sigma")),
    "lamp flicker": (("projector", "flicker"),),
    "lamp drift": (("projector", "drift"),),
    "camera PSF": (("camera", "psf_sigma"),),
    "camera veiling glare": (("camera", "glare"), ("camera", "glare_sigma")),
    "Bayer mosaic + demosaic": (("camera", "bayer"),),
    "vignetting": (("camera", "vignetting"),),
    "camera lens distortion": (("camera", "distortion"),),
    "JPEG": (("camera", "jpeg_quality"),),
    "exposure rule": (("camera", "exposure_mode"),),
    "estimated homography": (("registration", "method"),),
}
OFF = {("surface", "relief"): 0.0, ("projector", "distortion_k1"): 0.0, ("projector", "distortion_k2"): 0.0,
       ("projector", "translucency_mfp"): 0.0, ("projector", "flare"): 0.0, ("camera", "glare"): 0.0,
       ("projector", "psf_sigma"): 0.0, ("projector", "aperture"): 0.0, ("projector", "flicker"): 0.0,
       ("projector", "drift"): 0.0, ("camera", "psf_sigma"): 0.0, ("camera", "bayer"): "none",
       ("camera", "vignetting"): 0.0, ("camera", "distortion"): 0.0, ("camera", "jpeg_quality"): 0,
       ("camera", "exposure_mode"): "manual", ("registration", "method"): "exact",
       ("projector", "dynamic_lamp"): 0.0, ("projector", "white_boost"): 0.0, ("camera", "adaptive_tone"): 0.0,
       ("camera", "style_contrast"): 0.0, ("camera", "style_saturation"): 1.0, ("camera", "sharpen_amount"): 0.0}
"""Each effect's off value (those of :data:`CONTENT` too, for a setup that turns them on)."""
PAIRS = (("compennet", "tps-textured"), ("compennet", "tps"), ("tps-textured", "tps"))
"""Paired comparisons per row, image by image on the surrogate benchmark: CompenNet against each
TPS, and TPS textured − TPS (the paper's signature)."""
SETUP_FILE = "effects_setup.toml"
"""The resolved setup whose effects a folder's runs turn off and on, beside its ``effects_runs.csv``."""
IMAGE_COLUMNS = ("setup", "method", "image", "psnr", "cl_psnr")
"""Columns of ``effects_per_image.csv``."""
NETWORK_OPTIONS = ("iters", "patch", "batch")
"""Training options of the call kept with the runs of the methods that take them."""


def with_values(setup, name: str, values: dict):
    """``setup`` renamed, with ``{(section, key): value}`` replaced (a surface's own keys, such as
    ``relief``, in its ``shape``)."""
    sections = {}
    for (section, key), value in values.items():
        sections.setdefault(section, {})[key] = value
    surface = sections.pop("surface", {})
    shape = {k: surface.pop(k) for k in list(surface) if hasattr(setup.surface.shape, k)}
    sections["surface"] = {**surface, "shape": dataclasses.replace(setup.surface.shape, **shape)}
    return dataclasses.replace(setup, name=name, **{
        s: dataclasses.replace(getattr(setup, s), **kv) for s, kv in sections.items()})


def _value(setup, section: str, key: str):
    """A key's value in a setup (a surface's own keys from its ``shape``)."""
    part = getattr(setup, section)
    return getattr(part.shape if section == "surface" and not hasattr(part, key) else part, key)


def setups(default=None) -> list:
    """The base, one setup per effect (:data:`EFFECTS`, then :data:`CONTENT`), the default setup
    (all its effects) and the default setup with every content-dependent effect, in table order.
    ``default``: the setup whose effects the rows turn off and on (``scenes/default.toml`` if none)."""
    default = default or load_setup(scene_path("default"))
    if not hasattr(default.surface.shape, "relief"):
        raise ProcamError(f"setup {default.name!r}: surface.geometry = {default.surface.geometry!r}: the "
                          "table's relief row needs a plane surface (geometry = \"plane\")")
    first, *names, everything, processed = setup_names()
    base = with_values(default, first, OFF)
    rows = [{k: _value(default, *k) for k in keys} for keys in EFFECTS.values()] + list(CONTENT.values())
    return [base, *(with_values(base, name, on) for name, on in zip(names, rows)),
            dataclasses.replace(default, name=everything),
            with_values(default, processed, {k: v for on in CONTENT.values() for k, v in on.items()})]


def setup_names() -> list[str]:
    """The names of :func:`setups`' setups, in table order.

    >>> names = setup_names()
    >>> names[:2], names[-2:]
    (['effects_base', 'effects_01'], ['effects_all', 'effects_all_content'])
    """
    rows = len(EFFECTS) + len(CONTENT)
    return ["effects_base", *(f"effects_{i:02d}" for i in range(1, rows + 1)), "effects_all", "effects_all_content"]


def _number(text: str) -> float:
    return float(text) if text not in ("", None) else math.nan


def _rows(path: Path) -> list[dict]:
    """Table 1 rows of a results CSV (none if it does not exist)."""
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return [r for r in csv.DictReader(f) if r.get("table", "1") == "1"]


def misregistration(out: Path, setup: str) -> dict:
    """The residual misregistration of a row's dataset ``OUT/data/<setup>`` (its ``meta.json``), in
    canonical pixels: ``misreg_mean`` and ``misreg_p95`` of the homography its captures were
    registered with, 0 where they were registered by the exact map; none without a dataset."""
    try:
        reg = read_json(out / "data" / setup / META_FILE)["registration"]
    except (OSError, ValueError, KeyError, TypeError, ProcamError):
        return {}
    if reg.get("method") == "exact":
        return {"misreg_mean": 0.0, "misreg_p95": 0.0}
    px = reg.get("homography", {}).get("canonical_px", {})
    return {f"misreg_{k}": px[k] for k in ("mean", "p95") if k in px}


def made_at(method: str, size: int, n_train: int, n_test: int, overrides: dict) -> dict[str, str]:
    """The settings a call makes a method's runs at, as ``effects_runs.csv`` keeps them: ``size``,
    ``n_train``, ``n_test`` and, for a method that takes them, the :data:`NETWORK_OPTIONS` given
    ("" for the profile's).

    >>> made_at("tps", 256, 125, 50, {"iters": 2000})
    {'size': '256', 'n_train': '125', 'n_test': '50'}
    >>> made_at("compennet", 256, 125, 50, {"iters": 2000, "patch": 64})
    {'size': '256', 'n_train': '125', 'n_test': '50', 'iters': '2000', 'patch': '64', 'batch': ''}
    """
    names = get_method(method).options.names()
    return {"size": str(size), "n_train": str(n_train), "n_test": str(n_test),
            **{k: str(overrides.get(k, "")) for k in NETWORK_OPTIONS if k in names}}


def check_kept(path: Path | None, settings) -> None:
    """Refuse an ``effects_runs.csv`` holding runs made at other settings than ``settings(method)``
    (:func:`made_at` of this call): their changes against this call's base would mix sizes, test
    counts or training budgets.

    Raises
    ------
    ProcamError
        Naming the file, the run, and each setting with its value there and in this call.
    """
    for r in _rows(path) if path else []:
        if missing := [k for k in ("setup", "method", "status") if not r.get(k)]:
            raise ProcamError(f"{path}: a run without {', '.join(missing)}: expected the effects_runs.csv "
                              "this script writes")
        try:
            want = settings(r["method"])
        except ProcamError as exc:
            raise ProcamError(f"{path}: run {r['setup']}/{r['method']}: {exc}") from None
        if any(not r.get(k) for k in ("size", "n_train", "n_test")) or any(r.get(k) is None for k in want):
            raise ProcamError(f"{path}: run {r['setup']}/{r['method']} carries no record of the settings "
                              f"it was made at ({', '.join(want)}): keep only runs written by this script")
        differ = [f"{k} {r[k] or 'default'} (this call: {v or 'default'})" for k, v in want.items() if r[k] != v]
        if differ:
            raise ProcamError(f"{path}: run {r['setup']}/{r['method']} was made at {', '.join(differ)}: "
                              "keep runs of the same settings, or write to another --out")


def _keys(setup) -> dict:
    """A setup's values by ``section.key`` (its name aside)."""
    return {f"{section}.{k}": v for section in SECTIONS for k, v in flat_items(getattr(setup, section)).items()}


def check_setup(path: Path | None, setup) -> None:
    """Refuse an ``effects_runs.csv`` holding runs made from another setup than ``setup``, the one
    whose effects this call turns off and on: the :data:`SETUP_FILE` beside it must read back to
    the same resolved setup (its name aside).

    Raises
    ------
    ProcamError
        Naming the file, and each key whose value differs, with its value there and in this call.
    """
    if path is None or not _rows(path):
        return
    kept = path.with_name(SETUP_FILE)
    if not kept.is_file():
        raise ProcamError(f"{path}: no {SETUP_FILE} beside it records the setup its runs were made from "
                          "(runs made before the table kept it: put the setup file they were made from "
                          f"there as {SETUP_FILE})")
    there, here = (_keys(s) for s in (load_setup(kept), setup))
    differ = [f"{k} = {there.get(k, 'unset')} (this call: {here.get(k, 'unset')})"
              for k in dict.fromkeys([*there, *here]) if there.get(k) != here.get(k)]
    if differ:
        raise ProcamError(f"{path}: its runs were made from another setup ({kept}): {'; '.join(differ)}; "
                          "keep runs of the same setup (--setup), or write to another --out")


def merge_runs(out: Path, settings, keep: Path | None = None) -> list[dict]:
    """The runs of every call so far: ``OUT/effects_runs.csv`` (the calls before; with ``keep``,
    an ``effects_runs.csv`` of calls into another folder too, the folder's own runs first) updated
    with the bench's ``OUT/results.csv`` (this call's runs, which replace earlier ones of the same
    setup and method, each with its dataset's :func:`misregistration` and ``settings(method)``,
    :func:`made_at` of this call), written back. Check the earlier runs with :func:`check_kept`
    first."""
    store = out / "effects_runs.csv"
    new = [{**r, **misregistration(out, r["setup"]), **settings(r["method"])} for r in _rows(out / "results.csv")]
    earlier = _earlier(out, keep)
    done = {(r["setup"], r["method"]) for r in new}
    rows = new + [r for key, r in earlier.items() if key not in done]
    _write_csv(store, rows)
    return rows


def merge_images(out: Path, keep: Path | None = None) -> list[dict]:
    """The per-image scores (:data:`IMAGE_COLUMNS`) of every call so far, merged as
    :func:`merge_runs` merges the runs: ``OUT/effects_per_image.csv`` (with ``keep``, the
    ``effects_per_image.csv`` beside it first) updated with the bench's ``OUT/per_image.csv``; a
    later source's images of a setup and method replace all earlier ones. Written back."""
    store = out / "effects_per_image.csv"
    groups: dict[tuple[str, str], list[dict]] = {}
    for path in (keep.with_name(store.name) if keep else None, store, out / "per_image.csv"):
        mine: dict[tuple[str, str], list[dict]] = {}
        for r in _rows(path) if path else []:
            mine.setdefault((r["setup"], r["method"]), []).append({k: r.get(k, "") for k in IMAGE_COLUMNS})
        groups.update(mine)
    rows = [r for group in groups.values() for r in group]
    _write_csv(store, rows, IMAGE_COLUMNS)
    return rows


def _write_csv(path: Path, rows: list[dict], cols=None) -> None:
    """``rows`` as they are, by :func:`~compensation.reports.summary.write_csv` (columns: ``cols``,
    else every key in order of appearance)."""
    write_csv(path, list(cols or dict.fromkeys(k for r in rows for k in r)), rows, digits=None)


def _earlier(out: Path, keep: Path | None) -> dict[tuple[str, str], dict]:
    """The runs of earlier calls by (setup, method): those of ``keep``, replaced by the folder's own
    (``OUT/effects_runs.csv``)."""
    return {(r["setup"], r["method"]): r for path in (keep, out / "effects_runs.csv") if path for r in _rows(path)}


def base_kept(out: Path, keep: Path | None, methods: tuple[str, ...]) -> bool:
    """Whether the runs of earlier calls (:func:`_earlier`, as the table will merge them) hold a
    finished base run of every method in ``methods``, so that a call with ``--only`` need not render
    and run the base again."""
    earlier = _earlier(out, keep)
    return all(earlier.get(("effects_base", m), {}).get("status") == "ok" for m in methods)


def _row_names() -> list[tuple[str, str]]:
    """(row name, setup name) of every row, in table order."""
    names = ["base (all effects off)", *EFFECTS, *CONTENT, "all (the default setup)",
             "all + content-dependent processing"]
    return list(zip(names, setup_names()))


def paired(images: list[dict]) -> list[dict]:
    """Per row and pair of :data:`PAIRS` whose runs both kept per-image scores: the surrogate PSNR
    difference A − B over the test images both scored (:func:`~compensation.reports.paired.paired_comparison`
    of one group: ``mean``, the bootstrap interval ``lo`` … ``hi`` over images, ``share`` of images
    where A is ahead, ``images``)."""
    by: dict[tuple[str, str], dict[int, float]] = {}
    for r in images:
        by.setdefault((r["setup"], r["method"]), {})[int(r["image"])] = _number(r["psnr"])
    out = []
    for name, setup in _row_names():
        for a, b in PAIRS:
            sa, sb = by.get((setup, a), {}), by.get((setup, b), {})
            common = sorted(set(sa) & set(sb))
            diffs = image_differences([sa[i] for i in common], [sb[i] for i in common])
            if diffs:
                c = paired_comparison([diffs])
                out.append({"effect": name, "setup": setup, "a": a, "b": b,
                            **{k: c[k] for k in ("mean", "lo", "hi", "share", "images")}})
    return out


def table(rows: list[dict]) -> list[dict]:
    """Per setup and method, the change against the base (dB) of surrogate and closed-loop PSNR,
    and of the uncompensated captures, from the runs' result rows."""
    score = {(r["setup"], r["method"]): r for r in rows}
    out = []
    for name, setup in _row_names():
        line = {"effect": name, "setup": setup}
        first = next((r for (s, _), r in score.items() if s == setup), None)
        base_first = next((r for (s, _), r in score.items() if s == "effects_base"), None)
        if first is None or base_first is None:
            continue
        for key, col in (("unc_psnr", "uncompensated"), ("cl_unc_psnr", "uncompensated CL")):
            line[col] = _number(first[key]) - (0 if setup == "effects_base" else _number(base_first[key]))
        for key in ("misreg_mean", "misreg_p95"):  # the same dataset for every method of a row
            known = [v for (s, _), r in score.items() if s == setup and not math.isnan(v := _number(r.get(key)))]
            line[key] = known[0] if known else math.nan
        for m in METHODS:
            r, b = score.get((setup, m)), score.get(("effects_base", m))
            for key, suffix in (("psnr", ""), ("cl_psnr", " CL")):
                value = math.nan if r is None or r["status"] != "ok" else _number(r[key])
                ref = 0.0 if setup == "effects_base" else (
                    math.nan if b is None or b["status"] != "ok" else _number(b[key]))
                line[m + suffix] = value - ref
        out.append(line)
    return out


def write(out: Path, lines: list[dict], how: str, pairs: list[dict] = ()) -> None:
    """``effects.csv`` and ``effects.md`` (the base row in absolute dB, the others as changes; then
    the paired differences of :func:`paired`, also in ``effects_paired.csv``)."""
    cols = ["effect", "misreg_mean", "misreg_p95", "uncompensated", "uncompensated CL",
            *(f"{m}{s}" for m in METHODS for s in ("", " CL"))]
    text = [",".join(cols)] + [",".join(l["effect"] if c == "effect" else f"{l.get(c, math.nan):.2f}"
                                        for c in cols) for l in lines]
    write_text(out / "effects.csv", "\n".join(text) + "\n")
    md = ["# Per-effect table: PSNR change (dB) against the base, surrogate / closed loop (CL)", "",
          how, "",
          "| effect | misregistration (canonical px: mean / p95) | uncompensated | " + " | ".join(METHODS) + " |",
          "|---|---|---|" + "---|" * len(METHODS)]
    for l in lines:
        sign = "" if l["setup"] == "effects_base" else "+"

        def pair(a, b):
            return " / ".join("–" if math.isnan(v := l.get(k, math.nan)) else f"{v:{sign}.2f}" for k in (a, b))
        misreg = f"{l['misreg_mean']:.2f} / {l['misreg_p95']:.2f}" if not math.isnan(l["misreg_mean"]) else "–"
        md.append(f"| {l['effect']} | {misreg} | {pair('uncompensated', 'uncompensated CL')} | "
                  + " | ".join(pair(m, m + ' CL') for m in METHODS) + " |")
    if pairs:
        _write_csv(out / "effects_paired.csv", [{k: (f"{v:.4f}" if isinstance(v, float) else v)
                                                  for k, v in p.items()} for p in pairs])
        md += ["", "Paired per test image, surrogate PSNR (dB): mean of the per-image differences, 95 % "
               "bootstrap interval over the images, share of images ahead (one run per method and row). "
               "The table above pools each run's squared error over its images, as the paper's code "
               "does; the two differ where a method fails badly on a few images.", "",
               "| effect | " + " | ".join(f"{a} − {b}" for a, b in PAIRS) + " |",
               "|---|" + "---|" * len(PAIRS)]
        cell = {(p["setup"], p["a"], p["b"]): p for p in pairs}
        for name, setup in _row_names():
            if not any(s == setup for s, _, _ in cell):
                continue
            md.append(f"| {name} | " + " | ".join(
                f"{c['mean']:+.2f} ({c['lo']:+.2f} … {c['hi']:+.2f}; {100 * c['share']:.0f} %)"
                if (c := cell.get((setup, a, b))) else "–" for a, b in PAIRS) + " |")
    write_text(out / "effects.md", "\n".join(md) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--setup", type=Path, default=None,
                    help="the setup file whose effects the rows turn off and on (default: scenes/default.toml)")
    ap.add_argument("--size", type=int, default=64, help="canonical pixels")
    ap.add_argument("--n-train", type=int, default=125)
    ap.add_argument("--n-test", type=int, default=50)
    ap.add_argument("--iters", type=int, default=None, help="CompenNet iterations (default: quick profile)")
    ap.add_argument("--patch", type=int, default=None, help="CompenNet training window (pixels; default: whole images)")
    ap.add_argument("--batch", type=int, default=None, help="CompenNet batch (default: quick profile)")
    ap.add_argument("--methods", default=",".join(METHODS),
                    help="comma-separated methods to run (the table keeps a column per method of "
                         f"{', '.join(METHODS)}; runs not made are blank); a later call with others resumes")
    ap.add_argument("--surrogate-only", action="store_true",
                    help="score the surrogate benchmark only (no closed loop, no oracle: minutes instead of hours at 256²)")
    ap.add_argument("--only", help="comma-separated setup names (with effects_base, unless --keep "
                                   "holds a finished base run of every method asked)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="an effects_runs.csv of calls into another folder (e.g. the one in "
                         "benchmarks/results/effects/256/, made from the setup beside it: --setup "
                         "benchmarks/results/effects/256/effects_setup.toml): its runs, and the "
                         "per-image scores of the effects_per_image.csv beside it, stay in the table "
                         "where this folder has none of the same setup and method")
    args = ap.parse_args()
    if args.keep is not None and not args.keep.is_file():
        ap.error(f"--keep {args.keep}: no such file")
    overrides = {k: v for k, v in (("iters", args.iters), ("patch", args.patch), ("batch", args.batch))
                 if v is not None}

    def settings(method: str) -> dict[str, str]:
        return made_at(method, args.size, args.n_train, args.n_test, overrides)
    try:
        default = load_setup(args.setup or scene_path("default"))
        for path in (args.keep, args.out / "effects_runs.csv"):
            check_kept(path, settings)
            check_setup(path, default)
        suite = setups(default)
    except ProcamError as exc:
        ap.exit(1, f"effects: {exc}\n")
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    if not set(methods) <= set(METHODS):
        ap.error(f"--methods {args.methods}: expected some of {', '.join(METHODS)}")
    if args.only:
        names = set(args.only.split(","))
        if not base_kept(args.out, args.keep, methods):
            names.add("effects_base")
        suite = [s for s in suite if s.name in names]
    cfg = BenchConfig(profile="quick", methods=methods, sizes=(args.n_train,), tables=("1",),
                      size=args.size, n_test=args.n_test, overrides=overrides,
                      closed_loop=not args.surrogate_only)
    try:
        run_bench(suite, args.out, cfg)
    except ProcamError as exc:
        ap.exit(1, f"effects: {exc}\n")
    write_text(args.out / SETUP_FILE, dump_setup(default))
    how = (f"`python benchmarks/effects.py --out {args.out}" + (f" --setup {args.setup}" if args.setup else "")
           + f" --size {args.size} --n-train {args.n_train} "
           f"--n-test {args.n_test}" + "".join(f" --{k} {v}" for k, v in overrides.items())
           + (" --surrogate-only" if args.surrogate_only else "") + "`: "
           f"{args.size}² canonical, {args.n_train} training / {args.n_test} test pairs, quick profile"
           + "".join(f", CompenNet {k} {v}" for k, v in overrides.items()) + ". Base row: absolute dB.")
    write(args.out, table(merge_runs(args.out, settings, args.keep)), how,
          paired(merge_images(args.out, args.keep)))
    print((args.out / "effects.md").read_text())


if __name__ == "__main__":
    main()
