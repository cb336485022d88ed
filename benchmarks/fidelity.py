"""Fidelity benchmark: captures per second of each level at 256², the calibration cost of
``transport``, and the time of the 24-setup suite (126 + 500 + 200 captures each) with ``auto``
against all-``direct`` at 16 spp — measured on a subset of the suite and extrapolated.

    .venv/bin/python benchmarks/fidelity.py [--n 20] [--subset 4] [--captures 40]

Per level: ``n`` captures of the default setup (and the corner for ``path``) through the whole
Simulator (render + camera model + registration warp; PNG writing excluded). Suite: ``subset``
setups of ``scenes/suite.toml`` (evenly spaced, so every pose appears) are written with
``sim.dataset.write_setup`` — 126 reference frames plus ``captures`` train/test frames each — once
with ``auto`` and once with ``direct`` at 16 spp; per mode the one-time cost (``auto``'s
measurement, scene and calibration) and the per-capture cost (everything else, PNGs included) are
averaged over the subset and extrapolated to 24 setups × 826 captures.
"""
from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from sim import images
from sim.capture import Simulator
from sim.dataset import FrameSpec, write_setup
from sim.fidelity import DATASET_CAPTURES
from sim.setup import load_setups

SIZE = (256, 256)


def captures_per_second(setup, level: str | None, spp: int | None, n: int) -> dict:
    """Time ``n`` captures (render + camera + warp) after one that compiles the kernels."""
    frames = images.projector_frames(n + 1, SIZE, seed=321)
    t0 = time.perf_counter()
    sim = Simulator(setup, SIZE, level, spp)
    setup_s = time.perf_counter() - t0
    sim.warp(sim.raw(frames[0], 50, 0))
    sim.timings.clear()
    t0 = time.perf_counter()
    for k, f in enumerate(frames[1:], start=1):
        sim.warp(sim.raw(f, 50, k))
    total = time.perf_counter() - t0
    r = sim.renderer
    level = f"auto -> {r.fidelity}" if level == "auto" else r.fidelity
    return {"setup": setup.name, "level": level, "spp": r.spp, "captures_per_s": n / total,
            "render_ms": 1000 * sim.timings["render"] / n, "camera_ms": 1000 * sim.timings["camera"] / n,
            "one_time_s": setup_s,
            "calibration_s": r.operator.info.seconds if r.fidelity == "transport" else None}


def suite_subset(setups, n: int) -> list:
    """``n`` setups evenly spaced through the suite."""
    idx = np.unique(np.linspace(0, len(setups) - 1, n).round().astype(int))
    return [setups[i] for i in idx]


def time_suite(setups, mode: str, captures: int, root: Path) -> dict:
    """Write each setup with ``mode`` ("auto" or "direct16"); one-time and per-capture seconds."""
    spec = FrameSpec(n_train=captures // 2, n_test=captures - captures // 2, size=SIZE)
    fidelity, spp = ("auto", None) if mode == "auto" else ("direct", 16)
    one_time, per_capture, choices = [], [], []
    for s in setups:
        out = write_setup(root / mode, s, spec, fidelity, spp, progress=False)
        meta = json.loads((out / "meta.json").read_text())
        t = meta["timings_s"]
        once = t.get("fidelity", 0.0) + t["scene"]
        one_time.append(once)
        per_capture.append((t["total"] - once) / meta["captures_this_run"])
        choices.append(f"{meta['fidelity']} {meta['spp']}")
    return {"one_time_s": float(np.mean(one_time)), "per_capture_s": float(np.mean(per_capture)),
            "choices": choices}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=20, help="timed captures per level")
    ap.add_argument("--subset", type=int, default=4, help="suite setups timed")
    ap.add_argument("--captures", type=int, default=40, help="train + test captures per timed setup")
    args = ap.parse_args()
    default, corner = load_setups("default")[0], load_setups("corner")[0]

    rows = [captures_per_second(default, "path", 16, args.n),
            captures_per_second(default, "direct", 16, args.n),
            captures_per_second(default, "transport", 16, args.n),
            captures_per_second(default, "auto", None, args.n),
            captures_per_second(corner, "path", 16, args.n),
            captures_per_second(corner, "auto", None, args.n)]
    print(f"Captures per second at 256² (render + camera model + warp; {args.n} captures, PNG excluded)\n")
    print("| setup | level | spp | captures/s | render ms | camera ms | one-time s | calibration s |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        cal = f"{r['calibration_s']:.1f}" if r["calibration_s"] is not None else ""
        print(f"| {r['setup']} | {r['level']} | {r['spp']} | {r['captures_per_s']:.1f} | "
              f"{r['render_ms']:.1f} | {r['camera_ms']:.1f} | {r['one_time_s']:.1f} | {cal} |")

    setups = load_setups("suite")
    subset = suite_subset(setups, args.subset)
    n_cap = 126 + args.captures
    with tempfile.TemporaryDirectory() as tmp:
        timed = {mode: time_suite(subset, mode, args.captures, Path(tmp)) for mode in ("auto", "direct16")}
    print(f"\nSuite: {len(subset)} of {len(setups)} setups timed ({', '.join(s.name for s in subset)}), "
          f"{n_cap} captures each (PNGs written), extrapolated to {len(setups)} x {DATASET_CAPTURES}\n")
    print("| mode | choices | one-time s/setup | s/capture | suite total (extrapolated) |")
    print("|---|---|---|---|---|")
    total = {}
    for mode, t in timed.items():
        total[mode] = len(setups) * (t["one_time_s"] + DATASET_CAPTURES * t["per_capture_s"])
        print(f"| {mode} | {', '.join(t['choices'])} | {t['one_time_s']:.1f} | {t['per_capture_s']:.3f} | "
              f"{total[mode] / 60:.1f} min |")
    print(f"\nauto is {total['direct16'] / total['auto']:.2f}x faster than all-direct 16 spp over the suite")


if __name__ == "__main__":
    main()
