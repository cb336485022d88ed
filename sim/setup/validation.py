"""Validation of a setup mapping (a parsed setup file) into a :class:`~sim.setup.schema.Setup`.

Everything is checked here, before any rendering. Each section is read by the one validator of
:mod:`sim.options` from the declarations of :mod:`sim.setup.schema` (and of the surface's own
options): unknown keys, a surface key that the chosen surface does not take, wrong types (a bool
is not a number; an int is accepted where a float is expected), vector lengths, ranges and
choices raise :class:`~sim.errors.SetupError` naming the file, the dotted key and what was
expected, e.g. ``scenes/bad.toml: camera.fov = -5.0: expected a number in (1, 120) degrees``.
The checks that involve more than one key follow: usable poses, the texture file (relative to
the setup file), the ambient light's two forms, inter-reflection against the rendering level.
Every key but ``name`` is optional and takes the dataclass default of :mod:`sim.setup.schema`.
"""
from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

from sim import images, surfaces
from sim.errors import DatasetError, SetupError
from sim.io import read_png
from sim.layout import SPLITS
from sim.options import Table, keys_of, parse, shown
from sim.setup.schema import NAME_PATTERN, SECTIONS, AmbientConfig, Setup, SurfaceConfig, temperature_rgb


def _texture_file(cfg: SurfaceConfig, data: Mapping, t: Table, base_dir: Path) -> SurfaceConfig:
    """``surface.texture``: a generator kind as it is, else an image file, resolved against
    ``base_dir`` (the setup file's folder) and checked to be a readable 8-bit RGB image."""
    value = cfg.texture
    if value == "uniform" or value in images.SURFACE_KINDS:
        return cfg
    kinds = ", ".join(f'"{k}"' for k in ("uniform", *images.SURFACE_KINDS))
    path = (base_dir / value).resolve()
    if not path.is_file():
        raise t.error("texture", value, f"expected {kinds} or an existing image file; "
                                        f"file not found: {path}")
    if path.suffix.lower() not in images.IMAGE_SUFFIXES:
        raise t.error("texture", value, f"expected an image file ({', '.join(images.IMAGE_SUFFIXES)}); "
                                        f"got {path}")
    try:
        read_png(path)
    except DatasetError as exc:
        raise t.error("texture", value, f"expected an 8-bit RGB image file; {exc}") from None
    return replace(cfg, texture=str(path))


def _pose(cfg, data: Mapping, t: Table, base_dir: Path):
    """A projector's or camera's ``position``, ``look_at`` and ``up`` checked for a usable view:
    in front of the surface, looking towards it, ``up`` across the optical axis."""
    (px, py, pz), (lx, ly, lz), up = cfg.position, cfg.look_at, cfg.up
    if not pz > 0:
        raise t.error("position", cfg.position, "expected z > 0 metres (in front of the surface at z = 0)")
    axis = (lx - px, ly - py, lz - pz)
    if not axis[2] < 0:
        raise t.error("look_at", cfg.look_at, f"expected a point of smaller z than "
                                              f"{t.dotted('position')} (the view looks towards -z)")
    cross = (up[1] * axis[2] - up[2] * axis[1], up[2] * axis[0] - up[0] * axis[2],
             up[0] * axis[1] - up[1] * axis[0])
    if math.hypot(*cross) <= 1e-9 * math.hypot(*up) * math.hypot(*axis):
        raise t.error("up", up, f"expected a direction not parallel to {t.dotted('look_at')} - "
                                f"{t.dotted('position')}")
    return cfg


def _ambient(cfg: AmbientConfig, data: Mapping, t: Table, base_dir: Path) -> AmbientConfig:
    """The ambient light's two forms: ``radiance``, or ``temperature`` with ``intensity`` (the
    radiance resolved from them)."""
    if "radiance" in data and "temperature" in data:
        raise SetupError(f"{t.source}: {t.dotted('radiance')} and {t.dotted('temperature')} both given: "
                         f"expected exactly one of {t.dotted('radiance')} or {t.dotted('temperature')} "
                         f"(with {t.dotted('intensity')})")
    if "temperature" not in data:
        if "intensity" in data:
            raise t.error("intensity", data["intensity"],
                          f"expected only together with {t.dotted('temperature')} "
                          f"(use {t.dotted('radiance')} for an RGB ambient)")
        return cfg
    if "intensity" not in data:
        raise t.error("intensity", None, f"missing: expected a number >= 0 (luminance) together "
                                         f"with {t.dotted('temperature')}")
    return replace(cfg, radiance=tuple(c * cfg.intensity for c in temperature_rgb(cfg.temperature)))


_CROSS_CHECKS = {"surface": _texture_file, "projector": _pose, "camera": _pose, "ambient": _ambient}
"""Per section, the checks that involve more than one key or the setup file's folder, run on the
section once its keys are checked: ``(section, table data, Table, base_dir) -> section``."""


def _check_interreflection(setup: Setup, source: str, prefix: str) -> None:
    """A surface whose parts light each other (a corner's wings): only path tracing of depth >= 3
    renders that."""
    geometry = setup.surface.geometry
    if not surfaces.get_surface(geometry).interreflection:
        return
    r = setup.render
    if r.fidelity in ("direct", "transport"):
        raise SetupError(f'{source}: {prefix}render.fidelity = "{r.fidelity}": expected "path" or "auto" for '
                         f'{prefix}surface.geometry = "{geometry}": its parts light each other '
                         "(inter-reflection), which only path tracing renders")
    if r.max_depth < 3:
        raise SetupError(f"{source}: {prefix}render.max_depth = {r.max_depth}: expected an integer >= 3 "
                         f'for {prefix}surface.geometry = "{geometry}" (inter-reflection needs a path depth '
                         "of at least 3)")


_SECTION_KEYS = {section: keys_of(cls) for section, cls in SECTIONS.items()}
"""Every key each section takes (its variants' included): where an unknown key of one belongs."""


def parse_setup(mapping: Mapping, source: str = "<string>", base_dir: Path | str | None = None,
                prefix: str = "") -> Setup:
    """Validate a setup mapping (e.g. from :func:`tomllib.load`).

    Parameters
    ----------
    mapping : Mapping
        ``name`` plus the optional sections ``surface``, ``projector``, ``camera``, ``ambient``,
        ``render`` and ``registration``.
    source : str
        Name of the file the mapping came from, for error messages.
    base_dir : Path or str, optional
        Folder that a relative ``surface.texture`` path is relative to; defaults to the current
        working directory.
    prefix : str
        Put before every dotted key in messages, e.g. ``"setup[3]."`` for an entry of a suite.

    Returns
    -------
    Setup

    Raises
    ------
    SetupError
        Naming ``source``, the dotted key and what was expected.
    """
    base_dir = Path.cwd() if base_dir is None else Path(base_dir)
    if not isinstance(mapping, Mapping):
        raise SetupError(f"{source}: {prefix.rstrip('.') or 'setup'}: expected a table")
    for key, value in mapping.items():
        if key != "name" and key not in SECTIONS:
            what = "section" if isinstance(value, Mapping) else "key"
            raise SetupError(f"{source}: {prefix}{key}: unknown {what}; valid keys: name and the "
                             f"sections {', '.join(SECTIONS)}")
    if "name" not in mapping:
        raise SetupError(f"{source}: {prefix}name: missing; expected a string matching {NAME_PATTERN}")
    name = mapping["name"]
    if not isinstance(name, str) or not re.fullmatch(NAME_PATTERN, name):
        raise SetupError(f"{source}: {prefix}name = {shown(name)}: expected a string matching {NAME_PATTERN}")
    if name.lower() in SPLITS:
        raise SetupError(f"{source}: {prefix}name = {shown(name)}: a dataset root's frame folder has that "
                         f"name ({', '.join(SPLITS)} are taken); choose another")
    sections = {}
    for section, cls in SECTIONS.items():
        data = mapping.get(section, {})
        if not isinstance(data, Mapping):
            raise SetupError(f"{source}: {prefix}{section} = {shown(data)}: expected a table [{section}]")
        table = Table(source, prefix + section)
        homes = {key: [f"[{s}]" for s, keys in _SECTION_KEYS.items() if key in keys]
                 for key in data if key not in _SECTION_KEYS[section]}
        sections[section] = parse(cls, data, table, {k: " and ".join(v) for k, v in homes.items() if v})
        if section in _CROSS_CHECKS:
            sections[section] = _CROSS_CHECKS[section](sections[section], data, table, base_dir)
    setup = Setup(name=name, **sections)
    _check_interreflection(setup, source, prefix)
    return setup
