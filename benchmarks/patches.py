"""Training-budget benchmark: CompenNet's test PSNR against training time, on full images and on
random aligned crops of a few sides (the ``patch`` option), for a few batch sizes and iteration
counts, at a size the CPU allows.

Renders the checkout's ``default`` setup (``--size``², ``--train`` / ``--test`` pairs) into a
temporary root, or uses a rendered setup folder (``--data``, e.g. the demo's ``data/default``),
then trains CompenNet from scratch for each crop side, batch size of ``--batches``, iteration
count of ``--iters`` and seed of ``--seeds`` (the chart plots the mean over seeds; the paper's
recipe otherwise, the learning-rate step after 80 % of the
iterations) and scores the test pairs. Writes ``patches.csv`` and ``patches.png`` into ``--out``
(default ``benchmarks/results/patches``). The CSV is rewritten after every point and a point it
already holds (same crop, batch, iterations and seed) is not trained again: rerun the same command
to go on after an interruption, or with more values to add points.

    .venv/bin/python benchmarks/patches.py [--size 64] [--patches 0,32,16] [--iters 75,150,300]
                                           [--batches 16] [--data DIR] [--seeds 0]
"""
from __future__ import annotations

import argparse
import csv
import itertools
import os
import statistics
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

from compensation.data import load_setup_data  # noqa: E402
from compensation.scores.metrics import evaluate  # noqa: E402
from compensation.methods.compennet import CompenNetMethod, CompenNetOptions  # noqa: E402
from compensation.reports.summary import write_csv  # noqa: E402
from compensation.training.config import TrainConfig  # noqa: E402
from sim.dataset import FrameSpec, write_setup  # noqa: E402
from sim.setup import load_setups  # noqa: E402

SCENE = Path(__file__).resolve().parents[1] / "scenes" / "default.toml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--train", type=int, default=100)
    ap.add_argument("--test", type=int, default=30)
    ap.add_argument("--patches", default="0,32,16", help="crop sides (0: full images)")
    ap.add_argument("--iters", default="75,150,300")
    ap.add_argument("--batches", default="16", help="batch sizes")
    ap.add_argument("--seeds", default="0", help="training seeds")
    ap.add_argument("--data", default=None, help="a rendered setup folder to use instead")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "patches"))
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    table = out / "patches.csv"
    rows = []
    if table.exists():
        with open(table, newline="") as f:
            rows = [{k: float(v) if k in ("train_seconds", "psnr", "ssim", "uncompensated_psnr") else int(v)
                     for k, v in r.items()} for r in csv.DictReader(f)]
    done = {(r["patch"], r["batch"], r["iters"], r["seed"]) for r in rows}
    with tempfile.TemporaryDirectory() as tmp:
        if args.data:
            folder = Path(args.data)
        else:
            setup = load_setups(str(SCENE))[0]
            folder = write_setup(Path(tmp), setup, FrameSpec(args.train, args.test, (args.size,) * 2),
                                 progress=False)
        data = load_setup_data(folder)
        size = data.test.frames.shape[-1]
        base = evaluate(data.test.captures, data.test.frames)
        print(f"{folder} at {size}², {len(data.train)} train / {len(data.test)} test pairs, "
              f"{torch.get_num_threads()} threads, load {os.getloadavg()[0]:.1f}; "
              f"uncompensated PSNR {base['psnr']:.2f} dB")
        for patch, batch, iters, seed in itertools.product(
                *([int(v) for v in a.split(",")] for a in (args.patches, args.batches, args.iters, args.seeds))):
            if (patch, batch, iters, seed) in done:
                continue
            options = CompenNetOptions(iters=iters, batch=batch, patch=patch)
            cfg = TrainConfig(method="compennet", options=options, n_train=None, n_test=None,
                              seed=seed, device="cpu")
            method = CompenNetMethod("cpu")
            fit = method.fit(data, cfg, progress=False)
            scores = evaluate(method.predict(data.test.captures, data.surface), data.test.frames)
            rows.append({"patch": patch, "batch": batch, "iters": iters, "seed": seed,
                         "train_seconds": round(fit.seconds, 2), "psnr": round(scores["psnr"], 3),
                         "ssim": round(scores["ssim"], 4), "uncompensated_psnr": round(base["psnr"], 3)})
            print(rows[-1], flush=True)
            write_csv(table, list(rows[-1]), rows, digits=None)
    fig, ax = plt.subplots(figsize=(6, 4))
    for patch, batch in dict.fromkeys((r["patch"], r["batch"]) for r in rows):
        mine = [r for r in rows if (r["patch"], r["batch"]) == (patch, batch)]
        points = {i: [r for r in mine if r["iters"] == i] for i in dict.fromkeys(r["iters"] for r in mine)}
        ax.plot([statistics.fmean(r["train_seconds"] for r in p) for p in points.values()],
                [statistics.fmean(r["psnr"] for r in p) for p in points.values()], "o-",
                label=(f"{patch}² crops" if patch else f"full {size}² images") + f", batch {batch}")
    ax.axhline(base["psnr"], color="gray", ls=":", label="uncompensated")
    ax.set_xlabel("training time (s, CPU)")
    ax.set_ylabel("test PSNR (dB)")
    ax.set_title(f"CompenNet, {folder.name} at {size}²")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "patches.png", dpi=120)


if __name__ == "__main__":
    main()
