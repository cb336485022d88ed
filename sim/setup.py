"""Setup files: the validated description of one simulated projector-camera setup.

A setup file (TOML, ``scenes/*.toml``) has a ``name`` and the sections ``surface``, ``projector``,
``camera``, ``ambient`` and ``render``; every key but ``name`` is optional and defaults to the
dataclass defaults below. World: metres and degrees; the (planar) surface lies in the x-y plane at
z = 0, centred at the origin, normal +z, up +y; projector and camera stand at z > 0 looking
towards -z.

Everything is checked here, before any rendering: unknown keys or sections, wrong types (a bool
is not a number; an int is accepted where a float is expected), vector lengths, ranges, missing
texture files, unknown camera responses and inconsistent combinations raise
:class:`~sim.errors.SetupError` naming the file, the dotted key and what was expected, e.g.
``scenes/bad.toml: camera.fov = -5.0: expected a number in (1, 120) degrees``.

A suite file holds ``base = "default.toml"`` (relative to the suite file) and ``[[setup]]`` tables,
each a ``name`` plus partial overrides deep-merged onto the base (:func:`load_suite`).
:func:`dump_setup` writes the fully resolved TOML that reads back to an equal :class:`Setup`.
"""
from __future__ import annotations

import copy
import importlib.resources
import math
import re
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from sim import images, surfaces
from sim.errors import SetupError

NAME_PATTERN = "[A-Za-z0-9_-]+"
"""Setup names (used as dataset folder names)."""
TEMPERATURE_RANGE = (1000.0, 25000.0)
"""Kelvin range accepted for ``ambient.temperature``."""


@dataclass(frozen=True)
class SurfaceConfig:
    """The projection surface (see :mod:`sim.surfaces` for its exact shape)."""

    geometry: str = "plane"
    """``"plane"`` (one rectangle at z = 0) or ``"corner"`` (two planes meeting at a vertical edge)."""
    size: tuple[float, float] = (1.2, 1.0)
    """Metres (width, height) of the plane; for a corner, of each wing."""
    corner_angle: float = 90.0
    """Degrees, opening angle of a corner, in (30, 180); unused for a plane."""
    texture: str = "brick"
    """``"uniform"``, a generator kind of :data:`sim.images.SURFACE_KINDS`, or the absolute path of
    an image file (a relative path in a setup file is relative to that file)."""
    texture_seed: int = 0
    """Seed (>= 0) of the texture generator."""
    texture_resolution: int = 512
    """Pixels along the longest side of the albedo texture, 16..4096."""
    albedo_scale: float = 0.8
    """Linear albedo multiplier, in (0, 1]."""
    tint: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Linear RGB albedo multiplier per channel, each in [0, 1]."""
    material: str = "diffuse"
    """``"diffuse"`` or ``"roughplastic"`` (semi-gloss)."""
    roughness: float = 0.1
    """GGX alpha of the roughplastic material, in (0, 1]."""


@dataclass(frozen=True)
class ProjectorConfig:
    """The projector: response, primaries mixing, pose and optics."""

    resolution: tuple[int, int] = (256, 256)
    """Pixels (width, height), each 8..4096."""
    fov: float = 30.0
    """Degrees, horizontal field of view, in (1, 120)."""
    position: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """Metres, world position of the lens (z > 0)."""
    look_at: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Metres, a world point on the optical axis (towards -z)."""
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    """Direction of the image's up (not parallel to the optical axis)."""
    brightness: float = 1.0
    """Emitter scale (> 0): irradiance 1 at 1 m head-on gives an outgoing radiance equal to the albedo."""
    gamma: float = 2.2
    """Projector response exponent (encoded input -> linear output), in (0.1, 10)."""
    black_level: float = 0.005
    """Fraction of full output emitted for input 0, in [0, 0.2)."""
    mixing: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    """3x3 primaries mixing matrix (rows: camera channel, columns: projector primary), entries >= 0."""
    aperture: float = 0.0
    """Metres, lens aperture diameter for defocus (>= 0); 0 is a pinhole (sharp)."""
    focus_distance: float = 1.0
    """Metres (> 0), distance at which the projector is in focus."""


@dataclass(frozen=True)
class CameraConfig:
    """The camera: pose, optics and sensor (exposure, noise, response, bit depth)."""

    resolution: tuple[int, int] = (256, 256)
    """Pixels (width, height), each 8..4096."""
    fov: float = 40.0
    """Degrees, horizontal field of view, in (1, 120)."""
    position: tuple[float, float, float] = (0.25, 0.0, 1.0)
    """Metres, world position (z > 0)."""
    look_at: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Metres, a world point on the optical axis (towards -z)."""
    up: tuple[float, float, float] = (0.0, 1.0, 0.0)
    """Direction of the image's up (not parallel to the optical axis)."""
    aperture_radius: float = 0.0
    """Metres, thin-lens aperture radius (>= 0); 0 is a pinhole."""
    focus_distance: float = 1.03
    """Metres (> 0), in-focus distance (used when ``aperture_radius > 0``)."""
    exposure: float = 1.0
    """Multiplier (> 0) from linear scene radiance to sensor signal; signal 1 is the full well."""
    white_balance: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Per-channel linear gains, each > 0."""
    response: str = "sRGB"
    """Camera response curve, a name accepted by :func:`sim.camera.check_response`."""
    shot_noise: float = 2e-4
    """Poisson gain a (>= 0): a signal s in [0, 1] has variance a * s (s / a electrons)."""
    read_noise: float = 2e-3
    """Gaussian read-noise sigma (>= 0), in linear signal units."""
    bit_depth: int = 8
    """Bits per channel of the captures; must be 8."""


@dataclass(frozen=True)
class AmbientConfig:
    """Constant ambient light, given as a radiance or as a colour temperature and intensity."""

    radiance: tuple[float, float, float] = (0.02, 0.02, 0.02)
    """Linear RGB radiance of the constant emitter, each >= 0 (resolved from the temperature
    when one is given)."""
    temperature: float | None = None
    """Kelvin (1000..25000) the radiance came from, or None when given directly."""
    intensity: float | None = None
    """Luminance (>= 0) the temperature's colour was scaled to, or None when given directly."""


@dataclass(frozen=True)
class RenderConfig:
    """Light transport and sampling."""

    fidelity: str = "auto"
    """``"auto"`` (measured: the cheapest level, and spp, whose error is below the camera's noise;
    see :mod:`sim.fidelity`), ``"path"``, ``"direct"`` or ``"transport"`` (a light-transport
    operator calibrated from direct renders at ``spp``)."""
    spp: int = 16
    """Samples per pixel of the projector contribution, 1..65536."""
    ambient_spp: int = 256
    """Samples per pixel of the ambient-only image (rendered once per setup), 1..65536."""
    max_depth: int = 3
    """Path depth for path tracing (>= 2; a corner needs >= 3 for its inter-reflection)."""
    seed: int = 0
    """Seed base (>= 0) of the Mitsuba sampler and of the camera noise."""


@dataclass(frozen=True)
class Setup:
    """One validated projector-camera setup."""

    name: str
    """Setup name, matching :data:`NAME_PATTERN`; the dataset folder name."""
    surface: SurfaceConfig = SurfaceConfig()
    """The projection surface."""
    projector: ProjectorConfig = ProjectorConfig()
    """The projector."""
    camera: CameraConfig = CameraConfig()
    """The camera."""
    ambient: AmbientConfig = AmbientConfig()
    """The ambient light."""
    render: RenderConfig = RenderConfig()
    """Rendering settings."""

    @property
    def is_planar_diffuse(self) -> bool:
        """True for a diffuse plane (direct light alone is exact)."""
        return surfaces.get_surface(self.surface.geometry).planar and self.surface.material == "diffuse"


_SECTIONS = {"surface": SurfaceConfig, "projector": ProjectorConfig, "camera": CameraConfig,
             "ambient": AmbientConfig, "render": RenderConfig}


def temperature_rgb(kelvin: float) -> tuple[float, float, float]:
    """Linear sRGB colour of a light of a given colour temperature, with luminance Y = 1.

    Chromaticity from the CIE daylight locus (:func:`colour.temperature.CCT_to_xy_CIE_D`) at
    4000 K and above, from a Planckian (black body) spectrum below; converted to linear sRGB
    (D65 white, no chromatic adaptation, so 6504 K is near (1, 1, 1)) and negative channels of
    out-of-gamut colours clipped to 0.

    Parameters
    ----------
    kelvin : float
        Colour temperature in kelvin, 1000..25000.

    Returns
    -------
    tuple of float
        Linear (R, G, B).

    Raises
    ------
    ValueError
        If ``kelvin`` is outside 1000..25000.
    """
    import colour

    lo, hi = TEMPERATURE_RANGE
    if not lo <= kelvin <= hi:
        raise ValueError(f"colour temperature {kelvin!r} K: expected {lo:g}..{hi:g} K")
    if kelvin >= 4000:
        xyz = colour.xy_to_XYZ(colour.temperature.CCT_to_xy_CIE_D(kelvin))
    else:
        # CIE 1931 2-degree observer (the default), on colour's default 360-780 nm grid
        xyz = colour.sd_to_XYZ(colour.sd_blackbody(kelvin, colour.SPECTRAL_SHAPE_DEFAULT))
        xyz = xyz / xyz[1]
    rgb = colour.XYZ_to_RGB(xyz, "sRGB")
    return tuple(max(float(c), 0.0) for c in rgb)


# --------------------------------------------------------------------------------------------
# Validation


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


def _toml_value(value: Any) -> str:
    """A value written as TOML (inline): numbers, strings, bools, lists/tuples, tables.

    Floats are written with ``repr`` so they read back exactly.
    """
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"')
        return '"' + "".join(f"\\u{ord(c):04x}" if ord(c) < 0x20 or ord(c) == 0x7F else c
                             for c in escaped) + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{" + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + "}"
    return str(value)


def _shown(value: Any) -> str:
    text = _toml_value(value)
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
        shown = "" if value is None else f" = {_shown(value)}"
        return SetupError(f"{self.source}: {self.dotted(name)}{shown}: {expected}")

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
            raise self.error(name, value, f"expected one of {', '.join(_toml_value(o) for o in options)}")
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


def _pose(t: _Table) -> dict:
    """position, look_at and up of a projector or camera, checked for a usable view."""
    pose = {"position": t.vector("position", 3, unit="metres"),
            "look_at": t.vector("look_at", 3, unit="metres"),
            "up": t.vector("up", 3)}
    (px, py, pz), (lx, ly, lz), up = pose["position"], pose["look_at"], pose["up"]
    if not pz > 0:
        raise t.error("position", pose["position"], "expected z > 0 metres (in front of the surface at z = 0)")
    axis = (lx - px, ly - py, lz - pz)
    if not axis[2] < 0:
        raise t.error("look_at", pose["look_at"], f"expected a point of smaller z than "
                                                  f"{t.dotted('position')} (the view looks towards -z)")
    cross = (up[1] * axis[2] - up[2] * axis[1], up[2] * axis[0] - up[0] * axis[2],
             up[0] * axis[1] - up[1] * axis[0])
    if math.hypot(*cross) <= 1e-9 * math.hypot(*up) * math.hypot(*axis):
        raise t.error("up", up, f"expected a direction not parallel to {t.dotted('look_at')} - "
                                f"{t.dotted('position')}")
    return pose


def _projector(t: _Table) -> ProjectorConfig:
    return ProjectorConfig(
        resolution=t.vector("resolution", 2, _PIXELS, "pixels", integer=True),
        fov=t.number("fov", _FOV, "degrees"),
        **_pose(t),
        brightness=t.number("brightness", _POSITIVE),
        gamma=t.number("gamma", _Range(0.1, 10, True, True)),
        black_level=t.number("black_level", _Range(0, 0.2, hi_open=True)),
        mixing=t.matrix("mixing", _NON_NEGATIVE),
        aperture=t.number("aperture", _NON_NEGATIVE, "metres"),
        focus_distance=t.number("focus_distance", _POSITIVE, "metres"),
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
    return CameraConfig(
        resolution=t.vector("resolution", 2, _PIXELS, "pixels", integer=True),
        fov=t.number("fov", _FOV, "degrees"),
        **_pose(t),
        aperture_radius=t.number("aperture_radius", _NON_NEGATIVE, "metres"),
        focus_distance=t.number("focus_distance", _POSITIVE, "metres"),
        exposure=t.number("exposure", _POSITIVE),
        white_balance=t.vector("white_balance", 3, _POSITIVE),
        response=_response(t),
        shot_noise=t.number("shot_noise", _NON_NEGATIVE),
        read_noise=t.number("read_noise", _NON_NEGATIVE, "(linear signal units)"),
        bit_depth=_bit_depth(t),
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


def _parse(mapping: Mapping, source: str, base_dir: Path, prefix: str) -> Setup:
    if not isinstance(mapping, Mapping):
        raise SetupError(f"{source}: {prefix.rstrip('.') or 'setup'}: expected a table")
    for key, value in mapping.items():
        if key != "name" and key not in _SECTIONS:
            what = "section" if isinstance(value, Mapping) else "key"
            raise SetupError(f"{source}: {prefix}{key}: unknown {what}; valid keys: name and the "
                             f"sections {', '.join(_SECTIONS)}")
    if "name" not in mapping:
        raise SetupError(f"{source}: {prefix}name: missing; expected a string matching {NAME_PATTERN}")
    name = mapping["name"]
    if not isinstance(name, str) or not re.fullmatch(NAME_PATTERN, name):
        raise SetupError(f"{source}: {prefix}name = {_shown(name)}: expected a string matching {NAME_PATTERN}")
    tables = {}
    for section, cls in _SECTIONS.items():
        data = mapping.get(section, {})
        if not isinstance(data, Mapping):
            raise SetupError(f"{source}: {prefix}{section} = {_shown(data)}: expected a table [{section}]")
        tables[section] = _Table(data, cls, source, prefix + section)
    setup = Setup(name=name, surface=_surface(tables["surface"], base_dir),
                  projector=_projector(tables["projector"]), camera=_camera(tables["camera"]),
                  ambient=_ambient(tables["ambient"]), render=_render(tables["render"]))
    _check_interreflection(setup, source, prefix)
    return setup


def parse_setup(mapping: Mapping, source: str = "<string>", base_dir: Path | str | None = None) -> Setup:
    """Validate a setup mapping (e.g. from :func:`tomllib.load`).

    Parameters
    ----------
    mapping : Mapping
        ``name`` plus the optional sections ``surface``, ``projector``, ``camera``, ``ambient``
        and ``render``.
    source : str
        Name of the file the mapping came from, for error messages.
    base_dir : Path or str, optional
        Folder that a relative ``surface.texture`` path is relative to; defaults to the current
        working directory.

    Returns
    -------
    Setup

    Raises
    ------
    SetupError
        Naming ``source``, the dotted key and what was expected.
    """
    return _parse(mapping, source, Path.cwd() if base_dir is None else Path(base_dir), "")


def _read_toml(path: Path) -> dict:
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except OSError as exc:
        raise SetupError(f"{path}: cannot read setup file ({exc.strerror or exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise SetupError(f"{path}: not valid TOML ({exc})") from None


def load_setup(path: Path | str) -> Setup:
    """Read and validate a setup file.

    Parameters
    ----------
    path : Path or str
        A TOML setup file; a relative ``surface.texture`` path is relative to its folder.

    Returns
    -------
    Setup

    Raises
    ------
    SetupError
        If the file cannot be read, is not TOML, or a key or value is invalid.
    """
    path = Path(path)
    return parse_setup(_read_toml(path), str(path), path.parent)


def _merge(base: Mapping, override: Mapping) -> dict:
    """Deep merge of ``override`` onto ``base`` (tables recursively, other values replaced).

    The two forms of the ambient light exclude each other: an override giving ``radiance`` drops
    the base's ``temperature``/``intensity`` and one giving ``temperature`` drops its ``radiance``.
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
            out[key] = _merge(merged, value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def load_suite(path: Path | str) -> list[Setup]:
    """Read a suite file: ``base`` (a setup file, relative to the suite) and ``[[setup]]`` tables.

    Each ``[[setup]]`` table holds a ``name`` and partial overrides that are deep-merged onto the
    base file's mapping (see :func:`_merge` for the ambient light) and validated; errors name the
    suite file and the key as ``setup[i].section.key`` (i from 0). Relative texture paths are
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
    source = str(path)
    suite = _read_toml(path)
    for key in suite:
        if key not in ("base", "setup"):
            raise SetupError(f"{source}: {key}: unknown key; valid keys of a suite: base, setup")
    base_data: dict = {}
    if "base" in suite:
        if not isinstance(suite["base"], str):
            raise SetupError(f"{source}: base = {_shown(suite['base'])}: expected the path of a setup file")
        base_path = path.parent / suite["base"]
        base_data = _read_toml(base_path)
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
        setup = _parse(_merge(base_data, entry), source, path.parent, prefix)
        if setup.name in seen:
            raise SetupError(f'{source}: {prefix}name = "{setup.name}": expected a unique name; '
                             f"setup[{seen[setup.name]}] has it too")
        seen[setup.name] = i
        setups.append(setup)
    return setups


def dump_setup(setup: Setup) -> str:
    """The fully resolved setup as TOML: every value, sections in schema order.

    ``parse_setup(tomllib.loads(dump_setup(s))) == s``. An ambient light given by colour
    temperature is written as ``temperature`` and ``intensity`` with the resolved radiance as a
    comment.

    Parameters
    ----------
    setup : Setup

    Returns
    -------
    str
    """
    lines = ["# procam setup, fully resolved (metres, degrees, linear RGB)",
             f"name = {_toml_value(setup.name)}"]
    for section in _SECTIONS:
        cfg = getattr(setup, section)
        lines += ["", f"[{section}]"]
        if section == "ambient" and cfg.temperature is not None:
            lines += [f"# resolved linear RGB radiance = {_toml_value(cfg.radiance)}",
                      f"temperature = {_toml_value(cfg.temperature)}",
                      f"intensity = {_toml_value(cfg.intensity)}"]
            continue
        lines += [f"{f.name} = {_toml_value(getattr(cfg, f.name))}" for f in fields(cfg)
                  if getattr(cfg, f.name) is not None]
    return "\n".join(lines) + "\n"


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
        ``"default"``, ``"white"``, ``"corner"``, ``"defocus"``, ``"suite"`` (with or without
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
