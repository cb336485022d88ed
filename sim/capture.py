"""The simulated hardware: projector frame → scene → camera → canonical view.

:class:`Simulator` is the public entry point the compensation side uses (closed loop) and the
dataset writer builds on. Each capture is identified by a ``(stream, index)`` pair that seeds both
the Monte-Carlo sampler and the camera noise (the streams are listed in :mod:`sim.seeds`), so a
capture is reproducible bit for bit and two different captures never share noise.
"""
from __future__ import annotations

import copy
import itertools
import math
import time
from collections import defaultdict, deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import TypeVar

import numpy as np

from sim import camera, registration, seeds, surfaces
from sim.cores import usable_cores
from sim.fidelity import make_renderer, resolve, with_depth
from sim.projector import chain as projector_chain
from sim.setup import Setup
from sim.stages import run, switch_off

Item = TypeVar("Item")
Result = TypeVar("Result")


def capture_workers() -> int:
    """Worker threads for the per-capture work after rendering: the usable cores, at most 4."""
    return max(1, min(4, usable_cores()))


def pipelined(items: Iterable[Item], render: Callable[[Item], object],
              finish: Callable[[Item, object], Result], workers: int | None = None) -> Iterator[Result]:
    """``finish(item, render(item))`` for each item, in order: ``render`` on the calling thread
    (one Mitsuba scene), ``finish`` (camera model, warp, PNG writes: NumPy, OpenCV and zlib
    release the GIL) on worker threads beside the next render.

    Each capture's noise is seeded by its own ``(seed, stream, index)``, so results do not depend
    on the number of workers. At most ``2 × workers`` items are in flight (bounded memory); an
    error in a worker is raised here, at that item.

    Parameters
    ----------
    items : iterable
        Work items, rendered in this order.
    render, finish : callable
        The two stages.
    workers : int, optional
        Worker threads; :func:`capture_workers` by default.
    """
    workers = workers or capture_workers()
    with ThreadPoolExecutor(workers) as pool:
        pending: deque = deque()
        for item in items:
            pending.append(pool.submit(finish, item, render(item)))
            while len(pending) > 2 * workers:
                yield pending.popleft().result()
        while pending:
            yield pending.popleft().result()


RULE_PREVIEW_SPP = 16
"""Samples per pixel of the preview the exposure rule is set from (it reads one percentile of the
whole frame of plain white, a statistic the preview's Monte-Carlo noise hardly moves)."""

class Simulator:
    """Capture projector frames through a simulated setup.

    Parameters
    ----------
    setup : Setup
        The validated setup.
    size : (int, int)
        Canonical (width, height) in pixels: the size of projector frames and warped captures.
    fidelity, spp : optional
        Override the setup's level and samples per pixel (:func:`sim.fidelity.resolve`; ``auto``
        measures its choice first, path depth included).
    cache_dir : Path, optional
        Where the ``transport`` level keeps its calibrated operator.
    max_depth : int, optional
        Path depth of a ``path`` level (a dataset's ``auto`` choice); default ``render.max_depth``.
    exposure : dict, optional
        What an earlier simulator of this setup recorded as its :attr:`exposure` (a dataset's
        ``camera_exposure``): with ``exposure_mode = "rule"`` it is used as it is, without the
        rule's preview renders (it is what the same preview gave).

    Attributes
    ----------
    setup : Setup
        The setup captured, its camera exposure set by the rule when ``exposure_mode = "rule"``.
    exposure : dict
        ``mode`` and ``exposure`` used (the rule adds what :func:`sim.camera.rule_exposure`
        measured).
    choice : sim.fidelity.Choice
        The level and spp used, and why.
    registration : sim.registration.Registration
        How captures are warped into the canonical view (``registration.method``; a homography is
        estimated from checkerboards captured through this simulator, stream
        :data:`sim.seeds.REGISTRATION`, so every simulator of a setup warps alike), with the exact
        map beside it.
    warp_map : sim.registration.WarpMap
        The map captures are warped with (``registration.warp_map``).
    timings : dict[str, float]
        Seconds spent per phase (``exposure`` — the rule's preview —, ``fidelity`` — the ``auto``
        measurement —, ``scene`` — including a
        ``transport`` calibration —, ``render``, ``camera``, ``registration`` — without the
        renders and camera model of its checkerboard captures) since creation.
    """

    def __init__(self, setup: Setup, size: tuple[int, int], fidelity: str | None = None,
                 spp: int | None = None, cache_dir=None, max_depth: int | None = None,
                 exposure: dict | None = None):
        self.setup = setup
        self.size = (int(size[0]), int(size[1]))
        self.timings: dict[str, float] = defaultdict(float)
        t0 = time.perf_counter()
        self.exposure = self._set_exposure(exposure)  # first: ``auto`` measures at the captures' exposure
        self.timings["exposure"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        self.choice = resolve(self.setup, fidelity, spp, max_depth=max_depth)
        self.timings["fidelity"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        self.renderer = make_renderer(with_depth(setup, self.choice.max_depth), self.choice.level,
                                      self.choice.spp, cache_dir)
        self.renderer.ambient_radiance()
        self.timings["scene"] += time.perf_counter() - t0
        t0 = time.perf_counter()
        captured = self.timings["render"] + self.timings["camera"]
        index = itertools.count()
        self.registration = registration.register(
            setup, self.size, lambda frame: self.raw(frame, seeds.REGISTRATION, next(index)))
        self.warp_map = self.registration.warp_map
        self.timings["registration"] += (time.perf_counter() - t0
                                         - (self.timings["render"] + self.timings["camera"] - captured))

    def _set_exposure(self, recorded: dict | None = None) -> dict:
        """The camera's exposure, as :attr:`exposure` records it; with ``exposure_mode = "rule"``
        set by :func:`sim.camera.rule_exposure` from a preview of plain white and plain black (as
        an operator sets it before capturing: rendered at :data:`RULE_PREVIEW_SPP`, direct light
        on surfaces that do not light themselves, path tracing at ``render.max_depth`` on those
        that do; stream :data:`sim.seeds.EXPOSURE`, steady lamp), and :attr:`setup` changed to use
        it for every capture. Set before the fidelity is chosen, so that ``auto`` weighs its errors
        against the noise at the exposure the captures use. A ``recorded`` rule exposure (see the
        class) is taken as it is."""
        cam = self.setup.camera
        if cam.exposure_mode != "rule":
            return {"mode": "manual", "exposure": cam.exposure}
        value = recorded.get("exposure") if isinstance(recorded, dict) else None
        if isinstance(value, (int, float)) and recorded.get("mode") == "rule" \
                and math.isfinite(value) and value > 0:  # else measured again, and compared by the caller
            self.setup = replace(self.setup, camera=replace(cam, exposure=float(value)))
            return dict(recorded)
        w, h = self.size
        inter = surfaces.surface_for(self.setup.surface).interreflection
        preview = make_renderer(self.setup, "path" if inter else "direct", RULE_PREVIEW_SPP)
        white, black = (preview.radiance(np.full((h, w, 3), level, np.uint8),
                                         seeds.mitsuba_seed(self.setup.render.seed, seeds.EXPOSURE, i))
                        for i, level in enumerate((255, 0)))
        rule = camera.rule_exposure(white, black, cam)
        self.setup = replace(self.setup, camera=replace(cam, exposure=rule["exposure"]))
        return rule

    def noise_free(self) -> Simulator:
        """This simulator without its random draws: the camera's noise stages and the lamp's
        flicker switched off (the lamp's drift, a deterministic test-time gain, is kept). Its
        captures are the expected captures up to the 8-bit output; at the ``direct`` and ``path``
        levels a capture still carries the Monte-Carlo samples of its stream and index (none at
        ``transport``), so a fixed stream and index make it a fixed function of the frame."""
        model = copy.copy(self)
        noise = [s for s in camera.STAGES if s.random]
        model.setup = replace(self.setup, camera=switch_off(self.setup.camera, noise),
                              projector=replace(self.setup.projector, flicker=0.0))
        model.timings = defaultdict(float)
        return model

    def linear(self, frame: np.ndarray, stream: int, index: int) -> np.ndarray:
        """Linear camera radiance (float32, camera resolution) of one projector frame.

        The projector's contribution goes through the projector's per-capture stages
        (:data:`sim.projector.chain.CAPTURE`: the lamp's brightness in this capture, flicker per
        capture, drift at test time); the ambient light does not.
        """
        t0 = time.perf_counter()
        r, p = self.setup.render, self.setup.projector
        mitsuba_seed = seeds.mitsuba_seed(r.seed, stream, index)
        if all(item.is_off(p) for item in projector_chain.CAPTURE):
            out = self.renderer.radiance(frame, mitsuba_seed)
        else:
            light = self.renderer.projector_radiance(self.renderer.emit(frame), mitsuba_seed)
            out = (run(projector_chain.CAPTURE, light, p, r.seed, stream, index)
                   + self.renderer.ambient_radiance())
        self.timings["render"] += time.perf_counter() - t0
        return out

    def expose(self, radiance: np.ndarray, stream: int, index: int) -> np.ndarray:
        """The camera model on linear radiance: 8-bit capture at camera resolution, noise seeded
        by ``(seed, stream, index)``. Keeps no timings, so worker threads may call it."""
        rng = seeds.noise_rng(self.setup.render.seed, stream, index)
        return camera.capture(radiance, self.setup.camera, rng)

    def raw(self, frame: np.ndarray, stream: int, index: int) -> np.ndarray:
        """8-bit capture at camera resolution (noise seeded by ``(seed, stream, index)``)."""
        radiance = self.linear(frame, stream, index)
        t0 = time.perf_counter()
        out = self.expose(radiance, stream, index)
        self.timings["camera"] += time.perf_counter() - t0
        return out

    def warp(self, raw: np.ndarray) -> np.ndarray:
        """Resample a camera image into the canonical projector view."""
        t0 = time.perf_counter()
        out = registration.warp(raw, self.warp_map)
        self.timings["registration"] += time.perf_counter() - t0
        return out

    def capture(self, frames: np.ndarray, stream: int, start: int = 0) -> np.ndarray:
        """Warped 8-bit captures of a stack of frames.

        Parameters
        ----------
        frames : numpy.ndarray
            uint8 (N, H, W, 3) projector frames at the canonical size (or float in [0, 1]).
        stream : int
            Capture stream (:mod:`sim.seeds`); frame k uses index ``start + k``.

        Returns
        -------
        numpy.ndarray
            uint8 (N, H, W, 3) captures in the canonical view.
        """
        def finish(k: int, radiance: np.ndarray) -> tuple[np.ndarray, float, float]:
            t0 = time.perf_counter()
            raw = self.expose(radiance, stream, start + k)
            t1 = time.perf_counter()
            return registration.warp(raw, self.warp_map), t1 - t0, time.perf_counter() - t1

        out = []
        for warped, camera_s, warp_s in pipelined(range(len(frames)),
                                                  lambda k: self.linear(frames[k], stream, start + k), finish):
            self.timings["camera"] += camera_s  # summed over the worker threads
            self.timings["registration"] += warp_s
            out.append(warped)
        return np.stack(out)
