"""The projector's lens: its Gaussian point-spread function and the defocus of each pixel's
depth (:class:`Lens`), built for a setup by :func:`lens_for`.

The lens's output is the panel padded by :attr:`Lens.pad` pixels of each side, so light it blurs
past the panel's border is kept; Mitsuba's emitter (:mod:`sim.scene`) and the transport operator
(:mod:`sim.transport`) use that padded grid (:meth:`Lens.fov`). The module declares the lens's
stages (:data:`PSF`, :data:`DEFOCUS`, fused as :data:`LENS`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property
from typing import Any

import cv2
import numpy as np

from sim import geometry, surfaces
from sim.errors import ProcamError
from sim.options import NON_NEGATIVE, POSITIVE, Range, number
from sim.projector.defocus import (SHARP_DIAMETER, defocus_blur_diameter_px, defocus_plan,
                                   disk_radius, varying_defocus)
from sim.projector.distortion import outward_reach
from sim.stages import Fused, Stage


def gaussian_radius(sigma: float) -> int:
    """Half-width in pixels of the Gaussian kernel :meth:`Lens.apply` uses (4 sigma, whole
    pixels; 0 for sigma 0)."""
    return int(math.ceil(4.0 * sigma)) if sigma > 0 else 0


@dataclass(frozen=True)
class Lens:
    """The projector's lens: Gaussian point-spread function, then the defocus disk of each pixel.

    Both blurs scatter each pixel's light over a normalised kernel, so the lens is linear and
    keeps all the light: the output grid is the panel plus :attr:`pad` pixels on each side, wide
    enough for the largest blur.

    Attributes
    ----------
    panel : (int, int)
        Native panel (width, height) in pixels.
    pad : int
        Pixels added on each side of the panel (0 when the lens is sharp).
    psf_sigma : float
        Gaussian PSF standard deviation in panel pixels (0: none).
    diameters : numpy.ndarray or None
        float (H + 2 pad, W + 2 pad): defocus disk diameter in pixels of the light leaving each
        pixel of the padded grid (from the depth of the surface it lands on), or None when the
        lens is in focus everywhere (every disk below :data:`~sim.projector.defocus.SHARP_DIAMETER`).
    surface_pitch : float
        Metres: the width of one panel pixel on the surface where the optical axis meets it
        (:func:`throw_distance` × 2 tan(fov / 2) / panel width), with which the stages after the
        lens convert lengths on the surface to pixels; 0 when unknown (a lens made by hand).
    """

    panel: tuple[int, int]
    pad: int = 0
    psf_sigma: float = 0.0
    diameters: np.ndarray | None = None
    surface_pitch: float = 0.0

    @property
    def size(self) -> tuple[int, int]:
        """(width, height) of the output grid in pixels: the panel plus the padding."""
        return self.panel[0] + 2 * self.pad, self.panel[1] + 2 * self.pad

    def fov(self, panel_fov: float) -> float:
        """Horizontal field of view (degrees) of the padded grid for a panel of ``panel_fov``:
        the same pixel pitch, ``pad`` more pixels each side."""
        if self.pad == 0:
            return float(panel_fov)
        t = math.tan(math.radians(panel_fov) / 2) * self.size[0] / self.panel[0]
        return math.degrees(2 * math.atan(t))

    @property
    def sharp(self) -> bool:
        """True when the lens changes nothing (no PSF, no defocus, no padding)."""
        return self.psf_sigma == 0 and self.diameters is None and self.pad == 0

    def apply(self, irradiance: np.ndarray) -> np.ndarray:
        """The light leaving the lens for the panel's irradiance.

        Parameters
        ----------
        irradiance : numpy.ndarray
            float (H, W, 3) panel irradiance.

        Returns
        -------
        numpy.ndarray
            float32 (H + 2 pad, W + 2 pad, 3); the input itself when the lens is :attr:`sharp`.
        """
        img = np.asarray(irradiance, np.float32)
        w, h = self.panel
        if img.shape != (h, w, 3):
            raise ValueError(f"irradiance: expected shape ({h}, {w}, 3), got {img.shape}")
        if self.sharp:
            return img
        p = self.pad
        img = cv2.copyMakeBorder(img, p, p, p, p, cv2.BORDER_CONSTANT, value=(0.0, 0.0, 0.0))
        if self.psf_sigma > 0:
            k = 2 * gaussian_radius(self.psf_sigma) + 1
            img = cv2.GaussianBlur(img, (k, k), self.psf_sigma, borderType=cv2.BORDER_CONSTANT)
        if self.diameters is not None:
            img = varying_defocus(img, self.diameters, self._plan)
        return img

    @cached_property
    def _plan(self) -> list:
        """:func:`~sim.projector.defocus.defocus_plan` of :attr:`diameters`, made on first use."""
        return defocus_plan(self.diameters)


def throw_distance(setup: Any) -> float:
    """Distance (metres) from the projector to the surface along its optical axis in a setup
    (:class:`sim.setup.Setup`)."""
    p = geometry.Pinhole.from_config(setup.projector, (1, 1))
    axis = p.frame()[:, 2]
    t, _ = surfaces.surface_for(setup.surface).intersect(p.position, axis[None])
    if not np.isfinite(t[0]):
        return float(np.linalg.norm(p.look_at - p.position))
    return float(t[0])


def lens_for(setup: Any) -> Lens:
    """The projector's lens (:class:`sim.Lens`) in a setup.

    The defocus disk of each pixel follows the depth of the surface point its ray hits
    (:meth:`sim.surfaces.base.Surface.projector_depth`; a pixel that misses the surface takes the
    median depth of those that hit). The padding covers the widest blur: the Gaussian's reach
    plus the largest disk radius over the padded grid, plus how far pincushion distortion carries
    the panel's edges (:func:`~sim.projector.distortion.outward_reach`).

    Parameters
    ----------
    setup : sim.setup.Setup
        The setup (``projector.psf_sigma``, ``aperture``, ``focus_distance``, pose; surface).

    Returns
    -------
    Lens
        A sharp lens without padding when ``psf_sigma`` and ``aperture`` are 0 and no pincushion
        distortion reaches past the panel; no defocus map
        when the surface lies in focus everywhere (a plane at the focus distance, head-on). Its
        :attr:`~Lens.surface_pitch` is the panel pixel's width where the optical axis meets the
        surface.

    Raises
    ------
    ProcamError
        If a defocus disk is wider than the panel (checked before its kernel is made), or the
        padding does not settle.
    """
    p = setup.projector
    w, h = p.resolution
    reach = gaussian_radius(p.psf_sigma) + outward_reach((w, h), p.distortion_k1, p.distortion_k2,
                                                          p.lens_offset)
    pitch = throw_distance(setup) * 2 * math.tan(math.radians(p.fov) / 2) / w
    if p.aperture == 0:
        return Lens((w, h), reach, p.psf_sigma, surface_pitch=pitch)
    surface = surfaces.surface_for(setup.surface)
    pad, diameters = 0, None
    for _ in range(4):  # the padded grid's own disks may need a little more padding
        grid = geometry.Pinhole.from_config(p, (w + 2 * pad, h + 2 * pad))
        grid = replace(grid, fov=Lens((w, h), pad).fov(p.fov), aspect=None)
        depth = surface.projector_depth(grid)
        hit = np.isfinite(depth) & (depth > 0)
        fill = float(np.median(depth[hit])) if hit.any() else p.focus_distance
        diameters = defocus_blur_diameter_px(
            p.aperture, p.focus_distance, np.where(hit, depth, fill), p.fov, w)
        widest = float(diameters.max())
        if not widest <= max(w, h):  # before its disk kernel is made: its size grows as the square
            raise ProcamError(f"setup {setup.name!r}: projector.aperture = {p.aperture:g} m focused at "
                              f"projector.focus_distance = {p.focus_distance:g} m blurs a pixel over a "
                              f"disk of {widest:.3g} projector pixels; expected at most the panel's "
                              f"{max(w, h)} pixels (a smaller aperture, or a focus distance nearer the "
                              "surface's)")
        need = reach + disk_radius(widest)
        if need <= pad:
            break
        pad = need
    else:
        raise ProcamError(f"setup {setup.name!r}: the projector's defocus padding does not settle "
                          f"(projector.aperture = {p.aperture} m is far too large for the scene)")
    if pad > need:  # crop to the padding needed
        c = pad - need
        diameters, pad = diameters[c:-c, c:-c], need
    if float(diameters.max()) < SHARP_DIAMETER:  # in focus everywhere: a point each
        return Lens((w, h), pad, p.psf_sigma, surface_pitch=pitch)
    return Lens((w, h), pad, p.psf_sigma, np.ascontiguousarray(diameters, np.float32), pitch)


@dataclass(frozen=True)
class PsfOptions:
    """The key of the lens's point-spread function."""

    psf_sigma: float = number(0.0, Range(0, 50), "projector pixels")
    """Native projector pixels, in [0, 50]: standard deviation of the lens's Gaussian point-spread
    function (0: sharp)."""


@dataclass(frozen=True)
class DefocusOptions:
    """The keys of the lens's defocus."""

    aperture: float = number(0.0, NON_NEGATIVE, "metres")
    """Metres, lens aperture diameter for defocus (>= 0); 0 is a pinhole (sharp)."""
    focus_distance: float = number(1.0, POSITIVE, "metres")
    """Metres (> 0), depth (along the optical axis) at which the projector is in focus; each
    surface point is blurred by the thin-lens disk of its own depth."""


def _lens(irradiance: np.ndarray, cfg, lens: Lens) -> np.ndarray:
    return lens.apply(irradiance)


PSF = Stage("psf", PsfOptions, "the lens's Gaussian point-spread function (Lens)", optical=True,
            linear=True, off={"psf_sigma": 0.0})
"""The lens's point-spread function stage."""
DEFOCUS = Stage("defocus", DefocusOptions, "the thin-lens defocus disk of each pixel's depth on the "
                "surface (lens_for, Lens)", optical=True, linear=True, off={"aperture": 0.0})
"""The lens's defocus stage."""
LENS = Fused("lens", (PSF, DEFOCUS), _lens)
"""The lens's stages at once (:meth:`Lens.apply` of the setup's lens, built by :func:`lens_for`)."""
