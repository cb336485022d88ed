"""Evaluation-metric benchmark: ``compensation.scores.metrics.evaluate`` (PSNR, RMSE, SSIM, ΔE of a
test set) against the implementation it replaced, timed side by side in one run.

The reference is the earlier one: SSIM's Gaussian passes as float64 grouped convolutions in the
channels-last layout (``metrics.grouped_filter``, the float32 path), and ΔE's sRGB decoding
evaluated per pixel by colour-science (kept here only). Both run interleaved on the same images
(random predictions against random targets, ``--n`` images of ``--size``², in batches of 64 as a
run evaluates them), and their values are compared; the figures are the best of ``--repeat`` runs
of each.

    .venv/bin/python benchmarks/metrics.py [--n 100] [--size 256] [--repeat 3]
"""
from __future__ import annotations

import argparse
import time
from unittest import mock

import colour
import numpy as np
import torch

from compensation.scores import metrics


def reference_lab(images: torch.Tensor) -> np.ndarray:
    """The earlier Lab conversion: every pixel decoded by colour-science."""
    rgb = np.rint(images.detach().double().clamp(0, 1).permute(0, 2, 3, 1).cpu().numpy() * 255) / 255
    return colour.XYZ_to_Lab(colour.sRGB_to_XYZ(rgb))


def timed(fn) -> tuple[float, dict]:
    t0 = time.perf_counter()
    out = fn()
    return time.perf_counter() - t0, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=100, help="test images")
    ap.add_argument("--size", type=int, default=256, help="image side (pixels)")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    g = torch.Generator().manual_seed(0)
    target = torch.rand(args.n, 3, args.size, args.size, generator=g)
    pred = (target + 0.1 * torch.randn(target.shape, generator=g)).clamp(0, 1)

    def reference() -> dict:
        with mock.patch.object(metrics, "gaussian_filter", metrics.grouped_filter), \
                mock.patch.object(metrics, "srgb_to_lab", reference_lab):
            return metrics.evaluate(pred, target, 64)

    best = {"reference": float("inf"), "procam": float("inf")}
    for _ in range(args.repeat):
        t, ref = timed(reference)
        best["reference"] = min(best["reference"], t)
        t, new = timed(lambda: metrics.evaluate(pred, target, 64))
        best["procam"] = min(best["procam"], t)
    print(f"evaluate(): {args.n} images of {args.size}², {torch.get_num_threads()} threads, "
          f"best of {args.repeat}")
    for name, t in best.items():
        print(f"  {name:<10}{t:8.2f} s")
    print(f"  speed-up  {best['reference'] / best['procam']:8.2f}x")
    print("  largest difference of a score: "
          f"{max(abs(ref[k] - new[k]) for k in ref):.1e} ({', '.join(f'{k} {new[k]:.6f}' for k in new)})")


if __name__ == "__main__":
    main()
