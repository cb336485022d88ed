"""What a setup key's value amounts to in the units a reader compares across setups: the physical
descriptors of :data:`DESCRIPTORS` (a study records them beside its axis values)."""
from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from sim.projector.lens import lens_for
from sim.projector.scaler import frame_area
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


@dataclass(frozen=True)
class Descriptor:
    """A physical quantity a setup key sets."""

    label: str
    """What it is, e.g. ``projector blur``."""
    unit: str
    """Its unit, e.g. ``canonical px``."""
    value: Callable[[Setup, tuple[int, int]], float]
    """Its value for a setup at a canonical (width, height)."""


DESCRIPTORS = {key: Descriptor("projector defocus blur", "canonical px", projector_blur)
               for key in ("projector.aperture", "projector.focus_distance")}
"""Setup key → the physical quantity it sets."""
