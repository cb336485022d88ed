"""Every random stream of the simulator, in one place.

A capture is identified by the setup's ``render.seed``, a *stream* and an index within the
stream: the Monte-Carlo sampler uses :func:`mitsuba_seed` of the three and the camera noise
:func:`noise_rng` of the same three, so a capture is reproducible bit for bit and two captures
never share samples or noise. The capture streams below keep the users of the simulator apart.

The image generator (:mod:`sim.images`) draws from its own generators: projector frame ``i`` of
``projector_frames(count, size, seed, stream)`` from ``(FRAME_TAG, seed, stream, i)``, a surface
texture from ``(SURFACE_TAG, texture_seed, kind index)``, a surface's relief from
``(RELIEF_TAG, relief_seed)``; the probe frames of :mod:`sim.fidelity`
from ``(render.seed, class index)``.

Changing any value here changes every dataset rendered afterwards.
"""
from __future__ import annotations

import numpy as np

SEED_MAX = 2 ** 32 - 1
"""Largest seed a setup takes (Mitsuba's sampler seeds are 32-bit)."""

# ------------------------------------------------------------------------- capture streams

REF = 0
"""Captures of a dataset's reference frames (the plain colours and the gray surface frame)."""
TRAIN = 1
"""Captures of a dataset's training frames."""
TEST = 2
"""Captures of a dataset's test frames."""
REGISTRATION = 3
"""Captures of the checkerboards that estimate the camera → canonical homography (indices 0, 1,
2: checkerboard, white, black) and the corner jitter (index :data:`REGISTRATION_JITTER`)."""
REGISTRATION_JITTER = 1000
"""Index in stream :data:`REGISTRATION` of the generator (:func:`noise_rng`) of the random
displacement of the detected checkerboard corners (``registration.jitter``)."""
STREAMS = {"ref": REF, "train": TRAIN, "test": TEST, "registration": REGISTRATION}
"""Capture stream of each dataset split and of registration, as recorded in ``meta.json``."""
CLOSED_LOOP = 16
"""Captures of compensated frames in the closed loop; feedback refinement round ``k`` (from 0)
uses stream ``CLOSED_LOOP + 1 + k``."""
OPTIMUM = 90
"""The noise-free evaluations through which the exact optimum is found: every evaluation of test
image ``i`` uses index ``i``, so at the ``direct`` and ``path`` levels it sees the same Monte-Carlo
samples (the model is a fixed function of the frame). A test-time stream, so the lamp's drift
applies."""
EXPOSURE = 95
"""Renders of plain white (index 0) and plain black (index 1) that the camera's exposure rule
sets the exposure from."""
PROBE = 96
"""Renders of the probe frames that ``auto`` fidelity measures each candidate level with
(index: the probe class's position)."""
REFERENCE = 97
"""The converged path-traced reference of the probe frames: renders ``2 i`` and ``2 i + 1`` of
probe class ``i``, and the camera noise of its capture ``i``."""
CALIBRATION = 98
"""The spaced-dot renders that calibrate a light-transport operator (index 0: one seed for all)."""
AMBIENT = 99
"""The ambient-only image of a setup (index 0)."""
RESPONSE = 100
"""Captures of plain black (index 0) and plain white (index 1) that check, before a dataset is
rendered, that its captures respond to the projector (kept in no file)."""
LIGHT = 101
"""Renders of plain white that measure a setup's light shares (:mod:`sim.light`): index 0 at the
captures' level, 1 path-traced, 2 direct light only."""
TEST_TIME = (TEST,) + tuple(range(CLOSED_LOOP, EXPOSURE))
"""Streams captured at test time (test frames, closed loop and its refinement rounds): the lamp's
``projector.drift`` applies to them, not to the calibration captures (reference, training,
registration, the exposure rule)."""

# ------------------------------------------------------------------------- image generator

FRAME_TAG = 1
"""First seed word of every projector frame: frames and surface textures never share a state."""
SURFACE_TAG = 2
"""First seed word of every surface texture."""
TRAIN_FRAMES = 0
"""Image-generator stream of a dataset's training frames (seed: the dataset's frame seed)."""
TEST_FRAMES = 1
"""Image-generator stream of a dataset's test frames."""
PROBE_FRAMES = 7
"""Image-generator stream of the ``natural`` probe frame (seed: the setup's ``render.seed``)."""

RELIEF_TAG = 4
"""First seed word of a surface's random relief, ``(RELIEF_TAG, relief_seed)``
(:mod:`sim.surfaces.relief`)."""

LAMP_TAG = 3
"""Last seed word of a capture's lamp flicker (:func:`lamp_rng`): never shares a state with its
camera noise (:func:`noise_rng`)."""

# ------------------------------------------------------------------------- fixed seeds

TRANSPORT_CHECK = 0
"""Seed of the random frame a calibrated light-transport operator is verified on."""
BENCH_TIMING = 1000
"""Mitsuba seed of bench-sim's first timed render; timed render ``i`` uses ``BENCH_TIMING + i``."""


def mitsuba_seed(seed: int, stream: int, index: int) -> int:
    """Sampler seed (uint32) of one capture: distinct per (setup seed, stream, frame index).

    Examples
    --------
    >>> mitsuba_seed(0, TRAIN, 5)
    100008
    """
    return (seed * 1_000_003 + stream * 100_003 + index) % 2**32


def noise_rng(seed: int, stream: int, index: int) -> np.random.Generator:
    """Generator of the camera noise of one capture (setup seed, stream, frame index)."""
    return np.random.default_rng([seed, stream, index])


def lamp_rng(seed: int, stream: int, index: int) -> np.random.Generator:
    """Generator of the lamp flicker of one capture (setup seed, stream, frame index)."""
    return np.random.default_rng([seed, stream, index, LAMP_TAG])


def test_time(stream: int) -> bool:
    """True for a capture stream of :data:`TEST_TIME`.

    Examples
    --------
    >>> test_time(TEST), test_time(TRAIN), test_time(CLOSED_LOOP + 2)
    (True, False, True)
    """
    return stream in TEST_TIME
