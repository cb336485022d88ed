"""pix2pix training step: the default memory layout, channels-last, and the default layout with
freed memory kept in the heap (:mod:`sim.heap`, procam's pix2pix step: the training loop runs
inside it), each in a process of its own and interleaved (``benchmarks/interleave.py``), at the
quick profile's 64² and batch 1 by default.

CompenNet's CPU training keeps its network in the channels-last layout (``benchmarks/train.py``);
this measures whether pix2pix (U-Net generator with BatchNorm at batch 1, PatchGAN discriminator)
gains from the same, and from the retained heap::

    .venv/bin/python benchmarks/pix2pix.py [--size 64] [--rounds 30]
"""
from __future__ import annotations

import argparse
import statistics

import torch

from compensation.methods.pix2pix import (BETAS, Pix2Pix, Pix2PixOptions, init_normal, to_signed,
                                          training_step, unet_levels)
from interleave import interleaved


def timed_step(size: int, channels_last: bool):
    """One pix2pix iteration (:func:`compensation.methods.pix2pix.training_step`, the default
    options' learning rate and ℓ1 weight) on fixed random images, in the given layout."""
    torch.manual_seed(0)
    model = Pix2Pix(unet_levels(size, size))
    init_normal(model)
    layout = torch.channels_last if channels_last else torch.contiguous_format
    model = model.to(memory_format=layout)
    gen, disc = model.generator, model.discriminator
    opt = Pix2PixOptions()
    opt_g = torch.optim.Adam(gen.parameters(), lr=opt.lr, betas=BETAS, fused=True)
    opt_d = torch.optim.Adam(disc.parameters(), lr=opt.lr, betas=BETAS, fused=True)
    x, y = (to_signed(torch.rand(1, 3, size, size)).contiguous(memory_format=layout) for _ in range(2))
    model.train()
    return lambda: training_step(gen, disc, opt_g, opt_d, x, y, opt.l1_weight)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=30)
    args = ap.parse_args()
    times = interleaved({"default layout": (timed_step, (args.size, False), False),
                         "channels_last": (timed_step, (args.size, True), False),
                         "retained heap": (timed_step, (args.size, False), True)}, args.rounds)
    base = statistics.median(times["default layout"])
    print(f"pix2pix step at {args.size}², batch 1, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads; median of {args.rounds} interleaved steps")
    for name, values in times.items():
        m = statistics.median(values)
        print(f"  {name:15s} {m * 1e3:8.1f} ms  ({base / m:.2f}x)")


if __name__ == "__main__":
    main()
