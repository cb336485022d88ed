"""The camera's and the projector's chains of stages: every key belongs to a stage, each flag is
true of the stage's code, and what the flags give (the sensor alone, the streams version)."""
from __future__ import annotations

import dataclasses
import shutil
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers import tiny_setup

import sim
from sim import camera, projector, scatter, seeds
from sim.camera import chain as camera_chain
from sim.camera.noise import stream_version
from sim.options import number
from sim.projector import chain as projector_chain
from sim.projector import distortion, translucency
from sim.setup import CameraConfig, ProjectorConfig
from sim.setup.schema import CameraView, ProjectorView
from sim.stages import Stage, streams_version, switch_off

CHAINS = {"camera": (camera_chain, CameraConfig, CameraView),
          "projector": (projector_chain, ProjectorConfig, ProjectorView)}


@dataclasses.dataclass(frozen=True)
class KeyA:
    a: float = number(0.0)


@pytest.mark.parametrize("device", CHAINS)
def test_the_section_is_the_keys_of_no_stage_then_each_stage_s_keys(device):
    chain, cls, view = CHAINS[device]
    owners = [*(f.name for f in dataclasses.fields(view)), *(k for s in chain.STAGES for k in s.keys)]
    assert owners == [f.name for f in dataclasses.fields(cls)]
    assert len({s.name for s in chain.STAGES}) == len(chain.STAGES)
    assert len({item.name for item in chain.CHAIN}) == len(chain.CHAIN)


@pytest.mark.parametrize("device", CHAINS)
def test_switching_a_stage_off_gives_valid_values(device):
    """The values that switch a stage off are valid keys (schema defaults, mostly)."""
    chain, cls, _ = CHAINS[device]
    base = cls()
    for stage in chain.STAGES:
        if stage.off:
            off = switch_off(base, [stage])
            assert all(getattr(off, k) == v for k, v in stage.off.items())


def test_stage_rules():
    with pytest.raises(ValueError, match="no streams version"):
        Stage("x", KeyA, "", streams=lambda: 1)
    with pytest.raises(ValueError, match="must be able to be switched off"):
        Stage("x", KeyA, "", optical=True)
    with pytest.raises(ValueError, match="a processing stage must be able to be switched off"):
        Stage("x", KeyA, "", processing=True)
    with pytest.raises(ValueError, match="an optical stage does not process"):
        Stage("x", KeyA, "", optical=True, processing=True, off={"a": 0.0})
    with pytest.raises(ValueError, match="keys it does not read"):
        Stage("x", KeyA, "", off={"b": 0})
    with pytest.raises(ValueError, match="random, without a streams version"):
        streams_version([Stage("x", KeyA, "", random=True)])
    with pytest.raises(ValueError, match="cannot be switched off"):
        switch_off(CameraConfig(), [s for s in camera_chain.STAGES if s.name == "exposure"])


# ---------------------------------------------------------------------------------- camera

GAIN_STAGE = '''\
"""A toy camera effect: a gain on the radiance."""
from __future__ import annotations

from dataclasses import dataclass

from sim.options import POSITIVE, number
from sim.stages import Stage


@dataclass(frozen=True)
class GainOptions:
    """The key of the gain."""

    gain: float = number(1.0, POSITIVE)
    """Multiplier of the radiance (> 0)."""


def _gain(radiance, cfg, rng):
    return radiance * cfg.gain


GAIN = Stage("gain", GainOptions, "a gain on the radiance", _gain, linear=True, off={"gain": 1.0})
'''

GAIN_CHECK = """\
import tomllib
from dataclasses import replace

import numpy as np

import sim
from sim import camera
from sim.setup import SetupError, dump_setup, parse_setup

assert sim.__file__.startswith(ROOT), sim.__file__
setup = parse_setup({"name": "t", "camera": {"gain": 2, "resolution": [24, 16]}})
assert setup.camera.gain == 2.0
text = dump_setup(setup)
assert "gain = 2.0" in text and parse_setup(tomllib.loads(text)) == setup
try:
    parse_setup({"name": "t", "camera": {"gain": -1}}, "t.toml")
except SetupError as exc:
    assert str(exc) == "t.toml: camera.gain = -1: expected a number > 0", exc
else:
    raise AssertionError("gain = -1 accepted")
assert [s.name for s in camera.STAGES if s.linear][4] == "gain"
rad = np.random.default_rng(0).uniform(0, 0.4, (16, 24, 3)).astype(np.float32)
doubled = camera.capture(rad, setup.camera, np.random.default_rng(1))
plain = camera.capture(2 * rad, replace(setup.camera, gain=1.0), np.random.default_rng(1))
assert np.array_equal(doubled, plain)
assert not np.array_equal(doubled, camera.capture(rad, replace(setup.camera, gain=1.0), np.random.default_rng(1)))
print("ok")
"""


@pytest.mark.slow
def test_a_new_camera_stage_is_one_module_and_one_line_in_the_chain(tmp_path):
    """A copy of ``sim`` with a toy stage module (a gain with its own key) and one entry in the
    camera's chain: the key is validated, dumped and applied, with no other edit."""
    shutil.copytree(Path(sim.__file__).parent, tmp_path / "sim", ignore=shutil.ignore_patterns("__pycache__"))
    (tmp_path / "sim" / "camera" / "gain.py").write_text(GAIN_STAGE)
    chain_file = tmp_path / "sim" / "camera" / "chain.py"
    text = chain_file.read_text()
    for old, new in (("from sim.camera import glare, optics, raw, sensor\n",
                      "from sim.camera import gain, glare, optics, raw, sensor\n"),
                     ("    optics.VIGNETTING,\n", "    optics.VIGNETTING,\n    gain.GAIN,\n")):
        assert text.count(old) == 1
        text = text.replace(old, new)
    chain_file.write_text(text)
    check = f"ROOT = {str(tmp_path)!r}\n" + GAIN_CHECK
    done = subprocess.run([sys.executable, "-c", check], cwd=tmp_path, capture_output=True, text=True,
                          env={"PYTHONPATH": str(tmp_path), "OMP_WAIT_POLICY": "PASSIVE",
                               "PATH": "/usr/bin:/bin"}, timeout=300)
    assert done.returncode == 0 and done.stdout.strip() == "ok", done.stderr[-3000:]


HARDWARE = replace(CameraConfig(), resolution=(48, 32), psf_sigma=0.7, glare=0.02, distortion=-0.05,
                   vignetting=0.3, bayer="RGGB", jpeg_quality=90, white_balance=(1.1, 1.0, 0.9),
                   shot_noise=1e-3, read_noise=2e-3)


def test_the_optical_stages_are_what_the_fidelity_probe_switches_off():
    assert [s.name for s in camera.STAGES if s.optical] == ["psf", "glare", "distortion", "vignetting"]
    assert camera.without_optics(HARDWARE) == replace(HARDWARE, psf_sigma=0.0, glare=0.0, distortion=0.0,
                                                      vignetting=0.0)
    rad = np.random.default_rng(1).uniform(0, 1, (32, 48, 3)).astype(np.float32)
    assert camera.apply_optics(rad, camera.without_optics(HARDWARE)) is rad


def test_the_processing_stages_are_what_the_sensor_alone_also_switches_off():
    """The processing of the encoded image sits in the sensor's group between the response curve
    and the quantisation, is not linear, and is off for the sensor alone."""
    names = [s.name for s in camera.STAGES]
    assert [s.name for s in camera.STAGES if s.processing] == ["adaptive_tone", "style", "sharpen"]
    assert names[names.index("response"):] == ["response", "adaptive_tone", "style", "sharpen", "jpeg"]
    assert not any(s.linear or s.optical for s in camera.STAGES if s.processing)
    styled = replace(HARDWARE, adaptive_tone=0.5, style_contrast=0.3, style_saturation=1.2,
                     sharpen_amount=0.5)
    assert camera.sensor_alone(styled) == camera.without_optics(HARDWARE)
    assert all(s.is_off(camera.sensor_alone(styled)) for s in camera.STAGES if s.processing)


def test_the_noise_version_is_the_random_stages():
    assert [s.name for s in camera.STAGES if s.random] == ["noise"]
    assert camera.noise_version() == stream_version() in (2, 3)


def _linear_camera_stage(name: str):
    """The code of each camera stage flagged linear, alone."""
    only = {k: 0.0 for k in ("psf_sigma", "glare", "distortion", "vignetting")}
    optics = {"psf": {"psf_sigma": 0.7}, "glare": {"glare": 0.02}, "distortion": {"distortion": -0.05},
              "vignetting": {"vignetting": 0.3}}
    if name in optics:
        cfg = replace(HARDWARE, **{**only, **optics[name]})
        return lambda x: camera.apply_optics(x, cfg)
    return {"exposure": lambda x: camera.expose(x, 1.7, None, 0.0, 0.0, None),
            "mosaic": lambda x: camera.mosaic(x, "RGGB"),
            "white_balance": lambda x: x * np.float32([1.1, 1.0, 0.9])}[name]


def test_stages_flagged_linear_are_linear():
    rng = np.random.default_rng(2)
    x, y = (rng.uniform(0, 0.5, (32, 48, 3)).astype(np.float32) for _ in range(2))
    linear = [s.name for s in camera.STAGES if s.linear]
    assert linear == ["psf", "glare", "distortion", "vignetting", "exposure", "mosaic", "white_balance"]
    for name in linear:
        f = _linear_camera_stage(name)
        np.testing.assert_allclose(f(0.3 * x + 0.5 * y), 0.3 * f(x) + 0.5 * f(y), atol=1e-6, err_msg=name)


def test_only_the_random_stages_draw():
    """With every random stage switched off a capture does not depend on the generator, with
    every other stage on; with the noise on it does."""
    rad = np.random.default_rng(3).uniform(0, 0.8, (32, 48, 3)).astype(np.float32)
    quiet = switch_off(HARDWARE, [s for s in camera.STAGES if s.random])
    a, b = (camera.capture(rad, quiet, np.random.default_rng(seed)) for seed in (0, 1))
    np.testing.assert_array_equal(a, b)
    a, b = (camera.capture(rad, HARDWARE, np.random.default_rng(seed)) for seed in (0, 1))
    assert not np.array_equal(a, b)


def test_the_fidelity_probe_captures_with_the_sensor_alone(monkeypatch):
    """What the fidelity probe switches off for its encoded noise floor is derived from the
    optical and processing flags: the picture processing is not noise."""
    from sim.fidelity import Probe

    seen = []
    real = camera.capture
    monkeypatch.setattr(camera, "capture", lambda rad, cfg, rng: seen.append(cfg) or real(rad, cfg, rng))
    setup = tiny_setup(camera={"resolution": [16, 16], "psf_sigma": 0.6, "vignetting": 0.2,
                               "distortion": 0.01, "style_contrast": 0.3, "sharpen_amount": 0.5,
                               "adaptive_tone": 0.5})
    Probe(setup, classes=("smooth",), reference_spp=4, window=None)
    assert seen == [camera.sensor_alone(setup.camera)]
    assert seen[0].psf_sigma == seen[0].distortion == seen[0].vignetting == 0.0
    assert seen[0].style_contrast == seen[0].sharpen_amount == seen[0].adaptive_tone == 0.0


# ---------------------------------------------------------------------------------- projector

def test_projector_stages_after_the_lens_are_linear():
    """The light transport runs after the lens (``defocus``): a capture is the lamp's gain times
    the operator's output, exact only if every later stage is linear."""
    names = [s.name for s in projector.STAGES]
    assert names[:7] == ["scaler", "response", "white_boost", "mixing", "dynamic_lamp", "psf", "defocus"]
    assert all(s.linear for s in projector.STAGES[names.index("defocus") + 1:])
    assert [s.name for s in projector.STAGES if s.optical] == ["psf", "defocus", "distortion",
                                                                "translucency", "flare"]


def test_projector_stages_flagged_linear_are_linear():
    rng = np.random.default_rng(4)
    x, y = (rng.uniform(0, 1, (24, 24, 3)).astype(np.float32) for _ in range(2))
    setup = tiny_setup(projector={"resolution": [24, 24], "psf_sigma": 0.8, "aperture": 0.02,
                                  "focus_distance": 0.8})
    lens = projector.lens_for(setup)
    mix = ((1.0, 0.1, 0.0), (0.1, 1.0, 0.1), (0.0, 0.1, 1.0))
    code = {"mixing": lambda v: projector.emitted_irradiance(v, 1.0, 0.0, mix),  # response off
            "psf": lens.apply, "defocus": lens.apply,
            # the stages after the lens, on its output
            "distortion": lambda v: distortion.distort(lens.apply(v), lens, 0.05, -0.01, 0.5),
            "translucency": lambda v: translucency.translucent(lens.apply(v), lens, 2.0, 0.7),
            "flare": lambda v: scatter.veil(lens.apply(v), 0.1, 6.0),
            "brightness": lambda v: 1.3 * v,  # the emitter's scale: Mitsuba's light is linear in it
            "lamp": lambda v: projector.lamp_gain(replace(setup.projector, flicker=0.1, drift=0.05),
                                                  0, seeds.TEST, 1) * v}
    assert [s.name for s in projector.STAGES if s.linear] == list(code)
    for name, f in code.items():
        np.testing.assert_allclose(f(0.3 * x + 0.5 * y), 0.3 * f(x) + 0.5 * f(y), atol=1e-6, err_msg=name)


def test_the_lamp_is_the_projector_stage_that_draws():
    assert [s.name for s in projector.STAGES if s.random] == ["lamp"]
    cfg = replace(ProjectorConfig(), flicker=0.1)
    assert len({projector.lamp_gain(cfg, seed, seeds.TRAIN, 1) for seed in range(4)}) == 4
    assert {projector.lamp_gain(ProjectorConfig(), seed, seeds.TRAIN, 1) for seed in range(4)} == {1.0}
