"""Which stage of the closed loop explains a method's score change between two points of a study.

A closed-loop score at a point has three sources, each made by that point's setup: the method's
fit (the training pairs it learnt from), the target y' (fitted to the point's black and white
captures under the study's target policy) and the camera that captures the projected
compensation (its noise, its room light). This script scores every mix of the two points A and B,
2³ closed loops per method and seed, each exactly as the study scores its runs (the run as
saved, the study's target policy, the point's test pairs and simulator), and prints the table and
each stage's main effect: the mean change of the closed-loop PSNR when that stage alone is taken
from B instead of A, over the four settings of the other two. The corners (A, A, A) and
(B, B, B) are the study's own scores.

    .venv/bin/python benchmarks/attribute.py STUDY --points A,B [--methods tps,compennet]
                                             [--seed 0] [--setup NAME] [--csv FILE]

STUDY is a finished ``procam study`` folder; A and B are point numbers of its ``results.csv``.
"""
from __future__ import annotations

import argparse
import csv
import io
import itertools
import math
import sys
from pathlib import Path

import torch

from compensation.data import load_setup_data
from compensation.experiments.closed_loop import closed_loop, simulator_for
from compensation.experiments.runs import load_run
from compensation.experiments.targets import TargetPolicy
from compensation.reports.summary import read_results, read_study
from sim.errors import ProcamError
from sim.io import atomic_write, read_json

STAGES = ("fit", "target", "camera")
"""The stages taken from one point or the other, in the order of a table row's key."""


CLOSED_LOOP_COLUMNS = ("run", "cl_psnr", "target_policy", "target_out_of_reach")
"""The ``results.csv`` columns read besides those every results table has."""


def _results(study: Path) -> list[dict]:
    """The study's ``results.csv``, read and checked as the reports read it."""
    path = study / "results.csv"
    axes = read_study(study)["axes"]
    rows = read_results(path, [a["key"] for a in axes], {a["key"]: a["values"] for a in axes})
    missing = [c for c in CLOSED_LOOP_COLUMNS if rows and c not in rows[0]]
    if missing:
        raise ProcamError(f"{path}: no column {', '.join(missing)}; expected the results.csv of a "
                          "procam study scored in closed loop")
    return rows


def _row(rows: list[dict], point: int, method: str, seed: int, study: Path, setup: str | None) -> dict:
    found = [r for r in rows if (r["point"], r["method"], r["seed"]) == (point, method, seed)
             and r["status"] == "ok" and math.isfinite(r["cl_psnr"]) and r["target_policy"]
             and setup in (None, r["setup"].split("__")[0])]
    if not found:
        raise ProcamError(f"{study / 'results.csv'}: no finished run of point {point}, method {method!r}, "
                          f"seed {seed}{'' if setup is None else f', setup {setup!r}'} scored in closed "
                          f"loop; expected one of the points {', '.join(map(str, sorted({r['point'] for r in rows})))}")
    if len(found) > 1:
        names = ", ".join(sorted({r["setup"].split("__")[0] for r in found}))
        raise ProcamError(f"{study / 'results.csv'}: point {point} holds the setups {names}; choose one "
                          "with --setup")
    return found[0]


def attribute(study: Path, points: tuple[int, int], methods: list[str], seed: int = 0,
              setup: str | None = None) -> list[dict]:
    """The closed-loop scores of every mix of the two points' stages (of the base setup ``setup``
    where a point holds several, as a study over a suite does).

    Returns
    -------
    list of dict
        One per method and mix: ``method``, ``fit``, ``target``, ``camera`` (each the point it was
        taken from), ``cl_psnr``, ``cl_ssim``, ``cl_deltae`` and ``study_cl_psnr`` (the study's
        own score where the three stages come from one point, else empty).
    """
    rows = _results(study)
    data, sims = {}, {}
    out = []
    for method in methods:
        picked = {p: _row(rows, p, method, seed, study, setup) for p in points}
        policy = {p: TargetPolicy(r["target_policy"], float(r["target_out_of_reach"])) for p, r in picked.items()}
        if policy[points[0]] != policy[points[1]]:
            raise ProcamError(f"{study}: points {points[0]} and {points[1]} were scored under different "
                              "target policies; expected one")
        fitted = {p: load_run(study / r["run"])[0] for p, r in picked.items()}
        setups = {p: r["setup"] for p, r in picked.items()}
        for p, r in picked.items():
            if r["setup"] not in data:
                setup_dir = study / "data" / r["setup"]
                n_test = read_json(study / r["run"] / "metrics.json", "run metrics")["n_test"]
                data[r["setup"]] = load_setup_data(setup_dir, n_train=1, n_test=n_test)
                sims[r["setup"]] = simulator_for(setup_dir)
        for fit, target, camera in itertools.product(points, repeat=3):
            scores = closed_loop(fitted[fit], data[setups[target]], sims[setups[camera]], policy=policy[target])
            own = fit == target == camera
            out.append({"method": method, "fit": fit, "target": target, "camera": camera,
                        "cl_psnr": scores["psnr"], "cl_ssim": scores["ssim"], "cl_deltae": scores["deltaE"],
                        "study_cl_psnr": picked[fit]["cl_psnr"] if own else ""})
    return out


def main_effects(table: list[dict], points: tuple[str, str]) -> dict[str, dict[str, float]]:
    """Per method, each stage's main effect on the closed-loop PSNR (dB): the mean over the other
    stages' four settings of the score with the stage from B minus with it from A.

    >>> t = [{"method": "m", "fit": f, "target": g, "camera": c, "cl_psnr": 30 - (f == "B") - 2 * (c == "B")}
    ...      for f, g, c in itertools.product("AB", repeat=3)]
    >>> main_effects(t, ("A", "B"))
    {'m': {'fit': -1.0, 'target': 0.0, 'camera': -2.0}}
    """
    effects: dict[str, dict[str, float]] = {}
    for method in dict.fromkeys(r["method"] for r in table):
        mine = [r for r in table if r["method"] == method]
        effects[method] = {
            stage: sum(r["cl_psnr"] * (1 if r[stage] == points[1] else -1) for r in mine) / (len(mine) / 2)
            for stage in STAGES}
    return effects


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("study", type=Path, help="a finished procam study folder")
    ap.add_argument("--points", required=True, help="two point numbers of its results.csv, A,B")
    ap.add_argument("--methods", default="tps,nayar,compennet")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--setup", help="the base setup's name, where a point holds several (a study over a suite)")
    ap.add_argument("--csv", type=Path, help="also write the table here")
    ap.add_argument("--threads", type=int, default=1, help="torch threads")
    args = ap.parse_args(argv)
    try:
        points = tuple(int(p) for p in args.points.split(","))
    except ValueError:
        points = ()
    if len(points) != 2 or points[0] == points[1]:
        print(f"attribute.py: --points {args.points!r}: expected two different point numbers, A,B",
              file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    try:
        table = attribute(args.study, points, args.methods.split(","), args.seed, args.setup)
    except ProcamError as exc:
        print(f"attribute.py: {exc}", file=sys.stderr)
        return 1
    a, b = points
    print(f"closed-loop PSNR (dB) of {args.study}, seed {args.seed}: each stage from point {a} or {b}")
    print(f"{'method':12s} {'fit':>4s} {'target':>7s} {'camera':>7s} {'cl_psnr':>8s} {'study':>8s}")
    for r in table:
        study = f"{r['study_cl_psnr']:.3f}" if r["study_cl_psnr"] != "" else ""
        print(f"{r['method']:12s} {r['fit']:>4} {r['target']:>7} {r['camera']:>7} {r['cl_psnr']:8.3f} {study:>8s}")
    print(f"main effects, dB (the stage from point {b} instead of {a}, mean over the other stages):")
    score = {(r["method"], r["fit"], r["target"], r["camera"]): r["cl_psnr"] for r in table}
    for method, effects in main_effects(table, points).items():
        total = score[(method, b, b, b)] - score[(method, a, a, a)]
        print(f"  {method:12s} " + "  ".join(f"{s} {v:+.2f}" for s, v in effects.items()) + f"  (all three {total:+.2f})")
    if args.csv:
        text = io.StringIO()
        w = csv.DictWriter(text, fieldnames=list(table[0]), lineterminator="\n")
        w.writeheader()
        w.writerows(table)
        atomic_write(args.csv, text.getvalue())
    return 0


if __name__ == "__main__":
    sys.exit(main())
