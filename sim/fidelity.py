"""The fidelity ladder: ``path``, ``direct``, ``transport`` and the measured ``auto`` choice.

*Model no more than a scene needs*. Every way procam produces a capture is a level:

- ``path``: Mitsuba path tracing to ``render.max_depth`` (inter-reflection);
- ``direct``: Mitsuba direct light only (exact where no surface sees another: a plane);
- ``transport``: the setup's light-transport operator (:mod:`sim.transport`), calibrated once
  from ``direct`` renders, then a sparse matrix product per frame;

each at some samples per pixel. ``auto`` measures instead of guessing (:func:`choose`): it renders
probe frames of the test-image classes that break cheap models (:data:`PROBE_CLASSES`) through a
window of the camera, compares the candidates with a converged path-traced reference (path depth
:data:`AUTO_REFERENCE_DEPTH`) and picks the cheapest one whose error stays below
:data:`FLOOR_FRACTION` of the camera's own noise floor (shot and read noise plus 8-bit
quantisation, :func:`noise_floor`) for every class. Where surfaces light each other it picks the
path depth the same way (:data:`DEPTH_LADDER`): a depth that drops light the camera would see
fails against the deeper reference.

Errors are in *signal* units — radiance times exposure and white balance, clipped to the full
well [0, 1] — the units of the camera's noise model, so they compare directly with it.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from sim import camera, images, seeds, surfaces, transport
from sim.errors import SetupError
from sim.io import to_uint8
from sim.render import Renderer
from sim.setup import Setup
from sim.setup.schema import MAX_SPP

LEVELS = ("path", "direct", "transport")
"""The rendering levels, most accurate first."""
CHOICES = ("auto",) + LEVELS
"""What ``render.fidelity`` and ``--fidelity`` accept."""
SPP_LADDER = (1, 4, 16, 64, 256)
"""Samples per pixel that ``auto`` tries, cheapest first."""
PROBE_CLASSES = ("smooth", "stripes1", "stripes2", "random", "natural")
"""Probe frames: low-frequency colour fields, 1- and 2-pixel black/white stripes, independent
random pixels, and a generated dataset frame (:func:`probe_frame`)."""
FLOOR_FRACTION = 1.0
"""``auto`` accepts a level whose RMS error is at most this fraction of the camera's RMS noise: an
error below the camera's own noise floor. Added in quadrature such an error raises the
total noise by at most sqrt(2) - 1 = 41 %; with ``transport`` it is the same in every capture."""
AUTO_REFERENCE_SPP = 256
"""Samples per pixel of ``auto``'s path-traced reference (two renders of about half as many)."""
AUTO_REFERENCE_DEPTH = 16
"""Path depth of ``auto``'s reference. Each further bounce between a corner's wings carries at most
albedo × F of the last, with F = 1 - sin(θ/2) the form factor between two equal wings meeting at
θ (0.29 at 90°, 0.5 at 60°, 0.74 at 30°), so the light beyond 16 bounces is below (albedo F)^13
of the direct light: 6e-9 at albedo 0.8 and 90°, 6e-5 at albedo 0.95 and 60°, but 2 % at albedo
1 and 30° — a corner that narrow and white needs a deeper reference than this one."""
DEPTH_LADDER = (3, 4, 5, 6, 8, 12)
"""Path depths ``auto`` tries for a surface that lights itself (those at least
``render.max_depth``)."""
DEPTH_GAIN = 0.9
"""``auto`` keeps a deeper path only where it lowers the worst error over the noise floor to at
most this fraction of the shallower one's (less is within the Monte-Carlo noise of the
comparison)."""
PROBE_WINDOW = 64
"""Side in camera pixels of the central window ``auto`` renders (Monte-Carlo error is per pixel,
so a window measures it at a fraction of the cost)."""
DATASET_CAPTURES = 826
"""Captures of one dataset setup (126 + 500 + 200): the count ``auto`` amortises a calibration over."""


def check_level(setup: Setup, level: str) -> None:
    """Raise :class:`SetupError` unless ``level`` can represent the setup's light transport.

    Parameters
    ----------
    setup : Setup
        The setup.
    level : str
        One of :data:`CHOICES`.

    Raises
    ------
    SetupError
        For an unknown level; ``direct`` or ``transport`` with inter-reflection; ``path`` too
        shallow for inter-reflection (``render.max_depth`` < 3).
    """
    if level not in CHOICES:
        raise SetupError(f"setup {setup.name!r}: fidelity {level!r}: expected one of "
                         f"{', '.join(repr(c) for c in CHOICES)}")
    inter = surfaces.surface_for(setup.surface).interreflection
    if level == "direct" and inter:
        raise SetupError(
            f'setup {setup.name!r}: fidelity "direct" cannot represent surface.geometry = '
            f'"{setup.surface.geometry}": its surfaces light each other (inter-reflection), which '
            'direct light drops; use "path" (render.max_depth >= 3) or "auto"')
    if level == "transport":
        transport.check_supported(setup)
    if level == "path" and inter and setup.render.max_depth < 3:
        raise SetupError(
            f"setup {setup.name!r}: render.max_depth = {setup.render.max_depth}: path tracing needs "
            f'a depth >= 3 for the inter-reflection of surface.geometry = "{setup.surface.geometry}"')


def check_spp(setup: Setup, spp: int | None) -> None:
    """Raise :class:`SetupError` unless ``spp`` (an override of ``render.spp``) is None or in
    1..:data:`~sim.setup.schema.MAX_SPP`."""
    if spp is not None and not 1 <= spp <= MAX_SPP:
        raise SetupError(f"setup {setup.name!r}: spp (--spp) = {spp}: expected samples per pixel "
                         f"from 1 to {MAX_SPP} (as render.spp)")


def with_depth(setup: Setup, max_depth: int | None) -> Setup:
    """The setup with ``render.max_depth`` replaced (unchanged for None)."""
    if max_depth is None or max_depth == setup.render.max_depth:
        return setup
    return replace(setup, render=replace(setup.render, max_depth=int(max_depth)))


def describe(setup: Setup, level: str) -> str:
    """How a level renders, for meta.json, e.g. ``"path (max_depth 3)"``."""
    if level == "path":
        return f"path (max_depth {setup.render.max_depth})"
    if level == "transport":
        return "light-transport operator (calibrated from direct renders)"
    return level


def probe_frame(kind: str, size: tuple[int, int], seed: int) -> np.ndarray:
    """A projector frame of one probe class.

    Parameters
    ----------
    kind : str
        One of :data:`PROBE_CLASSES`: ``smooth`` (sums of sinusoids with periods of at least half
        the frame, each channel its own), ``stripes1``/``stripes2`` (vertical black/white stripes
        1 or 2 pixels wide), ``random`` (independent uniform 8-bit values) or ``natural`` (a frame
        of :func:`sim.images.projector_frames`, as in a dataset).
    size : (int, int)
        (width, height) in pixels.
    seed : int
        Seed of the random content (the setup's ``render.seed``; see :mod:`sim.seeds`).

    Returns
    -------
    numpy.ndarray
        uint8 (height, width, 3), encoded projector input.

    Raises
    ------
    ValueError
        If ``kind`` is not a probe class.
    """
    if kind not in PROBE_CLASSES:
        raise ValueError(f"probe class {kind!r}: expected one of {', '.join(PROBE_CLASSES)}")
    w, h = size
    rng = np.random.default_rng([seed, PROBE_CLASSES.index(kind)])
    if kind == "smooth":
        y, x = np.mgrid[0:h, 0:w] / max(w, h)
        out = np.full((h, w, 3), 0.5)
        for c in range(3):
            for _ in range(3):
                fx, fy = rng.uniform(-2, 2, 2)
                out[..., c] += 0.13 * np.sin(2 * np.pi * (fx * x + fy * y) + rng.uniform(0, 2 * np.pi))
        return to_uint8(out)
    if kind in ("stripes1", "stripes2"):
        width = int(kind[-1])
        on = (np.arange(w) // width) % 2 == 0
        return np.broadcast_to(np.where(on, 255, 0).astype(np.uint8)[None, :, None], (h, w, 3)).copy()
    if kind == "random":
        return rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    return images.projector_frames(1, (w, h), seed, seeds.PROBE_FRAMES)[0]  # natural


def noise_floor(signal: np.ndarray, cfg) -> float:
    """RMS of the camera's own noise over an image, in linear signal units.

    Per pixel and channel the sensor noise (:func:`sim.camera.noise_sigma`) and the 8-bit
    quantisation (:func:`sim.camera.quantisation_sigma`) add in quadrature.

    Parameters
    ----------
    signal : numpy.ndarray
        Noiseless linear signal in [0, 1] (:func:`sim.camera.sensor_signal` without noise), any
        shape.
    cfg : CameraConfig
        Noise levels and response curve.

    Returns
    -------
    float
        sqrt(mean(sigma_sensor² + sigma_quantisation²)).

    Examples
    --------
    >>> from sim.setup import CameraConfig
    >>> cfg = CameraConfig(response="linear", shot_noise=0.0, read_noise=0.0)
    >>> round(noise_floor(np.full(4, 0.5), cfg) * 255 * 12 ** 0.5, 6)
    1.0
    """
    var = (camera.noise_sigma(signal, cfg.shot_noise, cfg.read_noise) ** 2
           + camera.quantisation_sigma(signal, cfg.response) ** 2)
    return float(np.sqrt(np.mean(var)))


def unbiased_rmse(x: np.ndarray, ref_a: np.ndarray, ref_b: np.ndarray) -> float:
    """RMS error of ``x`` against the expectation of a noisy reference given by two independent
    renders: ``mean((x - (a + b)/2)²) - mean((a - b)²)/4`` (the reference's own variance
    removed), clamped at 0, square-rooted.

    Examples
    --------
    >>> a, b = np.array([1.0, 3.0]), np.array([3.0, 1.0])
    >>> unbiased_rmse(np.array([2.0, 2.0]), a, b)
    0.0
    """
    ref = 0.5 * (ref_a + ref_b)
    mse = np.mean((x - ref) ** 2, dtype=np.float64) - np.mean((ref_a - ref_b) ** 2, dtype=np.float64) / 4
    return float(math.sqrt(max(float(mse), 0.0)))


def psnr_from_rmse(rmse: float, peak: float = 1.0) -> float:
    """Peak signal-to-noise ratio in dB of an RMS error: ``20 log10(peak / rmse)``.

    Parameters
    ----------
    rmse : float
        RMS error (>= 0), in the units of ``peak``.
    peak : float
        The largest value of the signal: 1 for the full well (linear) or the top code (encoded).

    Returns
    -------
    float
        dB; ``inf`` for an error of 0.

    Examples
    --------
    >>> psnr_from_rmse(0.01)
    40.0
    >>> psnr_from_rmse(0.0)
    inf
    """
    if rmse == 0:
        return math.inf
    return 20 * (math.log10(peak) - math.log10(rmse))


def window_setup(setup: Setup, window: int | None) -> Setup:
    """The setup with its camera cropped to a central window of about ``window`` pixels a side.

    The crop keeps the camera's pose and pixel pitch (the field of view shrinks with the
    resolution), so every pixel of the window sees exactly what it sees in the full image. A side
    is widened by one pixel where needed to keep the window centred on pixel edges. ``None`` or a
    window at least as large as the image returns the setup unchanged.
    """
    wc, hc = setup.camera.resolution
    if window is None or (window >= wc and window >= hc):
        return setup
    w = min(wc, window + (wc - window) % 2)
    h = min(hc, window + (hc - window) % 2)
    t = math.tan(math.radians(setup.camera.fov) / 2) * w / wc
    cam = replace(setup.camera, resolution=(w, h), fov=math.degrees(2 * math.atan(t)))
    return replace(setup, camera=cam)


def half_spp(spp: int) -> int:
    """Samples per pixel of each of a reference's two renders: about ``spp / 2``, rounded to a
    square (the stratified ``multijitter`` sampler rounds other counts up itself, with a warning).

    Examples
    --------
    >>> half_spp(1024), half_spp(256)
    (529, 121)
    """
    return max(1, round(math.sqrt(spp / 2))) ** 2


class Probe:
    """Probe frames of a setup and their converged reference, to measure any renderer against.

    Parameters
    ----------
    setup : Setup
        The setup.
    classes : sequence of str
        Probe classes (:data:`PROBE_CLASSES`), one frame each.
    reference_spp : int
        Samples per pixel of the path-traced reference (depth :data:`AUTO_REFERENCE_DEPTH` or
        ``render.max_depth`` if deeper), split over two independent renders (:func:`half_spp`).
    window : int or None
        Side of the central camera window rendered (:func:`window_setup`); None: the whole image.

    Attributes
    ----------
    setup : Setup
        The (windowed) setup every renderer measured must be built for.
    frames : dict[str, numpy.ndarray]
        uint8 projector frame per class.
    floors, floors_encoded : dict[str, float]
        The camera's RMS noise per class: linear signal units, and encoded values in [0, 1]
        (a real 8-bit noisy capture of the reference by the sensor alone,
        :func:`sim.camera.sensor_alone`, against its noiseless encoding: neither the optics nor
        the picture processing, a deterministic rendering of the encoded image that the
        noiseless encoding and the errors of :meth:`errors` do not have).
    reference_seconds : float
        Wall time of one reference capture (both renders), seconds; the first frame, which
        compiles the kernels, is left out when there are others.
    """

    def __init__(self, setup: Setup, classes=PROBE_CLASSES, reference_spp: int = AUTO_REFERENCE_SPP,
                 window: int | None = PROBE_WINDOW):
        self.setup = window_setup(setup, window)
        self.reference_spp = int(reference_spp)
        self.reference_depth = max(AUTO_REFERENCE_DEPTH, self.setup.render.max_depth)
        ref = Renderer(with_depth(self.setup, self.reference_depth), "path", half_spp(self.reference_spp))
        self._emit = ref.emit
        self._ambient = ref.ambient_radiance()
        size = tuple(setup.projector.resolution)
        self.frames = {k: probe_frame(k, size, setup.render.seed) for k in classes}
        cfg = self.setup.camera
        self._reference = {}
        self.floors, self.floors_encoded = {}, {}
        seconds = []
        for i, (k, frame) in enumerate(self.frames.items()):
            t0 = time.perf_counter()
            irr = self._emit(frame)
            halves = [ref.projector_radiance(irr, seeds.mitsuba_seed(setup.render.seed, seeds.REFERENCE,
                                                                     2 * i + j)) for j in range(2)]
            seconds.append(time.perf_counter() - t0)
            self._reference[k] = [camera.sensor_signal(r + self._ambient, cfg.exposure, cfg.white_balance)
                                  for r in halves]
            mean = 0.5 * (halves[0] + halves[1]) + self._ambient
            signal = camera.sensor_signal(mean, cfg.exposure, cfg.white_balance)
            self.floors[k] = noise_floor(signal, cfg)
            rng = seeds.noise_rng(setup.render.seed, seeds.REFERENCE, i)
            noisy = camera.capture(mean, camera.sensor_alone(cfg), rng).astype(np.float64) / 255
            clean = camera.encode(signal.astype(np.float64), cfg.response)
            self.floors_encoded[k] = float(np.sqrt(np.mean((noisy - clean) ** 2)))
        self.reference_seconds = float(np.mean(seconds[1:] or seconds))  # the first one compiles

    def errors(self, renderer: Renderer) -> dict[str, dict[str, float]]:
        """RMS error of a renderer's captures against the reference, per probe class.

        The projector contribution is rendered with probe seeds (ignored by ``transport``) and
        the reference's ambient image added, so only the light transport of the level differs.

        Parameters
        ----------
        renderer : Renderer
            Any level, built for :attr:`setup`.

        Returns
        -------
        dict
            class -> ``{"rmse": linear signal units, "rmse_encoded": encoded values in [0, 1],
            "seconds": wall time of the frame's emission and render}``, both errors with the
            reference's own Monte-Carlo variance removed (:func:`unbiased_rmse`).
        """
        cfg = self.setup.camera
        out = {}
        for i, (k, frame) in enumerate(self.frames.items()):
            t0 = time.perf_counter()
            rad = renderer.projector_radiance(self._emit(frame),
                                              seeds.mitsuba_seed(self.setup.render.seed, seeds.PROBE, i))
            seconds = time.perf_counter() - t0
            sig = camera.sensor_signal(rad + self._ambient, cfg.exposure, cfg.white_balance)
            a, b = self._reference[k]
            enc = [camera.encode(s.astype(np.float64), cfg.response) for s in (sig, a, b)]
            out[k] = {"rmse": unbiased_rmse(sig, a, b), "rmse_encoded": unbiased_rmse(*enc),
                      "seconds": seconds}
        return out


def make_renderer(setup: Setup, level: str, spp: int | None = None, cache_dir=None) -> Renderer:
    """A renderer of one level (``transport``: calibrated, or read from ``cache_dir``).

    Raises
    ------
    SetupError
        If the level cannot represent the setup (:func:`check_level`) or is ``auto``.
    """
    check_level(setup, level)
    if level == "auto":
        raise SetupError(f"setup {setup.name!r}: resolve fidelity 'auto' first (sim.fidelity.resolve)")
    if level == "transport":
        return transport.TransportRenderer(setup, spp, cache_dir=cache_dir)
    return Renderer(setup, level, spp)


@dataclass(frozen=True)
class Choice:
    """A resolved fidelity: the level and spp used, and why.

    Attributes
    ----------
    level : str
        ``path``, ``direct`` or ``transport``.
    spp : int
        Samples per pixel (``transport``: of its calibration).
    reason : str
        Why this level: asked for, or what ``auto`` measured.
    predicted_error : float or None
        ``auto``: worst RMS error over the probe classes (linear signal units).
    noise_floor : float or None
        ``auto``: the camera's RMS noise of that class (linear signal units).
    candidates : tuple of dict
        ``auto``: every candidate measured, in the order tried, with its path depth and its
        errors per class (linear signal units).
    max_depth : int or None
        Path depth to render with, chosen by ``auto`` for a surface that lights itself (or
        carried over from a dataset's choice); None: ``render.max_depth``.
    """

    level: str
    spp: int
    reason: str
    predicted_error: float | None = None
    noise_floor: float | None = None
    candidates: tuple = field(default=(), compare=False)
    max_depth: int | None = None

    def as_dict(self) -> dict:
        """JSON-ready form for meta.json."""
        return {"level": self.level, "spp": self.spp, "reason": self.reason,
                "predicted_error": self.predicted_error, "noise_floor": self.noise_floor,
                "max_depth": self.max_depth, "candidates": list(self.candidates)}


def _worst(errors: dict, floors: dict) -> tuple[str, float]:
    """The class whose error is the largest fraction of its floor, and that fraction."""
    k = max(errors, key=lambda c: errors[c]["rmse"] / floors[c])
    return k, errors[k]["rmse"] / floors[k]


def choose(setup: Setup, spp: int | None = None, n_captures: int = DATASET_CAPTURES,
           probe: Probe | None = None) -> Choice:
    """``auto``: the cheapest level whose error is below the camera's noise floor (measured).

    Candidates, cheapest first, for each spp of the ladder (or only ``spp`` when given):
    ``transport`` (its calibration is ``s² + 1`` direct renders, cheaper than rendering the
    ``n_captures`` captures whenever ``s² + 1 < n_captures``) or ``direct`` for a setup without
    inter-reflection, ``path`` for one with it. A candidate passes when its RMS error is at most
    :data:`FLOOR_FRACTION` × the camera's RMS noise for every probe class; if none passes, the
    most accurate candidate is used and the reason says so.

    Parameters
    ----------
    setup : Setup
        The setup.
    spp : int, optional
        Only try this spp.
    n_captures : int
        Captures the choice will render (the calibration of ``transport`` is amortised over them).
    probe : Probe, optional
        Precomputed probe frames and reference (default: :class:`Probe` of the setup).

    Returns
    -------
    Choice
    """
    probe = probe or Probe(setup)
    ladder = (int(spp),) if spp else SPP_LADDER
    inter = surfaces.surface_for(setup.surface).interreflection
    level = "path" if inter else "transport"
    if inter:
        return _choose_path(setup, ladder, probe)
    s = transport.dot_spacing(*transport.footprint_ranges(setup))
    if s > transport.MAX_SPACING or s * s + 1 >= n_captures:
        level = "direct"
    why_level = "no surface sees another: direct light is exact, " + (
        f"applied as a light-transport operator ({s * s} calibration renders)"
        if level == "transport" else
        f"rendered per capture (a transport calibration would take {s * s} renders)")
    candidates = []
    for n in ladder:
        errs = probe.errors(make_renderer(probe.setup, level, n))
        cls, frac = _worst(errs, probe.floors)
        candidates.append(_candidate(level, n, None, cls, frac, errs))
        if frac <= FLOOR_FRACTION:
            return Choice(level, n, f"{why_level}; {n} spp is the fewest whose error is at most "
                          f"{FLOOR_FRACTION:g} x the camera noise for every probe class (worst: "
                          f"{cls}, {frac:.2f} x)", errs[cls]["rmse"], probe.floors[cls],
                          tuple(candidates))
    return Choice(level, ladder[-1], f"{why_level}; no spp tried reaches {FLOOR_FRACTION:g} x the "
                  f"camera noise (worst: {cls}, {frac:.2f} x at {ladder[-1]} spp): using the most "
                  "samples tried", errs[cls]["rmse"], probe.floors[cls], tuple(candidates))


def _candidate(level: str, spp: int, depth: int | None, cls: str, frac: float, errs: dict) -> dict:
    """One measured candidate, JSON-ready."""
    return {"level": level, "spp": spp, "max_depth": depth, "worst_class": cls,
            "error_over_floor": round(frac, 4),
            "errors": {k: round(v["rmse"], 7) for k, v in errs.items()}}


def _choose_path(setup: Setup, ladder: tuple[int, ...], probe: Probe) -> Choice:
    """``auto`` for a surface that lights itself: path tracing, its spp and depth measured.

    For each spp of ``ladder`` the current depth (first ``render.max_depth``) is measured; if it
    fails, the next depth of :data:`DEPTH_LADDER` too, and the deeper one is kept while it lowers
    the worst error over the floor to at most :data:`DEPTH_GAIN` of the shallower one (the light
    it adds is above the Monte-Carlo noise at this spp); otherwise the next spp is tried at the
    current depth. The first candidate at most :data:`FLOOR_FRACTION` × the noise floor for every
    class is chosen; if none is, the last spp at the depth kept.
    """
    depths = sorted({setup.render.max_depth, *(d for d in DEPTH_LADDER if d > setup.render.max_depth)})
    why = (f"its surfaces light each other: path tracing, measured against a depth "
           f"{probe.reference_depth} reference")
    candidates: list[dict] = []
    measured: list[tuple[float, int, int, str, dict]] = []

    def measure(n: int, depth: int) -> float:
        errs = probe.errors(make_renderer(with_depth(probe.setup, depth), "path", n))
        cls, frac = _worst(errs, probe.floors)
        candidates.append(_candidate("path", n, depth, cls, frac, errs))
        measured.append((frac, n, depth, cls, errs))
        return frac

    def chosen(frac: float, n: int, depth: int, cls: str, errs: dict, how: str) -> Choice:
        return Choice("path", n, f"{why}; {how} (worst: {cls}, {frac:.2f} x the camera noise)",
                      errs[cls]["rmse"], probe.floors[cls], tuple(candidates), depth)

    i = 0
    for n in ladder:
        frac = measure(n, depths[i])
        while frac > FLOOR_FRACTION and i + 1 < len(depths):
            deeper = measure(n, depths[i + 1])
            if deeper > FLOOR_FRACTION and deeper > DEPTH_GAIN * frac:
                break  # the light a deeper path adds is lost in this spp's noise: more samples first
            i, frac = i + 1, deeper
        if frac <= FLOOR_FRACTION:  # the last candidate measured
            return chosen(*measured[-1], f"{n} spp and depth {depths[i]} are the fewest samples, then the "
                          f"shallowest depth, whose error is at most {FLOOR_FRACTION:g} x the camera "
                          "noise for every probe class")
    last = next(m for m in reversed(measured) if m[2] == depths[i])
    return chosen(*last, f"no spp and depth tried reaches {FLOOR_FRACTION:g} x the camera noise: "
                  f"using the most samples tried and depth {depths[i]}, the deepest that lowered "
                  "the error")


def resolve(setup: Setup, fidelity: str | None = None, spp: int | None = None,
            n_captures: int = DATASET_CAPTURES, max_depth: int | None = None) -> Choice:
    """The level and spp to render a setup with.

    Parameters
    ----------
    setup : Setup
        The setup.
    fidelity : str, optional
        Overrides ``setup.render.fidelity`` (one of :data:`CHOICES`).
    spp : int, optional
        Overrides ``setup.render.spp`` (for ``auto``: the only spp tried).
    n_captures : int
        Captures to render (``auto`` amortises a calibration over them).
    max_depth : int, optional
        Overrides ``render.max_depth`` of a ``path`` level (a dataset's ``auto`` choice, carried
        over to its closed loop); ``auto`` chooses its own.

    Raises
    ------
    SetupError
        If the level cannot represent the setup (:func:`check_level`) or ``spp`` is below 1.
    """
    level = fidelity or setup.render.fidelity
    check_level(with_depth(setup, max_depth), level)
    check_spp(setup, spp)
    if level == "auto":
        return choose(setup, spp, n_captures)
    return Choice(level, int(spp or setup.render.spp), "asked for" + (
        " (--fidelity)" if fidelity else " (render.fidelity)"),
        max_depth=max_depth if level == "path" else None)
