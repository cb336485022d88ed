"""The measured light shares of a setup (sim.light): the room light against the projector's white,
and the inter-reflected light against the direct light."""
from __future__ import annotations

import numpy as np
import pytest

from helpers import tiny_setup
from sim import registration, seeds
from sim.capture import Simulator
from sim.light import light_shares

SIZE = (32, 32)


def _sim(**sections) -> Simulator:
    return Simulator(tiny_setup(**sections), SIZE)


def test_room_light_share_is_linear_and_matches_the_captures():
    dark = light_shares(_sim())
    assert dark == {"ambient": 0.0, "indirect": 0.0}  # a plane does not light itself
    sim = _sim(ambient={"radiance": [0.05] * 3})
    share = light_shares(sim)["ambient"]
    assert light_shares(_sim(ambient={"radiance": [0.1] * 3}))["ambient"] == pytest.approx(2 * share, rel=1e-6)
    # independently, from the simulator's linear captures of black and white (no projector black)
    w, h = SIZE
    black, white = (registration.warp(sim.linear(np.full((h, w, 3), v, np.uint8), seeds.TEST, 0), sim.warp_map)
                    for v in (0, 255))
    seen = sim.warp_map.mask
    assert share == pytest.approx(black[seen].mean() / (white[seen] - black[seen]).mean(), rel=0.02)
    assert 0.02 < share < 0.2  # radiance 0.05 of white on the same albedo, moved by the falloff


def test_inter_reflection_share_grows_with_albedo_and_a_narrower_corner():
    def indirect(albedo: float, angle: float) -> float:
        return light_shares(_sim(surface={"geometry": "corner", "size": [0.6, 1.0], "albedo_scale": albedo,
                                          "corner_angle": angle},
                                 render={"fidelity": "path", "spp": 16, "max_depth": 3}))["indirect"]

    low, high, open_ = indirect(0.4, 90.0), indirect(0.8, 90.0), indirect(0.8, 150.0)
    assert 0.005 < low < high < 0.3
    assert 1.7 < high / low < 2.5  # one bounce at max_depth 3: proportional to the albedo
    assert open_ < 0.5 * high  # the wings see less of each other
