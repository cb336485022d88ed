"""What a setup key's value amounts to in the units a reader compares across setups: the physical
descriptors of :data:`DESCRIPTORS` (a study records them beside its axis values)."""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim.camera import thinlens
from sim.errors import ProcamError
from sim.projector.lens import lens_for
from sim.projector.scaler import frame_area
from sim.registration import exact_map
from sim.setup import Setup


def projector_blur(setup: Setup, size: tuple[int, int]) -> float:
    """The projector's defocus blur in canonical pixels: the median diameter of the defocus disks
    of the panel pixels the input frame lands on (:func:`~sim.projector.lens.lens_for`), over the
    panel pixels per canonical pixel (:func:`~sim.projector.scaler.frame_area`); 0 in focus.

    Parameters
    ----------
    setup : Setup
        The setup.
    size : (int, int)
        Canonical (width, height) in pixels.
    """
    lens = lens_for(setup)
    if lens.diameters is None:
        return 0.0
    p = setup.projector
    x0, y0, w, h = (int(v) for v in frame_area(tuple(p.resolution), tuple(size), p.keep_aspect))
    disks = lens.diameters[lens.pad + y0:lens.pad + y0 + h, lens.pad + x0:lens.pad + x0 + w]
    return float(np.median(disks)) * size[0] / w


def camera_blur(setup: Setup, size: tuple[int, int]) -> float:
    """The camera's defocus blur in canonical pixels: the median diameter of the thin lens's disks
    (:func:`sim.camera.thinlens.diameters`, in camera pixels) where the canonical pixels are
    seen, over the camera pixels per canonical pixel there (the exact map's spacing, the geometric
    mean of its two directions); 0 for a pinhole. The same whether the lens is rendered in image
    space or traced.

    Parameters
    ----------
    setup, size
        As for :func:`projector_blur`.

    Raises
    ------
    ProcamError
        If a disk is wider than :data:`sim.camera.thinlens.MAX_DISK_PX`, or no two
        neighbouring canonical pixels are seen.
    """
    if setup.camera.aperture_radius <= 0:
        return 0.0
    wmap = exact_map(setup, size)
    disks = thinlens.diameters(setup)
    h, w = disks.shape
    seen = wmap.mask
    cols = np.clip(wmap.xy[..., 0].astype(int), 0, w - 1)
    rows = np.clip(wmap.xy[..., 1].astype(int), 0, h - 1)
    dx = np.linalg.norm(np.diff(wmap.xy, axis=1), axis=-1)[seen[:, 1:] & seen[:, :-1]]
    dy = np.linalg.norm(np.diff(wmap.xy, axis=0), axis=-1)[seen[1:] & seen[:-1]]
    if not (dx.size and dy.size):
        raise ProcamError(f"setup {setup.name!r}: the camera sees too little of the projected frame "
                          "to measure its blur in canonical pixels")
    per_canonical = math.sqrt(float(np.median(dx)) * float(np.median(dy)))
    return float(np.median(disks[rows[seen], cols[seen]])) / per_canonical


@dataclass(frozen=True)
class Descriptor:
    """A physical quantity a setup key sets."""

    label: str
    """What it is, e.g. ``projector blur``."""
    unit: str
    """Its unit, e.g. ``canonical px``."""
    value: Callable[[Setup, tuple[int, int]], float]
    """Its value for a setup at a canonical (width, height)."""


DESCRIPTORS = {**{key: Descriptor("projector defocus blur", "canonical px", projector_blur)
                  for key in ("projector.aperture", "projector.focus_distance")},
               **{key: Descriptor("camera defocus blur", "canonical px", camera_blur)
                  for key in ("camera.aperture_radius", "camera.focus_distance")}}
"""Setup key → the physical quantity it sets."""
