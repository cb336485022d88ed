"""The projector outside Mitsuba: its scaler, photometry (response, black level, the colour
wheel's white segment, primaries mixing, the dynamic lamp), lens (Gaussian point-spread function
and depth-dependent defocus), lens distortion, the surface's translucency, flare and lamp (flicker
and drift), stage by stage in :data:`~sim.projector.chain.CHAIN`; each stage's module declares its
keys, which make up :class:`sim.setup.ProjectorConfig`.

A frame goes through the scaler to the native panel (:mod:`~sim.projector.scaler`), the response,
white segment (:mod:`~sim.projector.wheel`), mixing and dynamic lamp
(:mod:`~sim.projector.dynamic`), fused (:mod:`~sim.projector.photometry`), the lens
(:mod:`~sim.projector.lens`, built for a setup by :func:`lens_for`; its defocus in
:mod:`~sim.projector.defocus`), the lens's distortion about its offset axis
(:mod:`~sim.projector.distortion`), the surface's translucency (:mod:`~sim.projector.translucency`)
and the projector's flare (:mod:`~sim.projector.flare`, with its ANSI and full-on/full-off
contrasts). The scaler and the response act on encoded values; the white segment (on each pixel's
primaries) and the dynamic lamp (on the whole frame's light, by its content) are not linear either;
everything after the photometry is linear in the emitted light, so it belongs to the light
transport (the ``transport`` level's operator sees the output of the flare). The lens's output is
the panel padded by :attr:`Lens.pad` pixels of each side, so light it blurs past the panel's border
is kept; Mitsuba's emitter is widened to match (:meth:`Lens.fov`), and the later stages work on
that grid.

All outputs are *relative linear* irradiance: the projector's brightness is not applied here; the
scene applies it as the scale of Mitsuba's ``projector`` emitter, and the lamp's per-capture
brightness (:func:`lamp_gain`, :mod:`~sim.projector.lamp`) multiplies a capture's projector
contribution.
"""
from sim.projector.chain import CHAIN, STAGES
from sim.projector.defocus import (DEFOCUS_RELATIVE_STEP, DEFOCUS_STEP, SHARP_DIAMETER, defocus,
                                   defocus_blur_diameter_px, defocus_levels, defocus_plan,
                                   disk_kernel, disk_radius, varying_defocus)
from sim.projector.lamp import lamp_gain
from sim.projector.lens import Lens, gaussian_radius, lens_for, throw_distance
from sim.projector.photometry import emitted_irradiance, projector_irradiance
from sim.projector.scaler import frame_area, scale_to_panel

__all__ = [
    "CHAIN", "DEFOCUS_RELATIVE_STEP", "DEFOCUS_STEP", "SHARP_DIAMETER", "STAGES", "Lens", "defocus",
    "defocus_blur_diameter_px", "defocus_levels", "defocus_plan", "disk_kernel", "disk_radius",
    "emitted_irradiance", "frame_area", "gaussian_radius", "lamp_gain", "lens_for",
    "projector_irradiance", "scale_to_panel", "throw_distance", "varying_defocus",
]
