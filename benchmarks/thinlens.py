"""The camera's defocus in image space against Mitsuba's traced thin lens: error over the camera's
noise and seconds per capture, side by side in one run.

On the default setup (scenes/default.toml: 960x640 camera 1.12 m from the surface centre,
focused at 0.6 m as the camera-defocus study focuses it), for each aperture radius of that
study, a central window of the camera (:func:`sim.fidelity.window_setup`, the pixels seeing what
they see in the full image) renders probe frames (:func:`sim.fidelity.probe_frame`: a dataset's
natural frame and independent random pixels) three ways:

- the reference: Mitsuba's ``thinlens`` sensor (``camera.defocus = "ray"``) at ``--ref-spp``, as
  two renders of half as many samples (their difference gives its own Monte-Carlo error, which
  is removed: :func:`sim.fidelity.unbiased_rmse`);
- ``image`` at the pinhole's spp (``--spp``): the pinhole render, each pixel's light spread over
  its disk (:mod:`sim.camera.thinlens`);
- ``ray`` at 64 and 256 spp, the samples a traced lens gets in a dataset.

Errors (``image`` per class, ``ray`` the worse class) are RMS in linear signal units (radiance
times the exposure the exposure rule sets on the window), over the window's pixels farther than
the largest disk radius from its border, and given as a multiple of the camera's own noise there
(:func:`sim.fidelity.noise_floor`): ``auto`` accepts a level at 1x or less. Seconds are per full 960x640 capture, projector and ambient
(``image``: the pinhole render plus the spreading, timed alone as ``blur s``).

    .venv/bin/python benchmarks/thinlens.py [--window 128] [--ref-spp 4096] [--spp 16] [--radii R,...]
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from sim import camera, fidelity, seeds
from sim.render import Renderer
from sim.setup import load_setup

APERTURES = (0.0005, 0.00125, 0.0025, 0.005, 0.01)
"""Metres: a sub-pixel disk (f/40 on the study's 39 mm lens), then the camera-defocus study's
radii (f/16 to f/2)."""
FOCUS = 0.6
"""Metres: the study's focus distance."""
CLASSES = ("natural", "random")


def _lens(setup, radius: float, model: str, spp: int):
    return replace(setup, camera=replace(setup.camera, aperture_radius=radius, focus_distance=FOCUS,
                                         defocus=model),
                   render=replace(setup.render, spp=spp, ambient_spp=spp))


def _signal(radiance: np.ndarray, cfg) -> np.ndarray:
    return camera.sensor_signal(radiance, cfg.exposure, cfg.white_balance)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--setup", default="scenes/default.toml")
    ap.add_argument("--window", type=int, default=128, help="camera window side, pixels")
    ap.add_argument("--ref-spp", type=int, default=4096, help="samples per pixel of the reference")
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel of the image model")
    ap.add_argument("--radii", default=",".join(map(str, APERTURES)),
                    help="comma-separated aperture radii, metres")
    args = ap.parse_args()
    full = load_setup(args.setup)
    window = fidelity.window_setup(full, args.window)
    # the exposure the rule sets, measured on the window (a pinhole, the projector white and black)
    preview = Renderer(_lens(window, 0.0, "image", 64))
    w, h = full.projector.resolution
    white, black = (preview.radiance(np.full((h, w, 3), v, np.uint8), seeds.mitsuba_seed(0, seeds.EXPOSURE, i))
                    for i, v in enumerate((255, 0)))
    exposure = camera.rule_exposure(white, black, window.camera)["exposure"]
    window = replace(window, camera=replace(window.camera, exposure=exposure))
    frames = {k: fidelity.probe_frame(k, (w, h), 0) for k in CLASSES}
    print(f"# {args.setup}: window {window.camera.resolution[0]}x{window.camera.resolution[1]} of "
          f"{full.camera.resolution[0]}x{full.camera.resolution[1]}, focus {FOCUS} m, reference "
          f"thinlens {args.ref_spp} spp; error = worst class RMS / camera noise (auto accepts <= 1)")
    print(f"| aperture radius (m) | disk (camera px) | image, {args.spp} spp: natural / random | "
          "ray, 64 spp | ray, 256 spp | image s | blur s | ray 256 s | ray / image |")
    print("|---|---|---|---|---|---|---|---|---|")
    for radius in (float(r) for r in args.radii.split(",")):
        ref = Renderer(_lens(window, radius, "ray", fidelity.half_spp(args.ref_spp)))
        image = Renderer(_lens(window, radius, "image", args.spp))
        rays = {n: Renderer(_lens(window, radius, "ray", n)) for n in (64, 256)}
        d = image.camera_defocus.diameters
        edge = int(np.ceil(d.max() / 2)) + 1
        inner = (slice(edge, -edge), slice(edge, -edge))
        worst = {"image": 0.0, 64: 0.0, 256: 0.0}
        per_class = {}
        for i, (kind, frame) in enumerate(frames.items()):
            irr = ref.emit(frame)
            halves = [_signal(ref.projector_radiance(irr, 100 + 2 * i + j) + ref.ambient_radiance(),
                              window.camera)[inner] for j in range(2)]
            floor = fidelity.noise_floor(0.5 * (halves[0] + halves[1]), window.camera)
            for name, r in (("image", image), *rays.items()):
                sig = _signal(r.projector_radiance(irr, 7 + i) + r.ambient_radiance(), window.camera)[inner]
                err = fidelity.unbiased_rmse(sig, *halves) / floor
                worst[name] = max(worst[name], err)
                if name == "image":
                    per_class[kind] = err
        # seconds per full-size capture
        frame = frames["natural"]
        timed = {}
        for name, model, spp in (("image", "image", args.spp), ("ray", "ray", 256)):
            r = Renderer(_lens(full, radius, model, spp))
            r.ambient_radiance()
            r.radiance(frame, 1)  # compiles
            t0 = time.perf_counter()
            r.radiance(frame, 2)
            timed[name] = time.perf_counter() - t0
            if model == "image":
                sharp = r.transport_radiance(r.emit(frame), 3)
                t0 = time.perf_counter()
                r.camera_defocus(sharp)
                timed["blur"] = time.perf_counter() - t0
        print(f"| {radius:g} | {d.min():.1f}-{d.max():.1f} | "
              f"{' / '.join(f'{per_class[k]:.2f}x' for k in CLASSES)} | {worst[64]:.2f}x | "
              f"{worst[256]:.2f}x | {timed['image']:.2f} | {timed['blur']:.3f} | {timed['ray']:.2f} | "
              f"{timed['ray'] / timed['image']:.1f}x |", flush=True)


if __name__ == "__main__":
    main()
