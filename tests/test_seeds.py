"""sim.seeds: every random stream in one place; the values are part of every dataset's bytes."""
from __future__ import annotations

import numpy as np

from sim import seeds


def test_values_are_those_datasets_were_rendered_with():
    assert seeds.STREAMS == {"ref": 0, "train": 1, "test": 2, "registration": 3}
    assert (seeds.CLOSED_LOOP, seeds.PROBE, seeds.REFERENCE, seeds.CALIBRATION, seeds.AMBIENT) == (
        16, 96, 97, 98, 99)
    assert (seeds.FRAME_TAG, seeds.SURFACE_TAG, seeds.TRAIN_FRAMES, seeds.TEST_FRAMES,
            seeds.PROBE_FRAMES) == (1, 2, 0, 1, 7)
    assert (seeds.TRANSPORT_CHECK, seeds.BENCH_TIMING) == (0, 1000)


def test_capture_streams_are_distinct():
    streams = [*seeds.STREAMS.values(), seeds.CLOSED_LOOP, seeds.PROBE, seeds.REFERENCE,
               seeds.CALIBRATION, seeds.AMBIENT]
    assert len(set(streams)) == len(streams)


def test_capture_seeds():
    assert seeds.mitsuba_seed(3, seeds.TEST, 7) == (3 * 1_000_003 + 2 * 100_003 + 7) % 2**32
    assert 0 <= seeds.mitsuba_seed(2**40, 99, 5) < 2**32
    a, b = seeds.noise_rng(0, seeds.TRAIN, 1), np.random.default_rng([0, 1, 1])
    assert a.random() == b.random()
