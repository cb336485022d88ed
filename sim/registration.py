"""Camera → canonical projector view.

The canonical view is the projector's input frame at the dataset's size: canonical pixel
(column, row) of a W × H view shows the frame's area on the panel (:func:`sim.projector.frame_area`:
the scaler covers the panel keeping the frame's aspect, or stretches it with ``keep_aspect =
false``) at ((column + 0.5) / W, (row + 0.5) / H) of its width and height, whatever the
projector's native resolution (:meth:`sim.render.Renderer.emit`).

Two maps bring a capture into that view (:func:`register` picks one by ``registration.method``):

- the **homography** a real pipeline estimates on a plane (:func:`estimate_homography`): a
  checkerboard, a white and a black frame are projected and captured through the full camera
  model, the corners found with OpenCV and a homography fitted to them (:func:`homography_map`);
- the **exact** dense map from the scene geometry (:func:`exact_map`): every canonical pixel's
  projector ray is intersected with the surface and the hit point projected into the camera, with
  a mask of pixels the camera cannot see. It is exact on non-planar surfaces too, where a real
  pipeline measures such a dense map with structured light (e.g. Gray codes); it is always kept
  as the ground truth the homography's error is measured against.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from sim import camera, geometry, seeds, surfaces
from sim.errors import SetupError
from sim.projector import frame_area
from sim.projector.distortion import distort_points
from sim.setup import Setup

MIN_VISIBLE_FRACTION = 0.5
"""Least fraction of the canonical projector pixels that must land on the surface and be seen by
the camera for a setup to be rendered (:func:`check_visible`). Unseen pixels are black in every
warped capture: below one half, most of each training pair carries no signal and the metrics are
dominated by pixels no compensation can change. The shipped scenes see all of them; a projector
image that deliberately spills over an edge of the surface or the camera frame is still allowed."""


@dataclass(frozen=True)
class WarpMap:
    """Where each canonical pixel is found in the camera image.

    Attributes
    ----------
    xy : numpy.ndarray
        float32 (H, W, 2): camera pixel coordinates (column, row), pixel centres at integer + 0.5.
    mask : numpy.ndarray
        bool (H, W): True where the surface point is lit by that projector pixel and seen by the
        camera (not occluded, inside the camera frame).
    """

    xy: np.ndarray
    mask: np.ndarray


def exact_map(setup: Setup, size: tuple[int, int]) -> WarpMap:
    """Exact dense map from the scene geometry.

    Parameters
    ----------
    setup : Setup
        The setup (projector and camera poses, surface geometry, both lenses' distortion: each
        canonical pixel leaves the projector along the ray its panel point is distorted to).
    size : (int, int)
        Canonical (width, height) in pixels: the view of the frame's area on the panel
        (:func:`sim.projector.frame_area`; the whole panel with ``projector.keep_aspect = false``,
        when canonical pixels are not square if the two aspects differ).
    """
    surface = surfaces.surface_for(setup.surface)
    p = setup.projector
    x0, y0, w, h = frame_area(p.resolution, size, p.keep_aspect)
    # each canonical pixel's centre on the panel, and the ray it leaves the lens along
    u, v = np.meshgrid((np.arange(size[0]) + 0.5) / size[0], (np.arange(size[1]) + 0.5) / size[1])
    panel = np.stack([x0 + u * w, y0 + v * h], axis=-1)
    panel = distort_points(panel, tuple(p.resolution), p.distortion_k1, p.distortion_k2, p.lens_offset)
    proj = geometry.Pinhole.from_config(p)
    cam = geometry.Pinhole.from_config(setup.camera)
    rays = proj.rays(panel)
    t, idx = surface.intersect(proj.position, rays)
    hit = np.isfinite(t)
    points = proj.position + np.where(hit, t, 1.0)[..., None] * rays
    normals = surface.normals(points, idx)
    # one-sided surfaces: lit and seen only from the side their normal points to
    facing = (np.sum(normals * (proj.position - points), axis=-1) > 0) & (
        np.sum(normals * (cam.position - points), axis=-1) > 0)
    xy, in_front = cam.project(points)
    xy = camera.distort_points(xy, setup.camera)  # where the lens shows each point
    to_point = points - cam.position
    dist = np.linalg.norm(to_point, axis=-1)
    tc, _ = surface.intersect(cam.position, to_point / dist[..., None])
    unoccluded = np.abs(tc - dist) <= 1e-6 + 1e-5 * dist
    inside = (xy[..., 0] >= 0) & (xy[..., 0] <= cam.width) & (xy[..., 1] >= 0) & (xy[..., 1] <= cam.height)
    return WarpMap(xy.astype(np.float32), hit & facing & in_front & unoccluded & inside)


def check_visible(setup: Setup, size: tuple[int, int]) -> float:
    """Refuse a setup whose camera would capture too little of the projector image.

    Parameters
    ----------
    setup : Setup
        The setup.
    size : (int, int)
        Canonical (width, height) in pixels.

    Returns
    -------
    float
        The fraction of canonical pixels lit on the surface and seen by the camera
        (:attr:`WarpMap.mask` of :func:`exact_map`).

    Raises
    ------
    SetupError
        If that fraction is below :data:`MIN_VISIBLE_FRACTION`; the message gives it.
    """
    fraction = float(exact_map(setup, size).mask.mean())
    if fraction < MIN_VISIBLE_FRACTION:
        raise SetupError(
            f'setup "{setup.name}": only {fraction:.1%} of the projector image lands on the surface '
            f"and is seen by the camera (at least {MIN_VISIBLE_FRACTION:.0%} needed: the rest of "
            "every capture would be black); aim projector.position/look_at at the surface and "
            "camera.position/look_at/fov at the projected area")
    return fraction


def warp(image: np.ndarray, wmap: WarpMap) -> np.ndarray:
    """Sample a camera image at the canonical pixels (bilinear); unseen pixels are 0.

    Works on 8-bit captures (rounded back to uint8) and on float images alike.
    """
    src = np.asarray(image)
    work = src.astype(np.float32)
    out = cv2.remap(work, wmap.xy[..., 0] - 0.5, wmap.xy[..., 1] - 0.5, cv2.INTER_LINEAR,
                    borderMode=cv2.BORDER_REPLICATE)
    out[~wmap.mask] = 0
    if src.dtype == np.uint8:
        return np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return out


SQUARES = (9, 6)
"""Squares of the registration checkerboard (columns, rows). One count odd and the other even, so
that the pattern turned by 180° swaps its black and white squares: the corner order OpenCV finds
(which may start at either end) is then told apart by the capture itself. With both odd (e.g.
9 × 7) the turned pattern is the same pattern: both orders fit it equally well, and a dataset
could be registered turned by 180°."""
MAX_PATTERN_MISMATCH = 0.25
"""Largest mean absolute difference (as a fraction of white) between the pattern and its capture
warped by the fitted homography for the fit to be accepted; a correct fit differs only along the
squares' edges (a few per cent), a wrong corner order or a false detection by about half."""


def checkerboard(size: tuple[int, int], squares: tuple[int, int] = SQUARES) -> tuple[np.ndarray, np.ndarray]:
    """A checkerboard frame with a white margin of one square, and its inner corners.

    The square edges lie on pixel boundaries (the even split of the frame into ``squares + 2``
    squares, rounded to whole pixels, so squares differ by at most one pixel) and the returned
    corners are exactly where those edges cross: the true corners of the drawn pattern.

    Returns
    -------
    frame : numpy.ndarray
        uint8 (H, W, 3) projector frame at the canonical size.
    corners : numpy.ndarray
        float32 ((squares[0]-1) * (squares[1]-1), 2) inner-corner positions (column, row), pixel
        centres at integer + 0.5 (so a corner lies at whole numbers), in OpenCV's row-major order.
    """
    w, h = size
    nx, ny = squares
    # square edges in pixels, one square of margin each side
    xs = np.floor(np.linspace(0, w, nx + 3)[1:-1] + 0.5)
    ys = np.floor(np.linspace(0, h, ny + 3)[1:-1] + 0.5)
    cols = np.searchsorted(xs, np.arange(w) + 0.5) - 1
    rows = np.searchsorted(ys, np.arange(h) + 0.5) - 1
    inside = (cols[None, :] >= 0) & (cols[None, :] < nx) & (rows[:, None] >= 0) & (rows[:, None] < ny)
    black = inside & ((cols[None, :] + rows[:, None]) % 2 == 0)
    frame = np.where(black, 0, 255).astype(np.uint8)[..., None].repeat(3, axis=2)
    gx, gy = np.meshgrid(xs[1:-1], ys[1:-1])
    return frame, np.stack([gx.ravel(), gy.ravel()], axis=1).astype(np.float32)


def estimate_homography(capture: Callable[[np.ndarray], np.ndarray], size: tuple[int, int],
                        squares: tuple[int, int] = SQUARES, jitter: float = 0.0,
                        rng: np.random.Generator | None = None) -> np.ndarray | None:
    """Estimate the camera → canonical homography as a real system would.

    Three frames are projected (checkerboard, white, black); the checkerboard capture is
    normalised by the other two, which removes the surface texture and the ambient light, then
    OpenCV finds the inner corners. Their order may start at either end of the grid, so both
    orders are tried and the one whose warped capture matches the pattern is kept (the pattern is
    not symmetric under a turn by 180°: :data:`SQUARES`); a fit whose warped capture still differs
    from the pattern by more than :data:`MAX_PATTERN_MISMATCH` counts as not found.

    Parameters
    ----------
    capture : callable
        Maps a uint8 projector frame (canonical size) to a uint8 camera capture.
    size : (int, int)
        Canonical (width, height).
    squares : (int, int)
        Squares of the checkerboard (columns, rows), without its margin.
    jitter : float
        Canonical pixels: standard deviation of a Gaussian displacement (per axis) added to each
        detected corner, seen in the canonical view, before the final fit; 0 adds none.
    rng : numpy.random.Generator, optional
        Draws the displacements; needed when ``jitter > 0``.

    Returns
    -------
    numpy.ndarray or None
        3×3 homography mapping camera pixel coordinates to canonical ones (both with pixel centres
        at integer + 0.5), normalised so that its last entry is 1, or None when the corners were
        not found (or no order of them fits the pattern).
    """
    frame, corners = checkerboard(size, squares)
    w, h = size
    shots = [capture(f).astype(np.float32).mean(axis=2)
             for f in (frame, np.full_like(frame, 255), np.zeros_like(frame))]
    pattern, white, black = shots
    norm = (pattern - black) / np.maximum(white - black, 1.0)
    lit = (white - black) > 8
    binary = np.where(lit & (norm < 0.5), 0, 255).astype(np.uint8)
    pattern_size = (squares[0] - 1, squares[1] - 1)
    try:
        found, cam_corners = cv2.findChessboardCorners(binary, pattern_size,
                                                       flags=cv2.CALIB_CB_ADAPTIVE_THRESH)
    except cv2.error:  # a camera image too small for its adaptive threshold's window
        found = False
    if not found:
        return None
    gray = np.clip(norm * 255, 0, 255).astype(np.uint8)
    cam_corners = cv2.cornerSubPix(gray, cam_corners, (3, 3), (-1, -1),
                                   (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3))
    cam = cam_corners.reshape(-1, 2) + 0.5  # OpenCV puts pixel centres at integers
    best, best_order, best_err = None, cam, np.inf
    for order in (cam, cam[::-1]):
        hom, _ = cv2.findHomography(order, corners, 0)
        if hom is None:
            continue
        shift = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1]]) @ hom @ np.array(
            [[1, 0, 0.5], [0, 1, 0.5], [0, 0, 1]])
        seen = cv2.warpPerspective(binary, shift, (w, h), flags=cv2.INTER_NEAREST)
        err = np.mean(np.abs(seen.astype(np.float32) - frame[..., 0]))
        if err < best_err:
            best, best_order, best_err = hom, order, err
    if best is None or best_err > MAX_PATTERN_MISMATCH * 255:
        return None
    if jitter > 0:
        # displace each detected corner by the jitter as seen in the canonical view, and refit
        seen_at = cv2.perspectiveTransform(best_order[None].astype(np.float64), best)[0]
        seen_at += rng.normal(0.0, jitter, seen_at.shape)
        moved = cv2.perspectiveTransform(seen_at[None], np.linalg.inv(best))[0]
        best, _ = cv2.findHomography(moved, corners, 0)
    return best


def _camera_positions(hom: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """float64 (H, W, 2): where the homography ``hom`` (camera → canonical) finds each canonical
    pixel centre in the camera image."""
    w, h = size
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    canon = np.stack([u, v, np.ones_like(u)], axis=-1) @ np.linalg.inv(hom).T
    return canon[..., :2] / canon[..., 2:]


def homography_map(hom: np.ndarray, size: tuple[int, int], camera_resolution: tuple[int, int]) -> WarpMap:
    """The warp map of a homography: each canonical pixel sampled where the homography puts it.

    Parameters
    ----------
    hom : numpy.ndarray
        3×3 camera → canonical homography (:func:`estimate_homography`).
    size : (int, int)
        Canonical (width, height) in pixels.
    camera_resolution : (int, int)
        Camera (width, height) in pixels.

    Returns
    -------
    WarpMap
        Masked where the position falls outside the camera frame (a homography knows nothing of
        the surface's extent or of occlusion: those pixels show what the camera sees there).
    """
    xy = _camera_positions(hom, size)
    cw, ch = camera_resolution
    with np.errstate(invalid="ignore"):
        inside = (xy[..., 0] >= 0) & (xy[..., 0] <= cw) & (xy[..., 1] >= 0) & (xy[..., 1] <= ch)
    return WarpMap(np.where(inside[..., None], xy, 0.0).astype(np.float32), inside)


def homography_error(hom: np.ndarray, wmap: WarpMap) -> dict:
    """How far the homography's registration is from the exact map, over the exactly visible
    canonical pixels.

    Parameters
    ----------
    hom : numpy.ndarray
        3×3 camera → canonical homography.
    wmap : WarpMap
        The exact map (:func:`exact_map`).

    Returns
    -------
    dict
        ``mean_px`` and ``max_px``: camera pixels between where the homography and the exact map
        find each canonical pixel; ``canonical_px``: the misregistration in canonical pixels —
        the distance between a canonical pixel's centre and where the homography sends the camera
        position that truly shows it — as ``mean``, ``p95`` (95th percentile) and ``max``. A
        plane seen through distortion-free lenses gives ~0 (the corners' noise aside); relief and
        lens distortion give what one homography cannot follow.

    Examples
    --------
    >>> xy = np.array([[[1.5, 0.5], [2.5, 0.5]]], np.float32)  # one row of two canonical pixels
    >>> shift = np.array([[1.0, 0, -1], [0, 1, 0], [0, 0, 1]])  # canonical x = camera x - 1
    >>> homography_error(shift, WarpMap(xy, np.ones((1, 2), bool)))["canonical_px"]
    {'mean': 0.0, 'p95': 0.0, 'max': 0.0}
    >>> homography_error(np.eye(3), WarpMap(xy, np.ones((1, 2), bool)))["canonical_px"]["max"]
    1.0
    """
    h, w = wmap.mask.shape
    d = np.linalg.norm(_camera_positions(hom, (w, h)) - wmap.xy, axis=-1)[wmap.mask]
    cam = np.concatenate([wmap.xy.astype(np.float64), np.ones((h, w, 1))], axis=-1) @ np.asarray(hom, float).T
    u, v = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)
    c = np.linalg.norm(cam[..., :2] / cam[..., 2:] - np.stack([u, v], axis=-1), axis=-1)[wmap.mask]
    return {"mean_px": float(d.mean()), "max_px": float(d.max()),
            "canonical_px": {"mean": round(float(c.mean()), 6), "p95": round(float(np.percentile(c, 95)), 6),
                             "max": round(float(c.max()), 6)}}


def resolve_method(setup: Setup) -> str:
    """The map a setup's captures are warped with: ``"homography"`` or ``"exact"``
    (``registration.method = "auto"``: homography on a planar surface, exact otherwise)."""
    method = setup.registration.method
    if method == "auto":
        return "homography" if surfaces.surface_for(setup.surface).planar else "exact"
    return method


@dataclass(frozen=True)
class Registration:
    """The map a simulator warps its captures with, and the ground truth beside it.

    Attributes
    ----------
    method : str
        ``"homography"`` or ``"exact"``: the map in :attr:`warp_map`.
    warp_map : WarpMap
        The map captures are warped with.
    exact : WarpMap
        The exact map from the scene geometry (:func:`exact_map`), the ground truth.
    homography : numpy.ndarray or None
        The estimated camera → canonical homography (with the setup's jitter), None when none was
        estimated (a non-planar surface registered exactly) or its corners were not found.
    status : str
        ``"ok"`` when a homography was estimated, else why not.
    """

    method: str
    warp_map: WarpMap
    exact: WarpMap
    homography: np.ndarray | None
    status: str

    def record(self, setup: Setup) -> dict:
        """What a dataset records of the registration (JSON): ``method`` (used), ``requested``
        (the setup's), ``jitter``, ``visible_fraction`` (of the map used) and
        ``exact_visible_fraction``, and ``homography``: ``status`` and, when estimated, its
        ``matrix`` (camera → canonical, pixel centres at integer + 0.5) and its distance to the
        exact map (:func:`homography_error`): ``mean_px`` and ``max_px`` in camera pixels, and the
        residual misregistration ``canonical_px`` (mean, 95th percentile, max) in canonical
        pixels."""
        hom: dict = {"status": self.status}
        if self.homography is not None:
            hom.update(matrix=self.homography.tolist(), **homography_error(self.homography, self.exact))
        return {"method": self.method, "requested": setup.registration.method,
                "jitter": setup.registration.jitter,
                "visible_fraction": float(self.warp_map.mask.mean()),
                "exact_visible_fraction": float(self.exact.mask.mean()),
                "homography": hom}


def register(setup: Setup, size: tuple[int, int], capture: Callable[[np.ndarray], np.ndarray]) -> Registration:
    """Register a setup as ``registration.method`` asks (:func:`resolve_method`).

    The exact map is always computed. A homography is estimated (:func:`estimate_homography`,
    the corners displaced by ``registration.jitter`` drawn from
    ``noise_rng(render.seed, REGISTRATION, REGISTRATION_JITTER)`` of :mod:`sim.seeds`) whenever the
    surface is planar or the method asks for it, so that its error is recorded even when the
    exact map is used. With ``auto``, a plane whose checkerboard corners are not found (a
    canonical view or a camera too small for the pattern, or too little projector light at the
    camera) falls back to the exact map, as its record says.

    Parameters
    ----------
    setup : Setup
        The setup.
    size : (int, int)
        Canonical (width, height) in pixels.
    capture : callable
        Maps a uint8 projector frame (canonical size) to a uint8 camera capture (the full camera
        model, stream :data:`sim.seeds.REGISTRATION`).

    Raises
    ------
    SetupError
        If ``registration.method = "homography"`` and the corners were not found.
    """
    exact = exact_map(setup, size)
    method = resolve_method(setup)
    if method == "exact" and not surfaces.surface_for(setup.surface).planar:
        return Registration("exact", exact, exact, None, "not planar: exact map only")
    cfg = setup.registration
    rng = seeds.noise_rng(setup.render.seed, seeds.REGISTRATION, seeds.REGISTRATION_JITTER)
    hom = estimate_homography(capture, size, jitter=cfg.jitter, rng=rng)
    if hom is None:
        if cfg.method == "homography":
            raise SetupError(
                f'setup "{setup.name}": registration.method = "homography": the checkerboard '
                f"corners were not found in the camera's capture at the canonical size "
                f"{size[0]}x{size[1]} (a canonical size or camera.resolution too small for the "
                f"pattern, or too little of the projector's light at the camera: projector.brightness, "
                f"projector.mixing, camera.exposure); use a larger size or registration.method = "
                f"\"exact\"")
        status = "checkerboard corners not found" + (": exact map used" if method == "homography" else "")
        if method == "homography":
            warnings.warn(f'setup "{setup.name}": registration.method = "auto": the checkerboard corners '
                          f"were not found at the canonical size {size[0]}x{size[1]}; registered "
                          "with the exact map instead (recorded in meta.json)", stacklevel=2)
        return Registration("exact", exact, exact, None, status)
    if method == "exact":
        return Registration("exact", exact, exact, hom, "ok")
    return Registration("homography", homography_map(hom, size, setup.camera.resolution), exact, hom, "ok")
