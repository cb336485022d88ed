"""Camera-model benchmark: ``sim.camera.capture`` against the implementation it replaced, timed
side by side in one run, and the cost of every hardware effect at a camera's native size.

The reference is the earlier camera model, kept here only: float64 ``Generator.poisson`` and
``Generator.normal`` noise on the whole image from one generator (noise version 1), then the
response curve through colour-science and ``rint(255 x)``. ``sim.camera.capture`` draws the noise
of this process's version (``sim.camera.noise_version()``, printed). Both run interleaved on the same
radiance (a smooth random image in the camera's working range), so machine load hits both alike;
the figures are the best of ``--repeat`` runs of each, wall time and CPU time of this process
(the CPU time sums the camera's threads: its ratio is the gain on one core).

    .venv/bin/python benchmarks/camera.py [--repeat 15] [--pause 0.05]
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import cv2
import numpy as np

from sim import camera
from sim.cores import usable_cores
from sim.setup import load_setup, scene_path
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


def timed(fn, pause: float) -> tuple[float, float]:
    """(wall, CPU) seconds of one call, after ``pause`` seconds; the CPU time of this process is
    less disturbed by other processes on a busy machine. Dr.Jit's worker threads keep spinning for
    more work for a while after a kernel (~20 ms of CPU): without a pause that CPU time is counted
    to the next call, with one the call starts with every worker thread asleep."""
    time.sleep(pause)
    w, c = time.perf_counter(), time.process_time()
    fn()
    return time.perf_counter() - w, time.process_time() - c


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=15)
    parser.add_argument("--pause", type=float, default=0.05,
                        help="seconds of rest before each timed call (0: back to back)")
    args = parser.parse_args()
    base = CameraConfig()
    hardware = replace(base, psf_sigma=0.7, bayer="RGGB", demosaic="bilinear", vignetting=0.3,
                       distortion=-0.05, jpeg_quality=90)
    paper = load_setup(scene_path("default")).camera  # the paper-hardware default's own camera
    print(f"camera model, best of {args.repeat} (ms, wall / CPU), {args.pause * 1e3:g} ms rest before "
          f"each call; {usable_cores()} cores; noise "
          f"version {camera.noise_version()}; default camera: {base.response}, shot_noise "
          f"{base.shot_noise}, read_noise {base.read_noise}")
    for width, height in ((256, 256), (960, 640)):
        rad = scene(width, height)
        runs = {"before": [], "after": [], "hardware": [], "paper": []}
        for cfg in (hardware, paper):
            camera.capture(rad, cfg, np.random.default_rng(1))  # builds the cached maps
        for _ in range(args.repeat):  # interleaved: the same load for all
            for name, fn in (("after", lambda: camera.capture(rad, base, np.random.default_rng(1))),
                             ("before", lambda: reference_capture(rad, base, np.random.default_rng(1))),
                             ("hardware", lambda: camera.capture(rad, hardware, np.random.default_rng(1))),
                             ("paper", lambda: camera.capture(rad, paper, np.random.default_rng(1)))):
                runs[name].append(timed(fn, args.pause))
        best = {k: np.min(np.array(v), axis=0) * 1e3 for k, v in runs.items()}
        ratio = best["before"] / best["after"]
        print(f"{width}x{height}: before {best['before'][0]:7.2f} / {best['before'][1]:7.2f}   "
              f"after {best['after'][0]:7.2f} / {best['after'][1]:7.2f}   "
              f"ratio {ratio[0]:4.2f}x / {ratio[1]:4.2f}x")
        print(f"{width}x{height}: all effects on (psf_sigma 0.7, RGGB bilinear, vignetting 0.3, "
              f"distortion -0.05, jpeg_quality 90): {best['hardware'][0]:7.2f} / {best['hardware'][1]:7.2f}")
        print(f"{width}x{height}: scenes/default.toml's camera (psf_sigma {paper.psf_sigma}, {paper.bayer} "
              f"{paper.demosaic}, vignetting {paper.vignetting}, distortion {paper.distortion}, jpeg_quality "
              f"{paper.jpeg_quality}): {best['paper'][0]:7.2f} / {best['paper'][1]:7.2f}")


if __name__ == "__main__":
    main()
