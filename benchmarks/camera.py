"""Camera-model benchmark: ``sim.camera.capture`` against the implementation it replaced, timed
side by side in one run, and the cost of every hardware effect at a camera's native size.

The reference is the earlier camera model, kept here only: float64 ``Generator.poisson`` and
``Generator.normal`` noise on the whole image, then the response curve through colour-science
and ``rint(255 x)``. Both run interleaved on the same radiance (a smooth random image in the
camera's working range, ambient included), so machine load hits both alike; the figure is the
best of ``--repeat`` runs of each.

    .venv/bin/python benchmarks/camera.py [--repeat 15]
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import cv2
import numpy as np

from sim import camera
from sim.setup.schema import CameraConfig


def reference_capture(radiance: np.ndarray, cfg, rng: np.random.Generator) -> np.ndarray:
    """The earlier camera model (all hardware effects off)."""
    rad = np.asarray(radiance, dtype=np.float32)
    wb = np.asarray(cfg.white_balance, dtype=np.float32)
    s = np.maximum(rad * np.float32(cfg.exposure) * wb, 0.0)
    if cfg.shot_noise > 0:
        s = cfg.shot_noise * rng.poisson(s.astype(np.float64) / cfg.shot_noise)
    if cfg.read_noise > 0:
        s = s + rng.normal(0.0, cfg.read_noise, s.shape)
    signal = np.clip(s, 0.0, 1.0).astype(np.float32)
    return camera.quantise(camera.encode(signal, cfg.response), cfg.bit_depth)


def scene(width: int, height: int, seed: int = 0) -> np.ndarray:
    """A smooth random radiance image with values from about 0.02 to 1."""
    rng = np.random.default_rng(seed)
    low = rng.random((max(2, height // 32), max(2, width // 32), 3)).astype(np.float32)
    return cv2.resize(low, (width, height), interpolation=cv2.INTER_CUBIC).clip(0, 1) * 0.95 + 0.02


def best_of(fn, repeat: int) -> list[float]:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    args = parser.parse_args()
    base = CameraConfig()
    hardware = replace(base, psf_sigma=0.7, bayer="RGGB", demosaic="bilinear", vignetting=0.3,
                       distortion=-0.05, jpeg_quality=90)
    print(f"camera model, best of {args.repeat} (ms); default camera: sRGB, shot_noise "
          f"{base.shot_noise}, read_noise {base.read_noise}")
    for width, height in ((256, 256), (960, 640)):
        rad = scene(width, height)
        new_t, old_t = [], []
        for _ in range(args.repeat):  # interleaved: the same load for both
            new_t += best_of(lambda: camera.capture(rad, base, np.random.default_rng(1)), 1)
            old_t += best_of(lambda: reference_capture(rad, base, np.random.default_rng(1)), 1)
        new, old = min(new_t) * 1e3, min(old_t) * 1e3
        camera.capture(rad, hardware, np.random.default_rng(1))  # builds the cached maps
        hw = min(best_of(lambda: camera.capture(rad, hardware, np.random.default_rng(1)), args.repeat)) * 1e3
        print(f"{width}x{height}: before {old:7.2f}  after {new:7.2f}  ratio {old / new:5.2f}x   "
              f"all effects on (psf 0.7, RGGB bilinear, vignetting 0.3, distortion -0.05, "
              f"JPEG 90): {hw:7.2f}")


if __name__ == "__main__":
    main()
