"""The registry of compensation methods: every method by name, one module each, and the run
configurations built from a method's name.

Add a method by writing one module with a :class:`~compensation.methods.base.Method` subclass
(its :class:`~compensation.training.config.Options` and its training recipe), then adding the
class to :data:`METHODS` below.

>>> sorted(METHODS)
['compennet', 'compennet-nosurf', 'nayar', 'pix2pix', 'tps', 'tps-textured']
>>> get_method("tps").options.names()
('smoothing', 'scale_invariant', 'workers')
"""
from __future__ import annotations

from pathlib import Path

from compensation.methods.base import Method, parse_device, weights_file
from compensation.methods.compennet import CompenNetMethod, CompenNetNoSurfMethod
from compensation.methods.nayar import NayarMethod
from compensation.methods.pix2pix import Pix2PixMethod
from compensation.methods.tps import TPSMethod, TPSTexturedMethod
from compensation.training.config import COMMON, PROFILES, TrainConfig
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


def make_config(profile: str = "paper", method: str = "compennet", **values) -> TrainConfig:
    """A TrainConfig from a named profile, the method's profile values and explicit values.

    Layers: :data:`PROFILES` ``[profile]``, then the method's ``Options.profiles[profile]``, then
    what the explicit options imply (``Options.implied``), then ``values`` (common keys of
    :data:`COMMON` and the method's option names; None values are ignored).

    Raises
    ------
    ProcamError
        If the profile or method is unknown, a key is neither common nor an option of the method
        (the message names the method, the option and the options it has), or a value is out of
        range.

    Examples
    --------
    >>> make_config("quick", "compennet", iters=20).options.iters
    20
    >>> make_config("quick", "tps", loss="ssim")
    Traceback (most recent call last):
    ...
    sim.errors.ProcamError: method 'tps' does not use option 'loss' (its options: smoothing, scale_invariant, workers; common: n_train, n_test, seed, device, eval_batch, checkpoint_every)
    """
    if profile not in PROFILES:
        raise ProcamError(f"profile {profile!r}: choose one of {', '.join(PROFILES)}")
    options_cls = get_method(method).options
    values = {k: v for k, v in values.items() if v is not None}
    if unknown := [k for k in values if k not in COMMON and k not in options_cls.names()]:
        raise ProcamError(
            f"method {method!r} does not use option{'s' if len(unknown) > 1 else ''} "
            f"{', '.join(repr(k) for k in unknown)} (its options: "
            f"{', '.join(options_cls.names()) or 'none'}; common: {', '.join(COMMON)})")
    common = {k: v for k, v in PROFILES[profile].items() if k in COMMON}
    common.update({k: v for k, v in values.items() if k in COMMON})
    explicit = {k: v for k, v in values.items() if k in options_cls.names()}
    implied = {k: v for name in explicit for k, v in options_cls.implied.get(name, {}).items()}
    own = {**options_cls.profiles.get(profile, {}), **implied, **explicit}
    # init is recorded as an absolute path: the same run from any working directory
    if isinstance(own.get("init"), str) and own["init"].strip():
        own["init"] = str(Path(own["init"]).resolve())
    try:
        options = options_cls(**own)
    except TypeError as exc:
        raise ProcamError(f"method {method!r}: {exc}") from None
    return TrainConfig(method=method, options=options, profile=profile, **common)


def config_from_dict(data: dict) -> TrainConfig:
    """The inverse of :meth:`TrainConfig.to_dict <compensation.training.config.TrainConfig.to_dict>`.

    >>> cfg = make_config("quick", "tps")
    >>> config_from_dict(cfg.to_dict()) == cfg
    True
    """
    data = dict(data)
    options = get_method(data["method"]).options(**data.pop("options"))
    return check_config(TrainConfig(options=options, **data))


def check_config(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` itself, once its options are checked to be its method's own dataclass.

    Raises
    ------
    ProcamError
        If the method is unknown or its options are another method's.
    """
    cls = get_method(cfg.method).options
    if type(cfg.options) is not cls:
        raise ProcamError(f"method {cfg.method!r} takes {cls.__name__}, got {type(cfg.options).__name__}")
    return cfg


def check_runnable(cfg: TrainConfig, size: tuple[int, int] | None) -> None:
    """Check what a run needs beyond the ranges of its values, before anything is rendered for
    it: a device name torch knows (whether this machine has it is checked where the run is
    fitted: a cluster's workers may), the weights its ``init`` option names and, where its
    images' ``size`` (width, height) in pixels is known, a patch window within them and a size
    its network takes.

    >>> check_runnable(make_config("quick", "compennet", patch=64), (32, 32))  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    sim.errors.ProcamError: option patch = 64: expected at most the images' shorter side, 32 pixels ...

    Raises
    ------
    ProcamError
        Naming the option and what was expected.
    """
    parse_device(cfg.device)
    init = getattr(cfg.options, "init", None)
    if init is not None and not weights_file(init).is_file():
        raise ProcamError(f"option init = {init!r}: no weights there (expected a run folder holding "
                          f"{weights_file('').name} or a state dict file)")
    if size is not None:
        get_method(cfg.method).check_image_size(cfg.options, *size)


def applicable(method: str, values: dict) -> dict:
    """The entries of ``values`` that ``method`` takes (common options and its own).

    >>> applicable("tps", {"iters": 20, "seed": 1, "smoothing": 0.1})
    {'seed': 1, 'smoothing': 0.1}
    """
    names = set(COMMON) | set(get_method(method).options.names())
    return {k: v for k, v in values.items() if k in names}



def option_owners() -> dict[str, list[str]]:
    """Every method option name → the registered methods that take it (registry order)."""
    owners: dict[str, list[str]] = {}
    for name, cls in METHODS.items():
        for option in cls.options.names():
            owners.setdefault(option, []).append(name)
    return owners
