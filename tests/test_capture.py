"""The capture pipeline: render on the calling thread, camera model and warp on worker threads."""
from __future__ import annotations

import threading

import numpy as np
import pytest

import sim.capture
from helpers import tiny_setup
from sim import images
from sim.capture import Simulator, pipelined


def test_pipelined_keeps_order_runs_finish_on_workers_and_raises_errors():
    main = threading.get_ident()
    seen = []

    def finish(item, rendered):
        seen.append(threading.get_ident())
        return item, rendered

    rendered = []
    out = list(pipelined(range(20), lambda k: rendered.append(threading.get_ident()) or k * k, finish, workers=2))
    assert out == [(k, k * k) for k in range(20)]
    assert set(rendered) == {main} and main not in seen

    def broken(item, _):
        if item == 3:
            raise RuntimeError("camera failed on item 3")
        return item

    with pytest.raises(RuntimeError, match="item 3"):
        list(pipelined(range(10), lambda k: k, broken, workers=2))


def test_simulator_capture_does_not_depend_on_the_workers(monkeypatch):
    setup = tiny_setup(render={"fidelity": "direct", "spp": 4})
    frames = images.projector_frames(5, (32, 32), seed=4)
    pooled = Simulator(setup, (32, 32)).capture(frames, stream=16)
    monkeypatch.setattr(sim.capture, "capture_workers", lambda: 1)
    single = Simulator(setup, (32, 32)).capture(frames, stream=16)
    assert pooled.shape == (5, 32, 32, 3) and pooled.dtype == np.uint8
    assert np.array_equal(pooled, single)
    assert not np.array_equal(pooled[0], pooled[1])  # different frames, different captures
