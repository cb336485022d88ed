"""Projector-stage benchmark: the cost of the scaler, lens PSF and depth-dependent defocus at the
paper's hardware (800x600 DLP panel, 256x256 input frames, 960x640 camera, surface about 1 m away,
500 mm baseline), as ratios measured side by side in one run.

Each configuration emits the same frames (:meth:`sim.render.Renderer.emit`: scaler, response,
lens); times are the median over ``--n`` frames. Ratios are to the stage with every effect off
(the frame stretched to the panel, a sharp lens), and to the camera model on a 960x640 capture
(:func:`sim.camera.capture`) as a yardstick of the per-capture work after rendering.

    .venv/bin/python benchmarks/projector.py [--n 20] [--surface corner]
"""
from __future__ import annotations

import argparse
import time

import numpy as np

from sim import camera, images, projector, seeds
from sim.projector import lens_for
from sim.setup import parse_setup

PAPER = {
    "name": "paper_projector",
    # a corner makes the depth (and the defocus) vary over the panel; "plane" for a flat wall
    "surface": {"geometry": "corner", "size": [1.6, 1.2], "texture": "uniform"},
    # 800x600 DLP panel; 30 degrees across at 1 m covers about 0.54 m
    "projector": {"resolution": [800, 600], "fov": 30.0, "position": [0.0, 0.0, 1.0]},
    # 960x640 camera, 500 mm beside the projector (the paper's baseline)
    "camera": {"resolution": [960, 640], "fov": 40.0, "position": [0.5, 0.0, 1.0]},
}
EFFECTS = {
    "off (stretch, sharp)": {"keep_aspect": False},
    "scaler (keep aspect)": {},
    "scaler + PSF (sigma 0.7 px)": {"psf_sigma": 0.7},
    # a 10 mm aperture (about a 20 mm f/2 projection lens) focused at the corner's edge
    "scaler + defocus (10 mm aperture)": {"aperture": 0.01, "focus_distance": 1.0},
    "scaler + PSF + defocus": {"psf_sigma": 0.7, "aperture": 0.01, "focus_distance": 1.0},
}


def emit_seconds(setup, frames: np.ndarray) -> tuple[float, int, float]:
    """Median seconds per frame of the projector stage, the lens padding, and the largest disk."""
    p = setup.projector
    lens = lens_for(setup)
    times = []
    for frame in frames:
        t0 = time.perf_counter()
        x = projector.scale_to_panel(frame.astype(np.float32) / 255, p.resolution, p.keep_aspect)
        lens.apply(projector.projector_irradiance(np.clip(x, 0.0, 1.0), p))
        times.append(time.perf_counter() - t0)
    largest = float(lens.diameters.max()) if lens.diameters is not None else 0.0
    return float(np.median(times)), lens.pad, largest


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=20, help="frames to time per configuration")
    ap.add_argument("--surface", default="corner", choices=("corner", "plane"))
    args = ap.parse_args()
    frames = images.projector_frames(args.n, (256, 256), seed=123)
    base = {**PAPER, "surface": {**PAPER["surface"], "geometry": args.surface}}

    cam_setup = parse_setup(base, "<benchmark>")
    rng = seeds.noise_rng(0, seeds.TEST, 0)
    radiance = np.random.default_rng(0).random((640, 960, 3), dtype=np.float32) * 0.8
    cam_times = []
    for _ in range(args.n):
        t0 = time.perf_counter()
        camera.capture(radiance, cam_setup.camera, rng)
        cam_times.append(time.perf_counter() - t0)
    cam_s = float(np.median(cam_times))

    rows = []
    for label, keys in EFFECTS.items():
        setup = parse_setup({**base, "projector": {**base["projector"], **keys}}, "<benchmark>")
        rows.append((label, *emit_seconds(setup, frames)))
    off = rows[0][1]
    print(f"projector stage, 800x600 panel, 256x256 frames, {args.surface}; median of {args.n} frames")
    print(f"{'configuration':36s} {'ms':>8s} {'x off':>7s} {'x camera':>9s} {'pad px':>7s} {'max disk px':>12s}")
    for label, sec, pad, largest in rows:
        print(f"{label:36s} {1e3 * sec:8.2f} {sec / off:7.2f} {sec / cam_s:9.2f} {pad:7d} {largest:12.2f}")
    print(f"{'camera model, 960x640 (yardstick)':36s} {1e3 * cam_s:8.2f}")


if __name__ == "__main__":
    main()
