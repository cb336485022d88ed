"""What one training run is: the method, its options, the data it sees, its seed and device.

:class:`Options` is the base of every method's own options (a frozen dataclass, one documented
field per option); :class:`TrainConfig` holds what every method shares (data sizes, seed, device,
prediction batch) and the method's options. Building a configuration for a method by name (profiles
layered under explicit values, options the method does not take refused) needs the method registry:
:func:`compensation.methods.make_config`.
"""
from __future__ import annotations

import ast
import inspect
import re
import textwrap
from dataclasses import asdict, dataclass, fields
from functools import cache
from typing import ClassVar

from sim.errors import ProcamError
from sim.options import FLOAT32_MAX, FLOAT32_TINY
from sim.seeds import SEED_MAX

MAX_ITERS = 10 ** 6
"""Most iterations of a network method (the paper trains CompenNet for 1000, pix2pix for 10,000):
the loss log is allocated with one row per iteration before training starts."""


@dataclass(frozen=True)
class Options:
    """Base of every method's options: a frozen dataclass, one documented field per option.

    Subclasses declare fields with defaults (the paper's values, or None where the paper's rule
    derives one from another field) and a docstring each (unit, range, paper value);
    :func:`field_docs` reads those docstrings for the command line. ``profiles`` holds
    per-profile defaults (keys of :data:`PROFILES`) layered under explicit values; :meth:`check`
    validates ranges.
    """

    profiles: ClassVar[dict[str, dict]] = {}
    """Field values per training profile, layered over the field defaults."""
    implied: ClassVar[dict[str, dict]] = {}
    """Values an explicitly given option implies, by option name: they replace the profile's
    (an explicit value of their own still wins), so that an option of one mode, given alone,
    selects that mode."""

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Raise :class:`ProcamError` naming the option and the expected range (none by default)."""

    def _require(self, name: str, ok: bool, expected: str) -> None:
        """Raise a :class:`ProcamError` "``name`` = value: expected …" unless ``ok``."""
        if not ok:
            raise ProcamError(f"option {name} = {getattr(self, name)!r}: expected {expected}")

    def _optional_path(self, name: str) -> None:
        """Check that the named field is None or a non-empty path text."""
        value = getattr(self, name)
        self._require(name, value is None or (isinstance(value, str) and value.strip() != ""),
                      "the path of a run folder or of a state dict file")

    def _positive_ints(self, *names: str, most: int | None = None) -> None:
        """Check that each named field is an integer >= 1 (None allowed where typed optional), and
        at most ``most`` where given."""
        for name in names:
            value = getattr(self, name)
            self._require(name, value is None or (isinstance(value, int) and not isinstance(value, bool)
                                                  and value >= 1), "a positive integer")
            if most is not None and value is not None:
                self._require(name, value <= most, f"a positive integer, at most {most}")

    def _number(self, name: str, positive: bool) -> None:
        """Check that the named field is a number > 0 (``positive``) or >= 0 that float32, in
        which training computes, holds: at most :data:`~sim.options.FLOAT32_MAX`, and 0 or at
        least :data:`~sim.options.FLOAT32_TINY` (float32 rounds a smaller one towards 0)."""
        value = getattr(self, name)
        expected = "a positive number" if positive else "a number >= 0"
        self._require(name, isinstance(value, (int, float)) and not isinstance(value, bool)
                      and (value > 0 if positive else value >= 0), expected)
        self._require(name, value <= FLOAT32_MAX and (value == 0 or value >= FLOAT32_TINY),
                      f"{'a number' if positive else '0 or a number'} from {FLOAT32_TINY:.3g} to "
                      f"{FLOAT32_MAX:.3g} (training computes in float32)")

    def label(self) -> str:
        """What a table names beside the method when its rows could differ in these options (e.g.
        a spline's smoothing); empty by default."""
        return ""

    def tag(self) -> str:
        """The same in an official output tag (letters, digits, ``.``; empty by default)."""
        return ""

    @classmethod
    def names(cls) -> tuple[str, ...]:
        """The option names, in declaration order."""
        return tuple(f.name for f in fields(cls))


@dataclass(frozen=True)
class NoOptions(Options):
    """Options of a method that has none."""


PROFILES: dict[str, dict] = {
    # The paper's setting, meant for a GPU.
    "paper": dict(n_train=500, n_test=200, size=256),
    # CPU-sized: one CompenNet run trains in about one and a half minutes on 2 cores at 64² (the
    # method's own quick profile sets its iterations and batch).
    "quick": dict(n_train=250, n_test=100, size=64),
    # The paper's 256² canonical view on 2 CPU cores: Table 1's smallest training set and half the
    # paper's test pairs (each method's own faithful profile keeps the paper's recipe where a CPU
    # affords it: CompenNet trains on windows, benchmarks/results/patches/README.md).
    "faithful": dict(n_train=125, n_test=100, size=256),
}
"""Named settings common to every method: the training and test pairs, and ``size``, the canonical
square image size (pixels) a dataset is rendered at for that profile (training itself uses the
dataset's size)."""


CHECKPOINT_EVERY = 50
"""The default of :attr:`TrainConfig.checkpoint_every`."""


@dataclass(frozen=True)
class TrainConfig:
    """How to train one method on one setup."""

    method: str
    """Registered method name (``compennet``, ``tps``, …)."""
    options: Options
    """The method's options (an instance of its ``options`` class; the registry's
    :func:`~compensation.methods.make_config` builds the right one by method name)."""
    profile: str = "paper"
    """Profile the values came from (a key of :data:`PROFILES`: ``paper``, ``quick`` or
    ``faithful``); recorded only."""
    n_train: int | None = 500
    """Use the first n training pairs (>= 1); not given on the command line, the profile's count
    (quick 250, faithful 125, paper 500); None in a configuration uses all of them."""
    n_test: int | None = 200
    """Use the first n test pairs (>= 1); not given on the command line, the profile's count
    (quick 100, faithful 100, paper 200); None in a configuration uses all of them."""
    seed: int = 0
    """Seeds initialisation, batch order and any sampling of the method (0 to 2³²−1; paper 0)."""
    device: str = "auto"
    """``auto`` (CUDA if available, else CPU), ``cpu`` or ``cuda[:N]``."""
    eval_batch: int = 64
    """Images per forward pass when predicting (>= 1; does not change results)."""
    checkpoint_every: int = CHECKPOINT_EVERY
    """Iterations between the training-state checkpoints of an iterative method (>= 1; a
    CompenNet checkpoint is ~13 MB with Adam's moments): how much an interrupted run loses. A
    resumed run gives the results of an uninterrupted one whatever the interval, so it is not
    part of a run's identity (:data:`NOT_IDENTITY`)."""

    def __post_init__(self):
        if not isinstance(self.options, Options):
            raise ProcamError(f"method {self.method!r}: options must be the method's Options "
                              f"dataclass, got {type(self.options).__name__}")
        if self.profile not in PROFILES:
            raise ProcamError(f"profile {self.profile!r}: choose one of {', '.join(PROFILES)}")
        for key in ("n_train", "n_test", "eval_batch", "checkpoint_every"):
            value = getattr(self, key)
            if value is None and key in ("n_train", "n_test"):  # every pair
                continue
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ProcamError(f"{key} = {value!r}: expected a positive integer")
        if not isinstance(self.seed, int) or isinstance(self.seed, bool) or not 0 <= self.seed <= SEED_MAX:
            raise ProcamError(f"seed = {self.seed!r}: expected an integer from 0 to {SEED_MAX}")

    def to_dict(self) -> dict:
        """Every value, the options as a nested mapping (what ``config.json`` records)."""
        return {**{f.name: getattr(self, f.name) for f in fields(self) if f.name != "options"},
                "options": asdict(self.options)}


COMMON = tuple(f.name for f in fields(TrainConfig) if f.name not in ("method", "options", "profile"))
"""Options every method takes."""
NOT_IDENTITY = ("device", "checkpoint_every")
"""Options that do not make a run another run: a finished or interrupted run made with other
values of these is reused or resumed (the device's type aside, results are the same)."""


@cache
def field_docs(cls: type) -> dict[str, str]:
    """The docstring under each field of a dataclass (attribute docstrings), by field name, as
    plain text (the command line's help): roles such as ``:data:`X``` and double back-quotes are
    reduced to their text.

    Examples
    --------
    >>> field_docs(TrainConfig)["seed"]
    'Seeds initialisation, batch order and any sampling of the method (0 to 2³²−1; paper 0).'
    >>> field_docs(TrainConfig)["options"]
    "The method's options (an instance of its options class; the registry's make_config builds the right one by method name)."
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
                docs[node.target.id] = plain_text(after.value.value)
    return docs


def plain_text(doc: str) -> str:
    r"""A docstring fragment as one line of plain text: reST roles and literals reduced to their text.

    >>> plain_text(":data:`SIZE_MULTIPLE` pixels, ``None`` uses\n  :func:`~compensation.methods.make_config`")
    'SIZE_MULTIPLE pixels, None uses make_config'
    """
    doc = re.sub(r":\w+:`~?([^`]+)`", lambda m: m.group(1).rsplit(".", 1)[-1], doc)
    return " ".join(doc.replace("``", "").split())
