"""Projection surfaces: one :class:`~sim.surfaces.base.Surface` class per shape, registered by name.

A setup's ``surface.geometry`` names the class; :func:`surface_for` builds it from the setup's
surface section. The shipped surfaces are :class:`~sim.surfaces.plane.Plane` (``"plane"``) and
:class:`~sim.surfaces.corner.Corner` (``"corner"``); a new shape is a module here whose
:class:`~sim.surfaces.base.Surface` subclass is decorated with :func:`register` and imported below.

Examples
--------
>>> names()
('plane', 'corner')
>>> get_surface("corner").interreflection
True
"""
from __future__ import annotations

from typing import TYPE_CHECKING

from sim.surfaces.base import Surface

if TYPE_CHECKING:
    from sim.setup import SurfaceConfig

SURFACES: dict[str, type[Surface]] = {}
"""Registered surface classes by name, in registration order."""


def register(cls: type[Surface]) -> type[Surface]:
    """Class decorator adding a :class:`Surface` subclass to :data:`SURFACES` under ``cls.name``."""
    if cls.name in SURFACES:
        raise ValueError(f"surface {cls.name!r} is already registered ({SURFACES[cls.name].__name__})")
    SURFACES[cls.name] = cls
    return cls


def names() -> tuple[str, ...]:
    """Names of the registered surfaces, in registration order."""
    return tuple(SURFACES)


def get_surface(name: str) -> type[Surface]:
    """The surface class registered as ``name``.

    Raises
    ------
    ValueError
        If no surface has that name; the message lists the registered names.
    """
    try:
        return SURFACES[name]
    except KeyError:
        raise ValueError(f"unknown surface geometry {name!r}; expected one of: "
                         f"{', '.join(repr(n) for n in SURFACES)}") from None


def surface_for(config: SurfaceConfig) -> Surface:
    """The surface a setup's surface section describes (the class named by ``config.geometry``)."""
    return get_surface(config.geometry)(config)


# The shipped surfaces register themselves on import; the default, plane, first.
from sim.surfaces import plane  # noqa: E402,F401
from sim.surfaces import corner  # noqa: E402,F401
