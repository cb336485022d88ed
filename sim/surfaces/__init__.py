"""Projection surfaces: one :class:`~sim.surfaces.base.Surface` class per shape, registered by name.

A setup's ``surface.geometry`` names the class; :func:`surface_for` builds it from the setup's
surface section. The shipped surfaces are :class:`~sim.surfaces.plane.Plane` (``"plane"``) and
:class:`~sim.surfaces.corner.Corner` (``"corner"``, with its own key ``corner_angle``); a new
shape is a module here with a :class:`~sim.surfaces.base.Surface` subclass and its ``Options``
dataclass (the keys only it takes, declared with :mod:`sim.options`), added to :data:`SURFACES`
below: setup files can then select it and give its keys, checked like every other key.

Examples
--------
>>> names()
('plane', 'corner')
>>> get_surface("corner").interreflection
True
"""
from __future__ import annotations

from typing import Any

from sim.errors import SetupError
from sim.surfaces.base import Surface
from sim.surfaces.corner import Corner
from sim.surfaces.plane import Plane

SURFACES: dict[str, type[Surface]] = {cls.name: cls for cls in (Plane, Corner)}
"""Registered surface classes by name; the default, plane, first."""


def names() -> tuple[str, ...]:
    """Names of the registered surfaces, in registration order."""
    return tuple(SURFACES)


def get_surface(name: str) -> type[Surface]:
    """The surface class registered as ``name``.

    Raises
    ------
    SetupError
        If no surface has that name; the message lists the registered names.
    """
    try:
        return SURFACES[name]
    except KeyError:
        raise SetupError(f"unknown surface geometry {name!r}; expected one of: "
                         f"{', '.join(repr(n) for n in SURFACES)}") from None


def surface_for(config: Any) -> Surface:
    """The surface a setup's surface section (:class:`sim.setup.SurfaceConfig`) describes: the
    class named by its ``geometry``, built from its ``size``, ``texture_resolution`` and ``shape``
    (the surface's own options)."""
    return get_surface(config.geometry)(config.size, config.texture_resolution, config.shape)

