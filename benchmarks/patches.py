"""Training-budget benchmark: CompenNet's test PSNR against training time, on full images and on
random aligned crops of a few sides (the ``patch`` option), for a few batch sizes and iteration
counts, at a size the CPU allows.

Renders the checkout's ``default`` setup (``--size``², ``--train`` / ``--test`` pairs) into a
temporary root, or uses a rendered setup folder (``--data``, e.g. the demo's ``data/default``),
then trains CompenNet from scratch for each crop side, batch size of ``--batches``, iteration
count of ``--iters``, learning rate of ``--lrs`` and seed of ``--seeds`` (the chart plots the
mean over seeds; the paper's recipe otherwise, the learning-rate step after 80 % of the
iterations; ``--schedule one-cycle`` and ``--amp`` train as the faithful profile does) and scores
the test pairs. Writes ``patches.csv`` and ``patches.png`` into ``--out``
(default ``benchmarks/results/patches``). The CSV is rewritten after every point and a point it
already holds (same crop, batch, iterations, learning rate, schedule, precision and seed) is not
trained again: rerun the same command to go on after an interruption, or with more values to add
points.

    .venv/bin/python benchmarks/patches.py [--size 64] [--patches 0,32,16] [--iters 75,150,300]
                                           [--batches 16] [--lrs 1e-3] [--schedule step] [--amp]
                                           [--data DIR] [--seeds 0]
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


RECIPE = (1e-3, "step", 0)
"""The paper's learning rate, schedule and precision (float32): the values of a CSV row written
before these columns were."""


def _row(r: dict) -> dict:
    """A row of ``patches.csv`` with its values typed (the paper's recipe where a column is missing)."""
    floats, texts = ("train_seconds", "psnr", "ssim", "uncompensated_psnr", "lr"), ("schedule",)
    row = dict(zip(("lr", "schedule", "amp"), RECIPE))
    row.update({k: float(v) if k in floats else v if k in texts else int(v) for k, v in r.items()})
    return row


def _key(r: dict) -> tuple:
    """What makes a point of ``patches.csv`` another point."""
    return r["patch"], r["batch"], r["iters"], r["seed"], r["lr"], r["schedule"], r["amp"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--train", type=int, default=100)
    ap.add_argument("--test", type=int, default=30)
    ap.add_argument("--patches", default="0,32,16", help="crop sides (0: full images)")
    ap.add_argument("--iters", default="75,150,300")
    ap.add_argument("--batches", default="16", help="batch sizes")
    ap.add_argument("--seeds", default="0", help="training seeds")
    ap.add_argument("--lrs", default="1e-3", help="learning rates")
    ap.add_argument("--schedule", default="step", choices=("step", "one-cycle"),
                    help="learning-rate schedule")
    ap.add_argument("--amp", action="store_true", help="train under bf16 autocast")
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
            rows = [_row(r) for r in csv.DictReader(f)]
    done = {_key(r) for r in rows}
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
        lrs = [float(v) for v in args.lrs.split(",")]
        for patch, batch, iters, seed, lr in itertools.product(
                *([int(v) for v in a.split(",")] for a in (args.patches, args.batches, args.iters, args.seeds)),
                lrs):
            recipe = {"lr": lr, "schedule": args.schedule, "amp": int(args.amp)}
            if _key({"patch": patch, "batch": batch, "iters": iters, "seed": seed, **recipe}) in done:
                continue
            options = CompenNetOptions(iters=iters, batch=batch, patch=patch, lr=lr,
                                       lr_schedule=args.schedule, amp=args.amp)
            cfg = TrainConfig(method="compennet", options=options, n_train=None, n_test=None,
                              seed=seed, device="cpu")
            method = CompenNetMethod("cpu")
            fit = method.fit(data, cfg, progress=False)
            scores = evaluate(method.predict(data.test.captures, data.surface), data.test.frames)
            rows.append({"patch": patch, "batch": batch, "iters": iters, "seed": seed, **recipe,
                         "train_seconds": round(fit.seconds, 2), "psnr": round(scores["psnr"], 3),
                         "ssim": round(scores["ssim"], 4), "uncompensated_psnr": round(base["psnr"], 3)})
            print(rows[-1], flush=True)
            write_csv(table, list(rows[-1]), rows, digits=None)
    fig, ax = plt.subplots(figsize=(6, 4))
    for patch, batch, *recipe in dict.fromkeys(_key(r)[:2] + _key(r)[4:] for r in rows):
        mine = [r for r in rows if _key(r)[:2] + _key(r)[4:] == (patch, batch, *recipe)]
        points = {i: [r for r in mine if r["iters"] == i] for i in dict.fromkeys(r["iters"] for r in mine)}
        ax.plot([statistics.fmean(r["train_seconds"] for r in p) for p in points.values()],
                [statistics.fmean(r["psnr"] for r in p) for p in points.values()], "o-",
                label=(f"{patch}² crops" if patch else f"full {size}² images") + f", batch {batch}"
                + ("" if tuple(recipe) == RECIPE else f", lr {recipe[0]:g} {recipe[1]}{' bf16' * recipe[2]}"))
    ax.axhline(base["psnr"], color="gray", ls=":", label="uncompensated")
    ax.set_xlabel("training time (s, CPU)")
    ax.set_ylabel("test PSNR (dB)")
    ax.set_title(f"CompenNet, {folder.name} at {size}²")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "patches.png", dpi=120)


if __name__ == "__main__":
    main()
