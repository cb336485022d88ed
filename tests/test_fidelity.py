"""The fidelity ladder: the camera's noise floor, the measured `auto` choice, clear refusals, and
what a dataset records about its level."""
from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from helpers import tiny_setup, tiny_toml
from sim import camera, geometry
from sim.capture import Simulator
from sim.dataset import FrameSpec, write_setup
from sim.errors import SetupError
from sim.fidelity import (Probe, check_level, choose, noise_floor, probe_frame, resolve,
                          window_setup)

NOISY = {"shot_noise": 2e-4, "read_noise": 2e-3}
CORNER = {"geometry": "corner", "size": [0.6, 1.0]}


def test_noise_floor_matches_simulated_captures():
    """The predicted RMS camera noise (sensor + 8-bit quantisation, linear units) matches real
    simulated captures of a flat grey, decoded back to linear, within 10 %."""
    cfg = tiny_setup(camera=NOISY).camera
    signal = np.full((256, 256, 3), 0.3, np.float32)
    raw = camera.capture(signal, cfg, np.random.default_rng(0))
    measured = np.sqrt(np.mean((camera.decode(raw / 255.0, cfg.response) - signal) ** 2))
    assert noise_floor(signal, cfg) == pytest.approx(measured, rel=0.1)


def test_window_keeps_every_pixel_ray():
    """The central window of the camera sees exactly what those pixels see in the full image."""
    setup = tiny_setup(camera={"resolution": [96, 80]})
    win = window_setup(setup, 32)
    assert win.camera.resolution == (32, 32)
    full = geometry.Pinhole.from_config(setup.camera).pixel_rays()
    part = geometry.Pinhole.from_config(win.camera).pixel_rays()
    np.testing.assert_allclose(part, full[24:56, 32:64], atol=1e-12)


@pytest.mark.parametrize("kind", ["smooth", "stripes1", "stripes2", "random", "natural"])
def test_probe_frames(kind):
    frame = probe_frame(kind, (48, 32), seed=1)
    assert frame.shape == (32, 48, 3) and frame.dtype == np.uint8
    np.testing.assert_array_equal(frame, probe_frame(kind, (48, 32), seed=1))
    if kind.startswith("stripes"):
        w = int(kind[-1])
        assert frame[0, :2 * w, 0].tolist() == [255] * w + [0] * w


@pytest.mark.slow
def test_auto_picks_a_direct_light_level_for_a_plane():
    setup = tiny_setup(camera=NOISY, surface={"texture": "noise"}, render={"fidelity": "auto"})
    choice = resolve(setup)
    assert choice.level in ("transport", "direct")
    assert choice.predicted_error <= choice.noise_floor
    assert "direct light is exact" in choice.reason
    # cheaper candidates were tried first and failed
    tried = [c["spp"] for c in choice.candidates]
    assert tried[-1] == choice.spp and all(c["error_over_floor"] > 1 for c in choice.candidates[:-1])


@pytest.mark.slow
def test_auto_picks_path_depth_3_for_a_corner():
    setup = tiny_setup(camera=NOISY, surface=CORNER, projector={"position": [0.0, 0.0, 1.2]},
                       render={"fidelity": "auto", "max_depth": 3})
    probe = Probe(setup, classes=("smooth", "natural"))
    choice = choose(setup, probe=probe)
    assert choice.level == "path" and setup.render.max_depth >= 3
    assert "light each other" in choice.reason
    # direct light would be biased: its error stays above the floor whatever the spp
    from sim.render import Renderer

    direct = Renderer(replace(probe.setup, render=replace(probe.setup.render, max_depth=2)), "path", 256)
    errors = probe.errors(direct)
    assert errors["smooth"]["rmse"] > probe.floors["smooth"]


def test_each_level_refuses_what_it_cannot_represent():
    corner = tiny_setup(surface=CORNER, render={"fidelity": "path", "max_depth": 3})
    for level in ("direct", "transport"):
        with pytest.raises(SetupError, match="inter-reflection"):
            check_level(corner, level)
        with pytest.raises(SetupError, match=f'fidelity "{level}" cannot represent'):
            Simulator(corner, (32, 32), fidelity=level)
    shallow = replace(corner, render=replace(corner.render, max_depth=2))
    with pytest.raises(SetupError, match="max_depth = 2"):
        check_level(shallow, "path")
    with pytest.raises(SetupError, match="expected one of 'auto', 'path', 'direct', 'transport'"):
        check_level(corner, "fast")


@pytest.mark.slow
def test_dataset_records_the_choice_and_reuses_the_operator(tmp_path):
    setup = tiny_setup(camera=NOISY, render={"fidelity": "auto"})
    spec = FrameSpec(n_train=2, n_test=1, size=(32, 32))
    out = write_setup(tmp_path, setup, spec, progress=False)
    meta = json.loads((out / "meta.json").read_text())
    choice = meta["fidelity_choice"]
    assert meta["fidelity"] == choice["level"] == "transport" and meta["spp"] == choice["spp"]
    assert choice["predicted_error"] <= choice["noise_floor"] and "noise" in choice["reason"]
    assert meta["transport"]["verify_error"] < 1e-4 and not meta["transport"]["loaded_from_cache"]
    assert meta["timings_s"]["fidelity"] > 0
    # more captures: the setup is re-opened and the calibrated operator read back
    out = write_setup(tmp_path, setup, replace(spec, n_train=3), progress=False)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["transport"]["loaded_from_cache"] and meta["counts"]["train"] == 3


@pytest.mark.slow
def test_cli_render_transport_and_bench_sim(tmp_path, capsys):
    from compensation.cli import main

    path = tmp_path / "tinycli.toml"
    path.write_text(tiny_toml("tinycli", 32, render={"fidelity": "auto"}))
    args = ["--size", "16", "--n-train", "1", "--n-test", "1", "--quiet"]
    assert main(["render", str(path), "--out", str(tmp_path / "data"), "--fidelity", "transport", *args]) == 0
    meta = json.loads((tmp_path / "data" / "tinycli" / "meta.json").read_text())
    assert meta["fidelity"] == "transport" and meta["spp"] == 4 and meta["transport"]["spacing"] >= 1
    assert meta["fidelity_choice"]["reason"] == "asked for (--fidelity)"

    assert main(["bench-sim", str(path), "--out", str(tmp_path / "bench"), "--ref-spp", "64",
                 "--classes", "smooth,stripes1", "--spp", "4,16", "--repeats", "1", "--quiet"]) == 0
    rows = (tmp_path / "bench" / "bench_sim_tinycli.csv").read_text().splitlines()
    assert rows[0].startswith("setup,level,spp,class,seconds_per_capture")
    assert len(rows) == 1 + 3 * 2 * 2  # levels x spp x classes
    assert (tmp_path / "bench" / "bench_sim_tinycli.png").stat().st_size > 10_000
    assert "procam: for tinycli, transport at" in capsys.readouterr().out
    assert main(["bench-sim", str(path), "--out", str(tmp_path / "bench"), "--classes", "stripes3"]) == 2
