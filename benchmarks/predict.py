"""Prediction benchmark: a trained CompenNet run predicting its test set the ways procam could,
timed side by side and scored: in float32 and under the bf16 autocast its ``amp`` option trained
it under; in the channels-last memory layout procam predicts in and in the default layout; with
the weights as procam keeps them (subnormal weights zeroed) and as the run's ``model.pt`` holds
them.

A run trained with ``amp`` (the ``faithful`` profile's CompenNet) predicts under that autocast
(``CompenNetMethod.adopt_options``), every run in the channels-last layout
(``CompenNetMethod.layout``) with its subnormal weights set to zero when trained or loaded
(``flush_denormals``; runs saved before that was done hold them in ``model.pt``). Each way
predicts the same test captures, interleaved, ``--repeat`` times (best time kept); the scores are
a run's surrogate metrics (π†(x̃) against x).

    .venv/bin/python benchmarks/predict.py RUN [--images 100] [--repeat 2] [--threads 2]

``RUN`` is a CompenNet run folder (``procam train`` or a bench's ``runs/<setup>/<run>``) whose
``config.json`` names its dataset.
"""
from __future__ import annotations

import argparse
import copy
import time
from pathlib import Path

import torch

from compensation.data import load_setup_data
from compensation.experiments.runs import SSIM_CONVENTION, load_run
from compensation.methods.base import CHECKPOINT, load_state, subnormal
from compensation.methods.compennet import CompenNetMethod
from compensation.scores.metrics import evaluate


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path, help="a CompenNet run folder")
    ap.add_argument("--images", type=int, default=100, help="test pairs predicted and scored")
    ap.add_argument("--repeat", type=int, default=2, help="timed predictions of each way")
    ap.add_argument("--threads", type=int, default=torch.get_num_threads(), help="torch threads")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    method, config = load_run(args.run, device="cpu")
    if not isinstance(method, CompenNetMethod):
        raise SystemExit(f"{args.run}: a {config['train']['method']} run; expected a CompenNet run")
    data = load_setup_data(Path(config["dataset"]), n_train=1, n_test=args.images)
    captures, frames, batch = data.test.captures, data.test.frames, config["train"]["eval_batch"]
    kept = copy.deepcopy(method.model)  # the weights as the file holds them, subnormals kept
    kept.load_state_dict(load_state(args.run / CHECKPOINT))
    n_subnormal = sum(int(subnormal(p).sum()) for p in kept.parameters())
    zeroed, fast, default = method.model, torch.channels_last, torch.contiguous_format
    ways = {  # row: (bf16, layout, weights)
        "float32": (False, fast, zeroed),
        "float32, default layout": (False, default, zeroed),
        "float32, subnormals kept": (False, fast, kept),
        "bf16": (True, fast, zeroed),
        "bf16, default layout": (True, default, zeroed),
    }
    best, predicted = {}, {}
    for _ in range(args.repeat):
        for way, (amp, layout, model) in ways.items():
            method.amp, method.layout, method.model = amp, layout, model
            start = time.perf_counter()
            predicted[way] = method.predict(captures, data.surface, batch_size=batch)
            best[way] = min(best.get(way, float("inf")), time.perf_counter() - start)
    h, w = captures.shape[2:]
    print(f"{args.run}: {len(captures)} test pairs of {w}x{h}, {args.threads} threads, "
          f"best of {args.repeat}; {n_subnormal} of {sum(p.numel() for p in kept.parameters())} weights "
          f"in {CHECKPOINT} subnormal")
    for way in ways:
        scores = evaluate(predicted[way], frames, batch, SSIM_CONVENTION)
        print(f"  {way:24s} {best[way]:7.2f} s ({1e3 * best[way] / len(captures):6.1f} ms/image)  "
              f"PSNR {scores['psnr']:.4f}  SSIM {scores['ssim']:.4f}  deltaE {scores['deltaE']:.4f}")

    def compared(a: str, b: str) -> str:
        """``a``'s time over ``b``'s, and the mean and largest difference of their predictions."""
        difference = (predicted[a] - predicted[b]).abs()
        return (f"{best[a] / best[b]:.3f}; |difference| mean {255 * difference.mean():.3g}, "
                f"max {255 * difference.max():.3g} 8-bit levels")

    print(f"  bf16 / float32 time: {compared('bf16', 'float32')}")
    print(f"  channels-last / default layout time, float32: {compared('float32', 'float32, default layout')}")
    print(f"  channels-last / default layout time, bf16: {compared('bf16', 'bf16, default layout')}")
    print(f"  subnormals zeroed / kept time, float32: {compared('float32', 'float32, subnormals kept')}")

if __name__ == "__main__":
    main()
