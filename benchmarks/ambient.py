"""Ambient-image benchmark: render time and Monte-Carlo error of the room-light image, for MIS
(emitter + BSDF sampling, Mitsuba's ``direct`` default) and BSDF sampling alone (procam's
``direct`` ambient since it was measured here), side by side in one run.

The error is against a BSDF-sampled render at ``--ref-spp`` with another seed, relative to the
mean ambient radiance and, absolute, beside the camera's noise at the image's mean signal (the
noise of one capture, in the same radiance units: after dividing by the exposure).

    .venv/bin/python benchmarks/ambient.py [--setup default] [--spps 16,64,256] [--ref-spp 1024]
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np

from sim import scene
from sim.camera import noise_sigma
from sim.setup import load_setups
from sim.variant import use_variant


def render(setup, albedo, mis: bool, spp: int, seed: int) -> tuple[np.ndarray, float]:
    """The ambient image at ``spp`` as :func:`sim.scene.ambient_scene` renders it (BSDF
    sampling), or with Mitsuba's plain ``direct`` integrator (``mis``), and its render seconds."""
    import mitsuba as mi

    d = scene.ambient_scene(setup, albedo, "direct", spp)
    if mis:
        d["integrator"] = scene.integrator_for(setup, "direct")
    sc = mi.load_dict(d)
    t0 = time.perf_counter()
    img = np.array(mi.render(sc, seed=seed), dtype=np.float32)
    return img, time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--setup", default="default")
    ap.add_argument("--spps", default="16,64,256")
    ap.add_argument("--ref-spp", type=int, default=1024)
    ap.add_argument("--exposure", type=float, default=2.0,
                    help="camera exposure the noise is taken at (the default setup's rule gives ~2)")
    args = ap.parse_args()
    use_variant(None)
    setup = load_setups(args.setup)[0]
    setup = replace(setup, render=replace(setup.render, fidelity="direct"))
    albedo = scene.albedo_texture(setup)
    for mis in (True, False):  # compile both kernels before timing
        render(setup, albedo, mis, 4, 0)
    ref, ref_s = render(setup, albedo, False, args.ref_spp, 99)
    cam = setup.camera
    mean = float(ref.mean())
    sigma = float(noise_sigma(mean * args.exposure, cam.shot_noise, cam.read_noise)) / args.exposure
    w, h = cam.resolution
    print(f"ambient image of {setup.name!r}, {w}x{h}, mean radiance {mean:.3g}; camera noise at that "
          f"signal {sigma:.3g} (exposure {args.exposure:g}); reference: BSDF sampling, "
          f"{args.ref_spp} spp ({ref_s:.1f} s)")
    print(f"{'sampling':<8} {'spp':>5} {'seconds':>8} {'rms error':>10} {'relative':>9} {'x noise':>8}")
    for name, mis in (("MIS", True), ("BSDF", False)):
        for spp in (int(s) for s in args.spps.split(",")):
            img, seconds = render(setup, albedo, mis, spp, 7)
            err = float(np.sqrt(np.mean((img - ref) ** 2)))
            print(f"{name:<8} {spp:>5} {seconds:>8.2f} {err:>10.3g} {err / mean:>9.4f} {err / sigma:>8.4f}")


if __name__ == "__main__":
    main()
