"""The registry of compensation methods: every method by name, one module each.

Add a method by writing one module with a :class:`~compensation.methods.base.Method` subclass
(and its :class:`~compensation.methods.base.Options`), then adding the class to :data:`METHODS`
below.

>>> sorted(METHODS)
['compennet', 'compennet-nosurf', 'nayar', 'pix2pix', 'tps', 'tps-textured']
>>> get_method("tps").options.names()
('smoothing', 'workers')
"""
from __future__ import annotations

from compensation.methods.base import Method
from compensation.methods.compennet import CompenNetMethod, CompenNetNoSurfMethod
from compensation.methods.nayar import NayarMethod
from compensation.methods.pix2pix import Pix2PixMethod
from compensation.methods.tps import TPSMethod, TPSTexturedMethod
from sim.errors import ProcamError

METHODS: dict[str, type[Method]] = {cls.name: cls for cls in (
    CompenNetMethod, CompenNetNoSurfMethod, TPSMethod, TPSTexturedMethod, NayarMethod, Pix2PixMethod)}
"""Registered methods by name."""


def get_method(name: str) -> type[Method]:
    """The method class registered as ``name``.

    Raises
    ------
    ProcamError
        If no method has that name; the message lists the registered names.
    """
    try:
        return METHODS[name]
    except KeyError:
        raise ProcamError(f"unknown method {name!r}; choose one of: {', '.join(sorted(METHODS))}") from None
