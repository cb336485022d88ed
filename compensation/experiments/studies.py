"""Studies: how each method's scores change with one or two factors of a setup or of its training.

A study file (TOML; the shipped ones are ``scenes/studies/*.toml``)::

    name = "projector-defocus"      # optional, default: the file's stem
    question = "At which projector aperture does each method stop paying off?"
    base = "../default.toml"        # setup or suite file, relative to this file, or a shipped scene
    methods = ["tps", "compennet"]  # registry names
    seeds = [0, 1, 2]               # optional, default [0]
    n_train = 125                   # training pairs, or a list of sizes; default: the profile's
    n_test = 50                     # optional, default: the profile's
    size = 64                       # canonical pixels, N or [W, H]; default: the profile's
    profile = "quick"               # training profile, optional
    render_seeds = false            # optional: true renders every seed's own dataset too
    only = ["light1_*"]             # optional: setup-name patterns or point numbers to run (as --only)
    target_policy = "global"        # optional: what the closed loop scores against: none, global, image
    out_of_reach = 0.01             # optional: share of pixels a global or image target may leave out
    closed_loop = true              # optional: false scores the held-out pairs only (no re-projection)
    raw = false                     # optional: true keeps the captures at camera resolution (cam/raw)

    [setup]                         # optional: partial setup values applied to every point
    projector = { focus_distance = 0.8 }

    [options]                       # training options, for every run whose method takes them
    iters = 500                     #   (not seed, n_train, n_test: the study's own keys)

    [[axis]]                        # one or two
    key = "projector.aperture"      # a setup key "section.key", or a training option, given by the
                                    #   axis alone (not also in [setup], [options] or n_train)
    values = [0.0, 0.01, 0.02]      # distinct as results.csv writes them (decimals: 6 significant digits)
    label = "projector aperture"    # optional, default: the key
    unit = "m"                      # optional

An axis on a setup key deep-merges ``{section: {key: value}}`` onto every base setup (after the
study's ``[setup]`` values) and validates
it like a setup file (errors name the study file and the point); a number given for a key that
holds an RGB triple (``ambient.radiance``, ``surface.tint``, ``camera.white_balance``) applies to
all three channels. An axis on a training option (``n_train``, or a method option such as
``iters``) changes the runs only; a method that does not take the option is fitted once for all
its values, and a method fitted on the 125 plain colours (TPS, Nayar) once for every number of
training pairs. Two axes make the grid of their values (the *points*, numbered from 0).

The seed of a row is the training seed (:attr:`~compensation.training.config.TrainConfig.seed`:
initialisation, batch order, sampling); every seed shares one rendered dataset per point, so the
spread over seeds is the methods' own; a fit that takes no seed (TPS, Nayar) is made once, its
rows repeated per seed. With ``render_seeds = true`` the seed also shifts
``render.seed`` (the Mitsuba sampler and the camera noise: the point's render seed, from the base,
``[setup]`` or an axis, + seed) and each seed gets
its own dataset, so the spread includes the capture noise.

:func:`run_study` expands a study into jobs (:mod:`compensation.experiments.jobs`): render each
setup ``<base>__<section>-<key>-<value>`` into ``DIR/data``, fit each method per seed into
``DIR/runs/<setup>/<method>-n<n_train>-seed<seed>[-<option><value>]``, score it on held-out pairs and
in closed loop, and score each setup's baselines; then writes ``DIR/study.json`` and
``DIR/results.csv``. A finished job with the same configuration is reused, nothing else.
"""
from __future__ import annotations

import fnmatch
import itertools
import math
import re
import tomllib
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from compensation.experiments.executors import LocalExecutor
from compensation.experiments.jobs import cell_identity, check_study_folder, write_results, write_study_record
from compensation.experiments.plans import (Plan, Point, Run, Scoring, execute, fit_sizes, result_rows,
                                           run_name, slug)
from compensation.experiments.targets import DEFAULT_OUT_OF_REACH, TargetPolicy
from compensation.methods import applicable, check_runnable, get_method, make_config, option_owners
from compensation.methods.compennet import SIZE_MULTIPLE
from compensation.training.config import COMMON, PROFILES, TrainConfig
from sim.dataset import FrameSpec
from sim.descriptors import DESCRIPTORS
from sim.errors import DatasetError, ProcamError
from sim.light import AXIS_SHARES, SHARE_NAMES
from sim.options import repeated
from sim.seeds import SEED_MAX
from sim.setup import Setup, dump_setup, load_setups, merge_setup, parse_setup, suite_test_frames
from sim.setup.schema import SECTIONS
from sim.setup.toml import read_toml

STUDY_KEYS = ("name", "question", "base", "methods", "seeds", "n_train", "n_test", "size", "profile",
              "render_seeds", "only", "target_policy", "out_of_reach", "closed_loop", "raw", "setup",
              "options", "axis")
"""Keys of a study file."""
AXIS_KEYS = ("key", "values", "label", "unit")
"""Keys of an ``[[axis]]`` table."""
TRAIN_AXIS_REFUSED = ("n_test", "seed", "device", "eval_batch", "checkpoint_every")
"""Training options that cannot be an axis (seeds are their own list; the others change no score)."""
STUDY_OWN = {"seed": "its seeds are the study's seeds list", "n_train": "give the study's n_train",
             "n_test": "give the study's n_test"}
"""Training values a study sets with keys of its own, refused in ``[options]``, where they would be
overridden without a word."""
MAX_RUNS = 10_000
"""Most runs a study expands to (points × setups × seeds × methods × training sizes): each trains a
method, so more would not finish; the limit is checked before the runs are listed."""


@dataclass(frozen=True)
class Axis:
    """One factor of a study and the values it takes."""

    key: str
    """A setup key ``section.key`` or a training option (``n_train``, ``iters``, …)."""
    values: tuple
    """The values, in the order the charts draw them."""
    label: str = ""
    """Axis label for tables and charts (default: the key)."""
    unit: str = ""
    """Unit of the values (``m``, ``px``, …), or empty."""

    @property
    def on_setup(self) -> bool:
        """Whether the axis changes the setup (else the training)."""
        return "." in self.key


@dataclass(frozen=True)
class Study:
    """A study file, validated (see the module docstring for its keys)."""

    path: Path
    name: str
    question: str
    base: str
    axes: tuple[Axis, ...]
    methods: tuple[str, ...]
    seeds: tuple[int, ...] = (0,)
    n_train: tuple[int, ...] = (PROFILES["quick"]["n_train"],)
    n_test: int = PROFILES["quick"]["n_test"]
    size: tuple[int, int] = (PROFILES["quick"]["size"],) * 2
    profile: str = "quick"
    render_seeds: bool = False
    setup: dict = field(default_factory=dict)
    """Partial setup values applied to every point (before the axes)."""
    options: dict = field(default_factory=dict)
    """Training options of every run whose method takes them."""
    only: tuple[str, ...] = ()
    """Point numbers or setup-name patterns to run (``--only``); empty: all."""
    target: TargetPolicy = TargetPolicy()
    """What the closed loop scores against (``target_policy``, ``out_of_reach``)."""
    closed_loop: bool = True
    """Also project every compensation back through its setup and score the capture (false: the
    surrogate scores on held-out pairs only, for studies where re-rendering every test image of
    every run costs more than the fits)."""
    raw: bool = False
    """Keep each setup's captures at camera resolution too (``cam/raw``), which no method reads."""
    overrides: dict = field(default_factory=dict)
    """What the command line changed (recorded in ``study.json``)."""


def _error(path: Path, key: str, value, expected: str) -> ProcamError:
    return ProcamError(f"{path}: {key} = {value!r}: {expected}")


def _positive_ints(path: Path, key: str, value, allow_list: bool = True) -> tuple[int, ...]:
    items = value if allow_list and isinstance(value, list) else [value]
    if not items or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 1 for v in items):
        raise _error(path, key, value, "expected a positive integer" + (" or a list of them" if allow_list else ""))
    _once(path, key, items)
    return tuple(items)


def _once(path: Path, key: str, items: list) -> None:
    """Refuse a list of the study file that names one item twice (one run, or row, twice)."""
    if twice := repeated(items):
        raise _error(path, key, items, f"expected distinct values ({', '.join(map(repr, twice))} given twice)")


def _size(path: Path, value) -> tuple[int, int]:
    if isinstance(value, int) and not isinstance(value, bool):
        value = [value, value]
    if (not isinstance(value, list) or len(value) != 2
            or not all(isinstance(v, int) and not isinstance(v, bool) and v >= 8 for v in value)):
        raise _error(path, "size", value, "expected a side in pixels (>= 8) or [width, height]")
    return tuple(value)


def _axis(path: Path, i: int, table) -> Axis:
    where = f"axis[{i}]"
    if not isinstance(table, dict):
        raise ProcamError(f"{path}: {where}: expected a table with key and values")
    if unknown := sorted(set(table) - set(AXIS_KEYS)):
        raise ProcamError(f"{path}: {where}.{unknown[0]}: unknown key; valid keys: {', '.join(AXIS_KEYS)}")
    key, values = table.get("key"), table.get("values")
    if not isinstance(key, str) or not key:
        raise _error(path, f"{where}.key", key, "expected a setup key 'section.key' or a training option")
    if not isinstance(values, list) or not values:
        raise _error(path, f"{where}.values", values, "expected a non-empty list")
    broadcast = key in _triple_keys()  # a number there is the triple of it: 0.1 is [0.1, 0.1, 0.1]
    if len({cell_identity([v] * 3 if broadcast and isinstance(v, (int, float)) else v)
            for v in values}) < len(values):
        raise _error(path, f"{where}.values", values, "expected distinct values (1 and 1.0 are one, "
                     "and so are decimals equal to 6 significant digits, as results.csv writes them)")
    if "." in key:
        section = key.split(".", 1)[0]
        if section not in SECTIONS:
            raise _error(path, f"{where}.key", key, f"unknown setup section {section!r}; sections: "
                         f"{', '.join(SECTIONS)}")
    elif key in TRAIN_AXIS_REFUSED:
        raise _error(path, f"{where}.key", key, "not a study axis (seeds have their own list; "
                     f"{', '.join(k for k in TRAIN_AXIS_REFUSED if k != 'seed')} change no score)")
    elif key != "n_train" and key not in option_owners():
        raise _error(path, f"{where}.key", key, "expected a setup key 'section.key', n_train, or a "
                     f"method option ({', '.join(option_owners())})")
    for text_key in ("label", "unit"):
        if not isinstance(table.get(text_key, ""), str):
            raise _error(path, f"{where}.{text_key}", table[text_key], "expected a string")
    return Axis(key, tuple(values), table.get("label", key), table.get("unit", ""))


def load_study(path: Path | str, profile: str | None = None) -> Study:
    """Read and check a study file (the base and the points are checked by :func:`expand`).

    ``profile`` (the command line's ``--profile``) replaces the file's training profile: its
    methods' options, and the sizes (``n_train``, ``n_test``, ``size``) the file leaves to the
    profile; it is recorded in :attr:`Study.overrides`.

    Raises
    ------
    ProcamError
        If the file cannot be read or is not TOML, or a key or value is unknown or invalid (the
        message names the file and the key), or ``profile`` is not a profile (it names
        ``--profile``).
    """
    path = Path(path)
    data = read_toml(path, "the study file")
    if unknown := sorted(set(data) - set(STUDY_KEYS)):
        raise ProcamError(f"{path}: {unknown[0]}: unknown key; valid keys of a study: {', '.join(STUDY_KEYS)}")
    for key in ("base", "methods", "axis"):
        if key not in data:
            raise ProcamError(f"{path}: {key}: missing")
    if profile is not None and profile not in PROFILES:
        raise ProcamError(f"--profile {profile!r}: expected one of {', '.join(PROFILES)}")
    overrides = {} if profile is None else {"profile": profile}
    profile = profile or data.get("profile", "quick")
    if not isinstance(profile, str) or profile not in PROFILES:
        raise _error(path, "profile", profile, f"expected one of {', '.join(PROFILES)}")
    defaults = PROFILES[profile]
    for key in ("name", "question", "base"):
        if not isinstance(data.get(key, ""), str):
            raise _error(path, key, data[key], "expected a string")
    methods = data["methods"]
    if not isinstance(methods, list) or not methods or not all(isinstance(m, str) for m in methods):
        raise _error(path, "methods", methods, "expected a non-empty list of method names")
    for m in methods:
        try:
            get_method(m)
        except ProcamError as exc:
            raise ProcamError(f"{path}: methods: {exc}") from None
    _once(path, "methods", methods)
    seeds = data.get("seeds", [0])
    if (not isinstance(seeds, list) or not seeds
            or not all(isinstance(s, int) and not isinstance(s, bool) and 0 <= s <= SEED_MAX for s in seeds)):
        raise _error(path, "seeds", seeds, f"expected a non-empty list of integers from 0 to {SEED_MAX}")
    _once(path, "seeds", seeds)
    axes = data["axis"]
    if not isinstance(axes, list) or not 1 <= len(axes) <= 2:
        raise ProcamError(f"{path}: axis: expected one or two [[axis]] tables")
    axes = tuple(_axis(path, i, a) for i, a in enumerate(axes))
    if len({a.key for a in axes}) < len(axes):
        raise ProcamError(f"{path}: axis: the two axes have the same key {axes[0].key!r}")
    options = data.get("options", {})
    if not isinstance(options, dict):
        raise _error(path, "options", options, "expected a table of training options")
    for key, where in STUDY_OWN.items():
        if key in options:
            raise ProcamError(f"{path}: options.{key}: not a training option of a study ({where})")
    fixed = data.get("setup", {})
    if not isinstance(fixed, dict) or "name" in fixed:
        raise _error(path, "setup", fixed, "expected a table of setup sections (without a name)")
    _given_once(path, axes, data, options, fixed)
    for key in ("render_seeds", "closed_loop", "raw"):
        if key in data and not isinstance(data[key], bool):
            raise _error(path, key, data[key], "expected true or false")
    only = data.get("only", [])
    if not isinstance(only, list) or not all(isinstance(o, str) and o.strip() for o in only):
        raise _error(path, "only", only, "expected a list of setup-name patterns or point numbers")
    _once(path, "only", [o.strip() for o in only])
    try:
        target = TargetPolicy(data.get("target_policy", "global"), data.get("out_of_reach", DEFAULT_OUT_OF_REACH))
    except ProcamError as exc:
        raise ProcamError(f"{path}: {exc}") from None
    return Study(
        path=path, name=data.get("name", path.stem), question=data.get("question", ""),
        base=data["base"], axes=axes, methods=tuple(methods), seeds=tuple(seeds),
        n_train=_positive_ints(path, "n_train", data.get("n_train", defaults["n_train"])),
        n_test=_positive_ints(path, "n_test", data.get("n_test", defaults["n_test"]), False)[0],
        size=_size(path, data.get("size", defaults["size"])), profile=profile,
        render_seeds=data.get("render_seeds", False), setup=dict(fixed), options=dict(options),
        only=tuple(o.strip() for o in only), target=target, closed_loop=data.get("closed_loop", True),
        raw=data.get("raw", False), overrides=overrides)


AMBIENT_FORMS = ({"radiance"}, {"temperature", "intensity"})
"""The two forms of the room light; a setup gives one (:func:`~sim.setup.suites.merge_setup`)."""


def _given_once(path: Path, axes: tuple[Axis, ...], data: dict, options: dict, fixed: dict) -> None:
    """Refuse a value the study file gives twice, once as an axis and once more (its sizes,
    ``[options]``, ``[setup]``, the other form of the room light), where the axis would replace
    the other without a word; and a share out of reach for the target policy that takes none."""
    def twice(where: str, key: str) -> ProcamError:
        return ProcamError(f"{path}: {where}: also given by the axis on {key}, whose values replace it; "
                           "give it once")

    for key in (a.key for a in axes):
        if key == "n_train" and "n_train" in data:
            raise twice("n_train", key)
        if key in options:
            raise twice(f"options.{key}", key)
        section, _, leaf = key.partition(".")
        table = fixed.get(section)
        if leaf and isinstance(table, dict):
            if leaf in table:
                raise twice(f"setup.{section}.{leaf}", key)
            if section == "ambient" and leaf in set.union(*AMBIENT_FORMS):
                other = next(f for f in AMBIENT_FORMS if leaf not in f)
                if given := sorted(other & set(table)):
                    raise ProcamError(f"{path}: setup.ambient.{given[0]}: the room light is given as "
                                      f"{' and '.join(sorted(other))} or as radiance, and the axis on "
                                      f"{key} gives the other form, which drops it; give one form")
    if data.get("target_policy") == "none" and "out_of_reach" in data:
        raise ProcamError(f"{path}: out_of_reach: the target policy 'none' maps no target and leaves no "
                          "share out of reach; give it with 'global' or 'image'")


def with_overrides(study: Study, size: tuple[int, int] | None = None, n_train: tuple[int, ...] | None = None,
                   n_test: int | None = None, iters: int | None = None, seeds: int | None = None,
                   methods: tuple[str, ...] | None = None, only: tuple[str, ...] | None = None,
                   target_policy: str | None = None, out_of_reach: float | None = None,
                   closed_loop: bool | None = None, raw: bool | None = None) -> Study:
    """The study with the command line's overrides (None: unchanged), recorded in
    :attr:`Study.overrides`. ``n_train`` and ``iters`` replace the values of an axis on that key;
    ``seeds`` N takes the seeds 0 … N-1; ``target_policy``, ``out_of_reach``, ``closed_loop`` and
    ``raw`` replace the study file's.

    Raises
    ------
    ProcamError
        If a method is unknown, a value is not positive, a side of ``size`` is below 8 pixels (as
        the study file's), or ``seeds`` is above :data:`MAX_RUNS`.
    """
    given = {"size": size, "n_train": n_train, "n_test": n_test, "iters": iters, "seeds": seeds,
             "methods": methods, "only": only, "target_policy": target_policy, "out_of_reach": out_of_reach,
             "closed_loop": closed_loop, "raw": raw}
    given = {k: v for k, v in given.items() if v is not None}
    changes: dict = {}
    axes = list(study.axes)
    for key, value in (("n_train", n_train), ("iters", iters)):
        if value is None:
            continue
        values = tuple(value) if isinstance(value, tuple) else (value,)
        on_axis = [i for i, a in enumerate(axes) if a.key == key]
        if on_axis:
            axes[on_axis[0]] = replace(axes[on_axis[0]], values=values)
        elif key == "n_train":
            changes["n_train"] = values
        else:
            changes["options"] = {**study.options, key: value}
    if size is not None:
        if min(size) < 8:  # as the study file's size
            raise ProcamError(f"--size {'x'.join(map(str, size))}: expected sides of at least 8 pixels")
        changes["size"] = tuple(size)
    if n_test is not None:
        changes["n_test"] = n_test
    if seeds is not None:
        if seeds > MAX_RUNS:  # before the list of seeds is made
            raise ProcamError(f"--seeds {seeds}: expected at most {MAX_RUNS} (the most runs a study takes)")
        changes["seeds"] = tuple(range(seeds))
    if methods is not None:
        for m in methods:
            get_method(m)
        changes["methods"] = tuple(methods)
    if only is not None:
        changes["only"] = tuple(only)
    if closed_loop is not None:
        changes["closed_loop"] = closed_loop
    if raw is not None:
        changes["raw"] = raw
    if out_of_reach is not None and (target_policy or study.target.name) == "none":
        raise ProcamError(f"--out-of-reach {out_of_reach}: the target policy 'none' (the study's or "
                          "--target-policy) maps no target and leaves no share out of reach")
    if target_policy is not None or out_of_reach is not None:
        changes["target"] = TargetPolicy(target_policy or study.target.name,
                                         study.target.out_of_reach if out_of_reach is None else out_of_reach)
    return replace(study, axes=tuple(axes), overrides={**study.overrides, **given}, **changes)


def _triple_keys() -> set[str]:
    """Setup keys holding an RGB triple of numbers (a number given for them is broadcast)."""
    return {f"{section}.{f.name}" for section, cls in SECTIONS.items() for f in fields(cls)
            if isinstance(f.default, tuple) and len(f.default) == 3
            and all(isinstance(v, (int, float)) for v in f.default)}


def _of(study: Study, point: Point, on_setup: bool) -> dict:
    """The point's values of the axes on the setup (or on the training), by key."""
    on = {a.key: a.on_setup for a in study.axes}
    return {k: v for k, v in point.values.items() if on[k] == on_setup}


def base_path(study: Study) -> str:
    """The study's ``base``: a path relative to the study file where that file exists, else the
    name of a shipped scene."""
    candidate = study.path.parent / study.base
    return str(candidate) if candidate.exists() else study.base


def _point_setup(study: Study, base: Setup, point: Point, seed: int | None) -> Setup:
    """The base setup with the point's setup values (and, with ``seed``, its render seed)."""
    triples = _triple_keys()
    override: dict = {}
    name = base.name
    for key, value in _of(study, point, True).items():
        section, leaf = key.split(".", 1)
        name += f"__{section}-{leaf}-{slug(value)}"
        if key in triples and isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value] * 3
        override.setdefault(section, {})[leaf] = value
    mapping = merge_setup(merge_setup(tomllib.loads(dump_setup(base)), study.setup), override)
    if seed is not None:  # shifts the point's own render seed: the base's, [setup]'s or the axis's
        render = mapping.setdefault("render", {})
        own = render.get("seed", base.render.seed)  # not an integer: parse_setup refuses it by key
        render["seed"] = own + seed if isinstance(own, int) and not isinstance(own, bool) else own
        name += f"__seed{seed}"
    mapping["name"] = name
    shown = ", ".join(f"{k} = {v!r}" for k, v in _of(study, point, True).items())
    return parse_setup(mapping, f"{study.path} (point {point.index}: {shown})", study.path.parent)


def _train_config(study: Study, method: str, n_train: int, seed: int, point: Point) -> TrainConfig:
    values = {**study.options, **_of(study, point, False), "n_train": n_train, "n_test": study.n_test,
              "seed": seed}
    try:
        cfg = make_config(study.profile, method, **applicable(method, values))
        check_runnable(cfg, study.size)
        return cfg
    except ProcamError as exc:
        raise ProcamError(f"{study.path} (point {point.index}): {exc}") from None


def _selected(study: Study, point: Point, setup: str) -> bool:
    if not study.only:
        return True
    return any(item == str(point.index) or fnmatch.fnmatchcase(setup, item) for item in study.only)


def expand(study: Study) -> Plan:
    """The setups and runs of a study (nothing is rendered or trained).

    Raises
    ------
    ProcamError
        If the base cannot be loaded, the study has more than :data:`MAX_RUNS` runs, a point gives
        an invalid setup (named with the study file, the point and its values), two points give
        one setup name, the size is not divisible by 4, an option is not taken by any of the
        study's methods, a training value is invalid or cannot run here
        (:func:`~compensation.methods.check_runnable`), an item of ``only`` selects nothing, or
        ``render_seeds`` shifts two values of an axis on ``render.seed`` onto one seed.
    """
    try:
        bases = load_setups(base_path(study))
    except ProcamError as exc:
        raise ProcamError(f"{study.path}: base = {study.base!r}: {exc}") from None
    count = (math.prod(len(a.values) for a in study.axes) * len(bases) * len(study.seeds) * len(study.methods)
             * (1 if any(a.key == "n_train" for a in study.axes) else len(study.n_train)))
    if count > MAX_RUNS:  # before the runs are listed
        raise ProcamError(f"{study.path}: {count} runs (points x setups x seeds x methods x training sizes); "
                          f"expected at most {MAX_RUNS}")
    if any(side % SIZE_MULTIPLE for side in study.size):
        raise ProcamError(f"{study.path}: size {study.size[0]}x{study.size[1]} (W x H, the study's "
                          f"or --size): expected sides divisible by {SIZE_MULTIPLE}, the sizes "
                          "CompenNet takes and every method's data loader requires")
    if study.render_seeds:  # each seed its own dataset: no two points may share a shifted seed
        for axis in (a for a in study.axes if a.key == "render.seed"):
            shifted: dict = {}
            for value, seed in itertools.product(axis.values, study.seeds):
                if isinstance(value, int) and shifted.setdefault(value + seed, (value, seed)) != (value, seed):
                    first = shifted[value + seed]
                    raise ProcamError(f"{study.path}: render_seeds with the axis on render.seed: "
                                      f"{first[0]} + seed {first[1]} and {value} + seed {seed} are one "
                                      "render seed; give values further apart than the seeds")
    used = set(COMMON).union(*(get_method(m).options.names() for m in study.methods))
    if unknown := sorted(set(study.options) - used):
        key = unknown[0]
        given = (f"--{key} {study.overrides[key]}" if key in study.overrides  # the command line's
                 else f"options.{key}")
        raise ProcamError(f"{study.path}: {given}: not an option of any method of the study "
                          f"({', '.join(study.methods)}{', as --methods gives them' if 'methods' in study.overrides else ''})")
    for axis in study.axes:
        if not axis.on_setup and axis.key not in used:
            raise ProcamError(f"{study.path}: axis {axis.key!r}: not an option of any method of the "
                              f"study ({', '.join(study.methods)})")
    points = tuple(Point(i, {a.key: v for a, v in zip(study.axes, values)}) for i, values in
                   enumerate(itertools.product(*(a.values for a in study.axes))))
    train_axis = any(a.key == "n_train" for a in study.axes)
    setups: dict[str, Setup] = {}
    origin: dict[str, tuple] = {}
    runs = []
    fewest = min(next(a for a in study.axes if a.key == "n_train").values if train_axis else study.n_train)
    for point in points:
        for base in bases:
            for seed in study.seeds:
                setup = _point_setup(study, base, point, seed if study.render_seeds else None)
                key = (base.name, _of(study, point, True), seed if study.render_seeds else None)
                if origin.setdefault(setup.name, key) != key:
                    raise ProcamError(f"{study.path}: two points give the setup name {setup.name!r}; "
                                      "make the axis values differ in more than punctuation")
                if not _selected(study, point, setup.name):
                    continue
                setups.setdefault(setup.name, setup)
                sizes = (_of(study, point, False)["n_train"],) if train_axis else study.n_train
                for method in study.methods:
                    for n in sizes:
                        runs.append(_run(study, point, setup.name, method, n, seed, fewest))
    unmatched = [item for item in study.only if item not in {str(p.index) for p in points}
                 and not any(fnmatch.fnmatchcase(name, item) for name in origin)]
    if unmatched:
        given = f"--only {unmatched[0]}" if "only" in study.overrides else f"only = {unmatched[0]!r}"
        raise ProcamError(f"{study.path}: {given}: matches no point number or setup (points "
                          f"0-{len(points) - 1}; setups e.g. {next(iter(origin))})")
    return Plan(points, setups, tuple(runs))


def _run(study: Study, point: Point, setup: str, method: str, n_train: int, seed: int, fewest: int) -> Run:
    """The row of ``method`` with ``n_train`` pairs and ``seed`` at ``point``, and the run that
    gives it. Rows that differ in nothing the fit depends on share one run, fitted once: a method
    that does not take a training axis, for all its values; a method on the plain colours
    (:attr:`~compensation.methods.base.Method.plain_colours`), for every number of training pairs
    (its run loads the study's ``fewest`` and is named for the 125 it fits); an unseeded fit
    (:meth:`~compensation.methods.base.Method.seeded`), for every seed (the study's first)."""
    cls = get_method(method)
    fit_n, named_n = fit_sizes(method, n_train, fewest)
    cfg = _train_config(study, method, fit_n, seed, point)
    if not cls.seeded(cfg):
        cfg = replace(cfg, seed=study.seeds[0])
    varied = {k: v for k, v in applicable(method, _of(study, point, False)).items() if k != "n_train"}
    name = run_name(method, named_n, cfg.seed, varied)
    return Run(point, setup, method, n_train, seed, cfg, f"runs/{setup}/{name}")


def _first_setup(plan: Plan, axis: Axis, value) -> str | None:
    """The setup of the first run at an axis value (None where no run has it)."""
    return next((r.setup for r in plan.runs if r.point.values.get(axis.key) == value), None)


def physical_values(study: Study, plan: Plan, axis: Axis) -> dict | None:
    """What an axis's values amount to physically (:data:`sim.descriptors.DESCRIPTORS`): ``label``,
    ``unit`` and ``values`` (one per axis value, from the setup of the first run at that value at
    the study's size; None where no run has it), or None for a key without a descriptor."""
    descriptor = DESCRIPTORS.get(axis.key)
    if descriptor is None:
        return None
    values = []
    for value in axis.values:
        setup = _first_setup(plan, axis, value)
        try:
            values.append(None if setup is None else
                          round(descriptor.value(plan.setups[setup], tuple(study.size)), 4))
        except ProcamError:  # a setup that cannot be rendered: its point fails when rendered
            values.append(None)
    return {"label": descriptor.label, "unit": descriptor.unit, "values": values}


def measured_values(plan: Plan, axis: Axis, base: dict[str, dict]) -> dict | None:
    """What an axis on a key of :data:`sim.light.AXIS_SHARES` amounts to, measured: ``label``,
    ``unit`` and ``values`` (the share in percent, from the baselines record of the first setup at
    each axis value; None where none measured it), or None for another key."""
    share = AXIS_SHARES.get(axis.key)
    if share is None:
        return None
    values = []
    for value in axis.values:
        record = base.get(_first_setup(plan, axis, value)) or {}
        measured = (record.get("light") or {}).get(share) if record.get("ok") else None
        values.append(None if measured is None else round(100 * measured, 3))
    label, unit = SHARE_NAMES[share]
    return {"label": label, "unit": unit, "values": values}


def study_record(study: Study, plan: Plan, kind: str = "study", base: dict[str, dict] | None = None) -> dict:
    """The contents of ``study.json`` (without ``versions`` and ``created``); an axis whose key sets
    a physical quantity carries it (:func:`physical_values`), or once the baselines ran (``base``:
    setup name → baseline record) the share of light it sets, measured (:func:`measured_values`)."""
    sizes = sorted({r.n_train for r in plan.runs})
    axes = []
    for a in study.axes:
        axes.append({"key": a.key, "values": list(a.values), "label": a.label, "unit": a.unit})
        physical = physical_values(study, plan, a)
        if physical is None and base is not None:
            physical = measured_values(plan, a, base)
        if physical is not None:
            axes[-1]["physical"] = physical
    return {"name": study.name, "question": study.question, "kind": kind, "base": study.base,
            "axes": axes,
            "methods": list(study.methods), "seeds": list(study.seeds), "n_train": sizes,
            "n_test": study.n_test, "size": list(study.size), "profile": study.profile,
            "render_seeds": study.render_seeds, "only": list(study.only), "target": study.target.record(),
            "closed_loop": study.closed_loop,
            "setup_values": study.setup,
            "options": study.options,
            "overrides": {k: list(v) if isinstance(v, tuple) else v for k, v in study.overrides.items()},
            "study_file": str(study.path.resolve()),
            "setups": {name: f"data/{name}/setup.toml" for name in plan.setups}}


def run_study(study: Study, out: Path, executor=None, progress: bool = True) -> dict:
    """Run a study into the folder ``out`` (resumable) and write ``study.json`` and ``results.csv``.

    Every job runs whatever the others do: a setup that cannot be rendered or a run that fails
    gives rows of status ``failed`` with the error; an interruption stops the study (run it
    again to go on). The datasets take the test frames the base suite asks for (its
    ``test_frames``, as ``procam render`` and ``procam bench`` do), else ``mixed``.

    Parameters
    ----------
    study : Study
        The study (:func:`load_study`, :func:`with_overrides`).
    out : Path
        The study folder: ``data/<setup>/`` (datasets), ``runs/<setup>/<run>/`` (with
        ``closed_loop/img_000{1..4}.png``), ``baselines/<setup>.json``, ``study.json``,
        ``results.csv``.
    executor : LocalExecutor or RayExecutor, optional
        Where the jobs run (default: in this process, one after the other).
    progress : bool
        Progress bars (with the local executor).

    Returns
    -------
    dict
        ``study`` and ``results`` (paths), ``jobs`` (runs), ``trained`` and ``reused`` (runs),
        ``failed`` and ``rows`` (rows of ``results.csv``: failed, and all), ``setups`` (rendered or
        found finished).

    Raises
    ------
    ProcamError
        Before anything is written: if the study does not expand (:func:`expand`), its frames
        cannot be held (:class:`~sim.dataset.FrameSpec`), or ``out`` is not a folder this study
        may write (:func:`~compensation.experiments.jobs.check_study_folder`).
    """
    out = Path(out)
    executor = executor or LocalExecutor()
    plan = expand(study)
    try:
        spec = FrameSpec(max(r.n_train for r in plan.runs), study.n_test, study.size,
                         test_frames=suite_test_frames(base_path(study)) or "mixed")
    except DatasetError as e:
        raise ProcamError(f"{study.path}: {e}") from None
    check_study_folder(out, study.name, "study")
    out.mkdir(parents=True, exist_ok=True)
    record = study_record(study, plan)
    first = write_study_record(out, {**record, "executor": executor.name})
    outcome = execute(plan, out, out / "data", spec, Scoring(study.n_test, study.closed_loop, target=study.target), executor,
                      list(plan.setups), progress, study.raw)
    if any(a.key in AXIS_SHARES for a in study.axes):  # the light its axis sets, now measured
        write_study_record(out, {**study_record(study, plan, base=outcome.base), "executor": executor.name},
                           first["created"])
    rows = result_rows(plan, outcome, out)
    results = write_results(out, [a.key for a in study.axes], rows)
    fitted = [d for d in outcome.fitted.values() if not d.get("skipped")]
    trained = sum(1 for d in fitted if d["ok"] and d["trained"])
    return {"study": out / "study.json", "results": results, "jobs": len(fitted), "trained": trained,
            "reused": sum(1 for d in fitted if d["ok"]) - trained,
            "failed": sum(1 for row in rows if row["status"] == "failed"), "rows": len(rows),
            "setups": len(outcome.base)}


def study_file(spec: str) -> Path:
    """The study file a command line names: an existing path, else a study shipped in
    ``scenes/studies/`` by name (``projector-defocus``, with or without ``.toml``).

    Raises
    ------
    ProcamError
        If neither exists (the message lists the shipped studies).
    """
    path = Path(spec)
    if path.exists():
        return path
    from sim.setup import scene_path

    folder = scene_path("default").parent / "studies"
    candidate = folder / (spec if spec.endswith(".toml") else f"{spec}.toml")
    if re.fullmatch(r"[A-Za-z0-9_.-]+", spec) and candidate.is_file():
        return candidate
    shipped = sorted(p.stem for p in folder.glob("*.toml"))
    raise ProcamError(f"{spec}: no such study file, and not a shipped study; shipped: "
                      f"{', '.join(shipped) or 'none'}")

