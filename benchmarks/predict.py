"""Prediction benchmark: a trained CompenNet run predicting its test set in float32 and under the
bf16 autocast its ``amp`` option trained it under, timed side by side and scored both ways.

A run trained with ``amp`` (the ``faithful`` profile's CompenNet) predicts under that autocast
(``CompenNetMethod.adopt_options``); this script measures what that costs in accuracy and gains in
time. Both precisions predict the same test captures, interleaved, ``--repeat`` times each
(best time kept); the scores are a run's surrogate metrics (π†(x̃) against x).

    .venv/bin/python benchmarks/predict.py RUN [--images 100] [--repeat 2] [--threads 2]

``RUN`` is a CompenNet run folder (``procam train`` or a bench's ``runs/<setup>/<run>``) whose
``config.json`` names its dataset.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from compensation.data import load_setup_data
from compensation.experiments.runs import SSIM_CONVENTION, load_run
from compensation.methods.compennet import CompenNetMethod
from compensation.scores.metrics import evaluate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path, help="a CompenNet run folder")
    ap.add_argument("--images", type=int, default=100, help="test pairs predicted and scored")
    ap.add_argument("--repeat", type=int, default=2, help="timed predictions per precision")
    ap.add_argument("--threads", type=int, default=torch.get_num_threads(), help="torch threads")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    method, config = load_run(args.run, device="cpu")
    if not isinstance(method, CompenNetMethod):
        raise SystemExit(f"{args.run}: a {config['train']['method']} run; expected a CompenNet run")
    data = load_setup_data(Path(config["dataset"]), n_train=1, n_test=args.images)
    captures, frames, batch = data.test.captures, data.test.frames, config["train"]["eval_batch"]
    best, predicted = {}, {}
    for _ in range(args.repeat):
        for name, amp in (("float32", False), ("bf16", True)):
            method.amp = amp
            start = time.perf_counter()
            predicted[name] = method.predict(captures, data.surface, batch_size=batch)
            best[name] = min(best.get(name, float("inf")), time.perf_counter() - start)
    h, w = captures.shape[2:]
    print(f"{args.run}: {len(captures)} test pairs of {w}x{h}, {args.threads} threads, "
          f"best of {args.repeat}")
    for name in ("float32", "bf16"):
        scores = evaluate(predicted[name], frames, batch, SSIM_CONVENTION)
        print(f"  {name:7s} {best[name]:7.2f} s ({1e3 * best[name] / len(captures):6.1f} ms/image)  "
              f"PSNR {scores['psnr']:.4f}  SSIM {scores['ssim']:.4f}  deltaE {scores['deltaE']:.4f}")
    difference = (predicted["bf16"] - predicted["float32"]).abs()
    print(f"  bf16 / float32 time: {best['bf16'] / best['float32']:.3f}; |bf16 − float32| mean "
          f"{255 * difference.mean():.3f}, max {255 * difference.max():.2f} 8-bit levels")


if __name__ == "__main__":
    main()
