"""The projector, stage by stage (:data:`STAGES`): from an input frame to the light on the
surface and the brightness of each capture.

The stages up to the lens run before the light transport (:meth:`sim.render.Renderer.emit`), so
the ``transport`` level's operator sees the lens's output; those after it must be linear in the
light (the operator is, and a capture is ``lamp gain × (T p) + ambient``). A new effect is a stage
here, with its key in :class:`sim.setup.ProjectorConfig` and its code in this package.
"""
from __future__ import annotations

from sim.stages import Stage

RENDERED = ("resolution", "fov", "position", "look_at", "up")
"""Projector keys that Mitsuba's emitter renders with (panel pixels, field of view, pose)."""

STAGES = (
    Stage("scaler", ("keep_aspect",), "the input frame resampled onto the native panel, on encoded "
          "values (sim.projector.scaler.scale_to_panel)"),
    Stage("response", ("gamma", "black_level"), "power-law response with a black-level floor "
          "(sim.projector.photometry.emitted_irradiance)"),
    Stage("mixing", ("mixing",), "3x3 mixing of the primaries onto the camera channels "
          "(sim.projector.photometry.emitted_irradiance)", linear=True,
          off={"mixing": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))}),
    Stage("psf", ("psf_sigma",), "the lens's Gaussian point-spread function (sim.projector.Lens)",
          optical=True, linear=True, off={"psf_sigma": 0.0}),
    Stage("defocus", ("aperture", "focus_distance"), "the thin-lens defocus disk of each pixel's "
          "depth on the surface (sim.projector.lens_for, sim.projector.Lens)", optical=True,
          linear=True, off={"aperture": 0.0}),
    Stage("brightness", ("brightness",), "the scale of Mitsuba's projector emitter, in the light "
          "transport (sim.scene)", linear=True, off={"brightness": 1.0}),
    Stage("lamp", ("flicker", "drift"), "each capture's projector contribution scaled by the "
          "lamp's brightness, drawn from sim.seeds.lamp_rng (sim.projector.lamp.lamp_gain, applied "
          "in sim.capture; never in calibration renders)", linear=True, random=True,
          off={"flicker": 0.0, "drift": 0.0}),
)
"""The projector's stages, in the order light meets them; the light transport runs between
``defocus`` and ``brightness``."""
