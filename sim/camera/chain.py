"""The camera after the light transport, stage by stage (:data:`CHAIN`), and what its flags give.

:func:`sim.camera.capture` applies the chain in this order, each stage skipped (at no cost) when
its keys switch it off; a stage's function takes ``(image, cfg, rng)`` (the image so far, the
camera's setup section, the capture's generator) and returns the image. The camera's setup
section (:class:`sim.setup.CameraConfig`) is composed from the stages' options. What follows
from the flags: :func:`without_optics`, the camera with every optical stage switched off (behind a
perfect lens); :func:`sensor_alone`, with its processing of the encoded image switched off too
(the sensor alone, whose noise :mod:`sim.fidelity` measures: the picture processing is a
deterministic rendering of the sensor's measurement, which the probe's noiseless reference does
not have, so left on it would be counted as noise); and :func:`noise_version`, the version of a
capture's random streams (recorded in a dataset's ``render.json`` and ``meta.json``, so a setup
started under other streams is not resumed with these).

A new effect is a module of this package declaring its options, its function and its
:class:`~sim.stages.Stage`, and one entry here at its place in the chain.
"""
from __future__ import annotations

from typing import Any

from sim.camera import glare, optics, raw, sensor
from sim.stages import stages_of, streams_version, switch_off

CHAIN = (
    optics.PSF,
    glare.GLARE,
    optics.DISTORTION,
    optics.VIGNETTING,
    sensor.SENSOR,
    raw.JPEG,
)
"""The camera's stages (and fused groups), in the order light meets them."""
STAGES = stages_of(CHAIN)
"""Every stage of :data:`CHAIN`, those of a fused group in its place."""


def without_optics(cfg: Any) -> Any:
    """The camera configuration with every optical stage switched off: behind a perfect lens.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Cam:
    ...     psf_sigma: float = 0.5
    ...     glare: float = 0.02
    ...     distortion: float = -0.01
    ...     vignetting: float = 0.2
    ...     shot_noise: float = 1e-4
    >>> without_optics(Cam())
    Cam(psf_sigma=0.0, glare=0.0, distortion=0.0, vignetting=0.0, shot_noise=0.0001)
    """
    return switch_off(cfg, (s for s in STAGES if s.optical))


def sensor_alone(cfg: Any) -> Any:
    """The camera configuration with every optical and every processing stage switched off: the
    sensor alone (its noise, 8-bit quantisation and the JPEG encoder's loss).

    Examples
    --------
    >>> from dataclasses import make_dataclass
    >>> keys = ("psf_sigma", "glare", "distortion", "vignetting", "shot_noise", "adaptive_tone",
    ...         "style_contrast", "style_saturation", "sharpen_amount")
    >>> Cam = make_dataclass("Cam", [(k, float) for k in keys], frozen=True)
    >>> alone = sensor_alone(Cam(0.5, 0.02, -0.01, 0.2, 1e-4, 0.5, 0.3, 1.2, 0.5))
    >>> alone.glare, alone.shot_noise, alone.adaptive_tone, alone.style_saturation, alone.sharpen_amount
    (0.0, 0.0001, 0.0, 1.0, 0.0)
    """
    return switch_off(without_optics(cfg), (s for s in STAGES if s.processing))


def noise_version() -> int:
    """Version of a capture's random streams in this process, from the random stages
    (:func:`sim.stages.streams_version`); with noise the one random stage, its version
    (:func:`sim.camera.noise.stream_version`: 3 or 2)."""
    return streams_version(STAGES)
