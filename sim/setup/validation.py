"""Validation of a setup mapping (a parsed setup file) into a :class:`~sim.setup.schema.Setup`.

Everything is checked here, before any rendering: unknown keys or sections, wrong types (a bool
is not a number; an int is accepted where a float is expected), vector lengths, ranges, missing
or undecodable texture files, unknown camera responses and inconsistent combinations raise
:class:`~sim.errors.SetupError` naming the file, the dotted key and what was expected, e.g.
``scenes/bad.toml: camera.fov = -5.0: expected a number in (1, 120) degrees``. Every key but
``name`` is optional and takes the dataclass default of :mod:`sim.setup.schema`.
"""
from __future__ import annotations

import json
import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from sim import images, surfaces
from sim.errors import DatasetError, SetupError
from sim.io import read_png
from sim.setup.schema import (NAME_PATTERN, REGISTRATION_METHODS, SECTIONS, TEMPERATURE_RANGE, AmbientConfig,
                              CameraConfig, ProjectorConfig, RegistrationConfig, RenderConfig, Setup,
                              SurfaceConfig, temperature_rgb)


@dataclass(frozen=True)
class _Range:
    """An interval of numbers; ``None`` bounds are open-ended."""

    lo: float | None = None
    hi: float | None = None
    lo_open: bool = False
    hi_open: bool = False

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


_ANY = _Range()
_POSITIVE = _Range(0, lo_open=True)
_NON_NEGATIVE = _Range(0)
_UNIT = _Range(0, 1)
_FOV = _Range(1, 120, True, True)
_PIXELS = _Range(8, 4096)
_SPP = _Range(1, 65536)


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


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


class _Table:
    """One table of a setup mapping under validation: typed getters with clear errors.

    ``key`` is the dotted path of the table in messages (e.g. ``camera`` or
    ``setup[3].camera``); missing entries take the defaults of the dataclass ``cls``.
    """

    def __init__(self, data: Mapping, cls: type, source: str, key: str):
        self.data, self.cls, self.source, self.key = data, cls, source, key
        valid = sorted(f.name for f in fields(cls))
        for name in data:
            if name not in valid:
                raise self.error(name, None, f"unknown key; valid keys of [{self.key.rsplit('.', 1)[-1]}]: "
                                             f"{', '.join(valid)}")

    def dotted(self, name: str) -> str:
        return f"{self.key}.{name}"

    def error(self, name: str, value: Any, expected: str) -> SetupError:
        """The error for key ``name``; ``value`` None means it is not shown."""
        assigned = "" if value is None else f" = {shown(value)}"
        return SetupError(f"{self.source}: {self.dotted(name)}{assigned}: {expected}")

    def get(self, name: str) -> Any:
        if name in self.data:
            return self.data[name]
        return next(f.default for f in fields(self.cls) if f.name == name)

    def number(self, name: str, rng: _Range = _ANY, unit: str = "") -> float:
        value = self.get(name)
        if not (_is_number(value) and math.isfinite(value) and value in rng):
            raise self.error(name, value, " ".join(filter(None, ("expected a number", str(rng), unit))))
        return float(value)

    def integer(self, name: str, rng: _Range = _ANY, unit: str = "") -> int:
        value = self.get(name)
        if not (isinstance(value, int) and not isinstance(value, bool) and value in rng):
            raise self.error(name, value, " ".join(filter(None, ("expected an integer", str(rng), unit))))
        return value

    def vector(self, name: str, n: int, rng: _Range = _ANY, unit: str = "", integer: bool = False) -> tuple:
        value = self.get(name)
        kind = "integers" if integer else "numbers"
        each = f", each {rng}" if str(rng) else ""
        expected = " ".join(filter(None, (f"expected a list of {n} {kind}{each}", unit)))
        if not isinstance(value, (list, tuple)) or len(value) != n:
            raise self.error(name, value, expected)
        for v in value:
            ok = (isinstance(v, int) and not isinstance(v, bool)) if integer else (
                _is_number(v) and math.isfinite(v))
            if not (ok and v in rng):
                raise self.error(name, value, expected)
        return tuple(int(v) for v in value) if integer else tuple(float(v) for v in value)

    def matrix(self, name: str, rng: _Range) -> tuple[tuple[float, float, float], ...]:
        value = self.get(name)
        expected = f"expected a 3x3 matrix (a list of 3 lists of 3 numbers), each entry {rng}"
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            raise self.error(name, value, expected)
        rows = []
        for row in value:
            if not isinstance(row, (list, tuple)) or len(row) != 3 or not all(
                    _is_number(v) and math.isfinite(v) and v in rng for v in row):
                raise self.error(name, value, expected)
            rows.append(tuple(float(v) for v in row))
        return tuple(rows)

    def choice(self, name: str, options: tuple[str, ...]) -> str:
        value = self.get(name)
        if not isinstance(value, str) or value not in options:
            raise self.error(name, value, f"expected one of {', '.join(shown(o) for o in options)}")
        return value

    def boolean(self, name: str) -> bool:
        value = self.get(name)
        if not isinstance(value, bool):
            raise self.error(name, value, "expected true or false")
        return value

    def string(self, name: str) -> str:
        value = self.get(name)
        if not isinstance(value, str):
            raise self.error(name, value, "expected a string")
        return value


def _texture(t: _Table, base_dir: Path) -> str:
    value = t.string("texture")
    if value == "uniform" or value in images.SURFACE_KINDS:
        return value
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
    return str(path)


def _surface(t: _Table, base_dir: Path) -> SurfaceConfig:
    return SurfaceConfig(
        geometry=t.choice("geometry", surfaces.names()),
        size=t.vector("size", 2, _POSITIVE, "metres"),
        corner_angle=t.number("corner_angle", _Range(30, 180, True, True), "degrees"),
        texture=_texture(t, base_dir),
        texture_seed=t.integer("texture_seed", _NON_NEGATIVE),
        texture_resolution=t.integer("texture_resolution", _Range(16, 4096), "pixels"),
        albedo_scale=t.number("albedo_scale", _Range(0, 1, lo_open=True)),
        tint=t.vector("tint", 3, _UNIT, "(linear RGB)"),
        material=t.choice("material", ("diffuse", "roughplastic")),
        roughness=t.number("roughness", _Range(0, 1, lo_open=True), "(GGX alpha)"),
    )


def _view(t: _Table) -> dict:
    """resolution, fov, position, look_at and up of a projector or camera, checked for a usable
    view."""
    view = {"resolution": t.vector("resolution", 2, _PIXELS, "pixels", integer=True),
            "fov": t.number("fov", _FOV, "degrees"),
            "position": t.vector("position", 3, unit="metres"),
            "look_at": t.vector("look_at", 3, unit="metres"),
            "up": t.vector("up", 3)}
    (px, py, pz), (lx, ly, lz), up = view["position"], view["look_at"], view["up"]
    if not pz > 0:
        raise t.error("position", view["position"], "expected z > 0 metres (in front of the surface at z = 0)")
    axis = (lx - px, ly - py, lz - pz)
    if not axis[2] < 0:
        raise t.error("look_at", view["look_at"], f"expected a point of smaller z than "
                                                  f"{t.dotted('position')} (the view looks towards -z)")
    cross = (up[1] * axis[2] - up[2] * axis[1], up[2] * axis[0] - up[0] * axis[2],
             up[0] * axis[1] - up[1] * axis[0])
    if math.hypot(*cross) <= 1e-9 * math.hypot(*up) * math.hypot(*axis):
        raise t.error("up", up, f"expected a direction not parallel to {t.dotted('look_at')} - "
                                f"{t.dotted('position')}")
    return view


def _projector(t: _Table) -> ProjectorConfig:
    return ProjectorConfig(
        **_view(t),
        brightness=t.number("brightness", _POSITIVE),
        gamma=t.number("gamma", _Range(0.1, 10, True, True)),
        black_level=t.number("black_level", _Range(0, 0.2, hi_open=True)),
        mixing=t.matrix("mixing", _NON_NEGATIVE),
        aperture=t.number("aperture", _NON_NEGATIVE, "metres"),
        focus_distance=t.number("focus_distance", _POSITIVE, "metres"),
        keep_aspect=t.boolean("keep_aspect"),
        psf_sigma=t.number("psf_sigma", _Range(0, 50), "projector pixels"),
        flicker=t.number("flicker", _Range(0, 0.5), "(relative brightness std)"),
        drift=t.number("drift", _Range(-1, 1, True, True), "(relative brightness change)"),
    )


def _response(t: _Table) -> str:
    from sim import camera

    value = t.get("response")
    try:
        camera.check_response(value)
    except ValueError as exc:
        raise t.error("response", value, str(exc)) from None  # names the valid responses
    return value


def _bit_depth(t: _Table) -> int:
    value = t.get("bit_depth")
    if not (isinstance(value, int) and not isinstance(value, bool) and value == 8):
        raise t.error("bit_depth", value, "expected 8 (captures are 8-bit PNGs)")
    return value


def _camera(t: _Table) -> CameraConfig:
    from sim import camera

    return CameraConfig(
        **_view(t),
        aperture_radius=t.number("aperture_radius", _NON_NEGATIVE, "metres"),
        focus_distance=t.number("focus_distance", _POSITIVE, "metres"),
        exposure=t.number("exposure", _POSITIVE),
        white_balance=t.vector("white_balance", 3, _POSITIVE),
        response=_response(t),
        shot_noise=t.number("shot_noise", _NON_NEGATIVE),
        read_noise=t.number("read_noise", _NON_NEGATIVE, "(linear signal units)"),
        bit_depth=_bit_depth(t),
        psf_sigma=t.number("psf_sigma", _Range(0, 16), "camera pixels"),
        bayer=t.choice("bayer", ("none", *camera.BAYER_PATTERNS)),
        demosaic=t.choice("demosaic", camera.DEMOSAIC_METHODS),
        vignetting=t.number("vignetting", _Range(0, 1, hi_open=True), "(fraction lost at the corners)"),
        distortion=t.number("distortion", _Range(-0.14, 1), "(radial k1, normalised by the half-diagonal)"),
        jpeg_quality=t.integer("jpeg_quality", _Range(0, 100), "(0: no JPEG)"),
        exposure_mode=t.choice("exposure_mode", ("manual", "rule")),
    )


def _ambient(t: _Table) -> AmbientConfig:
    given = t.data.keys()
    if "radiance" in given and "temperature" in given:
        raise SetupError(f"{t.source}: {t.dotted('radiance')} and {t.dotted('temperature')} both given: "
                         f"expected exactly one of {t.dotted('radiance')} or {t.dotted('temperature')} "
                         f"(with {t.dotted('intensity')})")
    if "temperature" not in given:
        if "intensity" in given:
            raise t.error("intensity", t.data["intensity"],
                          f"expected only together with {t.dotted('temperature')} "
                          f"(use {t.dotted('radiance')} for an RGB ambient)")
        return AmbientConfig(radiance=t.vector("radiance", 3, _NON_NEGATIVE, "(linear RGB radiance)"))
    lo, hi = TEMPERATURE_RANGE
    kelvin = t.number("temperature", _Range(lo, hi), "kelvin")
    if "intensity" not in given:
        raise t.error("intensity", None, f"missing: expected a number >= 0 (luminance) together "
                                         f"with {t.dotted('temperature')}")
    intensity = t.number("intensity", _NON_NEGATIVE, "(luminance)")
    return AmbientConfig(radiance=tuple(c * intensity for c in temperature_rgb(kelvin)),
                         temperature=kelvin, intensity=intensity)


def _render(t: _Table) -> RenderConfig:
    return RenderConfig(
        fidelity=t.choice("fidelity", ("auto", "direct", "path", "transport")),
        spp=t.integer("spp", _SPP),
        ambient_spp=t.integer("ambient_spp", _SPP),
        max_depth=t.integer("max_depth", _Range(2)),
        seed=t.integer("seed", _NON_NEGATIVE),
    )


def _registration(t: _Table) -> RegistrationConfig:
    return RegistrationConfig(
        method=t.choice("method", REGISTRATION_METHODS),
        jitter=t.number("jitter", _NON_NEGATIVE, "canonical pixels"),
    )


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
    tables = {}
    for section, cls in SECTIONS.items():
        data = mapping.get(section, {})
        if not isinstance(data, Mapping):
            raise SetupError(f"{source}: {prefix}{section} = {shown(data)}: expected a table [{section}]")
        tables[section] = _Table(data, cls, source, prefix + section)
    setup = Setup(name=name, surface=_surface(tables["surface"], base_dir),
                  projector=_projector(tables["projector"]), camera=_camera(tables["camera"]),
                  ambient=_ambient(tables["ambient"]), render=_render(tables["render"]),
                  registration=_registration(tables["registration"]))
    _check_interreflection(setup, source, prefix)
    return setup
