"""Suites of setups, the shipped scenes, and what a command line names: a file, a suite or a scene.

A suite file holds ``base = "default.toml"`` (relative to the suite file) and ``[[setup]]`` tables,
each a ``name`` plus partial overrides deep-merged onto the base (:func:`load_suite`), and may say
which kind of test frames its datasets take (``test_frames``, :func:`suite_test_frames`). The shipped
setup and suite files are the package ``procam_scenes`` (the ``scenes/`` folder), found by name
with :func:`scene_path`.
"""
from __future__ import annotations

import copy
import importlib.resources
import re
from collections.abc import Mapping
from pathlib import Path

from sim import images, surfaces
from sim.errors import SetupError
from sim.options import option_fields, shown
from sim.setup.schema import NAME_PATTERN, Setup, SurfaceConfig
from sim.setup.toml import read_toml
from sim.setup.validation import parse_setup


def merge_setup(base: Mapping, override: Mapping) -> dict:
    """Deep merge of ``override`` onto ``base`` (tables recursively, other values replaced).

    The two forms of the ambient light exclude each other: an override giving ``radiance`` drops
    the base's ``temperature``/``intensity`` and one giving ``temperature`` drops its ``radiance``.
    An override giving another ``surface.geometry`` drops the keys only the base's surface takes
    (a corner's ``corner_angle`` when the override chooses a plane).

    Examples
    --------
    >>> merge_setup({"surface": {"geometry": "corner", "corner_angle": 60.0, "size": [1, 1]}},
    ...             {"surface": {"geometry": "plane"}})
    {'surface': {'geometry': 'plane', 'size': [1, 1]}}
    """
    out = copy.deepcopy(dict(base))
    for key, value in override.items():
        if isinstance(value, Mapping) and isinstance(out.get(key), Mapping):
            merged = dict(out[key])
            if key == "ambient":
                if "radiance" in value:
                    merged.pop("temperature", None)
                    merged.pop("intensity", None)
                if "temperature" in value:
                    merged.pop("radiance", None)
            if key == "surface" and "geometry" in value:
                for name in _shape_keys(merged.get("geometry", SurfaceConfig.geometry), value["geometry"]):
                    merged.pop(name, None)
            out[key] = merge_setup(merged, value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _shape_keys(old: object, new: object) -> set[str]:
    """The keys surface ``old`` takes and surface ``new`` does not (none for an unknown name,
    which validation reports)."""
    def keys(name: object) -> set[str]:
        cls = surfaces.SURFACES.get(name) if isinstance(name, str) else None
        return {f.name for f in option_fields(cls.Options)} if cls else set()

    return keys(old) - keys(new)


SUITE_KEYS = ("base", "setup", "test_frames")
"""The top-level keys of a suite file."""


def load_suite(path: Path | str) -> list[Setup]:
    """Read a suite file: ``base`` (a setup file, relative to the suite) and ``[[setup]]`` tables.

    Each ``[[setup]]`` table holds a ``name`` and partial overrides that are deep-merged onto the
    base file's mapping (see :func:`merge_setup` for the ambient light) and validated; errors name
    the suite file and the key as ``setup[i].section.key`` (i from 0). Relative texture paths are
    relative to the file that gives them.

    Parameters
    ----------
    path : Path or str
        The suite file.

    Returns
    -------
    list of Setup
        In file order.

    Raises
    ------
    SetupError
        If a file cannot be read, a key or value is invalid, or two setups share a name.
    """
    path = Path(path)
    return _suite(read_toml(path), path)


def _suite(suite: Mapping, path: Path) -> list[Setup]:
    """The setups of a suite file's mapping (see :func:`load_suite`)."""
    source = str(path)
    for key in suite:
        if key not in SUITE_KEYS:
            raise SetupError(f"{source}: {key}: unknown key; valid keys of a suite: {', '.join(SUITE_KEYS)}")
    _test_frames(suite, source)
    base_data: dict = {}
    if "base" in suite:
        if not isinstance(suite["base"], str):
            raise SetupError(f"{source}: base = {shown(suite['base'])}: expected the path of a setup file")
        base_path = path.parent / suite["base"]
        base_data = read_toml(base_path)
        base = parse_setup(base_data, str(base_path), base_path.parent)
        if "texture" in base_data.get("surface", {}):
            base_data["surface"]["texture"] = base.surface.texture  # resolved against the base's folder
    entries = suite.get("setup")
    if not isinstance(entries, list) or not entries or not all(isinstance(e, Mapping) for e in entries):
        raise SetupError(f"{source}: setup: expected one or more [[setup]] tables")
    setups, seen = [], {}
    for i, entry in enumerate(entries):
        prefix = f"setup[{i}]."
        if "name" not in entry:
            raise SetupError(f"{source}: {prefix}name: missing; expected a string matching {NAME_PATTERN}")
        setup = parse_setup(merge_setup(base_data, entry), source, path.parent, prefix)
        if setup.name.lower() in seen:  # one folder on a case-insensitive file system
            raise SetupError(f'{source}: {prefix}name = "{setup.name}": expected a unique name (letter case '
                             f"aside); setup[{seen[setup.name.lower()]}] has it too")
        seen[setup.name.lower()] = i
        setups.append(setup)
    return setups


def _test_frames(suite: Mapping, source: str) -> str | None:
    """A suite mapping's ``test_frames`` (None where it does not say), checked."""
    value = suite.get("test_frames")
    if value is not None and value not in images.FRAME_KINDS:
        raise SetupError(f"{source}: test_frames = {shown(value)}: expected one of "
                         f"{', '.join(repr(k) for k in images.FRAME_KINDS)}")
    return value


def suite_test_frames(spec: str) -> str | None:
    """The kind of test frames (:data:`sim.images.FRAME_KINDS`) a suite file asks its datasets to
    take, its ``test_frames``; None for a setup file or a suite that does not say (the commands
    then generate ``mixed`` frames). ``spec`` as :func:`load_setups` takes it.

    Raises
    ------
    SetupError
        If the file cannot be read, or its ``test_frames`` is not a kind of frames.
    """
    path = Path(spec)
    if not path.exists():
        path = scene_path(spec)
    data = read_toml(path)
    return _test_frames(data, str(path)) if "setup" in data else None


def select_setups(setups: list[Setup], only: str | None, source: str) -> list[Setup]:
    """The setups named in ``only`` (``NAME[,NAME…]``), in the suite's order; all for None.

    Parameters
    ----------
    setups : list of Setup
        A suite's setups (:func:`load_setups`).
    only : str or None
        Comma-separated setup names (the ``--only`` option of ``procam render`` and ``bench``).
    source : str
        What the setups came from, for messages (the suite file or scene name).

    Raises
    ------
    SetupError
        If a name is empty, not a setup of the suite (the message lists the valid names) or given
        twice.
    """
    if only is None:
        return setups
    names = [n.strip() for n in only.split(",")]
    valid = [s.name for s in setups]
    if not any(names):
        raise SetupError(f"--only {only!r}: expected one or more comma-separated setup names of {source}")
    unknown = [n for n in names if n not in valid]
    if unknown:
        raise SetupError(f"--only {only}: no setup named {', '.join(repr(n) for n in unknown)} in "
                         f"{source}; its setups: {', '.join(valid)}")
    if twice := sorted({n for n in names if names.count(n) > 1}):
        raise SetupError(f"--only {only}: {', '.join(twice)} given twice; expected each setup once")
    return [s for s in setups if s.name in names]


def _shipped_dir():
    """The folder of the shipped setup files (package ``procam_scenes``)."""
    try:
        return importlib.resources.files("procam_scenes")
    except NotADirectoryError:
        # setuptools' editable installs add a non-folder placeholder to the namespace package's
        # path, which importlib.resources of Python 3.11 rejects: take the real folder.
        import procam_scenes

        return next(Path(p) for p in procam_scenes.__path__ if Path(p).is_dir())


def scene_path(name: str) -> Path:
    """Path of a shipped setup or suite file by name.

    Parameters
    ----------
    name : str
        ``"default"``, ``"ideal"``, ``"white"``, ``"corner"``, ``"defocus"``, ``"suite"`` (with or without
        ``.toml``).

    Returns
    -------
    Path

    Raises
    ------
    SetupError
        If no shipped file has that name (the message lists the shipped names).
    """
    folder = _shipped_dir()
    stem = name[:-5] if name.endswith(".toml") else name
    candidate = folder / f"{stem}.toml"
    if re.fullmatch(NAME_PATTERN, stem) and candidate.is_file():
        return Path(str(candidate))
    shipped = sorted(p.name[:-5] for p in folder.iterdir() if p.name.endswith(".toml"))
    raise SetupError(f"{name}: no such setup file, and not a shipped scene; shipped: {', '.join(shipped)}")


def load_setups(spec: str) -> list[Setup]:
    """The setups a command line names: a setup file, a suite file or a shipped scene name.

    Parameters
    ----------
    spec : str
        A path to an existing setup or suite file (a suite is a file with ``[[setup]]`` tables),
        else the name of a shipped one (:func:`scene_path`).

    Returns
    -------
    list of Setup
        One setup for a setup file, the suite's setups in file order for a suite.

    Raises
    ------
    SetupError
        If the file cannot be read or a setup in it is invalid, or no shipped file has that name.
    """
    path = Path(spec)
    if not path.exists():
        path = scene_path(spec)
    data = read_toml(path)
    return _suite(data, path) if "setup" in data else [parse_setup(data, str(path), path.parent)]
