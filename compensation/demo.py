"""``procam demo``: the whole pipeline on embedded defaults, in minutes on a laptop CPU.

Render the shipped default setup at the quick profile, train CompenNet, score it on the surrogate
benchmark and in closed loop (its compensation projected back through the simulated setup), print
the table and write a figure: surface, uncompensated, compensated, desired.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import torch

from compensation.closed_loop import CLOSED_LOOP_STREAM, project, simulator_for
from compensation.data import load_setup_data
from compensation.metrics import evaluate
from compensation.train import PROFILES, load_run, make_config, train_run
from sim.dataset import FrameSpec, write_json, write_setup
from sim.pngio import write_png
from sim.setup import load_setup, scene_path

PROFILE = "quick"
METHODS = ("compennet",)
N_FIGURE = 4


def _row(name: str, scores: dict) -> str:
    return f"| {name:<34} | {scores['psnr']:>6.2f} | {scores['rmse']:.4f} | {scores['ssim']:.4f} |"


def figure(surface: torch.Tensor, uncompensated: torch.Tensor, compensated: torch.Tensor,
           desired: torch.Tensor) -> np.ndarray:
    """A grid, one row per image: surface s̃ | y projected as is | x* projected | desired y."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = desired.shape[0]
    fig, axes = plt.subplots(n, 4, figsize=(8, 2.1 * n), squeeze=False)
    titles = ("surface s̃", "uncompensated", "compensated (closed loop)", "desired y")
    for r in range(n):
        for c, img in enumerate((surface[0], uncompensated[r], compensated[r], desired[r])):
            ax = axes[r][c]
            ax.imshow(img.permute(1, 2, 0).clamp(0, 1).numpy())
            ax.set_xticks([])
            ax.set_yticks([])
            if r == 0:
                ax.set_title(titles[c], fontsize=9)
    fig.tight_layout()
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())
    plt.close(fig)
    return np.ascontiguousarray(rgba[..., :3])


def run_demo(out: Path, progress: bool = True) -> dict:
    """Run the demo into ``out`` (resumable: a finished dataset or run is reused)."""
    out = Path(out)
    prof = PROFILES[PROFILE]
    setup = load_setup(scene_path("default"))
    spec = FrameSpec(prof["n_train"], prof["n_test"], (prof["size"],) * 2)
    setup_dir = write_setup(out / "data", setup, spec, progress=progress)
    results = {}
    data = load_setup_data(setup_dir, prof["n_train"], prof["n_test"])
    sim = simulator_for(setup_dir)
    y = data.test.frames
    lines = ["| method                             |  PSNR  |  RMSE  |  SSIM  |",
             "|------------------------------------|--------|--------|--------|"]
    results["uncompensated"] = evaluate(data.test.captures, y)
    lines.append(_row("uncompensated", results["uncompensated"]))
    for name in METHODS:
        run_dir = out / "runs" / f"default-{name}"
        if not (run_dir / "metrics.json").exists():
            train_run(setup_dir, make_config(PROFILE, method=name), run_dir, progress, overwrite=True)
        metrics = json.loads((run_dir / "metrics.json").read_text())
        method, _ = load_run(run_dir)
        x_star = method.predict(y, data.surface)
        captured = project(sim, x_star, CLOSED_LOOP_STREAM)
        closed = evaluate(captured, y)
        results[name] = {"surrogate": {k: metrics[k] for k in ("psnr", "rmse", "ssim")},
                         "closed_loop": closed, "train_seconds": metrics["train_seconds"]}
        lines.append(_row(f"{name} (surrogate π†(x̃) vs x)", metrics))
        lines.append(_row(f"{name} (closed loop: capture vs y)", closed))
        if name == METHODS[0]:
            grid = figure(data.surface, data.test.captures[:N_FIGURE], captured[:N_FIGURE], y[:N_FIGURE])
            write_png(out / "demo.png", grid)
    write_json(out / "demo.json", results)
    print(f"\nprocam demo: default setup, {PROFILE} profile ({prof['size']}² px, "
          f"{prof['n_train']} train / {prof['n_test']} test pairs)\n")
    print("\n".join(lines))
    print(f"\nfigure -> {out / 'demo.png'}; numbers -> {out / 'demo.json'}")
    return results
