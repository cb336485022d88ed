"""Training benchmark: CompenNet samples/second with the surface branch run per sample (naive)
against once per batch and broadcast (ours), side by side in one run; then the `quick` profile's
training time and test PSNR/SSIM on the default setup.

    .venv/bin/python benchmarks/train.py [--sizes 128,256] [--batch 16] [--steps 5] [--data out/data]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from compensation.evaluation.losses import get_loss
from compensation.methods.compennet import CompenNet


def samples_per_second(size: int, batch: int, steps: int, naive: bool) -> float:
    """Training steps (forward, ℓ1+SSIM, backward, Adam) per second × batch."""
    torch.manual_seed(0)
    model = CompenNet(surface=True)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3, weight_decay=1e-4)
    loss_fn = get_loss("l1+ssim")
    x = torch.rand(batch, 3, size, size)
    y = torch.rand(batch, 3, size, size)
    s = torch.rand(1, 3, size, size)
    s_in = s.expand(batch, -1, -1, -1).contiguous() if naive else s  # per sample vs broadcast
    for step in range(steps + 1):
        if step == 1:
            t0 = time.perf_counter()  # the first step warms up the allocator
        opt.zero_grad()
        loss = loss_fn(model(x, s_in), y)
        loss.backward()
        opt.step()
    return steps * batch / (time.perf_counter() - t0)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="128,256")
    ap.add_argument("--batch", type=int, default=16)
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--data", default=None, help="a dataset root with default/ rendered at the quick "
                    "profile (e.g. the demo's out/data): also time the quick profile on it")
    args = ap.parse_args()
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, batch {args.batch}")
    print(f"{'size':>6}{'naive samples/s':>18}{'ours samples/s':>16}{'ratio':>8}")
    for size in (int(s) for s in args.sizes.split(",")):
        naive = samples_per_second(size, args.batch, args.steps, naive=True)
        ours = samples_per_second(size, args.batch, args.steps, naive=False)
        print(f"{size:>6}{naive:>18.2f}{ours:>16.2f}{ours / naive:>8.2f}")
    if args.data:
        import tempfile

        from compensation.training.config import make_config
        from compensation.training.runs import train_run

        with tempfile.TemporaryDirectory() as tmp:
            m = train_run(Path(args.data) / "default", make_config("quick"), Path(tmp) / "run")
        print(f"\nquick profile on default: {m['train_seconds']:.0f} s training, test PSNR "
              f"{m['psnr']:.2f} dB, SSIM {m['ssim']:.4f} (uncompensated {m['uncompensated']['psnr']:.2f} dB, "
              f"{m['uncompensated']['ssim']:.4f})")


if __name__ == "__main__":
    main()
