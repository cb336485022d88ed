"""The DLP projector's content-dependent photometry: the dynamic lamp mode (the lamp's power per
frame) and the colour wheel's white segment (light per pixel's white content); off, they change
nothing."""
from __future__ import annotations

import re
from dataclasses import replace

import numpy as np
import pytest
from helpers import tiny_setup

from sim import projector
from sim.errors import SetupError
from sim.projector import dynamic, flare, lens_for, photometry, wheel
from sim.setup import load_setup, scene_path
from sim.stages import run

MIX = ((1.0, 0.08, 0.02), (0.10, 1.0, 0.10), (0.02, 0.08, 1.0))


def _frame(value, size=(32, 24)) -> np.ndarray:
    w, h = size
    return np.broadcast_to(np.asarray(value, np.float32), (h, w, 3)).copy()


# ------------------------------------------------------------------------------------ off

def test_off_values_emit_bit_for_bit_what_the_photometry_did_before():
    """At depth 0 and boost 0 the photometry is the response, black level and mixing alone, bit for
    bit, whatever the statistic; the new stages are skipped in the chain."""
    setup = tiny_setup(projector={"resolution": [40, 30], "black_level": 0.003, "mixing": MIX,
                                  "gamma": 2.4, "dynamic_lamp_statistic": "peak"})
    cfg = setup.projector
    frame = np.random.default_rng(1).random((30, 40, 3), dtype=np.float32)
    before = projector.emitted_irradiance(frame, 2.4, 0.003, MIX)
    assert wheel.WHITE_BOOST.is_off(cfg) and dynamic.DYNAMIC_LAMP.is_off(cfg)
    np.testing.assert_array_equal(photometry.PHOTOMETRY.apply(frame, cfg, lens_for(setup)), before)
    np.testing.assert_array_equal(projector.projector_irradiance(frame, cfg), before)


# ------------------------------------------------------------------------------------ dynamic lamp

@pytest.mark.parametrize("statistic", dynamic.STATISTICS)
def test_dynamic_lamp_dims_a_black_frame_by_its_depth(statistic):
    """The whole light of a black frame (the black level's) drops to 1 - depth; white keeps it."""
    depth, black = 0.55, 0.004
    off = replace(tiny_setup().projector, black_level=black, mixing=MIX)
    on = replace(off, dynamic_lamp=depth, dynamic_lamp_statistic=statistic)
    (black_off, white_off), (black_on, white_on) = (
        [projector.projector_irradiance(_frame(v), cfg) for v in (0.0, 1.0)] for cfg in (off, on))
    np.testing.assert_allclose(black_on, (1 - depth) * black_off, rtol=1e-6)
    np.testing.assert_allclose(black_off[0, 0], black * np.sum(MIX, axis=1), rtol=1e-6)
    np.testing.assert_allclose(white_on, white_off, rtol=1e-6)
    ratio = white_on.mean() / black_on.mean()
    assert ratio == pytest.approx(white_off.mean() / black_off.mean() / (1 - depth), rel=1e-6)


def test_dynamic_lamp_follows_the_mean_or_the_peak_luminance():
    """A frame an eighth white: the mean follows its average luminance, the peak its brightest
    pixel; a pure green frame's statistic is the green primary's luminance."""
    depth = 0.5
    frame = _frame(0.0)
    frame[:3] = 1.0  # 3 of 24 rows
    base = replace(tiny_setup().projector, gamma=2.0)
    gain = {}
    for statistic in dynamic.STATISTICS:
        cfg = replace(base, dynamic_lamp=depth, dynamic_lamp_statistic=statistic)
        gain[statistic] = projector.projector_irradiance(frame, cfg)[0, 0, 0] / \
            projector.projector_irradiance(frame, base)[0, 0, 0]
    assert gain["mean"] == pytest.approx(1 - depth * (1 - 1 / 8), rel=1e-6)
    assert gain["peak"] == pytest.approx(1.0, rel=1e-6)
    green = _frame((0.0, 1.0, 0.0))
    cfg = replace(base, dynamic_lamp=depth)
    assert projector.projector_irradiance(green, cfg)[0, 0, 1] == pytest.approx(
        1 - depth * (1 - dynamic.LUMINANCE[1]), rel=1e-6)
    # a mid-grey input: the lamp follows its linear light (0.5 ** gamma), not its code
    assert dynamic.dynamic_gain(_frame(0.5 ** 2.0), depth, "mean") == pytest.approx(1 - depth * 0.75)


def test_dynamic_lamp_raises_the_full_on_full_off_contrast_by_one_over_one_minus_depth():
    """The default setup with the depth measured on a dynamic-lamp DLP (0.55): the full-on/full-off
    contrast, read through every emission stage (lens, distortion, translucency, flare), grows by
    1 / (1 - 0.55); the ANSI checkerboard, half white, is dimmed as a whole and keeps its contrast."""
    setup = load_setup(scene_path("default"))
    lens = lens_for(setup)
    normal = setup.projector
    assert dynamic.DYNAMIC_LAMP.is_off(normal)
    dyn = replace(normal, dynamic_lamp=0.55)

    def emit(cfg):
        return lambda frame: run(projector.chain.EMISSION, frame, cfg, lens)

    full = flare.full_contrast(emit(normal), lens)
    assert flare.full_contrast(emit(dyn), lens) == pytest.approx(full / (1 - 0.55), rel=1e-5)
    assert flare.ansi_contrast(emit(dyn), lens) == pytest.approx(flare.ansi_contrast(emit(normal), lens),
                                                                 rel=1e-5)


# ------------------------------------------------------------------------------------ white segment

@pytest.mark.parametrize("boost", [0.5, 1.0, 2.0])
def test_white_segment_keeps_white_and_dims_a_primary_to_one_over_one_plus_boost(boost):
    cfg = replace(tiny_setup().projector, white_boost=boost)  # no black level, identity mixing
    plain = replace(cfg, white_boost=0.0)
    white = projector.projector_irradiance(_frame(1.0), cfg)
    np.testing.assert_allclose(white, 1.0, rtol=1e-6)
    for c in range(3):
        primary = _frame(np.eye(3)[c])
        out = projector.projector_irradiance(primary, cfg)[0, 0]
        np.testing.assert_allclose(out, np.eye(3)[c] / (1 + boost), rtol=1e-6, atol=1e-7)
    for v in (0.2, 0.5, 0.9):  # a grey keeps its light relative to white
        grey = projector.projector_irradiance(_frame(v), cfg)
        np.testing.assert_allclose(grey / white, projector.projector_irradiance(_frame(v), plain), rtol=1e-6)


def test_white_segment_on_the_primaries_with_the_black_level_floor_and_mixing():
    """Applied to the response's output before the floor, as the photometry does, the white segment
    gives the light of applying it to each primary's floored output, then mixing."""
    boost, black, gamma = 0.8, 0.01, 2.2
    x = np.random.default_rng(2).random((24, 32, 3), dtype=np.float32)
    q = black + (1 - black) * x.astype(np.float64) ** gamma
    q = (q + boost * q.min(axis=2, keepdims=True)) / (1 + boost)
    want = q @ np.asarray(MIX).T
    got = projector.emitted_irradiance(x, gamma, black, MIX, white_boost=boost)
    np.testing.assert_allclose(got, want, rtol=2e-5)


# ------------------------------------------------------------------------------------ keys

@pytest.mark.parametrize("key, value, expected", [
    ("dynamic_lamp", 0.95, "expected a number in [0, 0.9]"),
    ("dynamic_lamp", -0.1, "expected a number in [0, 0.9]"),
    ("dynamic_lamp_statistic", "median", 'expected one of "mean", "peak"'),
    ("white_boost", 2.5, "expected a number in [0, 2]"),
    ("white_boost", "high", "expected a number in [0, 2]"),
])
def test_bad_dlp_keys_are_named(key, value, expected):
    with pytest.raises(SetupError, match=rf"projector\.{key} = .*{re.escape(expected)}"):
        tiny_setup(projector={key: value})


def test_the_dlp_stages_are_not_linear_nor_optics():
    names = [s.name for s in projector.STAGES]
    for stage in (wheel.WHITE_BOOST, dynamic.DYNAMIC_LAMP):
        assert stage.name in names and not stage.linear and not stage.optical and not stage.random
    x, y = (np.random.default_rng(s).random((8, 8, 3), dtype=np.float32) * 0.5 for s in (3, 4))
    for keys in ({"white_boost": 1.0}, {"dynamic_lamp": 0.5}):
        cfg = replace(tiny_setup().projector, gamma=1.0, **keys)  # linear response: only the stage
        f = lambda v: projector.projector_irradiance(v, cfg)  # noqa: E731
        assert np.abs(f(x + y) - (f(x) + f(y))).max() > 0.01
