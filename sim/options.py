"""Declared options: dataclass fields that carry their own validation, and the one validator.

A setup section (:mod:`sim.setup.schema`) or a surface's own options (:mod:`sim.surfaces`) is a
frozen dataclass whose every field is declared with one of the helpers below — :func:`number`,
:func:`integer`, :func:`vector`, :func:`matrix`, :func:`choice`, :func:`boolean`, :func:`string`
or :func:`variant` — each of which puts the field's :class:`Spec` (kind, range, unit, choices) in
its metadata; the field's docstring documents it. :func:`parse` checks a mapping (one table of a
setup file) against such a dataclass from those specs alone: a key missing from the mapping takes
the field's default, a key the dataclass does not declare is refused, and a dataclass with a
field declared without a spec cannot be parsed at all (:func:`spec_of` raises), so no key can be
read without being checked. :func:`repeated` finds a list's values given twice (the study file's
and the command line's lists take each value once).

Examples
--------
>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class Lamp:
...     power: float = number(1.0, POSITIVE, "watts")
...     colour: str = choice("white", ("white", "amber"))
>>> parse(Lamp, {"power": 3}, Table("lamp.toml", "lamp"))
Lamp(power=3.0, colour='white')
>>> parse(Lamp, {"power": -1}, Table("lamp.toml", "lamp"))
Traceback (most recent call last):
...
sim.errors.SetupError: lamp.toml: lamp.power = -1: expected a number > 0 watts
"""
from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping
from dataclasses import Field, dataclass, field, fields, make_dataclass
from typing import Any

from sim.errors import SetupError

SPEC = "procam.option"
"""The key of a field's metadata that holds its :class:`Spec`."""


@dataclass(frozen=True)
class Range:
    """An interval of numbers.

    Examples
    --------
    >>> str(Range(1, 120, lo_open=True, hi_open=True)), 0.5 in Range(0, 1), str(Range(0))
    ('in (1, 120)', True, '>= 0')
    """

    lo: float | None = None
    """Lower bound; None: none."""
    hi: float | None = None
    """Upper bound; None: none."""
    lo_open: bool = False
    """True: the lower bound itself is excluded."""
    hi_open: bool = False
    """True: the upper bound itself is excluded."""

    def __contains__(self, x: float) -> bool:
        if self.lo is not None and (x <= self.lo if self.lo_open else x < self.lo):
            return False
        return self.hi is None or (x < self.hi if self.hi_open else x <= self.hi)

    def __str__(self) -> str:
        if self.lo is not None and self.hi is not None:
            return f"in {'(' if self.lo_open else '['}{self.lo:g}, {self.hi:g}{')' if self.hi_open else ']'}"
        if self.lo is not None:
            return f"{'>' if self.lo_open else '>='} {self.lo:g}"
        if self.hi is not None:
            return f"{'<' if self.hi_open else '<='} {self.hi:g}"
        return ""


ANY = Range()
"""Every number."""
POSITIVE = Range(0, lo_open=True)
"""Numbers > 0."""
NON_NEGATIVE = Range(0)
"""Numbers >= 0."""
UNIT = Range(0, 1)
"""Numbers in [0, 1]."""

KINDS = ("number", "integer", "vector", "matrix", "choice", "boolean", "string", "variant")
"""What a key holds (:attr:`Spec.kind`)."""


@dataclass(frozen=True)
class Spec:
    """How one key is checked: its kind and, as the kind needs, range, unit, length or choices."""

    kind: str
    """One of :data:`KINDS`."""
    range: Range = ANY
    """Numbers (each entry of a vector or matrix) must lie in it."""
    unit: str = ""
    """Unit or meaning shown in messages (``"metres"``, ``"(linear RGB)"``)."""
    length: int = 0
    """Entries of a vector (rows and columns of a square matrix)."""
    integer: bool = False
    """A vector of integers instead of numbers."""
    choices: tuple | Callable[[], tuple] = ()
    """The strings a choice accepts (a function returning them, for lists made elsewhere)."""
    check: Callable[[Any], None] | None = None
    """Further check of a value that has the kind: raises ValueError saying what was expected."""
    selector: str = ""
    """A variant: the field (before it in the same dataclass) whose value picks the variant."""
    variants: Mapping[str, type] | None = None
    """A variant: the options dataclass of each value of :attr:`selector`."""

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"option kind {self.kind!r}: expected one of {', '.join(KINDS)}")

    def expected(self) -> str:
        """What a valid value is, for messages (e.g. ``expected a number in (1, 120) degrees``)."""
        if self.kind == "number":
            what = f"expected a number {self.range}"
        elif self.kind == "integer":
            what = f"expected an integer {self.range}"
        elif self.kind == "vector":
            each = f", each {self.range}" if str(self.range) else ""
            what = f"expected a list of {self.length} {'integers' if self.integer else 'numbers'}{each}"
        elif self.kind == "matrix":
            n = self.length
            what = f"expected a {n}x{n} matrix (a list of {n} lists of {n} numbers), each entry {self.range}"
        elif self.kind == "choice":
            what = f"expected one of {', '.join(shown(c) for c in self.options())}"
        elif self.kind == "boolean":
            what = "expected true or false"
        elif self.kind == "string":
            what = "expected a string"
        else:
            what = "expected the options of " + self.selector
        return " ".join(filter(None, (what.rstrip(), self.unit)))

    def options(self) -> tuple:
        """The values a choice accepts."""
        return self.choices() if callable(self.choices) else tuple(self.choices)

    def value(self, value: Any) -> Any:
        """``value`` checked and converted (ints to floats where numbers are expected, lists to
        tuples); raises ValueError with :meth:`expected` or the message of :attr:`check`."""
        numbers = [] if self.integer else [v for v in _entries(value, self.kind)
                                           if _is_number(v) and v == v and abs(v) != math.inf]
        if any(abs(v) > FLOAT32_MAX for v in numbers):
            raise ValueError(f"{self.expected()}, and at most {FLOAT32_MAX:.3g} in magnitude (captures "
                             "are computed in float32)")
        if any(0 < abs(v) < FLOAT32_TINY for v in numbers):
            least = f"{'0 or ' if 0 in self.range else ''}at least {FLOAT32_TINY:.3g}"
            raise ValueError(f"{self.expected()}, and {least} in magnitude (a smaller number is 0 in the "
                             "float32 the captures are computed in)")
        if self.kind == "number":
            ok = _is_number(value) and _finite(value) and value in self.range
            out = float(value) if ok else None
        elif self.kind == "integer":
            ok = _is_integer(value) and value in self.range
            out = value
        elif self.kind == "vector":
            ok = _is_list(value, self.length) and all(self._entry(v) for v in value)
            out = tuple(int(v) if self.integer else float(v) for v in value) if ok else None
        elif self.kind == "matrix":
            ok = _is_list(value, self.length) and all(
                _is_list(row, self.length) and all(self._entry(v) for v in row) for row in value)
            out = tuple(tuple(float(v) for v in row) for row in value) if ok else None
        elif self.kind == "choice":
            ok = isinstance(value, str) and value in self.options()
            out = value
        elif self.kind == "boolean":
            ok, out = isinstance(value, bool), value
        elif self.kind == "string":
            ok, out = isinstance(value, str), value
        else:
            raise TypeError("a variant's keys are read by sim.options.parse")
        if not ok:
            raise ValueError(self.expected())
        if self.check is not None:
            self.check(out)
        return out

    def _entry(self, v: Any) -> bool:
        ok = _is_integer(v) if self.integer else _is_number(v) and _finite(v)
        return ok and v in self.range


FLOAT32_MAX = 3.4028234663852886e38
"""The largest float32: captures are computed in float32, so a larger number is not a value."""
FLOAT32_TINY = 1.1754943508222875e-38
"""The smallest normal float32: a positive number below it is rounded towards 0 in float32."""


def _finite(value: float) -> bool:
    """Finite in float32, the precision the renderer and the camera compute in (an integer of
    any size is compared exactly, not converted).

    >>> _finite(1e30), _finite(1e39), _finite(float("nan")), _finite(10 ** 400)
    (True, False, False, False)
    """
    return abs(value) <= FLOAT32_MAX


def _entries(value: Any, kind: str) -> list:
    """The entries of a number, vector or matrix value as given (anything else: none)."""
    if kind == "number":
        return [value]
    if kind == "vector" and isinstance(value, (list, tuple)):
        return list(value)
    if kind == "matrix" and isinstance(value, (list, tuple)):
        return [v for row in value if isinstance(row, (list, tuple)) for v in row]
    return []


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _is_integer(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _is_list(value: Any, n: int) -> bool:
    return isinstance(value, (list, tuple)) and len(value) == n


def _declare(default: Any, spec: Spec) -> Any:
    return field(default=default, metadata={SPEC: spec})


def number(default: float | None, range: Range = ANY, unit: str = "") -> float:
    """A number (an int is accepted) in ``range``; ``default`` None: optional, None when not given."""
    return _declare(default, Spec("number", range, unit))


def integer(default: int, range: Range = ANY, unit: str = "",
            check: Callable[[Any], None] | None = None) -> int:
    """An integer in ``range`` (``check``: a further condition)."""
    return _declare(default, Spec("integer", range, unit, check=check))


def vector(default: tuple, range: Range = ANY, unit: str = "", integer: bool = False) -> tuple:
    """A list of ``len(default)`` numbers (or integers), each in ``range``."""
    return _declare(default, Spec("vector", range, unit, length=len(default), integer=integer))


def matrix(default: tuple, range: Range = ANY) -> tuple:
    """A square matrix (list of rows) of ``len(default)`` rows of numbers, each in ``range``."""
    return _declare(default, Spec("matrix", range, length=len(default)))


def choice(default: str, choices: tuple | Callable[[], tuple]) -> str:
    """One of ``choices`` (strings; a function returning them for a list kept elsewhere)."""
    return _declare(default, Spec("choice", choices=choices))


def boolean(default: bool) -> bool:
    """true or false."""
    return _declare(default, Spec("boolean"))


def string(default: str, check: Callable[[Any], None] | None = None) -> str:
    """A string (``check``: a further condition, raising ValueError)."""
    return _declare(default, Spec("string", check=check))


def variant(selector: str, variants: Mapping[str, type]) -> Any:
    """The options of the variant that field ``selector`` names (``variants[value]``, a dataclass
    of declared options), read from the same table; None (the default) stands for the variant's
    defaults until the owning dataclass fills it in."""
    return _declare(None, Spec("variant", selector=selector, variants=variants))


def spec_of(f: Field) -> Spec:
    """The :class:`Spec` of a dataclass field.

    Raises
    ------
    TypeError
        If the field was declared without one of this module's helpers: no key is read unchecked.
    """
    spec = f.metadata.get(SPEC)
    if spec is None:
        raise TypeError(f"option {f.name!r} is declared without a check: declare it with "
                        "sim.options.number, integer, vector, matrix, choice, boolean, string or variant")
    return spec


def shown(value: Any) -> str:
    """A value as a setup file writes it (TOML), for messages; cut to 80 characters.

    Examples
    --------
    >>> print(shown({"fov": [40, True, "wide"]}))
    {fov = [40, true, "wide"]}
    """
    if isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = json.dumps(value, ensure_ascii=False)  # a TOML basic string has JSON's escapes
    elif isinstance(value, (list, tuple)):
        text = "[" + ", ".join(shown(v) for v in value) + "]"
    elif isinstance(value, Mapping):
        text = "{" + ", ".join(f"{k} = {shown(v)}" for k, v in value.items()) + "}"
    else:
        text = repr(value)
    return text if len(text) <= 80 else text[:77] + "..."


@dataclass(frozen=True)
class Table:
    """Where a table under validation sits, for messages."""

    source: str
    """The file it came from."""
    key: str
    """Its dotted path, e.g. ``camera`` or ``setup[3].camera``."""

    def dotted(self, name: str) -> str:
        """The dotted path of key ``name`` of the table."""
        return f"{self.key}.{name}"

    def error(self, name: str, value: Any, expected: str) -> SetupError:
        """The error for key ``name``: ``FILE: table.name = VALUE: EXPECTED`` (``value`` None: not
        shown)."""
        assigned = "" if value is None else f" = {shown(value)}"
        return SetupError(f"{self.source}: {self.dotted(name)}{assigned}: {expected}")


def option_fields(cls: type) -> list[Field]:
    """The fields of an options dataclass, each with its :class:`Spec` (:func:`spec_of`)."""
    found = fields(cls)
    for f in found:
        spec_of(f)
    return list(found)


def combine(name: str, parts: tuple[type, ...], doc: str, module: str) -> type:
    """One frozen options dataclass whose fields are those of ``parts``, in order (a device's setup
    section from the options its stages declare, :mod:`sim.setup.schema`).

    Parameters
    ----------
    name : str
        The class's name.
    parts : tuple of type
        Options dataclasses, each field declared with this module's helpers.
    doc : str
        The class's docstring.
    module : str
        The module that holds it as ``name`` (so its instances pickle).

    Raises
    ------
    TypeError
        If two parts declare the same key, or a field is declared without a spec.

    Examples
    --------
    >>> @dataclass(frozen=True)
    ... class Lens:
    ...     blur: float = number(0.0)
    >>> @dataclass(frozen=True)
    ... class Lamp:
    ...     power: float = number(1.0, POSITIVE, "watts")
    >>> Device = combine("Device", (Lens, Lamp), "A device.", __name__)
    >>> Device(power=2.0)
    Device(blur=0.0, power=2.0)
    """
    found: dict[str, type] = {}
    declared = []
    for part in parts:
        for f in option_fields(part):
            if f.name in found:
                raise TypeError(f"{name}: key {f.name!r} declared by both {found[f.name].__name__} "
                                f"and {part.__name__}")
            found[f.name] = part
            declared.append((f.name, f.type, field(default=f.default, metadata=f.metadata)))
    cls = make_dataclass(name, declared, frozen=True)
    cls.__doc__, cls.__module__ = doc, module
    return cls


def flat_items(options: Any) -> dict[str, Any]:
    """The keys and values of an options dataclass as its table holds them: a variant's own keys
    in the variant field's place.

    Examples
    --------
    >>> from dataclasses import dataclass
    >>> @dataclass(frozen=True)
    ... class Tube:
    ...     length: float = number(1.0)
    >>> @dataclass(frozen=True)
    ... class Shape:
    ...     kind: str = choice("tube", ("tube",))
    ...     own: object = variant("kind", {"tube": Tube})
    ...     colour: str = string("red")
    >>> flat_items(Shape("tube", Tube(2.0)))
    {'kind': 'tube', 'length': 2.0, 'colour': 'red'}
    """
    out = {}
    for f in option_fields(type(options)):
        value = getattr(options, f.name)
        if spec_of(f).kind == "variant":
            out.update(flat_items(value))
        else:
            out[f.name] = value
    return out


def keys_of(cls: type) -> set[str]:
    """Every key a table of ``cls`` takes: its fields', and those of each of its variants."""
    keys = set()
    for f in option_fields(cls):
        spec = spec_of(f)
        if spec.kind == "variant":
            keys.update(g.name for options in spec.variants.values() for g in option_fields(options))
        else:
            keys.add(f.name)
    return keys


def parse(cls: type, data: Mapping, table: Table, elsewhere: Mapping[str, str] | None = None) -> Any:
    """An options dataclass from one table of a setup file, every key checked by its spec.

    Keys missing from ``data`` take the field's default (an optional key, default None, stays
    None). A variant field (:func:`variant`) is read from the same table once its selector is
    known: the selected variant's keys are checked by their own specs, and a key of another
    variant is refused.

    Parameters
    ----------
    cls : type
        A frozen dataclass whose every field is declared with this module's helpers.
    data : Mapping
        The table.
    table : Table
        Where it is, for messages.
    elsewhere : Mapping, optional
        Keys of other tables, each to where it belongs (e.g. ``"[projector]"``): an unknown key
        found there is pointed to it.

    Returns
    -------
    cls instance

    Raises
    ------
    SetupError
        Naming the file, the dotted key, the value and what was expected: for an unknown key, a
        key of another variant, or a value that fails its spec.
    TypeError
        If a field of ``cls`` (or of a variant) was declared without a spec (:func:`spec_of`).
    """
    own = option_fields(cls)
    variants = {f.name: {value: {g.name for g in option_fields(options)}
                         for value, options in spec_of(f).variants.items()}
                for f in own if spec_of(f).kind == "variant"}
    shared = {f.name for f in own if f.name not in variants}
    every = keys_of(cls)
    section = table.key.rsplit(".", 1)[-1]
    for name in data:
        if name not in every:
            home = f"; {name} is a key of {elsewhere[name]}" if elsewhere and name in elsewhere else ""
            raise table.error(name, None, f"unknown key; valid keys of [{section}]: {', '.join(sorted(every))}"
                                          + home)
    values: dict[str, Any] = {}
    for f in own:
        spec = spec_of(f)
        if spec.kind == "variant":
            chosen = values[spec.selector]
            keys = variants[f.name][chosen]
            for name in data:
                takers = [value for value, ks in variants[f.name].items() if name in ks]
                if takers and name not in keys:
                    raise table.error(name, data[name], (
                        f"not a key of {table.dotted(spec.selector)} = {shown(chosen)} (only of "
                        f"{', '.join(shown(t) for t in takers)}); valid keys of [{section}]: "
                        f"{', '.join(sorted(shared | keys))}"))
            values[f.name] = parse(spec.variants[chosen], {k: v for k, v in data.items() if k in keys}, table)
            continue
        given = f.name in data
        value = data[f.name] if given else f.default
        if value is None and not given:  # an optional key left out
            values[f.name] = None
            continue
        try:
            values[f.name] = spec.value(value)
        except ValueError as exc:
            raise table.error(f.name, value, str(exc)) from None
    return cls(**values)


def repeated(values) -> list:
    """The values given more than once, each once, in the order of their ``repr`` (a list of runs,
    rows or option values names each once).

    >>> repeated([8, 4, "a", 8, "a", 4, 2])
    ['a', 4, 8]
    """
    values = list(values)
    return sorted({v for v in values if values.count(v) > 1}, key=repr)
