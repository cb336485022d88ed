"""The setup schema: frozen dataclasses describing one projector-camera setup, field by field.

Every key is declared once, here (or, for a surface's own keys, in its module of
:mod:`sim.surfaces`; for the keys of a camera's or projector's stage, in the stage's module, from
which :class:`CameraConfig` and :class:`ProjectorConfig` are composed): its default, kind, range
and unit in the field's declaration (:mod:`sim.options`), its meaning in the field's docstring.
:mod:`sim.setup.validation` checks a setup file against these declarations alone.

World: metres and degrees; the (planar) surface lies in the x-y plane at z = 0, centred at the
origin, normal +z, up +y; projector and camera stand at z > 0 looking towards -z. The defaults
here are the defaults of a setup file (a missing key takes its default).
"""
from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType

from sim import surfaces
from sim.camera import chain as camera_chain
from sim.camera import thinlens
from sim.options import (NON_NEGATIVE, POSITIVE, UNIT, Range, choice, combine, integer, number,
                         string, variant, vector)
from sim.projector import chain as projector_chain
from sim.seeds import SEED_MAX

MAX_SPP = 65536
"""Most samples per pixel of a render."""
NAME_PATTERN = "[A-Za-z0-9_-]+"
"""Setup names (used as dataset folder names)."""
TEMPERATURE_RANGE = (1000.0, 25000.0)
"""Kelvin range accepted for ``ambient.temperature``."""


@dataclass(frozen=True)
class SurfaceConfig:
    """The projection surface (see :mod:`sim.surfaces` for its exact shape)."""

    geometry: str = choice("plane", surfaces.names)
    """A surface of :data:`sim.surfaces.SURFACES`: ``"plane"`` (one rectangle at z = 0) or
    ``"corner"`` (two planes meeting at a vertical edge)."""
    size: tuple[float, float] = vector((1.2, 1.0), POSITIVE, "metres")
    """Metres (width, height) of the plane; for a corner, of each wing."""
    shape: object = variant("geometry", {name: cls.Options for name, cls in surfaces.SURFACES.items()})
    """The options only the surface ``geometry`` names takes (its ``Options``, declared in its module
    of :mod:`sim.surfaces`, e.g. a corner's ``corner_angle``), given as keys of the same
    ``[surface]`` table; None (the default) stands for that surface's defaults."""
    texture: str = string("brick")
    """``"uniform"``, a generator kind of :data:`sim.images.SURFACE_KINDS`, or the absolute path of
    an image file (a relative path in a setup file is relative to that file)."""
    texture_seed: int = integer(0, Range(0, SEED_MAX))
    """Seed (>= 0) of the texture generator (see :mod:`sim.seeds`)."""
    texture_resolution: int = integer(512, Range(16, 4096), "pixels")
    """Pixels along the longest side of the albedo texture, 16..4096."""
    albedo_scale: float = number(0.8, Range(0, 1, lo_open=True))
    """Linear albedo multiplier, in (0, 1]."""
    tint: tuple[float, float, float] = vector((1.0, 1.0, 1.0), UNIT, "(linear RGB)")
    """Linear RGB albedo multiplier per channel, each in [0, 1]."""
    ink_density: float = number(1.0, Range(0, 2), "(relative optical density)")
    """Optical density of the print's inks relative to the texture as generated, 0..2. The linear
    albedo is ``albedo_scale * tint * texture ** ink_density``: an ink layer's optical density
    (minus log10 of its reflectance) grows with the ink laid down, so 1 keeps the texture, below 1
    prints it lighter and less saturated (0: the bare sheet, ``albedo_scale * tint`` everywhere),
    above 1 darker and more saturated."""
    material: str = choice("diffuse", ("diffuse", "roughplastic"))
    """``"diffuse"`` or ``"roughplastic"`` (semi-gloss)."""
    roughness: float = number(0.1, Range(0, 1, lo_open=True), "(GGX alpha)")
    """GGX alpha of the roughplastic material, in (0, 1]."""

    def __post_init__(self):
        options = surfaces.get_surface(self.geometry).Options
        if self.shape is None:
            object.__setattr__(self, "shape", options())
        elif not isinstance(self.shape, options):
            raise TypeError(f"surface shape {self.shape!r}: expected {options.__name__} for "
                            f"geometry {self.geometry!r}")


@dataclass(frozen=True)
class ProjectorView:
    """The projector keys of no stage: Mitsuba's emitter renders with them (panel pixels, field of
    view, pose)."""

    resolution: tuple[int, int] = vector((256, 256), Range(8, 4096), "pixels", integer=True)
    """Pixels (width, height), each 8..4096."""
    fov: float = number(30.0, Range(1, 120, lo_open=True, hi_open=True), "degrees")
    """Degrees, horizontal field of view, in (1, 120)."""
    position: tuple[float, float, float] = vector((0.0, 0.0, 1.0), unit="metres")
    """Metres, world position of the lens (z > 0)."""
    look_at: tuple[float, float, float] = vector((0.0, 0.0, 0.0), unit="metres")
    """Metres, a world point on the optical axis (towards -z)."""
    up: tuple[float, float, float] = vector((0.0, 1.0, 0.0))
    """Direction of the image's up (not parallel to the optical axis)."""


ProjectorConfig = combine(
    "ProjectorConfig", (ProjectorView, *(stage.options for stage in projector_chain.STAGES)),
    """The projector: the keys of :class:`ProjectorView` (pose, field of view, panel), then those
    of each stage of :data:`sim.projector.chain.CHAIN` in order (scaler, response, white segment,
    mixing, dynamic lamp, lens, distortion, translucency, flare, brightness, lamp), each declared
    and documented by its stage's options.""", __name__)


@dataclass(frozen=True)
class CameraView:
    """The camera keys of no stage: Mitsuba's sensor renders with them (pixels, field of view,
    pose, thin lens), shaping the linear radiance the camera's stages receive."""

    resolution: tuple[int, int] = vector((256, 256), Range(8, 4096), "pixels", integer=True)
    """Pixels (width, height), each 8..4096."""
    fov: float = number(40.0, Range(1, 120, lo_open=True, hi_open=True), "degrees")
    """Degrees, horizontal field of view, in (1, 120)."""
    position: tuple[float, float, float] = vector((0.25, 0.0, 1.0), unit="metres")
    """Metres, world position (z > 0)."""
    look_at: tuple[float, float, float] = vector((0.0, 0.0, 0.0), unit="metres")
    """Metres, a world point on the optical axis (towards -z)."""
    up: tuple[float, float, float] = vector((0.0, 1.0, 0.0))
    """Direction of the image's up (not parallel to the optical axis)."""
    aperture_radius: float = number(0.0, NON_NEGATIVE, "metres")
    """Metres, thin-lens aperture radius (>= 0); 0 is a pinhole."""
    focus_distance: float = number(1.03, POSITIVE, "metres")
    """Metres (> 0), depth along the optical axis of the plane in focus (used when
    ``aperture_radius > 0``)."""
    defocus: str = choice("image", thinlens.DEFOCUS_MODELS)
    """How the thin lens's defocus is rendered (when ``aperture_radius > 0``): ``"image"``, the
    pinhole render with each pixel's light spread over its circle of confusion, at a pinhole's
    samples per pixel (it cannot restore detail finer than a pixel, which a disk of a few pixels
    would move across pixel borders); ``"ray"``, Mitsuba's thin-lens sensor sampling the
    aperture per ray (see :mod:`sim.camera.thinlens`)."""


CameraConfig = combine(
    "CameraConfig", (CameraView, *(stage.options for stage in camera_chain.STAGES)),
    """The camera: the keys of :class:`CameraView` (pose, field of view, resolution, thin lens),
    then those of each stage of :data:`sim.camera.chain.CHAIN` in order (optics, exposure, noise,
    response, processing, JPEG, …), each declared and documented by its stage's options.""", __name__)


@dataclass(frozen=True)
class AmbientConfig:
    """Constant ambient light, given as a radiance or as a colour temperature and intensity."""

    radiance: tuple[float, float, float] = vector((0.02, 0.02, 0.02), NON_NEGATIVE, "(linear RGB radiance)")
    """Linear RGB radiance of the constant emitter, each >= 0 (resolved from the temperature
    when one is given)."""
    temperature: float | None = number(None, Range(*TEMPERATURE_RANGE), "kelvin")
    """Kelvin (1000..25000) the radiance came from, or None when given directly."""
    intensity: float | None = number(None, NON_NEGATIVE, "(luminance)")
    """Luminance (>= 0) the temperature's colour was scaled to, or None when given directly."""


@dataclass(frozen=True)
class RenderConfig:
    """Light transport and sampling."""

    fidelity: str = choice("auto", ("auto", "direct", "path", "transport"))
    """``"auto"`` (measured: the cheapest level, and spp, whose error is below the camera's noise;
    see :mod:`sim.fidelity`), ``"path"``, ``"direct"`` or ``"transport"`` (a light-transport
    operator calibrated from direct renders at ``spp``)."""
    spp: int = integer(16, Range(1, MAX_SPP))
    """Samples per pixel of the projector contribution, 1..65536."""
    ambient_spp: int = integer(256, Range(1, MAX_SPP))
    """Samples per pixel of the ambient-only image (rendered once per setup), 1..65536."""
    max_depth: int = integer(3, Range(2, 64))
    """Path depth for path tracing, 2..64 (a corner needs >= 3 for its inter-reflection; past 64
    bounces no surface of albedo <= 1 keeps light a camera could see)."""
    seed: int = integer(0, Range(0, SEED_MAX))
    """Seed base (0..2³²−1: Mitsuba's sampler seed is 32-bit) of the Mitsuba sampler and of the
    camera noise (see :mod:`sim.seeds`)."""


REGISTRATION_METHODS = ("auto", "homography", "exact")
"""Values of ``registration.method``."""


@dataclass(frozen=True)
class RegistrationConfig:
    """How captures are brought from the camera into the canonical projector view
    (:mod:`sim.registration`)."""

    method: str = choice("auto", REGISTRATION_METHODS)
    """``"homography"``: warp by the homography fitted to projected checkerboard corners found in
    the captures, as a real pipeline does on a plane; ``"exact"``: the dense map computed from the
    scene geometry (what a structured-light scan measures); ``"auto"``: homography on a planar
    surface, exact map otherwise."""
    jitter: float = number(0.0, NON_NEGATIVE, "canonical pixels")
    """Canonical pixels (>= 0): standard deviation of a random displacement added to each detected
    checkerboard corner before the homography fit (a sloppier calibration); 0 adds none."""


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
    registration: RegistrationConfig = RegistrationConfig()
    """Camera → canonical view registration."""

    @property
    def is_planar_diffuse(self) -> bool:
        """True for a diffuse plane (direct light alone is exact)."""
        return surfaces.get_surface(self.surface.geometry).planar and self.surface.material == "diffuse"


SECTIONS = MappingProxyType({
    "surface": SurfaceConfig, "projector": ProjectorConfig, "camera": CameraConfig,
    "ambient": AmbientConfig, "render": RenderConfig, "registration": RegistrationConfig})
"""Section name -> its dataclass, in the order of the fields of :class:`Setup` and of a written file."""


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
