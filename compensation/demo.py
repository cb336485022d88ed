"""``procam demo``: the whole pipeline on embedded defaults, in minutes on a laptop CPU.

Render the shipped default setup at the quick profile, fit CompenNet and TPS, score both on the
surrogate benchmark and in closed loop (their compensation of the target y' projected back through
the simulated setup and scored against y'; y' is the desired image mapped by the target policy,
:mod:`~compensation.experiments.targets`), beside the iterative-feedback oracle, the exact optimum
(:mod:`~compensation.experiments.optimum`) and the reachable share of y''s pixels; print the
table, headed by the policy and its map, and write a figure: surface, uncompensated, each method's
compensated capture, target. The folder is a
one-point bench (``study.json``, ``results.csv``, each run's closed-loop captures), and the demo ends
by writing its HTML report (``report.html``, :mod:`compensation.reports.report`).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from compensation.data import load_setup_data, to_tensor
from compensation.experiments.closed_loop import (CAPTURES_DIR, N_CAPTURES, closed_loop_target, projected_as_is,
                                                 reachable_mask, reachable_overlay, simulator_for)
from compensation.experiments.targets import TargetPolicy
from compensation.reports.report import build_report
from compensation.experiments.jobs import (BaselineJob, FitJob, baselines, bound_cells, check_study_folder,
                                          fit, target_cells, write_results, write_study_record)
from compensation.methods import applicable, make_config
from compensation.training.config import PROFILES
from compensation.experiments.runs import SCORES
from sim.dataset import FrameSpec, write_setup
from sim.io import read_png, write_json, write_png
from sim.layout import SETUP_FILE, image_name
from sim.setup import load_setup, scene_path

PROFILE = "quick"
METHODS = ("compennet", "tps")
ORACLE_ITERATIONS = 4
"""Feedback rounds of the demo's oracle row. On the default setup at the quick profile its
closed-loop PSNR is 12.51 dB after 4 rounds and 12.52 after 8 (the reachable pixels: 29.4 and
30.0 dB); each round is 100 captures."""
N_FIGURE = N_CAPTURES
"""Test images in the figure: the first, whose closed-loop captures every run keeps."""


def _row(name: str, scores: dict) -> str:
    reach = f"{scores['psnr_reachable']:>6.2f}" if "psnr_reachable" in scores else "     -"
    return (f"| {name:<40} | {scores['psnr']:>6.2f} | {scores['rmse']:.4f} | {scores['ssim']:.4f} "
            f"| {scores['deltaE']:>6.2f} | {reach}    |")


def _scores(metrics: dict, closed: dict) -> dict:
    """A run's ``results.csv`` cells: surrogate, closed-loop and uncompensated scores, fit time and
    inference ms per frame."""
    keys = (("psnr", "psnr"), ("rmse", "rmse"), ("ssim", "ssim"), ("deltae", "deltaE"))
    return {**{k: metrics[m] for k, m in keys}, **{f"cl_{k}": closed[m] for k, m in keys},
            **{f"unc_{k}": metrics["uncompensated"][m] for k, m in keys},
            "fit_s": metrics["train_seconds"], "infer_ms": closed["infer_ms_per_frame"]}


def figure(surface: torch.Tensor, as_is: torch.Tensor, compensated: dict[str, torch.Tensor],
           desired: torch.Tensor, reachable: torch.Tensor) -> np.ndarray:
    """A grid, one row per image: surface s̃ | y' projected as is | x* of each method projected | y' |
    y' with its unreachable pixels tinted.

    Parameters
    ----------
    surface : torch.Tensor
        s̃ (1, 3, H, W), encoded [0, 1].
    as_is, desired : torch.Tensor
        (N, 3, H, W) captures of the targets y' projected as is, and y'.
    compensated : dict[str, torch.Tensor]
        Per method, the (N, 3, H, W) captures of its compensation images.
    reachable : torch.Tensor
        bool (N, H, W): pixels of y' the projector can produce on the surface.

    Returns
    -------
    numpy.ndarray
        The figure as uint8 RGB (rows, cols, 3).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    columns = {"surface s̃": surface.expand_as(desired), "uncompensated": as_is,
               **{f"{name} (closed loop)": c for name, c in compensated.items()}, "target y'": desired,
               "unreachable (magenta)": reachable_overlay(desired, reachable)}
    n = desired.shape[0]
    fig, axes = plt.subplots(n, len(columns), figsize=(2 * len(columns), 2.1 * n), squeeze=False)
    for c, (title, images) in enumerate(columns.items()):
        for r in range(n):
            ax = axes[r][c]
            ax.imshow(images[r].permute(1, 2, 0).clamp(0, 1).numpy())
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(title, fontsize=9)
    fig.tight_layout()
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())
    plt.close(fig)
    return np.ascontiguousarray(rgba[..., :3])


def _policy_line(record: dict) -> str:
    """The table's heading line: what the closed-loop rows are scored against.

    >>> _policy_line({"policy": "global", "out_of_reach": 0.01, "out_of_reach_used": 0.01, "a": 0.4, "b": 0.08})
    "closed loop against y' = 0.4000·y + 0.0800 (target policy global: at most 1 % of the pixels out of reach)"
    >>> _policy_line({"policy": "global", "out_of_reach": 0.01, "out_of_reach_used": 0.3, "a": 0.03, "b": 0.14})
    "closed loop against y' = 0.0300·y + 0.1400 (target policy global: at most 30 % of the pixels out of reach, the least that leaves any contrast; 1 % asked)"
    >>> _policy_line({"policy": "none", "out_of_reach": 0.01, "a": 1.0, "b": 0.0, "gap": 0.0})
    "closed loop against y' = y, the desired image itself (target policy none)"
    """
    if record["policy"] == "none":
        return "closed loop against y' = y, the desired image itself (target policy none)"
    mean = ", means over the images" if record["policy"] == "image" else ""
    used, asked = 100 * record["out_of_reach_used"], 100 * record["out_of_reach"]
    relaxed = f", the least that leaves any contrast; {asked:g} % asked" if used > asked + 1e-9 else ""
    return (f"closed loop against y' = {record['a']:.4f}·y + {record['b']:.4f} (target policy "
            f"{record['policy']}: at most {used:.3g} % of the pixels out of reach{relaxed}{mean})")


def run_demo(out: Path, progress: bool = True, target: TargetPolicy = TargetPolicy(), **overrides) -> dict:
    """Run the demo into ``out`` (resumable: a finished dataset, run, closed loop or set of
    baselines, i.e. uncompensated, oracle and optimum, is reused where nothing it depends on changed).

    Parameters
    ----------
    out : path-like
        Output folder: ``data/``, ``runs/`` (each with ``closed_loop/`` captures), ``baselines/``,
        ``demo.png``, ``demo.json``, ``study.json``, ``results.csv`` and ``report.html`` go there.
    progress : bool
        Show progress bars.
    target : TargetPolicy
        What the closed loop scores against (default: the ``global`` map).
    **overrides
        Training options over the quick profile (e.g. ``size``, ``n_train``, ``n_test``,
        ``iters`` for a smaller run); the dataset is rendered at the resulting size and counts.

    Returns
    -------
    dict
        What ``demo.json`` holds: ``uncompensated`` (closed loop, y' projected as is, with the
        ``target`` record), per method ``surrogate``, ``closed_loop`` and ``train_seconds``, and
        ``oracle`` (iterative refinement rows) and ``optimum`` (the exact optimum's scores).

    Raises
    ------
    ProcamError
        Before anything is written, if ``out`` is not a folder the demo may write
        (:func:`~compensation.experiments.jobs.check_study_folder`).
    """
    out = Path(out)
    prof = {**PROFILES[PROFILE], **{k: v for k, v in overrides.items() if v is not None}}
    setup = load_setup(scene_path("default"))
    spec = FrameSpec(prof["n_train"], prof["n_test"], (prof["size"],) * 2)
    check_study_folder(out, "demo", "bench")
    setup_dir = write_setup(out / "data", setup, spec, progress=progress)
    data = load_setup_data(setup_dir, prof["n_train"], prof["n_test"])
    sim = simulator_for(setup_dir)
    y = data.test.frames
    lines = [f"| {'method':<40} |  PSNR  |  RMSE  |  SSIM  |   ΔE   | PSNR reachable |",
             f"|{'-' * 42}|--------|--------|--------|--------|----------------|"]
    y_target = closed_loop_target(data, y, target)[0][:N_FIGURE]  # those the closed loop scores against
    mask = reachable_mask(data, y_target)
    as_is = projected_as_is(data, sim, y_target, own=target.name == "none")[:N_FIGURE]
    captures, rows, fitted = {}, [], {}
    for name in METHODS:
        run_dir = out / "runs" / f"default-{name}"
        train_cfg = make_config(PROFILE, name, **applicable(name, overrides))
        # a run of other options is trained again, one scored under another target policy scored again
        metrics = fit(FitJob(setup_dir, train_cfg, run_dir, progress=progress, target=target))["metrics"]
        fitted[name] = metrics
        captures[name] = to_tensor(np.stack([read_png(run_dir / CAPTURES_DIR / image_name(i))
                                             for i in range(1, len(y_target) + 1)]))
        rows.append({"method": name, "n_train": prof["n_train"], "seed": train_cfg.seed,
                     "run": f"runs/{run_dir.name}", **_scores(metrics, metrics["closed_loop"])})
    kept = baselines(BaselineJob(setup_dir, prof["n_test"], record=out / "baselines" / f"{setup.name}.json",
                                 target=target, oracle_rounds=(ORACLE_ITERATIONS,), progress=progress))
    unc = kept["uncompensated"]["closed_loop"]
    results = {"uncompensated": unc}
    lines.append(_row("uncompensated (y' projected as is)", unc))
    for name, metrics in fitted.items():
        results[name] = {"surrogate": {k: metrics[k] for k in SCORES},
                         "closed_loop": metrics["closed_loop"], "train_seconds": metrics["train_seconds"]}
        lines.append(_row(f"{name}: surrogate π†(x̃) vs x", metrics))
        lines.append(_row(f"{name}: closed loop, capture vs y'", metrics["closed_loop"]))
    results["oracle"], results["optimum"] = kept["oracle"], kept["optimum"]
    lines.append(_row(f"oracle: feedback, {ORACLE_ITERATIONS} it. ({ORACLE_ITERATIONS + 1} projections)",
                      results["oracle"][-1]))
    lines.append(_row(f"exact optimum ({results['optimum']['evaluations']:g} noise-free eval.)",
                      results["optimum"]))
    write_png(out / "demo.png", figure(data.surface, as_is, captures, y_target, mask))
    write_json(out / "demo.json", results)
    oracle = results["oracle"][-1]
    base = {"point": 0, "setup": setup.name, "status": "ok", "error": "", **target_cells(unc),
            **bound_cells("cl_unc_", unc), **bound_cells("oracle_", oracle),
            **bound_cells("optimum_", results["optimum"])}
    study = {"name": "demo", "kind": "bench", "question": "How well do CompenNet and TPS compensate "
             "the default setup, on held-out pairs and in closed loop?",
             "base": "default", "axes": [], "methods": list(METHODS),
             "seeds": sorted({r["seed"] for r in rows}), "n_train": prof["n_train"],
             "n_test": prof["n_test"], "size": [prof["size"]] * 2, "profile": PROFILE,
             "overrides": {k: v for k, v in overrides.items() if v is not None}, "target": target.record(),
             "setups": {setup.name: f"data/{setup.name}/{SETUP_FILE}"}}
    write_study_record(out, study)
    write_results(out, (), [{**base, **r} for r in rows])

    report = build_report(out)
    reachable = results["uncompensated"]["reachable_fraction"]
    print(f"\nprocam demo: default setup, {PROFILE} profile ({prof['size']}² px, "
          f"{prof['n_train']} train / {prof['n_test']} test pairs)\n")
    print(_policy_line(unc["target"]) + "; surrogate rows against x\n")
    print("\n".join(lines))
    print(f"\n{100 * reachable:.1f} % of the target's pixels are physically reachable on this surface; "
          "'PSNR reachable' scores those only. SSIM as the official CompenNet code computes it; ΔE: "
          "CIEDE2000.")
    print(f"figure -> {out / 'demo.png'}; numbers -> {out / 'demo.json'}")
    print(f"report -> {report}")
    return results
