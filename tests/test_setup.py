"""sim.setup: shipped scenes, validation messages, TOML round trip, suites, colour temperature,
and the geometry of every shipped setup (projected area on the surface and inside the frame)."""
from __future__ import annotations

import dataclasses
import math
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from sim import images, surfaces
from sim.camera import thinlens
from sim.projector import frame_area
from sim.errors import SetupError
from sim.io import write_png
from sim.options import Table, parse, spec_of
from sim.setup.schema import SECTIONS
from sim.setup import (AmbientConfig, CameraConfig, ProjectorConfig, RenderConfig, Setup,
                       SurfaceConfig, dump_setup, load_setup, load_setups, load_suite, parse_setup,
                       scene_path, suite_test_frames, temperature_rgb)

SCENES = Path(__file__).resolve().parents[1] / "scenes"
SHIPPED = ("default", "ideal", "white", "corner", "defocus")
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])  # linear sRGB -> Y


def _shipped_setups() -> list[Setup]:
    return ([load_setup(scene_path(n)) for n in SHIPPED] + load_suite(scene_path("suite"))
            + load_suite(scene_path("paper")))


ALL = _shipped_setups()


# ---------------------------------------------------------------------------------- shipped files

@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_setup_loads_by_name(name):
    path = scene_path(name)
    assert path == SCENES / f"{name}.toml"
    assert scene_path(f"{name}.toml") == path
    setup = load_setup(path)
    assert setup.name == name


def test_scene_path_unknown_name_lists_shipped():
    with pytest.raises(SetupError) as err:
        scene_path("marble")
    msg = str(err.value)
    assert msg.startswith("marble: ") and all(n in msg for n in (*SHIPPED, "suite"))


def test_ideal_scene_key_numbers():
    s = load_setup(scene_path("ideal"))
    assert s.is_planar_diffuse and s.render.fidelity == "auto" and s.render.spp == 16
    assert s.surface.texture in images.SURFACE_KINDS and s.surface.albedo_scale == 0.8
    assert s.projector.resolution == (256, 256) and s.camera.resolution == (256, 256)
    assert s.projector.position == (0.0, 0.0, 1.0) and s.camera.position == (0.25, 0.0, 1.0)
    assert 0.02 <= s.ambient.radiance[0] <= 0.05 and s.camera.response == "sRGB"


def test_variants_differ_from_ideal_only_where_intended():
    ideal = load_setup(scene_path("ideal"))
    white = load_setup(scene_path("white"))
    defocus = load_setup(scene_path("defocus"))
    assert white == dataclasses.replace(
        ideal, name="white",
        surface=dataclasses.replace(ideal.surface, texture="uniform", texture_seed=0, albedo_scale=0.9))
    assert defocus == dataclasses.replace(
        ideal, name="defocus",
        projector=dataclasses.replace(ideal.projector, aperture=0.02, focus_distance=0.8),
        camera=dataclasses.replace(ideal.camera, aperture_radius=0.005, focus_distance=0.9, defocus="ray"))


def test_defocus_blurs_a_few_pixels():
    s = load_setup(scene_path("defocus")).projector
    d = s.position[2]  # head-on: throw distance to the plane
    coc = s.aperture * abs(d - s.focus_distance) / s.focus_distance  # metres on the surface
    pixel = 2 * d * math.tan(math.radians(s.fov) / 2) / s.resolution[0]
    assert 2.0 <= coc / pixel <= 4.0
    c = load_setup(scene_path("defocus")).camera
    dist = math.dist(c.position, c.look_at)
    cam_coc = 2 * c.aperture_radius * abs(dist - c.focus_distance) / c.focus_distance
    cam_pixel = 2 * dist * math.tan(math.radians(c.fov) / 2) / c.resolution[0]
    assert 0.2 <= cam_coc / cam_pixel <= 1.0  # slightly defocused: a disk under a pixel, traced
    assert c.defocus == "ray" and thinlens.traced(c)


def test_corner_scene_uses_inter_reflection():
    s = load_setup(scene_path("corner"))
    assert s.surface.geometry == "corner" and s.surface.shape.corner_angle == 90.0
    assert s.render.fidelity == "auto" and s.render.max_depth == 3  # auto measures the depth
    assert s.projector.look_at == (0.0, 0.0, 0.0) and not s.is_planar_diffuse


def test_paper_suite_is_4_lights_by_6_surfaces_on_the_paper_hardware():
    suite = load_suite(scene_path("paper"))
    default = load_setup(scene_path("default"))
    assert len(suite) == 24 and len({s.name for s in suite}) == 24
    names = [re.fullmatch(r"light(\d)_pos(\d)_([a-z]+)", s.name) for s in suite]
    assert all(names)
    lights, poses, kinds = ({m.group(i) for m in names} for i in (1, 2, 3))
    assert lights == {"1", "2", "3", "4"} and poses == {"1", "2", "3", "4", "5"}
    assert kinds == {"curves", "squares", "stripes", "lavender", "cloud", "cubes"} <= set(images.SURFACE_KINDS)
    assert {(m.group(1), m.group(3)) for m in names} == {(l, k) for l in lights for k in kinds}
    for s in suite:  # the paper's hardware everywhere
        assert s.projector.resolution == (800, 600) and s.camera.resolution == (960, 640)
        assert s.projector.keep_aspect and s.camera.exposure_mode == "rule"
        baseline = np.linalg.norm(np.subtract(s.projector.position, s.camera.position))
        assert 0.45 <= baseline <= 0.56  # "camera-projector distance 500 mm"
        assert 0.9 <= s.projector.position[2] <= 1.2  # "about 1000 mm" from the surface
    # the default setup is the official README's example setup, light2/pos1/curves
    assert dataclasses.replace(next(s for s in suite if s.name == "light2_pos1_curves"),
                               name="default") == default


def test_suite_is_3_ambient_levels_by_8_surface_kinds():
    suite = load_suite(scene_path("suite"))
    assert len(suite) == 24 and len({s.name for s in suite}) == 24
    levels = sorted({s.ambient.radiance for s in suite}, key=lambda r: float(LUMINANCE @ r))
    assert len(levels) == 3
    assert sum(s.ambient.temperature is not None for s in suite) == 8  # one level by temperature
    assert [round(float(LUMINANCE @ r), 3) for r in levels] == [0.01, 0.05, 0.12]
    pairs = {(s.ambient.radiance, s.surface.texture) for s in suite}
    kinds = {s.surface.texture for s in suite}
    assert len(kinds) == 8 and kinds <= set(images.SURFACE_KINDS)
    assert pairs == {(r, k) for r in levels for k in kinds}
    assert len({s.surface.texture_seed for s in suite if s.surface.texture == "brick"}) == 3
    assert len({(s.projector.position, s.camera.position) for s in suite}) >= 4  # varied poses


# ---------------------------------------------------------------------------------- round trip

@pytest.mark.parametrize("setup", ALL, ids=[s.name for s in ALL])
def test_dump_parse_round_trip(setup):
    text = dump_setup(setup)
    assert parse_setup(tomllib.loads(text)) == setup
    assert dump_setup(parse_setup(tomllib.loads(text))) == text


def test_dump_writes_every_value_and_the_resolved_ambient():
    s = load_suite(scene_path("suite"))[8]  # a2: ambient from a colour temperature
    assert s.ambient.temperature == 3200.0
    text = dump_setup(s)
    data = tomllib.loads(text)
    assert data["ambient"] == {"temperature": 3200.0, "intensity": 0.05}
    assert "# resolved linear RGB radiance = [" in text
    for section in ("projector", "camera", "render"):
        cfg = getattr(s, section)
        assert set(data[section]) == {f.name for f in dataclasses.fields(cfg)}
    corner = load_setup(scene_path("corner")).surface  # a surface's own keys in its table
    for surface in (s.surface, corner):
        own = {f.name for f in dataclasses.fields(surface.shape)}
        written = tomllib.loads(dump_setup(dataclasses.replace(s, surface=surface)))["surface"]
        assert set(written) == {f.name for f in dataclasses.fields(surface) if f.name != "shape"} | own
    assert tomllib.loads(dump_setup(dataclasses.replace(s, surface=corner)))["surface"]["corner_angle"] == 90.0


def test_round_trip_of_texture_file_and_odd_strings(tmp_path):
    write_png(tmp_path / "tex" / "my wall.png", np.full((8, 8, 3), 200, np.uint8))
    (tmp_path / "s.toml").write_text('name = "x"\n[surface]\ntexture = "tex/my wall.png"\n')
    s = load_setup(tmp_path / "s.toml")
    assert s.surface.texture == str((tmp_path / "tex" / "my wall.png").resolve())
    assert parse_setup(tomllib.loads(dump_setup(s)), base_dir="/") == s
    odd_name = 'a "quoted"\\path\t\n\u00e9\x7f.png'
    odd = dataclasses.replace(s, surface=dataclasses.replace(s.surface, texture=odd_name))
    assert tomllib.loads(dump_setup(odd))["surface"]["texture"] == odd_name


# ---------------------------------------------------------------------------------- defaults

def test_defaults_are_the_schema_defaults():
    s = parse_setup({"name": "bare"})
    assert s == Setup("bare", SurfaceConfig(), ProjectorConfig(), CameraConfig(), AmbientConfig(),
                      RenderConfig())
    assert s.surface.size == (1.2, 1.0) and s.surface.texture == "brick" and s.surface.tint == (1.0, 1.0, 1.0)
    assert s.projector.fov == 30.0 and s.projector.gamma == 2.2 and s.projector.black_level == 0.005
    assert s.projector.mixing == ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    assert s.camera.fov == 40.0 and s.camera.focus_distance == 1.03 and s.camera.response == "sRGB"
    assert s.camera.shot_noise == 2e-4 and s.camera.read_noise == 2e-3 and s.camera.bit_depth == 8
    assert s.ambient == AmbientConfig((0.02, 0.02, 0.02), None, None)
    assert s.render == RenderConfig("auto", 16, 256, 3, 0)
    assert s.is_planar_diffuse


def test_ints_are_accepted_where_floats_are_expected():
    s = parse_setup({"name": "n", "camera": {"fov": 35, "position": [0, 0, 2]}})
    assert s.camera.fov == 35.0 and type(s.camera.fov) is float
    assert all(type(v) is float for v in s.camera.position)


def test_setups_are_hashable_and_frozen():
    s = parse_setup({"name": "n"})
    assert hash(s) == hash(parse_setup({"name": "n"}))
    with pytest.raises(dataclasses.FrozenInstanceError):
        s.camera.fov = 10.0


# ---------------------------------------------------------------------------------- bad input

BAD = {
    "unknown key": ('name = "b"\n[camera]\nfov = 40.0\nfocal = 3\n',
                    ["camera.focal", "unknown key", "valid keys", "aperture_radius", "white_balance"]),
    "unknown section": ('name = "b"\n[lens]\nf = 1\n',
                        ["lens", "unknown section", "surface, projector, camera, ambient, render"]),
    "unknown top-level key": ('name = "b"\nseed = 3\n', ["seed", "unknown key", "name and the sections"]),
    "section not a table": ('name = "b"\ncamera = 3\n', ["camera = 3", "expected a table"]),
    "missing name": ("[camera]\nfov = 40.0\n", ["name", "missing", "[A-Za-z0-9_-]+"]),
    "bad name": ('name = "my setup"\n', ['name = "my setup"', "[A-Za-z0-9_-]+"]),
    "wrong type": ('name = "b"\n[camera]\nfov = "wide"\n',
                   ['camera.fov = "wide"', "expected a number in (1, 120) degrees"]),
    "bool is not a number": ('name = "b"\n[projector]\nbrightness = true\n',
                             ["projector.brightness = true", "expected a number > 0"]),
    "not finite": ('name = "b"\n[camera]\nexposure = inf\n', ["camera.exposure = inf", "expected a number > 0"]),
    "float for an integer": ('name = "b"\n[render]\nspp = 16.5\n',
                             ["render.spp = 16.5", "expected an integer in [1, 65536]"]),
    "list length": ('name = "b"\n[camera]\nposition = [0.0, 1.0]\n',
                    ["camera.position = [0.0, 1.0]", "expected a list of 3 numbers"]),
    "list element type": ('name = "b"\n[projector]\nresolution = [256, 256.5]\n',
                          ["projector.resolution", "expected a list of 2 integers, each in [8, 4096] pixels"]),
    "matrix shape": ('name = "b"\n[projector]\nmixing = [[1, 0, 0], [0, 1, 0]]\n',
                     ["projector.mixing", "expected a 3x3 matrix", ">= 0"]),
    "out of range": ('name = "b"\n[surface]\nalbedo_scale = 1.5\n',
                     ["surface.albedo_scale = 1.5", "expected a number in (0, 1]"]),
    "ink density": ('name = "b"\n[surface]\nink_density = 2.5\n',
                    ["surface.ink_density = 2.5", "expected a number in [0, 2] (relative optical density)"]),
    "out of range tint": ('name = "b"\n[surface]\ntint = [1.0, -0.1, 1.0]\n',
                          ["surface.tint", "each in [0, 1]"]),
    "unknown choice": ('name = "b"\n[surface]\ngeometry = "sphere"\n',
                       ['surface.geometry = "sphere"', 'expected one of "plane", "corner"']),
    "bit depth": ('name = "b"\n[camera]\nbit_depth = 16\n', ["camera.bit_depth = 16", "expected 8"]),
    "missing texture file": ('name = "b"\n[surface]\ntexture = "walls/marble.png"\n',
                             ['surface.texture = "walls/marble.png"', "existing image file", "not found",
                              "walls/marble.png", '"uniform"', '"brick"']),
    "bad response name": ('name = "b"\n[camera]\nresponse = "Kodachrome"\n',
                          ['camera.response = "Kodachrome"', "expected one of", "'sRGB'", "gamma:<g>"]),
    "radiance and temperature": ('name = "b"\n[ambient]\nradiance = [0.1, 0.1, 0.1]\ntemperature = 3200.0\n'
                                 'intensity = 0.1\n',
                                 ["ambient.radiance", "ambient.temperature", "both given", "exactly one"]),
    "intensity without temperature": ('name = "b"\n[ambient]\nintensity = 0.1\n',
                                      ["ambient.intensity = 0.1", "together with ambient.temperature"]),
    "temperature without intensity": ('name = "b"\n[ambient]\ntemperature = 3200.0\n',
                                      ["ambient.intensity", "missing", "together with ambient.temperature"]),
    "temperature out of range": ('name = "b"\n[ambient]\ntemperature = 500.0\nintensity = 0.1\n',
                                 ["ambient.temperature = 500.0", "in [1000, 25000] kelvin"]),
    "corner with direct light": ('name = "b"\n[surface]\ngeometry = "corner"\n[render]\nfidelity = "direct"\n',
                                 ['render.fidelity = "direct"', 'expected "path" or "auto"',
                                  'surface.geometry = "corner"', "inter-reflection"]),
    "corner with depth 2": ('name = "b"\n[surface]\ngeometry = "corner"\n[render]\nmax_depth = 2\n',
                            ["render.max_depth = 2", "expected an integer >= 3", "corner"]),
    "pose behind the surface": ('name = "b"\n[camera]\nposition = [0.0, 0.0, -1.0]\n',
                                ["camera.position = [0.0, 0.0, -1.0]", "expected z > 0"]),
    "looking away": ('name = "b"\n[camera]\nlook_at = [0.0, 0.0, 2.0]\n',
                     ["camera.look_at = [0.0, 0.0, 2.0]", "smaller z than camera.position"]),
    "up along the axis": ('name = "b"\n[projector]\nup = [0.0, 0.0, 1.0]\n',
                          ["projector.up = [0.0, 0.0, 1.0]", "not parallel to projector.look_at"]),
    "not TOML": ('name = "b"\n[camera\n', ["not valid TOML"]),
    "a frame folder's name": ('name = "train"\n', ['name = "train"', "frame folder", "ref, train, test"]),
    "a frame folder's name in capitals": ('name = "Ref"\n', ['name = "Ref"', "frame folder"]),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_input_names_file_key_and_expectation(tmp_path, case):
    text, parts = BAD[case]
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SetupError) as err:
        load_setup(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ")
    missing = [p for p in parts if p not in msg]
    assert not missing, f"{msg!r} lacks {missing}"


def test_out_of_range_message_is_the_documented_one(tmp_path):
    path = tmp_path / "bad.toml"
    path.write_text('name = "b"\n[camera]\nfov = -5.0\n')
    with pytest.raises(SetupError, match=r"^.*bad\.toml: camera\.fov = -5\.0: expected a number in "
                                         r"\(1, 120\) degrees$"):
        load_setup(path)


def test_missing_setup_file():
    with pytest.raises(SetupError, match="nowhere.toml: cannot read setup file"):
        load_setup("nowhere.toml")


# ---------------------------------------------------------------------------------- declared keys

def _option_classes() -> list[type]:
    return [*SECTIONS.values(), *(cls.Options for cls in surfaces.SURFACES.values())]


@pytest.mark.parametrize("cls", _option_classes(), ids=lambda c: c.__name__)
def test_every_key_declares_its_check(cls):
    """A key without a declared check cannot exist: every field carries a Spec, and each
    default passes its own check (the defaults are what a missing key becomes)."""
    for f in dataclasses.fields(cls):
        spec = spec_of(f)
        if spec.kind != "variant" and f.default is not None:
            assert spec.value(f.default) == f.default, f.name


def test_a_field_declared_without_a_check_cannot_be_parsed():
    @dataclasses.dataclass(frozen=True)
    class Flare:
        strength: float = 0.3

    with pytest.raises(TypeError, match="'strength' is declared without a check"):
        parse(Flare, {}, Table("<test>", "camera"))


OTHER_VALUES = {"position": (0.1, 0.0, 1.5), "look_at": (0.0, 0.1, -0.1), "up": (1.0, 1.0, 0.0),
                "texture": "uniform", "response": "linear"}
"""Valid non-default values where a rule of thumb gives none (poses, strings)."""
SINGLE_VALUED = {("camera", "bit_depth")}
"""Keys with one valid value: nothing else to read."""


def _other_value(f: dataclasses.Field):
    """A valid value of a declared key other than its default."""
    spec = spec_of(f)
    if f.name in OTHER_VALUES:
        return OTHER_VALUES[f.name]

    def number(default, integer=False):
        candidates = (default + 1, default * 2, 8, 1) if integer else (
            default * 0.5 if default else 0.5, 0.3, 1.5, -0.01)
        return next(v for v in candidates if v in spec.range and v != default)

    if spec.kind == "choice":
        return next(c for c in spec.options() if c != f.default)
    if spec.kind == "boolean":
        return not f.default
    if spec.kind in ("number", "integer"):
        return number(f.default, spec.kind == "integer")
    if spec.kind == "vector":
        return tuple(number(v, spec.integer) for v in f.default)
    assert spec.kind == "matrix"
    return tuple(tuple(v + 0.1 for v in row) for row in f.default)


@pytest.mark.parametrize("section", SECTIONS)
def test_every_key_of_a_section_is_read_from_the_file(section):
    """Each key given with a value other than its default reaches the parsed setup: none is
    silently replaced by its default. (Optional keys, default None, are read together with
    another: the ambient light's temperature and intensity, tested above.)"""
    for f in dataclasses.fields(SECTIONS[section]):
        if spec_of(f).kind == "variant" or f.default is None or (section, f.name) in SINGLE_VALUED:
            continue
        value = _other_value(f)
        given = [list(v) for v in value] if spec_of(f).kind == "matrix" else (
            list(value) if isinstance(value, tuple) else value)
        parsed = getattr(parse_setup({"name": "n", section: {f.name: given}}), section)
        assert getattr(parsed, f.name) == value != f.default, f"{section}.{f.name}"


def test_unknown_camera_key_is_refused(tmp_path):
    path = tmp_path / "flare.toml"
    path.write_text('name = "b"\n[camera]\nflare = 0.3\n')
    with pytest.raises(SetupError, match=r"flare\.toml: camera\.flare: unknown key; valid keys of "
                                         r"\[camera\]: adaptive_tone, aperture_radius, bayer, .*; flare is a "
                                         r"key of \[projector\]$"):
        load_setup(path)
    path.write_text('name = "b"\n[camera]\nflares = 0.3\n')  # a key of no section: no pointer
    with pytest.raises(SetupError, match=r"camera\.flares: unknown key; valid keys of \[camera\]: [a-z_, ]*$"):
        load_setup(path)


def test_a_surface_key_is_refused_for_a_surface_that_does_not_take_it(tmp_path):
    path = tmp_path / "plane.toml"
    path.write_text('name = "b"\n[surface]\ngeometry = "plane"\ncorner_angle = 60.0\n')
    with pytest.raises(SetupError) as err:
        load_setup(path)
    assert str(err.value).startswith(
        f'{path}: surface.corner_angle = 60.0: not a key of surface.geometry = "plane" (only of '
        '"corner"); valid keys of [surface]: albedo_scale, bow, geometry, ink_density, material, '
        'relief, relief_length, relief_seed, roughness, size, ')
    assert "corner_angle" not in str(err.value).split("valid keys")[1]
    corner = parse_setup({"name": "c", "surface": {"geometry": "corner", "corner_angle": 60}})
    assert corner.surface.shape.corner_angle == 60.0 and type(corner.surface.shape.corner_angle) is float
    with pytest.raises(SetupError, match=r"surface\.corner_angle = 200\.0: expected a number in "
                                         r"\(30, 180\) degrees"):
        parse_setup({"name": "c", "surface": {"geometry": "corner", "corner_angle": 200.0}})


def test_unknown_surface_key_lists_every_surface_key():
    with pytest.raises(SetupError, match=r"surface\.angle: unknown key; valid keys of \[surface\]: "
                                         r"albedo_scale, bow, corner_angle, geometry, ink_density, "
                                         r"material, relief, relief_length, relief_seed, "):
        parse_setup({"name": "c", "surface": {"angle": 60}})


def test_surface_options_follow_the_geometry():
    assert SurfaceConfig().shape == surfaces.get_surface("plane").Options()
    corner = SurfaceConfig(geometry="corner")
    assert corner.shape == surfaces.get_surface("corner").Options() and corner.shape.corner_angle == 90.0
    with pytest.raises(TypeError, match="expected CornerOptions for geometry 'corner'"):
        SurfaceConfig(geometry="corner", shape=SurfaceConfig().shape)
    wide = parse_setup({"name": "w", "surface": {"geometry": "corner", "corner_angle": 120.0}})
    assert parse_setup(tomllib.loads(dump_setup(wide))) == wide


def test_a_suite_entry_changing_the_surface_drops_the_base_surface_keys(tmp_path):
    (tmp_path / "base.toml").write_text('name = "base"\n[surface]\ngeometry = "corner"\ncorner_angle = 60.0\n'
                                        '[render]\nfidelity = "path"\n')
    (tmp_path / "s.toml").write_text('base = "base.toml"\n[[setup]]\nname = "c"\n'
                                     '[[setup]]\nname = "p"\nsurface = { geometry = "plane" }\n')
    corner, plane = load_suite(tmp_path / "s.toml")
    assert corner.surface.shape.corner_angle == 60.0
    assert plane.surface == SurfaceConfig()


# ---------------------------------------------------------------------------------- suites

def _suite(tmp_path: Path, text: str) -> Path:
    (tmp_path / "base.toml").write_text('name = "base"\n[ambient]\ntemperature = 5000.0\nintensity = 0.02\n'
                                        '[camera]\nfov = 38.0\n')
    path = tmp_path / "suite.toml"
    path.write_text('base = "base.toml"\n' + text)
    return path


def test_suite_deep_merges_onto_the_base(tmp_path):
    path = _suite(tmp_path, '[[setup]]\nname = "one"\ncamera = { exposure = 0.5 }\n'
                            '[[setup]]\nname = "two"\nambient = { radiance = [0.1, 0.1, 0.1] }\n'
                            '[[setup]]\nname = "three"\nambient = { intensity = 0.04 }\n')
    one, two, three = load_suite(path)
    assert one.camera.fov == 38.0 and one.camera.exposure == 0.5  # merged, not replaced
    assert one.ambient.temperature == 5000.0
    assert two.ambient == AmbientConfig((0.1, 0.1, 0.1), None, None)  # the other form is dropped
    assert three.ambient.temperature == 5000.0 and three.ambient.intensity == 0.04
    np.testing.assert_allclose(three.ambient.radiance, 2 * np.array(one.ambient.radiance))


def test_suite_resolves_texture_paths_against_the_file_that_gives_them(tmp_path):
    write_png(tmp_path / "base" / "wall.png", np.full((8, 8, 3), 90, np.uint8))
    write_png(tmp_path / "other.png", np.full((8, 8, 3), 90, np.uint8))
    (tmp_path / "base" / "b.toml").write_text('name = "b"\n[surface]\ntexture = "wall.png"\n')
    (tmp_path / "s.toml").write_text('base = "base/b.toml"\n[[setup]]\nname = "x"\n'
                                     '[[setup]]\nname = "y"\nsurface = { texture = "other.png" }\n')
    x, y = load_suite(tmp_path / "s.toml")
    assert x.surface.texture == str((tmp_path / "base" / "wall.png").resolve())
    assert y.surface.texture == str((tmp_path / "other.png").resolve())


@pytest.mark.parametrize("text, parts", [
    ('[[setup]]\nname = "a"\n[[setup]]\nname = "a"\n', ['setup[1].name = "a"', "unique", "setup[0]"]),
    ('[[setup]]\nname = "a"\n[[setup]]\nname = "b"\ncamera = { fov = 500.0 }\n',
     ["setup[1].camera.fov = 500.0", "expected a number in (1, 120) degrees"]),
    ('[[setup]]\nname = "a"\nlens = { f = 1 }\n', ["setup[0].lens", "unknown section"]),
    ('[[setup]]\ncamera = { fov = 30.0 }\n', ["setup[0].name", "missing"]),
    ('[[setup]]\nname = "a"\nambient = { radiance = [0.1, 0.1, 0.1], temperature = 3000.0 }\n',
     ["setup[0].ambient.radiance", "setup[0].ambient.temperature", "exactly one"]),
    ('[[setup]]\nname = "a"\nsurface = { geometry = "corner" }\nrender = { fidelity = "direct" }\n',
     ['setup[0].render.fidelity = "direct"', "inter-reflection"]),
    ("setups = 3\n", ["setups", "unknown key", "base, setup, test_frames"]),
    ('test_frames = "natural"\n[[setup]]\nname = "a"\n',
     ['test_frames = "natural"', "expected one of 'mixed', 'photo'"]),
    ("", ["setup", "expected one or more [[setup]] tables"]),
])
def test_bad_suite_names_suite_file_and_entry(tmp_path, text, parts):
    path = _suite(tmp_path, text)
    with pytest.raises(SetupError) as err:
        load_suite(path)
    msg = str(err.value)
    assert msg.startswith(f"{path}: ")
    missing = [p for p in parts if p not in msg]
    assert not missing, f"{msg!r} lacks {missing}"


def test_load_setups_takes_a_setup_file_a_suite_file_or_a_shipped_name(tmp_path):
    assert load_setups("default") == [load_setup(scene_path("default"))]
    assert load_setups("suite.toml") == load_suite(scene_path("suite"))
    one = tmp_path / "one.toml"
    one.write_text('name = "one"\n[camera]\nfov = 38.0\n')
    assert load_setups(str(one)) == [load_setup(one)]
    suite = _suite(tmp_path, '[[setup]]\nname = "a"\n[[setup]]\nname = "b"\n')
    assert [s.name for s in load_setups(str(suite))] == ["a", "b"]
    with pytest.raises(SetupError, match="nowhere: no such setup file, and not a shipped scene; shipped: "
                                         ".*default"):
        load_setups("nowhere")
    (tmp_path / "broken.toml").write_text("name = \n")
    with pytest.raises(SetupError, match="broken.toml: not valid TOML"):
        load_setups(str(tmp_path / "broken.toml"))
    (tmp_path / "bom.toml").write_bytes(b"\xef\xbb\xbf" + one.read_bytes())  # as some editors save
    assert load_setups(str(tmp_path / "bom.toml"))[0].camera.fov == 38.0


def test_a_suite_says_which_test_frames_its_datasets_take(tmp_path):
    assert suite_test_frames("paper") == "photo"
    assert suite_test_frames("suite") is None and suite_test_frames("default") is None  # a setup file
    suite = _suite(tmp_path, 'test_frames = "mixed"\n[[setup]]\nname = "a"\n')
    assert suite_test_frames(str(suite)) == "mixed" and [s.name for s in load_suite(suite)] == ["a"]
    suite.write_text('test_frames = 3\n[[setup]]\nname = "a"\n')
    with pytest.raises(SetupError, match=f"^{re.escape(str(suite))}: test_frames = 3: expected one of"):
        suite_test_frames(str(suite))


def test_suite_base_errors_name_the_base_file(tmp_path):
    path = _suite(tmp_path, '[[setup]]\nname = "a"\n')
    (tmp_path / "base.toml").write_text('name = "base"\n[camera]\nfov = 0.5\n')
    with pytest.raises(SetupError, match=r"base\.toml: camera\.fov = 0\.5: expected"):
        load_suite(path)


# ---------------------------------------------------------------------------------- colour temperature

def test_temperature_6500_is_near_white_with_unit_luminance():
    rgb = np.array(temperature_rgb(6500.0))
    assert rgb.max() / rgb.min() < 1.1
    assert LUMINANCE @ rgb == pytest.approx(1.0, abs=1e-4)


def test_temperature_3000_is_reddish():
    r, g, b = temperature_rgb(3000.0)
    assert r > g > b > 0
    assert LUMINANCE @ np.array([r, g, b]) == pytest.approx(1.0, abs=1e-4)


def test_temperature_blue_to_red_ratio_rises_with_kelvin():
    ratios = [temperature_rgb(k)[2] / temperature_rgb(k)[0] for k in (2000, 3000, 5000, 6500, 10000, 25000)]
    assert ratios == sorted(ratios) and ratios[-1] > 1 > ratios[0]


def test_temperature_clips_negative_channels_and_checks_range():
    assert min(temperature_rgb(1000.0)) == 0.0  # out of the sRGB gamut: blue clipped
    with pytest.raises(ValueError, match="1000..25000"):
        temperature_rgb(30000.0)


def test_ambient_from_temperature_is_intensity_times_colour():
    s = parse_setup({"name": "t", "ambient": {"temperature": 3000, "intensity": 0.04}})
    assert s.ambient.temperature == 3000.0 and s.ambient.intensity == 0.04
    assert s.ambient.radiance == tuple(0.04 * c for c in temperature_rgb(3000.0))


# ---------------------------------------------------------------------------------- geometry

def _frame(position, look_at, up) -> np.ndarray:
    """Columns: image x, image y and forward axes of a look-at pose."""
    z = np.subtract(look_at, position)
    z = z / np.linalg.norm(z)
    x = np.cross(up, z)
    x = x / np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z], axis=1)


def _projector_rays(p: ProjectorConfig, n: int = 17) -> tuple[np.ndarray, np.ndarray, int]:
    """Unit directions through the border of a square input frame's area on the panel (4 (n)
    points) and through an n x n grid inside it; the cosine of their angle to the optical axis;
    the border count."""
    _, _, w, h = frame_area(p.resolution, (256, 256), p.keep_aspect)
    t = math.tan(math.radians(p.fov) / 2) * w / p.resolution[0]
    th = math.tan(math.radians(p.fov) / 2) * h / p.resolution[0]
    s = np.linspace(-1, 1, n)
    border = np.concatenate([np.stack([s * t, np.full(n, v * th)], 1) for v in (-1, 1)]
                            + [np.stack([np.full(n, u * t), s * th], 1) for u in (-1, 1)])
    gx, gy = np.meshgrid(s * t, s * th)
    local = np.concatenate([border, np.stack([gx.ravel(), gy.ravel()], 1)])
    local = np.concatenate([local, np.ones((len(local), 1))], 1)
    cos_axis = 1 / np.linalg.norm(local, axis=1)
    return (local * cos_axis[:, None]) @ _frame(p.position, p.look_at, p.up).T, cos_axis, 4 * n


def _walls(s: SurfaceConfig) -> list[tuple[np.ndarray, float, float]]:
    """The surface as rectangles through the origin spanned by a horizontal unit axis u
    (from u0 to u1 metres) and +y (height h): (u, u0, u1)."""
    if s.geometry == "plane":
        return [(np.array([1.0, 0.0, 0.0]), -s.size[0] / 2, s.size[0] / 2)]
    half = math.radians(s.shape.corner_angle) / 2  # wings leave the vertical edge towards +z
    return [(np.array([-math.sin(half), 0.0, math.cos(half)]), 0.0, s.size[0]),
            (np.array([math.sin(half), 0.0, math.cos(half)]), 0.0, s.size[0])]


def _hits(setup: Setup, rays: np.ndarray):
    """Nearest hit of projector rays on the surface: points, wall normals, inside-extent flags."""
    o = np.array(setup.projector.position)
    best = np.full(len(rays), np.inf)
    normal = np.zeros((len(rays), 3))
    inside = np.zeros(len(rays), bool)
    for u, u0, u1 in _walls(setup.surface):
        n = np.cross(u, [0.0, 1.0, 0.0])
        n = n if n @ o > 0 else -n  # towards the projector's side
        with np.errstate(divide="ignore"):
            t = -(o @ n) / (rays @ n)
        p = o + t[:, None] * rays
        ok = (t > 0) & (p @ u >= u0) & (p @ u <= u1) & (np.abs(p[:, 1]) <= setup.surface.size[1] / 2)
        closer = ok & (t < best)
        best[closer], normal[closer], inside[closer] = t[closer], n, True
    return o + np.where(inside, best, 0)[:, None] * rays, normal, best, inside


def _camera_uv(c: CameraConfig, points: np.ndarray) -> np.ndarray:
    """Pinhole image coordinates in [-1, 1]^2 across the frame (z > 0 required)."""
    local = (points - np.array(c.position)) @ _frame(c.position, c.look_at, c.up)
    assert np.all(local[:, 2] > 0)
    t = math.tan(math.radians(c.fov) / 2)
    return np.stack([local[:, 0] / (local[:, 2] * t),
                     local[:, 1] / (local[:, 2] * t * c.resolution[1] / c.resolution[0])], 1)


@pytest.mark.parametrize("setup", ALL, ids=[s.name for s in ALL])
def test_projected_area_lies_on_the_surface_and_inside_the_camera_frame(setup):
    rays, _, n_border = _projector_rays(setup.projector)
    points, normal, _, inside = _hits(setup, rays)
    assert inside.all(), "part of the projected frame misses the surface"
    cam = np.array(setup.camera.position)
    assert np.all(np.sum(normal * (cam - points), axis=1) > 0), "the camera sees a wall from behind"
    uv = _camera_uv(setup.camera, points[:n_border])
    assert np.abs(uv).max() <= 0.95, "the projected area reaches the edge of the camera frame"


@pytest.mark.parametrize("setup", ALL, ids=[s.name for s in ALL])
def test_brightest_capture_stays_below_clipping(setup):
    """White input on the brightest albedo plus ambient, from the projector's falloff
    (irradiance = brightness * cos(normal) / (cos(axis) * depth^2), 1 head-on at 1 m). A camera
    whose exposure follows the over-exposure rule is checked by the rule's own tests instead."""
    if setup.camera.exposure_mode == "rule":
        pytest.skip("exposure set by the rule at render time")
    rays, cos_axis, _ = _projector_rays(setup.projector)
    _, normal, dist, _ = _hits(setup, rays)
    cos_n = np.abs(np.sum(normal * rays, axis=1))
    irradiance = setup.projector.brightness * cos_n / (cos_axis * (dist * cos_axis) ** 2)
    s, c = setup.surface, setup.camera
    peak = c.exposure * max(c.white_balance) * s.albedo_scale * max(s.tint) * (
        irradiance.max() + max(setup.ambient.radiance))
    if setup.surface.geometry == "corner":
        assert peak < 0.75  # room for the light the wings reflect onto each other
    else:
        assert peak < 0.95
    if setup.name == "ideal":
        assert 0.8 <= peak <= 0.9


def test_ideal_projected_area_fills_most_of_the_frame():
    setup = load_setup(scene_path("ideal"))
    p = setup.projector
    t = math.tan(math.radians(p.fov) / 2)
    corners = np.array([[-t, -t, 1], [t, -t, 1], [t, t, 1], [-t, t, 1]]) @ _frame(p.position, p.look_at, p.up).T
    points = np.array(p.position) - (p.position[2] / corners[:, 2])[:, None] * corners
    uv = _camera_uv(setup.camera, points)
    area = 0.5 * abs(np.dot(uv[:, 0], np.roll(uv[:, 1], 1)) - np.dot(uv[:, 1], np.roll(uv[:, 0], 1))) / 4
    assert 0.55 <= area <= 0.8
