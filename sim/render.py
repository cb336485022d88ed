"""Linear camera radiance of a setup for any projector frame.

The scene is built once; each projector frame is swapped into the projector's texture through
``mi.traverse`` (no reload, no recompilation). The ambient-only image is rendered once per setup at
``render.ambient_spp`` and added: light transport is linear in the projector irradiance. A camera
defocus applied in image space (:mod:`sim.camera.thinlens`) acts on both renders, after the
light transport.
"""
from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import replace

import numpy as np

from sim import projector, scene, seeds
from sim.camera import thinlens
from sim.io import to_float
from sim.projector import chain as projector_chain
from sim.setup import ProjectorConfig, RegistrationConfig, Setup, dump_setup
from sim.stages import run
from sim.variant import use_variant

_TEXTURE = f"{scene.PROJECTOR_KEY}.irradiance.data"

AMBIENT_MEMO_SIZE = 4
"""Ambient images a process keeps (7 MB each at 960x640): the exposure rule's preview and the
capture renderer (or its transport calibration) of one setup render the same ambient scene,
which at ``render.ambient_spp`` costs more than the preview's projector renders."""
_ambient_memo: OrderedDict[str, np.ndarray] = OrderedDict()


def _ambient_key(setup: Setup, fidelity: str, variant: str) -> str:
    """What identifies an ambient image as Mitsuba renders it: the resolved setup but what the
    ambient scene (:func:`sim.scene.ambient_scene`) does not see — the name, the projector, the
    registration, the camera's exposure (which the exposure rule sets after the preview) and a
    defocus applied in image space (:func:`sim.camera.thinlens.mitsuba_view`) — the integrator
    and the variant. Setups that differ only in their projector (a projector study's points) or
    in such a defocus share one ambient render."""
    radiance_setup = replace(setup, name="ambient", projector=ProjectorConfig(),
                             registration=RegistrationConfig(),
                             camera=replace(thinlens.mitsuba_view(setup.camera), exposure=1.0))
    text = (f"{dump_setup(radiance_setup)}\n{scene.integrator_for(setup, fidelity)!r}\n"
            f"variant={variant}\n")
    return hashlib.sha256(text.encode()).hexdigest()


def _render(*args, **kwargs) -> np.ndarray:
    """``mi.render(*args, **kwargs)`` as a float32 array.

    Raises
    ------
    KeyboardInterrupt
        On Ctrl-C during the render, which Dr.Jit reports as a ``RuntimeError`` raised from the
        interrupt: a study would take that for a failed render and go on.
    """
    import mitsuba as mi

    try:
        return np.array(mi.render(*args, **kwargs), dtype=np.float32)
    except RuntimeError as exc:
        cause = exc
        while cause is not None and not isinstance(cause, KeyboardInterrupt):
            cause = cause.__cause__ or cause.__context__
        if cause is not None:
            raise KeyboardInterrupt from None
        raise


class Renderer:
    """Renders linear radiance (camera resolution, RGB float32) of one setup.

    Parameters
    ----------
    setup : Setup
        The validated setup.
    fidelity : {"direct", "path"}, optional
        Light-transport level; defaults to the setup's resolved level (``auto`` → direct for a
        plane, path for a corner).
    spp : int, optional
        Samples per pixel of the projector contribution; defaults to ``setup.render.spp``.
    variant : str, optional
        Mitsuba variant; defaults to the one chosen for this machine (:mod:`sim.variant`).

    Attributes
    ----------
    lens : sim.projector.Lens
        The projector's lens (:func:`sim.projector.lens_for`); the emitter's texture is its
        padded grid.
    defocus_px : float
        Defocus disk diameter (projector pixels) where the optical axis meets the surface (each
        pixel's own disk is in ``lens.diameters``).
    camera_defocus : sim.camera.thinlens.ImageDefocus or None
        The camera's defocus in image space, applied to both renders (None: none to apply).
    """

    def __init__(self, setup: Setup, fidelity: str | None = None, spp: int | None = None,
                 variant: str | None = None):
        import mitsuba as mi

        self.variant = use_variant(variant)
        self.setup = setup
        self.fidelity = fidelity or scene.resolve_fidelity(setup)
        self.spp = int(spp or setup.render.spp)
        self.albedo = scene.albedo_texture(setup)
        self.lens = projector.lens_for(setup)
        self.camera_defocus = thinlens.image_defocus(setup)  # refuses too wide a disk first
        self._scene = mi.load_dict(scene.projector_scene(setup, self.albedo, self.fidelity, self.spp,
                                                         self.lens.pad, self.lens.fov(setup.projector.fov)))
        self._params = mi.traverse(self._scene)
        self._ambient: np.ndarray | None = None
        self._transport_ambient: np.ndarray | None = None
        p = setup.projector
        self.defocus_px = projector.defocus_blur_diameter_px(
            p.aperture, p.focus_distance, projector.throw_distance(setup), p.fov, p.resolution[0])

    def emit(self, frame: np.ndarray) -> np.ndarray:
        """Relative linear irradiance the projector emits for an input frame.

        Parameters
        ----------
        frame : numpy.ndarray
            Projector input, uint8 (H, W, 3) or float in [0, 1] (encoded), any size: the
            projector's scaler resamples it onto the panel (:func:`sim.projector.scale_to_panel`).

        Returns
        -------
        numpy.ndarray
            float32 (Hp + 2 pad, Wp + 2 pad, 3) with ``pad = self.lens.pad``: the projector's
            stages before the light transport (:data:`sim.projector.chain.EMISSION`: the scaler,
            response, black level, white segment, primaries mixing and dynamic lamp, then the
            lens, PSF and depth-dependent defocus, its distortion, the surface's translucency and
            the projector's flare).
        """
        frame = np.asarray(frame)
        x = to_float(frame) if frame.dtype == np.uint8 else frame.astype(np.float32)
        return run(projector_chain.EMISSION, x, self.setup.projector, self.lens)

    def _defocused(self, radiance: np.ndarray) -> np.ndarray:
        """``radiance`` through the camera's defocus in image space (itself when there is none)."""
        return radiance if self.camera_defocus is None else self.camera_defocus(radiance)

    def projector_radiance(self, irradiance: np.ndarray, seed: int = 0) -> np.ndarray:
        """Radiance due to the projector alone for a relative irradiance texture (linear).

        Exactly linear in ``irradiance`` for a fixed ``seed``.
        """
        return self._defocused(self.transport_radiance(irradiance, seed))

    def transport_radiance(self, irradiance: np.ndarray, seed: int = 0) -> np.ndarray:
        """:meth:`projector_radiance` as the light transport gives it, before the camera's
        defocus in image space (the Mitsuba render)."""
        import mitsuba as mi

        use_variant(self.variant)
        self._params[_TEXTURE] = mi.TensorXf(np.ascontiguousarray(irradiance, dtype=np.float32))
        self._params.update()
        return _render(self._scene, self._params, seed=int(seed))

    def ambient_radiance(self) -> np.ndarray:
        """Radiance due to the ambient light alone (rendered once, at ``render.ambient_spp``, then
        through the camera's defocus in image space). Read-only."""
        if self._ambient is None:
            self._ambient = self._defocused(self.transport_ambient())
            self._ambient.flags.writeable = False
        return self._ambient

    def transport_ambient(self) -> np.ndarray:
        """:meth:`ambient_radiance` before the camera's defocus in image space: the Mitsuba
        render, which a renderer of the same setup as Mitsuba sees it (:func:`_ambient_key`) in
        this process reuses. Read-only."""
        import mitsuba as mi

        if self._transport_ambient is None:
            amb = self.setup.ambient.radiance
            w, h = self.setup.camera.resolution
            key = None if max(amb) <= 0 else _ambient_key(self.setup, self.fidelity, self.variant)
            if key is None:
                self._transport_ambient = np.zeros((h, w, 3), np.float32)
            elif key in _ambient_memo:
                self._transport_ambient = _ambient_memo[key]
                _ambient_memo.move_to_end(key)
            else:
                use_variant(self.variant)
                sc = mi.load_dict(scene.ambient_scene(self.setup, self.albedo, self.fidelity,
                                                      self.setup.render.ambient_spp))
                seed = seeds.mitsuba_seed(self.setup.render.seed, seeds.AMBIENT, 0)
                self._transport_ambient = _render(sc, seed=seed)
                _ambient_memo[key] = self._transport_ambient
                while len(_ambient_memo) > AMBIENT_MEMO_SIZE:
                    _ambient_memo.popitem(last=False)
            self._transport_ambient.flags.writeable = False
        return self._transport_ambient

    def radiance(self, frame: np.ndarray, seed: int = 0) -> np.ndarray:
        """Total linear radiance at the camera for a projector input frame (projector + ambient)."""
        return self.projector_radiance(self.emit(frame), seed) + self.ambient_radiance()
