"""Patch training benchmark: CompenNet's test PSNR against training time, on full images and on
random aligned crops of a few sides (the ``patch`` option), at a size the CPU allows.

Renders the checkout's ``default`` setup (``--size``², ``--train`` / ``--test`` pairs) into a
temporary root, then trains CompenNet from scratch for each crop side and each iteration count of
``--iters`` (batch ``--batch``, the paper's recipe otherwise, the learning-rate step after 80 % of
the iterations) and scores the test pairs. Writes ``patches.csv`` and ``patches.png`` into
``--out`` (default ``benchmarks/results/patches``).

    .venv/bin/python benchmarks/patches.py [--size 64] [--patches 0,32,16] [--iters 75,150,300]
"""
from __future__ import annotations

import argparse
import csv
import os
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

from compensation.data import load_setup_data  # noqa: E402
from compensation.evaluation.metrics import evaluate  # noqa: E402
from compensation.methods.compennet import CompenNetMethod, CompenNetOptions  # noqa: E402
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
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--out", default=str(Path(__file__).parent / "results" / "patches"))
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        setup = load_setups(str(SCENE))[0]
        folder = write_setup(Path(tmp), setup, FrameSpec(args.train, args.test, (args.size, args.size)),
                             progress=False)
        data = load_setup_data(folder)
        base = evaluate(data.test.captures, data.test.frames)
        print(f"default at {args.size}², {args.train} train / {args.test} test pairs, "
              f"{torch.get_num_threads()} threads, load {os.getloadavg()[0]:.1f}; "
              f"uncompensated PSNR {base['psnr']:.2f} dB")
        for patch in (int(p) for p in args.patches.split(",")):
            for iters in (int(i) for i in args.iters.split(",")):
                options = CompenNetOptions(iters=iters, batch=args.batch, patch=patch,
                                           lr_step=max(1, round(0.8 * iters)))
                cfg = TrainConfig(method="compennet", options=options, n_train=None, n_test=None,
                                  device="cpu")
                method = CompenNetMethod("cpu")
                fit = method.fit(data, cfg, progress=False)
                scores = evaluate(method.predict(data.test.captures, data.surface), data.test.frames)
                rows.append({"patch": patch, "iters": iters, "train_seconds": round(fit["seconds"], 2),
                             "psnr": round(scores["psnr"], 3), "ssim": round(scores["ssim"], 4),
                             "uncompensated_psnr": round(base["psnr"], 3)})
                print(rows[-1], flush=True)
    with open(out / "patches.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    fig, ax = plt.subplots(figsize=(6, 4))
    for patch in dict.fromkeys(r["patch"] for r in rows):
        mine = [r for r in rows if r["patch"] == patch]
        ax.plot([r["train_seconds"] for r in mine], [r["psnr"] for r in mine], "o-",
                label=f"{patch}² crops" if patch else f"full {args.size}² images")
    ax.axhline(base["psnr"], color="gray", ls=":", label="uncompensated")
    ax.set_xlabel("training time (s, CPU)")
    ax.set_ylabel("test PSNR (dB)")
    ax.set_title(f"CompenNet, default setup at {args.size}², batch {args.batch}")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "patches.png", dpi=120)


if __name__ == "__main__":
    main()
