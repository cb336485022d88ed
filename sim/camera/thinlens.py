"""The camera's thin lens: its defocus rendered in image space, or traced by Mitsuba.

A thin lens of aperture radius ``r`` focused on the plane at depth ``f`` (along the optical axis)
images a surface point at depth ``d`` onto a uniform disk centred on the point's pinhole image,
of diameter ``2 r |d - f| / (f d)`` times the focal length in pixels: the ray through an aperture
point ``a`` towards the point meets the plane of focus at ``x f / d + a (1 - f / d)``, so the
pixel it lands in is offset from the pinhole pixel by ``a (1 - f / d)`` scaled to pixels, and the
aperture is sampled uniformly over its disk, each sample of weight one. Hence ``camera.defocus``:

- ``"image"`` (the default): Mitsuba renders the pinhole image and each camera pixel's light is
  scattered over its own disk (:func:`sim.projector.varying_defocus`, the projector lens's model:
  anti-aliased disks, linear in the light, keeping its energy). Exact for a surface that hides
  no part of itself from any point of the aperture (every surface procam builds: planes, relief of
  millimetres, corners opening towards the camera), up to three things: the detail finer than a
  pixel, which the pinhole render has averaged and a disk of a few pixels would move across
  pixel borders; the disk's anti-aliasing; and the light a disk would carry in from outside the
  field of view (missing within one disk radius of the image border). The Monte-Carlo error is
  that of a pinhole render, and a ``transport`` operator is the pinhole camera's, shared by every
  aperture and focus.
- ``"ray"``: Mitsuba's ``thinlens`` sensor samples the aperture per ray (exact with occlusion
  too), whose Monte-Carlo error grows with the blur (hundreds of samples per pixel) and whose
  ``transport`` operator needs one calibration per aperture with footprints as wide as the disk.

``tests/test_thinlens.py`` compares the two on a textured plane; ``benchmarks/thinlens.py``
measures the error of ``"image"`` over the camera's noise by disk size (within it on natural
frames at every size measured, 0.8 to 16 pixels; on frames of random pixels from 4) and the time
of both. A disk under about a pixel is the identity kernel: such a lens renders as the pinhole.
"""
from __future__ import annotations

from dataclasses import fields, replace

import numpy as np

from sim import geometry, surfaces
from sim.errors import ProcamError
from sim.projector.defocus import SHARP_DIAMETER, defocus_blur_diameter_px, defocus_plan, varying_defocus

DEFOCUS_MODELS = ("image", "ray")
"""Values of ``camera.defocus``."""
MAX_DISK_PX = 1024
"""Widest disk (camera pixels) the image model spreads a pixel's light over: its kernel has 1025²
taps. Fixed rather than the image's size, so that ``auto``'s probe window (a crop of the camera)
accepts the disks of the whole camera."""


def traced(cam) -> bool:
    """True when Mitsuba's sensor traces the thin lens (``defocus = "ray"`` with an aperture)."""
    return cam.aperture_radius > 0 and cam.defocus == "ray"


def mitsuba_view(cam):
    """The camera configuration as Mitsuba's sensor sees it: unchanged when it traces the thin
    lens (:func:`traced`), else a pinhole (``aperture_radius`` 0, the default focus and model), so
    that every camera whose defocus is applied in image space, or that has none, renders (and
    calibrates, and caches) the same pinhole image."""
    if traced(cam):
        return cam
    default = {f.name: f.default for f in fields(cam) if f.name in ("focus_distance", "defocus")}
    return replace(cam, aperture_radius=0.0, **default)


def diameters(setup) -> np.ndarray:
    """Each camera pixel's defocus disk diameter, in camera pixels.

    Parameters
    ----------
    setup : Setup
        The setup (the camera's pose, field of view, resolution, ``aperture_radius`` and
        ``focus_distance``; the surface).

    Returns
    -------
    numpy.ndarray
        float64 (height, width): ``2 r |d - f| / (f d)`` times the focal length in pixels, ``d``
        the depth of the surface point the pixel's pinhole ray hits; a pixel that sees no
        surface sees the room light's constant emitter, at infinite depth: ``2 r / f`` times the
        focal length.

    Raises
    ------
    ProcamError
        If a disk is wider than :data:`MAX_DISK_PX` (its kernel's size grows as the square of
        its diameter): checked before any kernel is made.
    """
    cam = setup.camera
    pinhole = geometry.Pinhole.from_config(cam)
    depth = surfaces.surface_for(setup.surface).projector_depth(pinhole)
    hit = np.isfinite(depth) & (depth > 0)
    near = defocus_blur_diameter_px(2.0 * cam.aperture_radius, cam.focus_distance,
                                    np.where(hit, depth, cam.focus_distance), cam.fov, cam.resolution[0])
    far = 2.0 * cam.aperture_radius / cam.focus_distance * (cam.resolution[0] / 2) / pinhole.tan_half
    out = np.where(hit, near, far).astype(np.float64)
    widest = float(out.max())
    if not widest <= MAX_DISK_PX:
        raise ProcamError(f"setup {setup.name!r}: camera.aperture_radius = {cam.aperture_radius:g} m "
                          f"focused at camera.focus_distance = {cam.focus_distance:g} m blurs a pixel "
                          f"over a disk of {widest:.3g} camera pixels; expected at most {MAX_DISK_PX} "
                          "(a smaller aperture, or a focus distance nearer the surface's; "
                          'camera.defocus = "ray" traces the lens instead)')
    return out


class ImageDefocus:
    """The camera's defocus in image space for one setup: call it on a pinhole radiance image.

    Parameters
    ----------
    setup : Setup
        The setup (see :func:`diameters`).

    Attributes
    ----------
    diameters : numpy.ndarray
        float64 (height, width) disk diameter per camera pixel.
    """

    def __init__(self, setup):
        self.diameters = diameters(setup)
        self._plan = defocus_plan(self.diameters)

    def __call__(self, radiance: np.ndarray) -> np.ndarray:
        """Spread each pixel's light over its disk.

        Parameters
        ----------
        radiance : numpy.ndarray
            (H, W, 3) linear radiance of the pinhole camera.

        Returns
        -------
        numpy.ndarray
            float32 (H, W, 3).
        """
        return varying_defocus(np.asarray(radiance, np.float32), self.diameters, self._plan)


def image_defocus(setup) -> ImageDefocus | None:
    """The image-space defocus a renderer of ``setup`` applies, or None where it applies none
    (a pinhole, a traced thin lens, or a lens in focus on every pixel)."""
    cam = setup.camera
    if cam.aperture_radius <= 0 or traced(cam):
        return None
    blur = ImageDefocus(setup)
    return blur if float(blur.diameters.max()) >= SHARP_DIAMETER else None
