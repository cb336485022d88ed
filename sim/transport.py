"""The ``transport`` fidelity level: a per-setup light-transport operator.

Light transport is linear in the projector irradiance, so a capture's radiance is ``T p + b``
for the setup's own sparse matrix ``T`` (camera pixel × projector pixel, per colour channel) and
ambient image ``b``. Where direct light is the whole story (no surface sees another) each camera
pixel sees only the few projector pixels its footprint on the surface covers, so ``T`` is sparse
and can be measured from a handful of Mitsuba renders:

1. From the geometry (:func:`footprint_ranges`), every camera pixel's footprint — its pixel
   square, widened by the thin-lens aperture when Mitsuba traces the camera's lens — is
   intersected with the surface and projected into the projector: a range of projector columns
   and rows.
2. ``s × s`` *spaced-dot* frames light every ``s``-th projector pixel in x and y, with ``s`` the
   widest footprint range, so at most one lit pixel lies in any camera pixel's range. Each is
   rendered with the ``direct`` integrator at the calibration spp and **one fixed seed**, and a
   camera pixel's value is attributed to the one lit pixel in its range.
3. Because Mitsuba draws the same samples for the same seed whatever the texture, the dot frames
   sum to any frame exactly: ``T p`` equals the direct render of ``p`` at that spp and seed to
   float precision, for every ``p``. :meth:`TransportOperator.calibrate` checks this on a random
   frame and refuses an operator that misses it. The Monte-Carlo error of the calibration spp is
   therefore *frozen* into ``T``: the same for every capture instead of fresh per capture.

The projector's scaler, response, black level, colour-wheel white segment, primaries mixing and
dynamic lamp, lens (PSF and the defocus of each pixel's depth), lens distortion, the surface's
translucency and the projector's flare are applied before ``T`` (:meth:`sim.render.Renderer.emit`;
all after the photometry are linear; the white segment and the dynamic lamp are not, but act on
the frame before ``T`` sees it), so ``T`` is the scene's light transport alone; its projector
side is the lens's padded grid (:class:`sim.projector.Lens`), which keeps the light blurred past
the panel's border. A camera defocus applied in image space (``camera.defocus = "image"``,
:mod:`sim.camera.thinlens`) acts after ``T``: the operator is the pinhole camera's, shared by
every aperture and focus. Inter-reflection (a corner) makes ``T`` dense: this level declines
such setups (:func:`check_supported`) and ``auto`` falls back to path tracing.
"""
from __future__ import annotations

import hashlib
import io
import json
import time
import warnings
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path

import numpy as np
import scipy.sparse
import torch

from sim import geometry, seeds, surfaces
from sim.camera import thinlens
from sim.errors import ProcamError, SetupError
from sim.io import atomic_write
from sim.projector import chain as projector_chain
from sim.projector import lens_for
from sim.render import Renderer
from sim.setup import CameraConfig, ProjectorConfig, RegistrationConfig, Setup, dump_setup
from sim.setup.schema import CameraView, ProjectorView
from sim.stages import stages_of

MAX_SPACING = 12
"""Largest dot spacing (``MAX_SPACING²`` calibration renders) before this level declines."""
APERTURE_SAMPLES = 16
"""Points on the thin-lens aperture rim used to bound a camera pixel's footprint."""
MARGIN_PX = 0.05
"""Projector pixels added to each side of a footprint before rounding to whole pixels."""
VERIFY_TOLERANCE = 1e-4
"""Largest ``max|T p - R(p)| / max R(p)`` accepted for the random verification frame."""
FORMAT = 2
"""Version of the cache file layout (part of the cache key): 2 is :meth:`TransportOperator.save`'s
compressed layout, 1 held the triples as they were measured, uncompressed."""


def check_supported(setup: Setup) -> None:
    """Raise :class:`SetupError` when a setup's light transport is not sparse direct light.

    Parameters
    ----------
    setup : Setup
        The setup to check.

    Raises
    ------
    SetupError
        For a surface whose parts light each other (a corner's wings), which adds a dense
        inter-reflection part.
    """
    if surfaces.surface_for(setup.surface).interreflection:
        raise SetupError(
            f'setup {setup.name!r}: fidelity "transport" cannot represent surface.geometry = '
            f'"{setup.surface.geometry}": its surfaces light each other (inter-reflection), which '
            'makes the light transport dense; use "path" or "auto" (auto falls back to path)')


def _aperture_offsets(radius: float) -> np.ndarray:
    """Offsets (local x, y; metres) of the aperture points bounding a thin lens: its centre, or
    ``APERTURE_SAMPLES`` points on the rim of a circle of ``radius`` (0 = pinhole)."""
    if radius <= 0:
        return np.zeros((1, 2))
    phi = 2 * np.pi * np.arange(APERTURE_SAMPLES) / APERTURE_SAMPLES
    return radius * np.stack([np.cos(phi), np.sin(phi)], axis=1)


def emitter_pinhole(setup: Setup) -> geometry.Pinhole:
    """The projector's emitter as a pinhole: the lens's padded grid (:func:`sim.projector.lens_for`),
    the panel itself when the lens is sharp."""
    p = setup.projector
    lens = lens_for(setup)
    if lens.pad == 0:
        return geometry.Pinhole.from_config(p)
    w, h = lens.size
    return geometry.Pinhole(np.asarray(p.position, float), np.asarray(p.look_at, float),
                            np.asarray(p.up, float), lens.fov(p.fov), w, h)


def footprint_ranges(setup: Setup) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The projector pixels each camera pixel can see, from the scene geometry.

    Rays from every camera pixel corner (and, for a thin lens, from points on the aperture rim
    through the corner's point on the focus plane) are intersected with the surface and projected
    into the projector. On a planar surface the projective map sends a pixel's square to the
    quadrilateral of its corners, so the bounding box of those hits, widened by
    :data:`MARGIN_PX`, holds every sample Mitsuba can draw in that pixel.

    Parameters
    ----------
    setup : Setup
        The setup (camera and projector poses, fields of view, resolutions; surface geometry).

    Returns
    -------
    lo, hi : numpy.ndarray
        int64 (Hc, Wc, 2) first and last projector (column, row) index of each camera pixel's
        footprint, clipped to the emitter's grid (the panel plus the lens's padding).
    seen : numpy.ndarray
        bool (Hc, Wc), True where the footprint touches the surface at all.
    """
    cam_cfg = thinlens.mitsuba_view(setup.camera)  # the operator is of the camera Mitsuba renders
    wc, hc = cam_cfg.resolution
    cam = geometry.Pinhole.from_config(cam_cfg)
    # A pinhole one pixel wider and taller whose field of view is scaled by (W + 1) / W has its
    # pixel centres exactly on the camera's pixel corners (same aspect, same focal length).
    fov = float(np.degrees(2 * np.arctan(cam.tan_half * (wc + 1) / wc)))
    corners = geometry.Pinhole(cam.position, cam.look_at, cam.up, fov, wc + 1, hc + 1)
    dirs = corners.pixel_rays()
    frame = cam.frame()
    surface = surfaces.surface_for(setup.surface)
    proj = emitter_pinhole(setup)
    lo = np.full((hc + 1, wc + 1, 2), np.inf)
    hi = np.full((hc + 1, wc + 1, 2), -np.inf)
    radius = cam_cfg.aperture_radius
    focus = dirs * (cam_cfg.focus_distance / (dirs @ frame[:, 2]))[..., None]  # camera-relative
    for offset in _aperture_offsets(radius):
        origin = cam.position + frame[:, :2] @ offset
        rays = dirs if radius <= 0 else focus - frame[:, :2] @ offset
        rays = rays / np.linalg.norm(rays, axis=-1, keepdims=True)
        t, _ = surface.intersect(origin, rays)
        hit = np.isfinite(t)
        xy, in_front = proj.project(origin + np.where(hit, t, 1.0)[..., None] * rays)
        ok = (hit & in_front)[..., None]
        lo = np.minimum(lo, np.where(ok, xy, np.inf))
        hi = np.maximum(hi, np.where(ok, xy, -np.inf))
    # each camera pixel: the extremes over its four corners
    lo = np.minimum.reduce([lo[:-1, :-1], lo[1:, :-1], lo[:-1, 1:], lo[1:, 1:]])
    hi = np.maximum.reduce([hi[:-1, :-1], hi[1:, :-1], hi[:-1, 1:], hi[1:, 1:]])
    seen = np.all(np.isfinite(lo) & np.isfinite(hi), axis=-1)
    size = np.array([proj.width, proj.height])
    lo = np.clip(np.floor(np.where(seen[..., None], lo, 0) - MARGIN_PX), 0, size - 1).astype(np.int64)
    hi = np.clip(np.floor(np.where(seen[..., None], hi, 0) + MARGIN_PX), 0, size - 1).astype(np.int64)
    return lo, hi, seen


def dot_spacing(lo: np.ndarray, hi: np.ndarray, seen: np.ndarray) -> int:
    """Spacing ``s`` of the calibration dots: the widest footprint range (projector pixels), so
    that no camera pixel's range holds two lit pixels of one dot frame."""
    if not seen.any():
        return 1
    return int((hi - lo + 1)[seen].max())


def cache_key(setup: Setup, spp: int, variant: str) -> str:
    """Hex digest identifying an operator: what the calibration sees of a setup, spp, variant and
    format.

    The calibration renders the surface under the projector and the ambient light through
    Mitsuba's camera (:func:`sim.scene.projector_scene`, :func:`sim.scene.ambient_scene`): the
    surface, ambient and render sections, the camera's :class:`~sim.setup.schema.CameraView` as
    Mitsuba renders it (:func:`sim.camera.thinlens.mitsuba_view`: a defocus in image space acts
    on the operator's output),
    the projector's :class:`~sim.setup.schema.ProjectorView`, the options of its
    :data:`~sim.projector.chain.TRANSPORT` stages (the emitter's scale) and the lens's padding
    (the emitter's grid and field of view, :func:`sim.projector.lens_for`). The camera's stages,
    the projector's stages before and after the transport, the registration and the name act
    on the operator's input or output only: setups that differ in nothing else (a study of the
    camera noise, the projector's response or the registration) share one operator, bit for bit.
    """
    p, c = setup.projector, thinlens.mitsuba_view(setup.camera)
    projector_keys = [f.name for f in fields(ProjectorView)] + [
        f.name for stage in stages_of(projector_chain.TRANSPORT) for f in fields(stage.options)]
    seen = replace(setup, name="transport", registration=RegistrationConfig(),
                   projector=ProjectorConfig(**{k: getattr(p, k) for k in projector_keys}),
                   camera=CameraConfig(**{f.name: getattr(c, f.name) for f in fields(CameraView)}))
    text = (f"{dump_setup(seen)}\npad={lens_for(setup).pad}\nspp={spp}\nvariant={variant}\n"
            f"format={FORMAT}\n")
    return hashlib.sha256(text.encode()).hexdigest()[:16]


@dataclass(frozen=True)
class CalibrationInfo:
    """How an operator was made.

    Attributes
    ----------
    spp : int
        Samples per pixel of the calibration renders.
    seed : int
        Mitsuba seed shared by all calibration renders.
    spacing : int
        Dot spacing s (s² renders), in projector pixels.
    seconds : float
        Wall time of the calibration (renders, assembly and verification), seconds.
    verify_error : float
        ``max|T p - R(p)| / max R(p)`` on a random frame (dimensionless).
    variant : str
        Mitsuba variant of the renders.
    """

    spp: int
    seed: int
    spacing: int
    seconds: float
    verify_error: float
    variant: str


class TransportOperator:
    """``radiance = T · irradiance + b`` for one setup, applied with torch sparse matrices.

    ``T`` is block-diagonal over colour channels (light keeps its channel in an RGB scene) and is
    stored as (camera pixel, projector pixel, RGB value) triples; it is used as one torch CSR
    matrix over interleaved (pixel, channel) indices, built once per device.

    Parameters
    ----------
    rows, cols : numpy.ndarray
        int (nnz,) flat camera pixel ``row * Wc + col`` and projector pixel indices.
    values : numpy.ndarray
        float32 (nnz, 3) linear radiance per unit relative irradiance, per channel.
    camera_size, projector_size : (int, int)
        (width, height) in pixels.
    ambient : numpy.ndarray
        float32 (Hc, Wc, 3) linear radiance of the ambient light alone (``b``).
    info : CalibrationInfo
        How the operator was made.
    """

    def __init__(self, rows: np.ndarray, cols: np.ndarray, values: np.ndarray,
                 camera_size: tuple[int, int], projector_size: tuple[int, int], ambient: np.ndarray,
                 info: CalibrationInfo):
        self.rows = np.asarray(rows, np.int64)
        self.cols = np.asarray(cols, np.int64)
        self.values = np.asarray(values, np.float32)
        self.camera_size = (int(camera_size[0]), int(camera_size[1]))
        self.projector_size = (int(projector_size[0]), int(projector_size[1]))
        self.ambient = np.asarray(ambient, np.float32)
        self.info = info
        self._matrices: dict[str, torch.Tensor | scipy.sparse.csr_matrix] = {}

    @property
    def nnz(self) -> int:
        """Stored (camera pixel, projector pixel) pairs (each with three channel values)."""
        return len(self.rows)

    def matrix(self, device: str | torch.device = "cpu") -> torch.Tensor:
        """``T`` as a float32 torch CSR matrix of shape (3 Nc, 3 Np) on ``device``; index
        ``3 * pixel + channel`` on both sides (the memory order of (H, W, 3) images)."""
        key = str(torch.device(device))
        if key not in self._matrices:
            r = (3 * self.rows[:, None] + np.arange(3)).ravel()
            c = (3 * self.cols[:, None] + np.arange(3)).ravel()
            v = self.values.ravel()
            keep = v != 0
            r, c, v = r[keep], c[keep], v[keep]
            order = np.lexsort((c, r))
            wc, hc = self.camera_size
            wp, hp = self.projector_size
            crow = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=3 * wc * hc))])
            with warnings.catch_warnings():  # "Sparse CSR tensor support is in beta state"
                warnings.simplefilter("ignore", UserWarning)
                # int32 indices: torch's MKL kernels take them (int64 falls back, ~10x slower)
                self._matrices[key] = torch.sparse_csr_tensor(
                    torch.from_numpy(crow.astype(np.int32)), torch.from_numpy(c[order].astype(np.int32)),
                    torch.from_numpy(v[order]), size=(3 * wc * hc, 3 * wp * hp), dtype=torch.float32,
                    device=device, check_invariants=True)
        return self._matrices[key]

    def scipy_matrix(self) -> scipy.sparse.csr_matrix:
        """``T`` as a SciPy CSR matrix (same layout as :meth:`matrix`), for one image at a time on
        the CPU: single-threaded, so it does not fight other processes for the cores the way
        torch's multi-threaded kernel does (measured 0.4 ms vs 0.5-8 ms at 256², 2 busy cores)."""
        if "scipy" not in self._matrices:
            m = self.matrix("cpu")
            self._matrices["scipy"] = scipy.sparse.csr_matrix(
                (m.values().numpy(), m.col_indices().numpy(), m.crow_indices().numpy()), shape=m.shape)
        return self._matrices["scipy"]

    def project(self, irradiance: torch.Tensor) -> torch.Tensor:
        """The projector's contribution ``T · irradiance`` for a batch (exactly linear).

        Parameters
        ----------
        irradiance : torch.Tensor
            (N, 3, Hp, Wp) or (3, Hp, Wp) relative linear irradiance (after
            :meth:`sim.render.Renderer.emit`), on any device.

        Returns
        -------
        torch.Tensor
            float32 (N, 3, Hc, Wc) (or (3, Hc, Wc)) linear radiance, on the input's device.
        """
        single = irradiance.dim() == 3
        x = irradiance[None] if single else irradiance
        wp, hp = self.projector_size
        if x.dim() != 4 or tuple(x.shape[1:]) != (3, hp, wp):
            raise ValueError(f"irradiance: expected shape (N, 3, {hp}, {wp}), got {tuple(irradiance.shape)}")
        n = x.shape[0]
        flat = x.to(torch.float32).permute(2, 3, 1, 0).reshape(3 * hp * wp, n)
        wc, hc = self.camera_size
        t = self.matrix(x.device)
        # a matrix-vector product for one image (the matrix-matrix kernel is ~7x slower for n = 1)
        out = (t @ flat[:, 0])[:, None] if n == 1 else t @ flat
        out = out.reshape(hc, wc, 3, n).permute(3, 2, 0, 1)
        return out[0] if single else out

    def project_image(self, irradiance: np.ndarray, device: str = "cpu") -> np.ndarray:
        """:meth:`project` for one NumPy image: float (Hp, Wp, 3) -> float32 (Hc, Wc, 3).

        On the CPU with SciPy's single-threaded product; on another torch device (``cuda``) with
        the torch CSR matrix there (the GPU path of a ``cuda_*`` variant)."""
        wp, hp = self.projector_size
        x = np.ascontiguousarray(irradiance, dtype=np.float32)
        if x.shape != (hp, wp, 3):
            raise ValueError(f"irradiance: expected shape ({hp}, {wp}, 3), got {x.shape}")
        if torch.device(device).type != "cpu":
            out = self.project(torch.from_numpy(x).permute(2, 0, 1).to(device))
            return out.permute(1, 2, 0).cpu().numpy()
        wc, hc = self.camera_size
        return (self.scipy_matrix() @ x.reshape(-1)).astype(np.float32).reshape(hc, wc, 3)

    @classmethod
    def calibrate(cls, renderer: Renderer) -> "TransportOperator":
        """Measure ``T`` and ``b`` of a setup from spaced-dot renders (see the module docstring).

        Parameters
        ----------
        renderer : Renderer
            A ``direct`` renderer of the setup; its ``spp`` is the calibration spp.

        Returns
        -------
        TransportOperator

        Raises
        ------
        SetupError
            If the setup has inter-reflection, or a camera pixel's footprint spans more than
            :data:`MAX_SPACING` projector pixels (the calibration would need too many renders).
        ProcamError
            If the operator does not reproduce a direct render of a random frame.
        """
        setup = renderer.setup
        check_supported(setup)
        if renderer.fidelity != "direct":
            raise ValueError(f"transport calibration needs a 'direct' renderer, got {renderer.fidelity!r}")
        t0 = time.perf_counter()
        lo, hi, seen = footprint_ranges(setup)
        s = dot_spacing(lo, hi, seen)
        if s > MAX_SPACING:
            raise SetupError(
                f'setup {setup.name!r}: fidelity "transport": a camera pixel sees up to {s} projector '
                f"pixels across (camera pixels much larger than projector pixels, or a strong camera "
                f"defocus), which would take {s * s} calibration renders (limit {MAX_SPACING ** 2}); "
                'use "direct" or "auto"')
        wp, hp = renderer.lens.size
        wc, hc = setup.camera.resolution
        seed = seeds.mitsuba_seed(setup.render.seed, seeds.CALIBRATION, 0)
        cam_idx = np.flatnonzero(seen)
        lo_s, hi_s = lo.reshape(-1, 2)[cam_idx], hi.reshape(-1, 2)[cam_idx]
        rows, cols, values = [], [], []
        for b, a in np.ndindex(s, s):
            dots = np.zeros((hp, wp, 3), np.float32)
            dots[b::s, a::s] = 1.0
            img = renderer.transport_radiance(dots, seed).reshape(-1, 3)[cam_idx]
            # the one lit column (row) in each footprint's range, if any
            lit = lo_s + (np.array([a, b]) - lo_s) % s
            ok = np.all(lit <= hi_s, axis=1) & np.any(img != 0, axis=1)
            rows.append(cam_idx[ok])
            cols.append(lit[ok, 1] * wp + lit[ok, 0])
            values.append(img[ok])
        op = cls(np.concatenate(rows), np.concatenate(cols), np.concatenate(values), (wc, hc),
                 (wp, hp), renderer.transport_ambient(),
                 CalibrationInfo(renderer.spp, seed, s, 0.0, 0.0, renderer.variant))
        test = np.random.default_rng(seeds.TRANSPORT_CHECK).random((hp, wp, 3), dtype=np.float32)
        want = renderer.transport_radiance(test, seed)
        err = float(np.abs(op.project_image(test) - want).max() / max(float(want.max()), 1e-12))
        if err > VERIFY_TOLERANCE:
            raise ProcamError(
                f"setup {setup.name!r}: the transport operator differs from a direct render of a "
                f"random frame by {err:.2e} (relative; limit {VERIFY_TOLERANCE:g}): the camera pixel "
                'footprints were underestimated; use "direct" for this setup')
        op.info = CalibrationInfo(renderer.spp, seed, s, time.perf_counter() - t0, err, renderer.variant)
        return op

    def save(self, path: Path) -> None:
        """Write the operator to a compressed ``.npz`` file (atomically: temporary file, then
        rename); :meth:`load` reads back the same operator, bit for bit.

        The triples are stored in camera-pixel order, as the number of projector pixels each camera
        pixel sees (``counts``, uint8: at most one per dot frame, so at most
        :data:`MAX_SPACING`² = 144) and the differences of consecutive projector pixels
        (``cols``, small numbers that deflate well); the float32 values and the ambient image as
        their four byte planes (``values``, ``ambient``: sign and exponent bytes apart from the
        noisy low mantissa bytes, which deflate then leaves alone). At 960x640 camera pixels and
        an 800x600 panel this takes 14 MB where the triples as measured took 35 MB.
        """
        order = np.lexsort((self.cols, self.rows))
        wc, hc = self.camera_size
        buffer = io.BytesIO()
        np.savez_compressed(buffer, counts=np.bincount(self.rows[order], minlength=wc * hc).astype(np.uint8),
                            cols=np.diff(self.cols[order], prepend=0).astype(np.int32),
                            values=_byte_planes(self.values[order]), ambient=_byte_planes(self.ambient),
                            camera_size=np.array(self.camera_size),
                            projector_size=np.array(self.projector_size),
                            info=np.array(json.dumps(asdict(self.info))))
        atomic_write(path, buffer.getvalue())

    @classmethod
    def load(cls, path: Path) -> "TransportOperator":
        """Read an operator written by :meth:`save` (no pickled objects are loaded)."""
        with np.load(Path(path), allow_pickle=False) as z:
            camera_size = tuple(int(n) for n in z["camera_size"])
            rows = np.repeat(np.arange(camera_size[0] * camera_size[1]), z["counts"])
            return cls(rows, np.cumsum(z["cols"], dtype=np.int64),
                       _from_byte_planes(z["values"], (len(rows), 3)), camera_size,
                       tuple(z["projector_size"]),
                       _from_byte_planes(z["ambient"], (camera_size[1], camera_size[0], 3)),
                       CalibrationInfo(**json.loads(str(z["info"]))))


def _byte_planes(a: np.ndarray) -> np.ndarray:
    """uint8 (4, N): the four bytes of each little-endian float32 value of ``a``, plane by plane."""
    return np.ascontiguousarray(np.ascontiguousarray(a, "<f4").view(np.uint8).reshape(-1, 4).T)


def _from_byte_planes(planes: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    """The float32 array of ``shape`` whose bytes :func:`_byte_planes` gave."""
    return np.ascontiguousarray(planes.T).view("<f4").reshape(shape).astype(np.float32)


class TransportRenderer(Renderer):
    """A :class:`~sim.render.Renderer` whose projector contribution is ``T · irradiance``.

    The operator is calibrated from the ``direct`` level at ``spp`` samples per pixel (or read from
    ``cache_dir`` when an operator of the same setup, spp and variant is there). ``seed`` is
    ignored: the Monte-Carlo error of the calibration is the same in every capture.

    Parameters
    ----------
    setup : Setup
        The validated setup (a plane; see :func:`check_supported`).
    spp : int, optional
        Calibration samples per pixel; defaults to ``setup.render.spp``.
    variant : str, optional
        Mitsuba variant of the calibration renders.
    cache_dir : Path, optional
        Folder holding ``transport_<key>.npz`` operators.

    Attributes
    ----------
    operator : TransportOperator
        The calibrated operator.
    loaded_from_cache : bool
        True when the operator was read from ``cache_dir`` instead of calibrated.
    device : str
        Where frames are projected through the operator: ``cuda`` under a ``cuda_*`` variant,
        else ``cpu``.
    """

    def __init__(self, setup: Setup, spp: int | None = None, variant: str | None = None,
                 cache_dir: Path | None = None):
        check_supported(setup)
        super().__init__(setup, "direct", spp, variant)
        path = (Path(cache_dir) / f"transport_{cache_key(setup, self.spp, self.variant)}.npz"
                if cache_dir is not None else None)
        self.loaded_from_cache = path is not None and path.exists()
        if self.loaded_from_cache:
            self.operator = TransportOperator.load(path)
        else:
            self.operator = TransportOperator.calibrate(self)
            if path is not None:
                self.operator.save(path)
        self.fidelity = "transport"
        self.device = "cuda" if self.variant.startswith("cuda") and torch.cuda.is_available() else "cpu"

    def transport_radiance(self, irradiance: np.ndarray, seed: int = 0) -> np.ndarray:
        """``T · irradiance`` (the Mitsuba direct render during calibration); ``seed`` is unused
        once calibrated."""
        if self.fidelity != "transport":
            return super().transport_radiance(irradiance, seed)
        return self.operator.project_image(irradiance, self.device)

    def transport_ambient(self) -> np.ndarray:
        """The ambient image ``b`` (rendered once, at ``render.ambient_spp``, direct light)."""
        if self.fidelity != "transport":
            return super().transport_ambient()
        return self.operator.ambient
