"""Stages of a device's chain: what each reads and does, flagged optical, linear or random.

The projector (:data:`sim.projector.chain.STAGES`) and the camera
(:data:`sim.camera.chain.STAGES`) each list their stages in the order light meets them. What
depends on a kind of stage is derived from the flags instead of kept by hand:
:func:`switch_off` of the optical stages gives the camera's sensor alone (what
:mod:`sim.fidelity` measures the noise floor with), :func:`streams_version` of the random stages
the version of a capture's random streams.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any


@dataclass(frozen=True)
class Stage:
    """One stage of a chain."""

    name: str
    """Short name, unique in its chain."""
    keys: tuple[str, ...]
    """Keys of the device's setup section the stage reads."""
    what: str
    """What it does, and where (the function that applies it)."""
    optical: bool = False
    """The lens or another optical element (not the sensor nor its processing)."""
    linear: bool = False
    """Linear in the projector's light: a sum of inputs gives the sum of outputs."""
    random: bool = False
    """Draws random numbers."""
    off: Mapping[str, Any] = field(default_factory=dict)
    """Values of its keys that switch the stage off (empty: it cannot be switched off)."""
    streams: Callable[[], int] | None = None
    """A random stage's version of its random streams (1..999), bumped whenever it draws
    differently; needed where the chain's :func:`streams_version` is recorded (the camera's)."""

    def __post_init__(self):
        if self.streams is not None and not self.random:
            raise ValueError(f"stage {self.name!r}: draws no random numbers, so has no streams version")
        if not set(self.off) <= set(self.keys):
            raise ValueError(f"stage {self.name!r}: switches off keys it does not read: "
                             f"{sorted(set(self.off) - set(self.keys))}")
        if self.optical and not self.off:
            raise ValueError(f"stage {self.name!r}: an optical stage must be able to be switched off")


def switch_off(cfg: Any, stages: Iterable[Stage]) -> Any:
    """``cfg`` (a frozen dataclass) with each of ``stages`` switched off (:attr:`Stage.off`).

    Raises
    ------
    ValueError
        If a stage cannot be switched off.
    """
    values: dict[str, Any] = {}
    for stage in stages:
        if not stage.off:
            raise ValueError(f"stage {stage.name!r} cannot be switched off")
        values.update(stage.off)
    return replace(cfg, **values)


def streams_version(stages: Iterable[Stage]) -> int:
    """Version of the random streams of a chain: the versions of its random stages
    (:attr:`Stage.streams`), in chain order, as the digits of one number in base 1000. A chain
    with one random stage has that stage's version; a stage that draws differently, or a random
    stage added or removed, gives another number.

    Examples
    --------
    >>> streams_version([Stage("a", (), "", random=True, streams=lambda: 3), Stage("b", (), "")])
    3
    >>> streams_version([Stage("a", (), "", random=True, streams=lambda: 3),
    ...                  Stage("c", (), "", random=True, streams=lambda: 1)])
    3001
    """
    version = 0
    for stage in stages:
        if stage.random:
            if stage.streams is None:
                raise ValueError(f"stage {stage.name!r}: random, without a streams version")
            v = stage.streams()
            if not 1 <= v <= 999:
                raise ValueError(f"stage {stage.name!r}: streams version {v}: expected 1..999")
            version = version * 1000 + v
    return version
