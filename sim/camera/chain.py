"""The camera after the light transport, stage by stage (:data:`STAGES`), and what its flags give.

:func:`sim.camera.capture` applies the stages in this order, each skipped (at no cost) when its
keys switch it off. Two things follow from the flags: :func:`without_optics`, the camera with
every optical stage switched off (the sensor alone, whose noise :mod:`sim.fidelity` measures),
and :func:`noise_version`, the version of a capture's random streams (recorded in a dataset's
``render.json`` and ``meta.json``, so a setup started under other streams is not resumed with
these). A new effect is a stage here, with its key in :class:`sim.setup.CameraConfig`.
"""
from __future__ import annotations

from typing import Any

from sim.camera.noise import stream_version
from sim.stages import Stage, streams_version, switch_off

RENDERED = ("resolution", "fov", "position", "look_at", "up", "aperture_radius", "focus_distance")
"""Camera keys that Mitsuba's sensor renders with (pixels, field of view, pose, thin lens): they
shape the linear radiance the stages receive."""

STAGES = (
    Stage("psf", ("psf_sigma",), "Gaussian optical PSF / anti-alias filter of psf_sigma camera "
          "pixels (sim.camera.optics.blur)", optical=True, linear=True, off={"psf_sigma": 0.0}),
    Stage("distortion", ("distortion",), "radial lens distortion, Brown's k1 "
          "(sim.camera.optics.distort_image)", optical=True, linear=True, off={"distortion": 0.0}),
    Stage("vignetting", ("vignetting",), "cos^4-like falloff towards the corners "
          "(sim.camera.optics.vignetting_profile)", optical=True, linear=True, off={"vignetting": 0.0}),
    Stage("exposure", ("exposure", "exposure_mode"), "radiance to sensor signal (exposure_mode = "
          '"rule": the exposure set by sim.camera.rule_exposure)', linear=True),
    Stage("mosaic", ("bayer",), "with a Bayer pattern, one colour channel per pixel "
          "(sim.camera.raw.mosaic)", linear=True, off={"bayer": "none"}),
    Stage("noise", ("shot_noise", "read_noise"), "Poisson-Gaussian noise (on the mosaic's sites "
          "with a Bayer sensor), then the full-well clip to [0, 1] (sim.camera.noise.expose)",
          random=True, streams=stream_version, off={"shot_noise": 0.0, "read_noise": 0.0}),
    Stage("white_balance", ("white_balance",), "per-channel gains: with a Bayer sensor the digital "
          "gain of each site after the noise and the clip (clipped to [0, 1] again), without one "
          "ahead of the noise", linear=True, off={"white_balance": (1.0, 1.0, 1.0)}),
    Stage("demosaic", ("demosaic",), "OpenCV demosaicing of the mosaic quantised to 16 bits (vng: "
          "of the mosaic encoded to 8 bits, OpenCV's VNG being 8-bit only; sim.camera.raw.demosaic)"),
    Stage("response", ("response", "bit_depth"), "response curve and 8-bit quantisation, at once "
          "from the linear signal (sim.camera.response.codes)"),
    Stage("jpeg", ("jpeg_quality",), "JPEG compression and decompression (sim.camera.raw.jpeg)",
          off={"jpeg_quality": 0}),
)
"""The camera's stages, in the order light meets them."""


def without_optics(cfg: Any) -> Any:
    """The camera configuration with every optical stage switched off: the sensor alone.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Cam:
    ...     psf_sigma: float = 0.5
    ...     distortion: float = -0.01
    ...     vignetting: float = 0.2
    ...     shot_noise: float = 1e-4
    >>> without_optics(Cam())
    Cam(psf_sigma=0.0, distortion=0.0, vignetting=0.0, shot_noise=0.0001)
    """
    return switch_off(cfg, (s for s in STAGES if s.optical))


def noise_version() -> int:
    """Version of a capture's random streams in this process, from the random stages
    (:func:`sim.stages.streams_version`); with noise the one random stage, its version
    (:func:`sim.camera.noise.stream_version`: 3 or 2)."""
    return streams_version(STAGES)
