"""What one training run is: the method, its options, the data it sees, its seed and device.

:class:`TrainConfig` holds what every method shares (data sizes, seed, device, prediction batch)
and the method's own options (:class:`~compensation.methods.base.Options`). :func:`make_config`
layers a named profile, the method's profile values and explicit options, and refuses an option
the method does not have, naming the method and the option.
"""
from __future__ import annotations

import ast
import inspect
import textwrap
from dataclasses import asdict, dataclass, fields
from functools import cache
from pathlib import Path

from compensation.methods import METHODS, get_method
from compensation.methods.base import Options
from sim.errors import ProcamError

PROFILES: dict[str, dict] = {
    # The paper's setting, meant for a GPU.
    "paper": dict(n_train=500, n_test=200, size=256),
    # CPU-sized: one CompenNet run trains in about one and a half minutes on 2 cores at 64² (the
    # method's own quick profile sets its iterations and batch).
    "quick": dict(n_train=250, n_test=100, size=64),
}
"""Named settings common to every method: the training and test pairs, and ``size``, the canonical
square image size (pixels) a dataset is rendered at for that profile (training itself uses the
dataset's size)."""


@dataclass(frozen=True)
class TrainConfig:
    """How to train one method on one setup."""

    method: str = "compennet"
    """Registered method name (``compennet``, ``tps``, …)."""
    options: Options | None = None
    """The method's options (an instance of its ``options`` class); None: its defaults."""
    profile: str = "paper"
    """Profile the values came from (``paper`` or ``quick``); recorded only."""
    n_train: int | None = 500
    """Use the first n training pairs (>= 1); None uses all of them."""
    n_test: int | None = 200
    """Use the first n test pairs (>= 1); None uses all of them."""
    seed: int = 0
    """Seeds initialisation, batch order and any sampling of the method (paper 0)."""
    device: str = "auto"
    """``auto`` (CUDA if available, else CPU), ``cpu`` or ``cuda[:N]``."""
    eval_batch: int = 64
    """Images per forward pass when predicting (>= 1; does not change results)."""

    def __post_init__(self):
        cls = get_method(self.method).options
        if self.options is None:
            object.__setattr__(self, "options", cls())
        elif type(self.options) is not cls:
            raise ProcamError(f"method {self.method!r} takes {cls.__name__}, got "
                              f"{type(self.options).__name__}")
        if self.profile not in PROFILES:
            raise ProcamError(f"profile {self.profile!r}: choose one of {', '.join(PROFILES)}")
        for key in ("n_train", "n_test", "eval_batch"):
            value = getattr(self, key)
            if value is not None and (not isinstance(value, int) or isinstance(value, bool) or value < 1):
                raise ProcamError(f"{key} = {value!r}: expected a positive integer")
        if not isinstance(self.seed, int) or self.seed < 0:
            raise ProcamError(f"seed = {self.seed!r}: expected an integer >= 0")

    def to_dict(self) -> dict:
        """Every value, the options as a nested mapping (what ``config.json`` records)."""
        return {**{f.name: getattr(self, f.name) for f in fields(self) if f.name != "options"},
                "options": asdict(self.options)}

    @classmethod
    def from_dict(cls, data: dict) -> TrainConfig:
        """The inverse of :meth:`to_dict`."""
        data = dict(data)
        options = get_method(data["method"]).options(**data.pop("options"))
        return cls(options=options, **data)


COMMON = tuple(f.name for f in fields(TrainConfig) if f.name not in ("method", "options", "profile"))
"""Options every method takes."""


def make_config(profile: str = "paper", method: str = "compennet", **values) -> TrainConfig:
    """A TrainConfig from a named profile, the method's profile values and explicit values.

    Layers: :data:`PROFILES` ``[profile]``, then the method's ``Options.profiles[profile]``, then
    ``values`` (common keys of :data:`COMMON` and the method's option names; None values are
    ignored).

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
    sim.errors.ProcamError: method 'tps' does not use option 'loss' (its options: smoothing, workers; common: n_train, n_test, seed, device, eval_batch)
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
    own = {**options_cls.profiles.get(profile, {}),
           **{k: v for k, v in values.items() if k in options_cls.names()}}
    if own.get("init"):  # recorded as an absolute path: the same run from any working directory
        own["init"] = str(Path(own["init"]).resolve())
    try:
        options = options_cls(**own)
    except TypeError as exc:
        raise ProcamError(f"method {method!r}: {exc}") from None
    return TrainConfig(method=method, options=options, profile=profile, **common)


def applicable(method: str, values: dict) -> dict:
    """The entries of ``values`` that ``method`` takes (common options and its own).

    >>> applicable("tps", {"iters": 20, "seed": 1, "smoothing": 0.1})
    {'seed': 1, 'smoothing': 0.1}
    """
    names = set(COMMON) | set(get_method(method).options.names())
    return {k: v for k, v in values.items() if k in names}


@cache
def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of a dataclass (attribute docstrings), by field name.

    Examples
    --------
    >>> field_docs(TrainConfig)["seed"]
    'Seeds initialisation, batch order and any sampling of the method (paper 0).'
    """
    docs: dict[str, str] = {}
    for klass in reversed(cls.__mro__):
        if klass is object or not hasattr(klass, "__dataclass_fields__"):
            continue
        body = ast.parse(textwrap.dedent(inspect.getsource(klass))).body[0].body
        for node, after in zip(body, body[1:]):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                    and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                    and isinstance(after.value.value, str)):
                docs[node.target.id] = " ".join(after.value.value.split())
    return docs


def option_owners() -> dict[str, list[str]]:
    """Every method option name → the registered methods that take it (registry order)."""
    owners: dict[str, list[str]] = {}
    for name, cls in METHODS.items():
        for option in cls.options.names():
            owners.setdefault(option, []).append(name)
    return owners
