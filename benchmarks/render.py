"""Render benchmark: captures/second of a setup, the split between phases, and the Monte-Carlo
noise of its spp against a 1024-spp render — measured side by side in one run.

The level is the setup's own (``auto`` resolved as in a dataset render); a ``transport`` operator
is compared with the 1024-spp ``direct`` render it is calibrated from.

    .venv/bin/python benchmarks/render.py [--setup default] [--size 256] [--n 30]
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from sim import camera, images
from sim.capture import Simulator
from sim.dataset import FrameSpec, write_setup
from sim.io import write_png
from sim.render import Renderer
from sim.setup import load_setups


def psnr(a: np.ndarray, b: np.ndarray, peak: float) -> float:
    return float(10 * np.log10(peak**2 / np.mean((a - b) ** 2)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--setup", default="default")
    ap.add_argument("--size", type=int, default=256)
    ap.add_argument("--n", type=int, default=30, help="captures to time")
    args = ap.parse_args()
    setup = load_setups(args.setup)[0]
    size = (args.size, args.size)
    frames = images.projector_frames(args.n + 1, size, seed=123)

    sim = Simulator(setup, size)
    sim.raw(frames[0], 50, 0)  # compile kernels once
    sim.timings.clear()
    png = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        t_all = time.perf_counter()
        for k, f in enumerate(frames[1:], start=1):
            raw = sim.raw(f, 50, k)
            warped = sim.warp(raw)
            t0 = time.perf_counter()
            write_png(Path(tmp) / "raw.png", raw)
            write_png(Path(tmp) / "warp.png", warped)
            png += time.perf_counter() - t0
        total = time.perf_counter() - t_all
    phases = {"render (Mitsuba)": sim.timings["render"], "camera model": sim.timings["camera"],
              "registration (warp)": sim.timings["registration"], "PNG writing": png}
    r = sim.renderer
    print(f"setup {setup.name}: variant {r.variant}, {r.fidelity}, {r.spp} spp, camera "
          f"{setup.camera.resolution[0]}x{setup.camera.resolution[1]}, canonical {args.size}²")
    print(f"\n{'phase':<22}{'ms/capture':>12}{'share':>8}")
    for name, sec in phases.items():
        print(f"{name:<22}{1000 * sec / args.n:>12.1f}{sec / total:>8.0%}")
    print(f"{'total':<22}{1000 * total / args.n:>12.1f}{'':>8}   -> {args.n / total:.1f} captures/s")

    with tempfile.TemporaryDirectory() as tmp:  # the same work in the dataset writer's pipeline
        setup_dir = write_setup(Path(tmp), setup, FrameSpec(args.n, 1, size), progress=False)
        meta = json.loads((setup_dir / "meta.json").read_text())
    t = meta["timings_s"]
    loop = t["total"] - t["fidelity"] - t["scene"]  # without the one-time scene set-up
    print(f"dataset writer, {meta['capture_workers']} worker threads for camera/warp/PNG: "
          f"{meta['captures_this_run']} captures in {loop:.1f} s after {t['total'] - loop:.1f} s set-up "
          f"-> {meta['captures_this_run'] / loop:.1f} captures/s ({meta['captures_this_run'] / loop * total / args.n:.2f}x "
          "the sequential loop above)")

    ref_level = "direct" if r.fidelity == "transport" else r.fidelity
    ref = Renderer(setup, ref_level, 1024)
    rows = []
    for k, f in enumerate(frames[1:4]):
        lo, hi = r.radiance(f, seed=900 + k), ref.radiance(f, seed=990 + k)
        peak = float(hi.max())
        noiseless = lambda x: camera.encode(np.clip(x * setup.camera.exposure *  # noqa: E731
                                                    np.asarray(setup.camera.white_balance), 0, 1),
                                            setup.camera.response)
        mc_8bit = np.std(255 * (noiseless(lo) - noiseless(hi)))
        signal = np.clip(hi * setup.camera.exposure, 0, 1)
        cam_sigma = np.sqrt(np.mean(camera.noise_sigma(signal, setup.camera.shot_noise,
                                                       setup.camera.read_noise) ** 2))
        rows.append((psnr(lo, hi, peak), float(np.std(lo - hi)), float(cam_sigma), mc_8bit))
    lin_psnr, mc_sigma, cam_sigma, mc_8bit = np.mean(rows, axis=0)
    print(f"\nMonte-Carlo noise of {r.fidelity} at {r.spp} spp against {ref_level} at 1024 spp "
          "(3 frames, linear radiance):")
    print(f"  PSNR {lin_psnr:.1f} dB, sigma {mc_sigma:.2e}; camera noise sigma {cam_sigma:.2e} "
          f"(ratio MC/camera {mc_sigma / cam_sigma:.2f}); after the camera curve {mc_8bit:.2f} "
          "8-bit levels")


if __name__ == "__main__":
    main()
