"""The camera after the light transport, stage by stage (:data:`CHAIN`), and what its flags give.

:func:`sim.camera.capture` applies the chain in this order, each stage skipped (at no cost) when
its keys switch it off; a stage's function takes ``(image, cfg, rng)`` (the image so far, the
camera's setup section, the capture's generator) and returns the image. The camera's setup
section (:class:`sim.setup.CameraConfig`) is composed from the stages' options. Two things
follow from the flags: :func:`without_optics`, the camera with every optical stage switched off
(the sensor alone, whose noise :mod:`sim.fidelity` measures), and :func:`noise_version`, the
version of a capture's random streams (recorded in a dataset's ``render.json`` and
``meta.json``, so a setup started under other streams is not resumed with these).

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
    """The camera configuration with every optical stage switched off: the sensor alone.

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


def noise_version() -> int:
    """Version of a capture's random streams in this process, from the random stages
    (:func:`sim.stages.streams_version`); with noise the one random stage, its version
    (:func:`sim.camera.noise.stream_version`: 3 or 2)."""
    return streams_version(STAGES)
