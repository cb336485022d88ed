"""Projection surfaces: one :class:`~sim.surfaces.base.Surface` class per shape, registered by name.

A setup's ``surface.geometry`` names the class; :func:`surface_for` builds it from the setup's
surface section. The shipped surfaces are :class:`~sim.surfaces.plane.Plane` (``"plane"``) and
:class:`~sim.surfaces.corner.Corner` (``"corner"``); a new shape is a module here with a
:class:`~sim.surfaces.base.Surface` subclass, added to :data:`SURFACES` below.

Examples
--------
>>> names()
('plane', 'corner')
>>> get_surface("corner").interreflection
True
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from sim.errors import SetupError
from sim.surfaces.base import Surface
from sim.surfaces.corner import Corner
from sim.surfaces.plane import Plane

if TYPE_CHECKING:
    from sim.setup import SurfaceConfig

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


def surface_for(config: SurfaceConfig) -> Surface:
    """The surface a setup's surface section describes (the class named by ``config.geometry``)."""
    return get_surface(config.geometry)(config)

