"""Stages of a device's chain: the keys each declares, what it does, flagged optical, processing,
linear or random.

A stage is declared by its own module: its options (a frozen dataclass of keys declared with
:mod:`sim.options`, the keys of the device's setup section it reads), its function and its
flags, as one :class:`Stage`. The projector (:data:`sim.projector.chain.CHAIN`) and the camera
(:data:`sim.camera.chain.CHAIN`) each list their stages in the order light meets them, a
:class:`Fused` group standing for consecutive stages applied by one function (fused for speed).
The device's setup section is composed from the stages' options (:func:`sim.options.combine`,
in :mod:`sim.setup.schema`), :func:`run` applies a chain, and what depends on a kind of stage is
derived from the flags instead of kept by hand: :func:`switch_off` of the optical and the
processing stages gives the camera's sensor alone (what :mod:`sim.fidelity` measures the noise
floor with), :func:`streams_version` of the random stages the version of a capture's random
streams.
"""
from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from sim.options import option_fields


@dataclass(frozen=True)
class Stage:
    """One stage of a chain."""

    name: str
    """Short name, unique in its chain."""
    options: type
    """Its keys: a frozen dataclass of options declared with :mod:`sim.options`, one field per key
    of the device's setup section the stage reads (the field's docstring documents the key)."""
    what: str
    """What it does."""
    apply: Callable[..., Any] | None = None
    """Its function on the chain's data, with the signature of its chain (see the chain's module);
    None for a stage applied by its :class:`Fused` group or outside the chain (by Mitsuba)."""
    optical: bool = False
    """The lens or another optical element (not the sensor nor its processing)."""
    processing: bool = False
    """Processing of the encoded image after the response curve (tone, colour, sharpening): a
    rendering of the sensor's measurement, not part of it."""
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
        if self.optical and self.processing:
            raise ValueError(f"stage {self.name!r}: an optical stage does not process the encoded image")
        if (self.optical or self.processing) and not self.off:
            kind = "an optical" if self.optical else "a processing"
            raise ValueError(f"stage {self.name!r}: {kind} stage must be able to be switched off")

    @property
    def keys(self) -> tuple[str, ...]:
        """The keys it reads: the fields of :attr:`options`."""
        return tuple(f.name for f in option_fields(self.options))

    @property
    def stages(self) -> tuple[Stage, ...]:
        """The stage itself (as :attr:`Fused.stages`)."""
        return (self,)

    def is_off(self, cfg: Any) -> bool:
        """True when ``cfg`` switches the stage off: each key of :attr:`off` at its off value (a
        key ``cfg`` lacks counts as off)."""
        return bool(self.off) and all(getattr(cfg, k, v) == v for k, v in self.off.items())


@dataclass(frozen=True)
class Fused:
    """Consecutive stages of a chain applied by one function, fused for speed; each keeps its own
    keys and flags."""

    name: str
    """Short name, unique in its chain."""
    stages: tuple[Stage, ...]
    """Its stages, in the order light meets them."""
    apply: Callable[..., Any]
    """The function that applies them all, with the signature of the chain."""

    def is_off(self, cfg: Any) -> bool:
        """True when ``cfg`` switches every one of its stages off."""
        return all(s.is_off(cfg) for s in self.stages)


def stages_of(chain: Iterable[Stage | Fused]) -> tuple[Stage, ...]:
    """The stages of a chain in order, those of a :class:`Fused` group in its place."""
    return tuple(s for item in chain for s in item.stages)


def run(chain: Iterable[Stage | Fused], x: Any, cfg: Any, *args: Any) -> Any:
    """``x`` through each item of ``chain`` in order, ``item.apply(x, cfg, *args)``, skipping (at
    no cost) the items ``cfg`` switches off and the stages applied outside the chain."""
    for item in chain:
        if item.apply is not None and not item.is_off(cfg):
            x = item.apply(x, cfg, *args)
    return x


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
    >>> from dataclasses import make_dataclass
    >>> none = make_dataclass("NoKeys", [])
    >>> streams_version([Stage("a", none, "", random=True, streams=lambda: 3), Stage("b", none, "")])
    3
    >>> streams_version([Stage("a", none, "", random=True, streams=lambda: 3),
    ...                  Stage("c", none, "", random=True, streams=lambda: 1)])
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
