"""pix2pix training step in the default memory layout against channels-last, interleaved in one
run (one step of each per round, medians reported), at the quick profile's 64² and batch 1.

CompenNet's CPU training keeps its network in the channels-last layout (``benchmarks/train.py``);
this measures whether pix2pix (U-Net generator with BatchNorm at batch 1, PatchGAN discriminator)
gains from the same::

    .venv/bin/python benchmarks/pix2pix_layout.py [--size 64] [--rounds 30]
"""
from __future__ import annotations

import argparse
import statistics
import time

import torch
import torch.nn.functional as F

from compensation.methods.pix2pix import BETAS, Pix2Pix, init_normal, to_signed, unet_levels


def training_step(size: int, channels_last: bool):
    """One pix2pix iteration (discriminator step, then generator step) as ``Pix2PixMethod.fit``
    runs it, on fixed random images, in the given layout."""
    torch.manual_seed(0)
    model = Pix2Pix(unet_levels(size, size))
    init_normal(model)
    layout = torch.channels_last if channels_last else torch.contiguous_format
    model = model.to(memory_format=layout)
    gen, disc = model.generator, model.discriminator
    opt_g = torch.optim.Adam(gen.parameters(), lr=2e-4, betas=BETAS, fused=True)
    opt_d = torch.optim.Adam(disc.parameters(), lr=2e-4, betas=BETAS, fused=True)
    x, y = (torch.rand(1, 3, size, size).contiguous(memory_format=layout) for _ in range(2))
    model.train()

    def step() -> None:
        cond, real = to_signed(x), to_signed(y)
        fake = gen(cond)
        disc.requires_grad_(True)
        opt_d.zero_grad(set_to_none=True)
        fake_logits = disc(torch.cat([cond, fake.detach()], 1))
        real_logits = disc(torch.cat([cond, real], 1))
        (0.5 * (F.binary_cross_entropy_with_logits(fake_logits, torch.zeros_like(fake_logits))
                + F.binary_cross_entropy_with_logits(real_logits, torch.ones_like(real_logits)))).backward()
        opt_d.step()
        disc.requires_grad_(False)
        opt_g.zero_grad(set_to_none=True)
        logits = disc(torch.cat([cond, fake], 1))
        (F.binary_cross_entropy_with_logits(logits, torch.ones_like(logits))
         + 100.0 * F.l1_loss(fake, real)).backward()
        opt_g.step()
    return step


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--size", type=int, default=64)
    ap.add_argument("--rounds", type=int, default=30)
    args = ap.parse_args()
    steps = {"default layout": training_step(args.size, False),
             "channels_last": training_step(args.size, True)}
    for step in steps.values():  # warm-up
        step()
        step()
    times = {name: [] for name in steps}
    for _ in range(args.rounds):
        for name, step in steps.items():
            t = time.perf_counter()
            step()
            times[name].append(time.perf_counter() - t)
    base = statistics.median(times["default layout"])
    print(f"pix2pix step at {args.size}², batch 1, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads; median of {args.rounds} interleaved steps")
    for name, values in times.items():
        m = statistics.median(values)
        print(f"  {name:15s} {m * 1e3:8.1f} ms  ({base / m:.2f}x)")


if __name__ == "__main__":
    main()
