"""Surfaces: the registry, ray intersection, projector-pixel depth and texture layout, each against
hand-computed geometry."""
from __future__ import annotations

import numpy as np
import pytest

from sim import surfaces
from sim.errors import SetupError
from sim.geometry import Pinhole
from sim.setup import SurfaceConfig
from sim.surfaces.corner import Corner, CornerOptions
from sim.surfaces.plane import Plane, PlaneOptions


def _corner(angle: float = 90.0, size=(1.0, 1.0)) -> Corner:
    return Corner(size, 512, CornerOptions(corner_angle=angle))


def _plane(size=(1.2, 1.0)) -> Plane:
    return Plane(size, 512, PlaneOptions())


def _projector(position, width=33, height=9, fov=40.0) -> Pinhole:
    return Pinhole(np.asarray(position, float), np.zeros(3), np.array([0.0, 1.0, 0.0]), fov, width, height)


def _local_x(p: Pinhole) -> np.ndarray:
    """Local x (image left) over local z of each column's ray: -(2u - 1) tan(fov / 2)."""
    u = (np.arange(p.width) + 0.5) / p.width
    return -(2 * u - 1) * p.tan_half


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# ---------------------------------------------------------------------------------- registry

def test_registry_lists_the_shipped_surfaces():
    assert surfaces.names() == ("plane", "corner")
    assert surfaces.get_surface("plane") is Plane and surfaces.get_surface("corner") is Corner
    assert isinstance(surfaces.surface_for(SurfaceConfig(geometry="corner")), Corner)
    assert isinstance(surfaces.surface_for(SurfaceConfig()), Plane)  # the default geometry
    built = surfaces.surface_for(SurfaceConfig(geometry="corner", size=(0.6, 1.0), texture_resolution=64,
                                               shape=CornerOptions(corner_angle=60.0)))
    assert built == Corner((0.6, 1.0), 64, CornerOptions(corner_angle=60.0))


def test_each_surface_takes_its_own_options():
    assert Plane.Options is PlaneOptions and Corner.Options is CornerOptions
    with pytest.raises(TypeError, match="Plane: options CornerOptions"):
        Plane((1.0, 1.0), 512, CornerOptions())


def test_registry_refuses_unknown_names():
    with pytest.raises(SetupError, match="unknown surface geometry 'sphere'; expected one of: 'plane', 'corner'"):
        surfaces.get_surface("sphere")
    with pytest.raises(SetupError, match="unknown surface geometry 'sphere'"):
        surfaces.surface_for(SurfaceConfig(geometry="sphere"))
    assert surfaces.names() == ("plane", "corner")


def test_flags():
    assert not Plane.interreflection and Plane.planar
    assert Corner.interreflection and not Corner.planar


# ---------------------------------------------------------------------------------- intersection

def test_plane_head_on_and_oblique_hits():
    plane = _plane()
    t, index = plane.intersect(np.array([0.1, 0.2, 2.0]), np.array([[0.0, 0.0, -1.0]]))
    assert t[0] == pytest.approx(2.0, abs=1e-12) and index[0] == 0
    # from (0, 0, 1) towards the point (0.3, -0.4, 0): t is the distance to it
    t, index = plane.intersect(np.array([0.0, 0.0, 1.0]), _unit([[0.3, -0.4, -1.0]]))
    assert t[0] == pytest.approx(np.sqrt(0.09 + 0.16 + 1.0), abs=1e-12) and index[0] == 0
    np.testing.assert_allclose(plane.normals(np.zeros((1, 3)), index), [[0.0, 0.0, 1.0]])


def test_plane_misses():
    plane = _plane()  # x in [-0.6, 0.6], y in [-0.5, 0.5]
    origin = np.array([0.0, 0.0, 1.0])
    dirs = _unit([[0.7, 0.0, -1.0],    # beyond the right edge
                  [0.0, -0.55, -1.0],  # below the bottom edge
                  [0.0, 0.0, 1.0],     # away from the plane
                  [1.0, 0.0, 0.0]])    # parallel to it
    t, index = plane.intersect(origin, dirs)
    assert np.all(np.isinf(t)) and np.all(index == -1)


def test_per_ray_origins():
    """``origin`` broadcasts: one origin per ray works as well as a shared one."""
    origins = np.array([[0.0, 0.0, 1.0], [0.2, 0.1, 3.0]])
    t, index = _plane().intersect(origins, np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]]))
    np.testing.assert_allclose(t, [1.0, 3.0], atol=1e-12)
    assert index.tolist() == [0, 0]


@pytest.mark.parametrize("angle", [90.0, 120.0])
def test_corner_hits_each_wing(angle):
    """Each wing runs from the edge at the origin along (±sin(a/2), 0, cos(a/2)); a ray aimed at
    the point 0.4 m along a wing hits that wing there, at the distance to it."""
    corner = _corner(angle)
    half = np.radians(angle) / 2
    origin = np.array([0.0, 0.1, 1.5])
    for side, index_expected in ((-1, 0), (1, 1)):
        target = 0.4 * np.array([side * np.sin(half), 0.0, np.cos(half)]) + [0.0, 0.2, 0.0]
        t, index = corner.intersect(origin, _unit(target - origin)[None])
        assert t[0] == pytest.approx(np.linalg.norm(target - origin), abs=1e-12)
        assert index[0] == index_expected
        # the front normal points into the corner: (cos(a/2), 0, sin(a/2)) for the left wing
        np.testing.assert_allclose(corner.normals(target[None], index),
                                   [[-side * np.cos(half), 0.0, np.sin(half)]], atol=1e-12)


def test_corner_nearer_wing_wins_and_misses():
    corner = _corner(90.0)  # wings 1 m wide (to x = ±0.707), 1 m tall (y in [-0.5, 0.5])
    # from inside the corner towards -x, a ray passes nothing but the left wing...
    t, index = corner.intersect(np.array([0.0, 0.0, 0.5]), np.array([[-1.0, 0.0, 0.0]]))
    assert t[0] == pytest.approx(0.5) and index[0] == 0
    # ...from outside the right wing, towards -x, the right wing (x = z = 0.3) comes first
    t, index = corner.intersect(np.array([2.0, 0.0, 0.3]), np.array([[-1.0, 0.0, 0.0]]))
    assert t[0] == pytest.approx(1.7) and index[0] == 1
    origin = np.array([0.0, 0.0, 1.0])
    dirs = _unit([[0.0, 1.0, -0.1],    # above the wings
                  [2.0, 0.0, -0.1],    # past the right wing's outer edge
                  [0.0, 0.0, 1.0]])    # away
    t, index = corner.intersect(origin, dirs)
    assert np.all(np.isinf(t)) and np.all(index == -1)


# ---------------------------------------------------------------------------------- depth

def test_plane_depth_head_on_is_the_distance_everywhere():
    """A plane perpendicular to the optical axis lies at one depth d for every pixel."""
    d = 1.7
    p = _projector([0.0, 0.0, d], width=16, height=12, fov=30.0)
    depth = _plane(size=(10.0, 10.0)).projector_depth(p)
    assert depth.shape == (12, 16)
    np.testing.assert_allclose(depth, d, rtol=1e-12)


def test_plane_depth_is_inf_where_pixels_miss():
    d = 1.0
    p = _projector([0.0, 0.0, d], width=16, height=16, fov=30.0)  # covers ±0.268 m at d
    depth = _plane(size=(0.2, 0.2)).projector_depth(p)           # ±0.1 m
    x = np.abs(_local_x(p)) * d
    inside = x < 0.1 - 1e-9
    np.testing.assert_allclose(depth[np.ix_(inside, inside)], d, rtol=1e-12)
    assert np.all(np.isinf(depth[:, ~inside])) and np.all(np.isinf(depth[~inside, :]))


def test_tilted_plane_depth():
    """Projector at distance d, turned by theta about the vertical axis, aimed at the origin.
    A pixel whose ray has local x / z = x_l meets the plane at depth z = d / (1 - x_l tan theta):
    d on the axis, the same down each column, and 1 / z linear across the image."""
    d, theta = 1.3, np.radians(30.0)
    p = _projector([d * np.sin(theta), 0.0, d * np.cos(theta)], width=32, height=8, fov=40.0)
    depth = _plane(size=(10.0, 10.0)).projector_depth(p)
    expected = d / (1 - _local_x(p) * np.tan(theta))
    np.testing.assert_allclose(depth, np.broadcast_to(expected, depth.shape), rtol=1e-12)
    np.testing.assert_allclose(np.diff(1 / depth[0], 2), 0.0, atol=1e-12)  # inverse depth: linear
    assert np.all(np.abs(np.diff(depth[0], 2)) > 1e-6)                     # depth itself is not
    assert depth[0, 0] > d > depth[0, -1]  # image left (towards -x, away from the projector) is deeper


@pytest.mark.parametrize("angle", [90.0, 120.0])
def test_corner_depth_edge_and_wings(angle):
    """Projector at (0, 0, d) facing the edge: its axis meets the vertex edge at depth d; a column
    with local x / z = x_l hits a wing at d / (1 + |x_l| cot(a/2)), nearer on both sides."""
    d = 1.5
    corner = _corner(angle, size=(5.0, 5.0))
    t, index = corner.intersect(np.array([0.0, 0.0, d]), np.array([[0.0, 0.0, -1.0]]))
    assert t[0] == pytest.approx(d, abs=1e-12) and index[0] >= 0
    p = _projector([0.0, 0.0, d], width=32, height=9)  # even width: columns 15 and 16 flank the edge
    depth = corner.projector_depth(p)
    expected = d / (1 + np.abs(_local_x(p)) / np.tan(np.radians(angle) / 2))
    np.testing.assert_allclose(depth, np.broadcast_to(expected, depth.shape), rtol=1e-12)
    np.testing.assert_allclose(depth[:, :16], depth[:, :15:-1], rtol=1e-12)  # symmetric wings
    assert np.all(depth[:, 15] == depth.max(axis=1)) and np.all(depth < d)


# ---------------------------------------------------------------------------------- texture

def test_texture_size_and_layout():
    """The albedo texture spans the whole surface: a corner's is two wings wide, its left half on
    the left wing (index 0) and its right half on the right wing."""
    assert _plane(size=(1.2, 1.0)).texture_size() == (512, 427)
    assert Plane((0.5, 1.0), 64, PlaneOptions()).texture_size() == (32, 64)
    assert _corner(size=(0.6, 1.0)).texture_size() == (512, 427)
    assert _corner(size=(1.2, 1.0)).texture_size() == (512, 213)
    assert [r.tex_span for r in _corner().rects()] == [(0.0, 0.5), (0.5, 1.0)]
    assert [r.tex_span for r in _plane().rects()] == [(0.0, 1.0)]


def test_shapes_place_the_texture_halves(variant):
    from sim.variant import use_variant

    use_variant(variant)
    albedo = np.arange(4 * 6 * 3, dtype=np.float32).reshape(4, 6, 3)
    parts = []
    shapes = _corner().shapes(albedo, lambda part: parts.append(part) or {"type": "diffuse"})
    assert list(shapes) == ["surface_0", "surface_1"]
    np.testing.assert_array_equal(parts[0], albedo[:, :3])
    np.testing.assert_array_equal(parts[1], albedo[:, 3:])
    for shape, rect in zip(shapes.values(), _corner().rects()):
        assert shape["type"] == "rectangle" and shape["bsdf"] == {"type": "diffuse"}
        np.testing.assert_allclose(np.array(shape["to_world"].matrix, float), rect.to_world(), atol=1e-6)
