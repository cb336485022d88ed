"""Mitsuba scene dictionaries for a setup: surface, projector, camera and ambient light.

The projector contribution and the ambient image are rendered by two separate scenes (two
emitters in one render make Mitsuba pick one per sample: ~10× the noise); by linearity their sum
is the full image.
"""
from __future__ import annotations

import numpy as np

from sim import images, surfaces
from sim.camera import thinlens
from sim.setup import Setup

PROJECTOR_KEY = "projector"
"""Name of the projector emitter in the scene; its texture is ``projector.irradiance.data``."""


def integrator_for(setup: Setup, fidelity: str) -> dict:
    """Mitsuba integrator for a fidelity level ("direct" or "path")."""
    if fidelity == "direct":
        return {"type": "direct"}
    if fidelity == "path":
        return {"type": "path", "max_depth": int(setup.render.max_depth)}
    raise ValueError(f"no Mitsuba integrator for fidelity {fidelity!r}; expected 'direct' or 'path'")


def resolve_fidelity(setup: Setup) -> str:
    """The Mitsuba level for a setup when none is given: ``auto`` is direct light for a plane
    (nothing on it sees anything else) and path tracing when surfaces see each other (corner);
    ``transport`` is direct light, the level its operator is calibrated from. (The measured
    ``auto`` of the Simulator and the operator itself live in :mod:`sim.fidelity`.)"""
    fid = setup.render.fidelity
    if fid == "auto":
        return "path" if surfaces.surface_for(setup.surface).interreflection else "direct"
    return "direct" if fid == "transport" else fid


def albedo_texture(setup: Setup) -> np.ndarray:
    """Linear albedo texture of the surface, float32 (H, W, 3) in [0, 1], row 0 at the top.

    Its size and layout over the surface's parts are the surface's
    (:meth:`sim.surfaces.base.Surface.texture_size`; a corner's wings share one texture, left half
    on the left wing).
    """
    s = setup.surface
    res = surfaces.surface_for(s).texture_size()
    if s.texture == "uniform":
        tex = np.ones((res[1], res[0], 3), np.float32)
    elif s.texture in images.SURFACE_KINDS:
        tex = images.surface_texture(s.texture, res, s.texture_seed)
    else:
        tex = images.load_texture_file(s.texture, res)
    if s.ink_density != 1.0:
        tex = np.power(tex, np.float32(s.ink_density), dtype=np.float32)
    albedo = tex * np.float32(s.albedo_scale) * np.asarray(s.tint, np.float32)
    return np.clip(albedo, 0.0, 1.0).astype(np.float32)


def _bsdf(setup: Setup, albedo: np.ndarray) -> dict:
    import mitsuba as mi

    # Mitsuba's rectangle puts texture row 0 at local y = -1 (the bottom): flip so row 0 is on top.
    tex = {"type": "bitmap", "data": mi.TensorXf(np.ascontiguousarray(albedo[::-1])), "raw": True,
           "filter_type": "bilinear", "wrap_mode": "clamp"}
    s = setup.surface
    if s.material == "diffuse":
        return {"type": "diffuse", "reflectance": tex}
    return {"type": "roughplastic", "diffuse_reflectance": tex, "alpha": float(s.roughness),
            "distribution": "ggx"}


def surface_shapes(setup: Setup, albedo: np.ndarray) -> dict:
    """The surface's shapes (:meth:`sim.surfaces.base.Surface.shapes`) with the setup's material.

    ``albedo`` is the surface's linear albedo texture from :func:`albedo_texture`.
    """
    return surfaces.surface_for(setup.surface).shapes(albedo, lambda part: _bsdf(setup, part))


def _look_at(cfg) -> "mi.ScalarTransform4f":
    import mitsuba as mi

    return mi.ScalarTransform4f().look_at(origin=list(cfg.position), target=list(cfg.look_at),
                                          up=list(cfg.up))


def sensor(setup: Setup, spp: int) -> dict:
    """The camera: perspective, or thin lens when it traces its defocus
    (:func:`sim.camera.thinlens.traced`); box-filtered HDR film."""
    c = thinlens.mitsuba_view(setup.camera)
    d = {"type": "perspective", "fov": float(c.fov), "fov_axis": "x", "to_world": _look_at(c),
         "film": {"type": "hdrfilm", "width": int(c.resolution[0]), "height": int(c.resolution[1]),
                  "rfilter": {"type": "box"}, "pixel_format": "rgb"},
         "sampler": {"type": "multijitter", "sample_count": int(spp)}}
    if c.aperture_radius > 0:
        d.update(type="thinlens", aperture_radius=float(c.aperture_radius),
                 focus_distance=float(c.focus_distance))
    return d


def projector_scene(setup: Setup, albedo: np.ndarray, fidelity: str, spp: int, pad: int = 0,
                    fov: float | None = None) -> dict:
    """Scene lit by the projector alone; its irradiance texture starts black (swap frames later).

    ``pad`` pixels on each side widen the emitter's texture beyond the panel, with the horizontal
    field of view ``fov`` (degrees; default ``projector.fov``) of the padded texture
    (:class:`sim.projector.Lens`)."""
    import mitsuba as mi

    p = setup.projector
    w, h = p.resolution[0] + 2 * pad, p.resolution[1] + 2 * pad
    integrator = integrator_for(setup, fidelity)
    if fidelity == "direct":
        integrator["bsdf_samples"] = 0  # a delta emitter cannot be hit by BSDF sampling
    return {"type": "scene", "integrator": integrator, "sensor": sensor(setup, spp),
            **surface_shapes(setup, albedo),
            PROJECTOR_KEY: {"type": "projector", "fov": float(p.fov if fov is None else fov),
                            "to_world": _look_at(p),
                            "scale": float(p.brightness),
                            "irradiance": {"type": "bitmap", "raw": True, "filter_type": "nearest",
                                           "wrap_mode": "clamp",
                                           "data": mi.TensorXf(np.zeros((h, w, 3), np.float32))}}}


def ambient_scene(setup: Setup, albedo: np.ndarray, fidelity: str, spp: int) -> dict:
    """Scene lit by the constant ambient emitter alone.

    At the ``direct`` level the light is sampled through the BSDF only: for a constant emitter
    over surfaces that do not see each other every BSDF sample returns albedo × radiance, so
    only the texture within a pixel varies between samples (emitter sampling, MIS's other half,
    draws directions uniformly over the sphere). Same expectation, several times less error at
    equal spp (``benchmarks/ambient.py``)."""
    integrator = integrator_for(setup, fidelity)
    if fidelity == "direct":
        integrator.update(emitter_samples=0, bsdf_samples=1)
    return {"type": "scene", "integrator": integrator,
            "sensor": sensor(setup, spp), **surface_shapes(setup, albedo),
            "ambient": {"type": "constant",
                        "radiance": {"type": "rgb", "value": list(setup.ambient.radiance)}}}
