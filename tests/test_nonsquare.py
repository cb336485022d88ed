"""Width and height kept apart end to end: render → train every method → compensate → closed loop
at a non-square canonical view (48x32) gives each method the same gain over uncompensated as the
square view (48x48) of the same setup."""
from __future__ import annotations

import numpy as np
import pytest
from helpers import tiny_setup

from compensation.cli import main
from compensation.data import load_setup_data
from compensation.experiments.closed_loop import closed_loop, simulator_for
from compensation.methods import METHODS, applicable, make_config
from compensation.methods.compennet import native_bf16
from compensation.experiments.runs import load_run, train_run
from compensation.experiments.targets import TargetPolicy
from sim.dataset import FrameSpec, write_setup
from sim.io import read_json, read_png, write_png

SIZES = {"square": (48, 48), "wide": (48, 32)}
"""Canonical (width, height) views of one setup."""
SMALL = dict(n_train=16, n_test=4, iters=100, batch=8, device="cpu", amp=native_bf16())
"""A budget of seconds per method (options a method does not take are dropped): CompenNet trains in
bf16 where the CPU computes it natively (its step 1.6x faster at this size on one thread; the
module 113 → 94 s alone), which changes no conclusion below."""
PIX2PIX_ITERS = 30
"""pix2pix's iterations: at 30 as at 100 it stays below uncompensated on both views (measured
surrogate gain −1.8 / −1.4 dB square / wide at 30, −1.5 / −1.2 at 100), so only the equality of the
views is asked of it, which 30 iterations test as well, in a third of the time."""
COMPENNET_SEEDS = (0, 1, 2)
"""CompenNet's gain is the median over these training seeds: at this budget one start in a few
ends with dead units and no gain (seed 0 of CompenNet at 48x32: loss stuck at 0.70, the other
seeds +4.0 to +4.2 dB surrogate), which says nothing about width and height."""
AS_IS = TargetPolicy("none")
"""The closed loop against the desired images themselves (the gains compare views of one setup)."""
SAME_GAIN_DB = 1.5
"""How far the non-square gain over uncompensated may fall below the square one (surrogate and
closed loop). Measured differences: at most 0.5 dB at 48x32 (0.7 dB at 64x48). Before
width and height were kept apart, TPS lost 11.6 dB of its surrogate gain at 64x48."""


@pytest.fixture(scope="module")
def gains(tmp_path_factory):
    """Per view and method: surrogate and closed-loop PSNR gains over uncompensated (dB)."""
    setup = tiny_setup(surface={"texture": "noise", "texture_seed": 3},
                       camera={"resolution": [80, 80]},
                       ambient={"radiance": [0.05, 0.05, 0.05]})
    out = {}
    for view, size in SIZES.items():
        root = tmp_path_factory.mktemp(view)
        setup_dir = write_setup(root / "data", setup, FrameSpec(SMALL["n_train"], SMALL["n_test"], size),
                                progress=False)
        data = load_setup_data(setup_dir)
        assert data.size == (size[1], size[0])  # tensors are (H, W)
        sim = simulator_for(setup_dir)
        plain = closed_loop(_Identity(), data, sim, policy=AS_IS)["psnr"]
        out[view] = {"dir": setup_dir, "runs": {}}
        for name in sorted(METHODS):
            seeds = COMPENNET_SEEDS if name.startswith("compennet") else (0,)
            found = []
            for seed in seeds:
                run = root / "runs" / f"{name}-seed{seed}"
                budget = {**SMALL, "seed": seed, **({"iters": PIX2PIX_ITERS} if name == "pix2pix" else {})}
                cfg = make_config("quick", name, **applicable(name, budget))
                metrics = train_run(setup_dir, cfg, run, progress=False)
                method, _ = load_run(run)
                found.append((metrics["psnr"] - metrics["uncompensated"]["psnr"],
                              closed_loop(method, data, sim, policy=AS_IS)["psnr"] - plain))
            out[view][name] = tuple(float(np.median(g)) for g in zip(*found))
            out[view]["runs"][name] = root / "runs" / f"{name}-seed0"
    return out


class _Identity:
    """Projects y as is (the uncompensated closed-loop baseline)."""

    def predict(self, captures, surface, batch_size=64):
        return captures


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(METHODS))
def test_same_gain_as_the_square_view(gains, name):
    (sur_sq, cl_sq), (sur_w, cl_w) = gains["square"][name], gains["wide"][name]
    assert sur_w > sur_sq - SAME_GAIN_DB, (name, sur_sq, sur_w)
    assert cl_w > cl_sq - SAME_GAIN_DB, (name, cl_sq, cl_w)


@pytest.mark.slow
def test_every_method_gains_on_the_wide_view(gains):
    """Not only equal: the per-pixel methods and CompenNet compensate at 48x32. Measured
    (surrogate dB): TPS +10.2, TPS textured +8.7, Nayar +10.4 (closed loop +1.8 to +1.9);
    CompenNet +3.7, w/o surf +3.9 after 100 iterations in bf16 (medians of the seeds; a dead start
    of seed 0 at −0.2); most of this surface's desired pixels are out of the projector's reach,
    which bounds every closed-loop gain. pix2pix, with a budget of seconds, does not beat
    uncompensated and is only required to match its square self above."""
    for name in ("tps", "tps-textured", "nayar"):
        assert gains["wide"][name][0] > 7.0 and gains["wide"][name][1] > 1.0, (name, gains["wide"][name])
    for name in ("compennet", "compennet-nosurf"):
        assert gains["wide"][name][0] > 1.0, (name, gains["wide"][name])


@pytest.mark.slow
def test_records_and_compensate_keep_width_and_height(gains, tmp_path):
    setup_dir, run = gains["wide"]["dir"], gains["wide"]["runs"]["tps"]
    meta = read_json(setup_dir / "meta.json")
    assert (meta["width"], meta["height"]) == (48, 32)
    assert read_json(run / "config.json")["image_size"] == {"width": 48, "height": 32}
    desired = tmp_path / "desired.png"
    write_png(desired, np.full((64, 96, 3), 128, np.uint8))  # resized to the run's 48x32
    assert main(["compensate", str(run), str(desired), "--out", str(tmp_path / "frame.png")]) == 0
    assert read_png(tmp_path / "frame.png").shape == (32, 48, 3)
