"""The projector, stage by stage (:data:`CHAIN`): from an input frame to the light on the surface
and the brightness of each capture.

The chain has three parts, each a list of stages in the order light meets them:

- :data:`EMISSION`, before the light transport: a stage's function takes ``(frame, cfg, lens)``
  (the frame so far, the projector's setup section, the setup's :class:`~sim.projector.Lens`)
  and returns the frame; :meth:`sim.render.Renderer.emit` applies them, so the ``transport``
  level's operator sees their output;
- :data:`TRANSPORT`, applied by Mitsuba in the light transport (the emitter's scale);
- :data:`CAPTURE`, per capture after the light transport: a stage's function takes
  ``(radiance, cfg, seed, stream, index)`` (the projector's contribution to one capture, the
  projector's setup section, the capture's ``render.seed``, stream and index) and returns it;
  :meth:`sim.capture.Simulator.linear` applies them. These must be linear (the operator is, and a
  capture is their output plus the ambient light), so the transport fast path stays exact.

The projector's setup section (:class:`sim.setup.ProjectorConfig`) is composed from the stages'
options. A new effect is a module of this package declaring its options, its function and its
:class:`~sim.stages.Stage`, and one entry here at its place in the chain.
"""
from __future__ import annotations

from sim.projector import distortion, flare, lamp, lens, photometry, scaler, translucency
from sim.stages import stages_of

EMISSION = (
    scaler.SCALER,
    photometry.PHOTOMETRY,
    lens.LENS,
    distortion.DISTORTION,
    translucency.TRANSLUCENCY,
    flare.FLARE,
)
"""The stages before the light transport, in order."""
TRANSPORT = (
    photometry.BRIGHTNESS,
)
"""The stages Mitsuba applies in the light transport."""
CAPTURE = (
    lamp.LAMP,
)
"""The stages applied to each capture's projector contribution, in order; linear."""
CHAIN = EMISSION + TRANSPORT + CAPTURE
"""The projector's stages (and fused groups), in the order light meets them."""
STAGES = stages_of(CHAIN)
"""Every stage of :data:`CHAIN`, those of a fused group in its place."""
