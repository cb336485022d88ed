"""TPS fit benchmark: milliseconds per pixel of the per-pixel spline fits with OpenBLAS on its own
thread count against one thread (:func:`sim.blas.one_blas_thread`, what
:func:`~compensation.methods.tps.fit_splines` does), measured side by side in one run.

Two kinds of pixels, on seeded random samples of ``--samples`` captured colours each: regular ones
(distinct colours, ``--smoothing`` λ), solved by one LU solve each, and singular ones (a third of
the colours clipped to black, λ = 0: duplicate centres), which fall back to minimum-norm least
squares — most pixels of a dark print at λ = 0. The two arms take turns for ``--rounds`` rounds;
each row gives both arms' median and their ratio.

    .venv/bin/python benchmarks/tps.py [--pixels 2000] [--samples 125] [--rounds 3]
                                       [--smoothing 0.01] [--workers N]
"""
from __future__ import annotations

import argparse
import contextlib
import os
import statistics
import time

import numpy as np

import compensation.methods.tps as tps
from sim.blas import one_blas_thread, openblas_threads


def pixels(count: int, samples: int, singular: bool, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(centres, values), (count, samples, 3): random colours, a third of them black if ``singular``."""
    rng = np.random.default_rng(seed)
    centres, values = rng.random((count, samples, 3)), rng.random((count, samples, 3))
    if singular:
        centres[:, :samples // 3] = 0.0
    return centres, values


def time_fit(centres: np.ndarray, values: np.ndarray, smoothing: float, workers: int | None,
             one_thread: bool) -> float:
    """Milliseconds per pixel of one :func:`~compensation.methods.tps.fit_splines`."""
    tps.one_blas_thread = one_blas_thread if one_thread else contextlib.nullcontext
    try:
        start = time.perf_counter()
        tps.fit_splines(centres, values, smoothing, workers)
        return (time.perf_counter() - start) / len(centres) * 1e3
    finally:
        tps.one_blas_thread = one_blas_thread


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--pixels", type=int, default=2000)
    ap.add_argument("--samples", type=int, default=125, help="samples per pixel (TPS: 125 plain colours)")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--smoothing", type=float, default=0.01, help="λ of the regular pixels")
    ap.add_argument("--workers", type=int, default=None, help="fit processes (default: one per core)")
    args = ap.parse_args()
    threads = openblas_threads()
    print(f"{os.cpu_count()} CPUs, load average before {os.getloadavg()[0]:.1f}; OpenBLAS threads as "
          f"loaded: {threads or 'no OpenBLAS found'}; ms per pixel, median of {args.rounds} interleaved fits "
          f"of {args.pixels} pixels × {args.samples} samples")
    for kind, smoothing, singular in (("regular", args.smoothing, False), ("singular", 0.0, True)):
        centres, values = pixels(args.pixels, args.samples, singular)
        ms = {True: [], False: []}
        for _ in range(args.rounds):
            for one in (False, True):
                ms[one].append(time_fit(centres, values, smoothing, args.workers, one))
        default, one = statistics.median(ms[False]), statistics.median(ms[True])
        print(f"  {kind} (λ = {smoothing:g}): OpenBLAS threads as loaded {default:.3f}, one thread "
              f"{one:.3f}, speed-up {default / one:.2f}×", flush=True)
    print(f"load average after {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
