"""The measurement no real benchmark can make: project x* = π†(y') back through the same simulated
setup and score what the camera sees against the target y'.

The target y' is the desired image y mapped into what the setup can show by a target policy
(:mod:`~compensation.experiments.targets`: ``none`` keeps y' = y; ``global``, the default, one map
y' = a·y + b per setup; ``image``, one per desired image). Every closed-loop score compares with
y': a method's (it compensates y'), the uncompensated row's (y' projected as is) and the oracle's.

Also the model-free iterative feedback refinement of Nayar et al. (project, capture, correct the
frame by the error, repeat) and the physically reachable pixels: those where y' lies between the
captures of a black and a white frame.
"""
from __future__ import annotations

import math
import time
from collections import OrderedDict
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from compensation.data import SetupData
from compensation.experiments.targets import IDENTITY, TargetPolicy, map_record, map_targets
from compensation.scores.metrics import evaluate, masked_scores, psnr_per_image
from sim import seeds
from sim.capture import Simulator
from sim.dataset import canonical_size
from sim.errors import DatasetError
from sim.io import read_json, to_float, to_uint8, write_png
from sim.layout import META_FILE, SETUP_FILE, cache_dir, image_name
from sim.setup import load_setup

CAPTURES_DIR = "closed_loop"
"""Folder of a run holding the closed-loop captures of its first test images (figures, reports)."""
N_CAPTURES = 4
"""Closed-loop captures kept per run: those of the first test images."""
REACH_TOLERANCE = 2 / 255
"""Slack (encoded units) for the reachable test: two 8-bit levels of camera noise."""


SIMULATORS_KEPT = 2
"""Simulators :func:`simulator_for` keeps in the process, the most recently used: a bench or study
projects every method's frames, the oracle's and the optimum's through the same setup one job
after the other, and building a simulator (Mitsuba scene, transport operator, registration
captures) costs seconds at the paper's 960x640 camera."""
_SIMULATORS: OrderedDict[tuple, Simulator] = OrderedDict()


def simulator_for(setup_dir: str | Path) -> Simulator:
    """The simulator a dataset was rendered with: its resolved ``setup.toml`` plus the canonical
    size, fidelity, spp, path depth and camera exposure recorded in ``meta.json`` (a transport
    operator comes from the cache; the exposure rule's preview is not rendered again).

    The last :data:`SIMULATORS_KEPT` are reused while the dataset's ``meta.json`` and
    ``setup.toml`` stay the same (the Mitsuba variant is chosen once per process): a simulator
    keeps no state between captures (each is seeded by its stream and index), so a reused one
    captures exactly what a new one would.
    """
    setup_dir = Path(setup_dir)
    key = (str(setup_dir.resolve()), _stamp(setup_dir / META_FILE), _stamp(setup_dir / SETUP_FILE))
    if key in _SIMULATORS:
        _SIMULATORS.move_to_end(key)
        return _SIMULATORS[key]
    sim = _new_simulator(setup_dir)
    _SIMULATORS[key] = sim
    while len(_SIMULATORS) > SIMULATORS_KEPT:
        _SIMULATORS.popitem(last=False)
    return sim


def _stamp(path: Path) -> tuple[int, int, int] | None:
    """A file's inode, modification time and size (None if it is missing): what changes when it
    is written again (procam writes by renaming a new file over the old)."""
    try:
        st = path.stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


def _new_simulator(setup_dir: Path) -> Simulator:
    """:func:`simulator_for` without the reuse."""
    meta = read_json(setup_dir / META_FILE, "dataset metadata")
    setup = load_setup(setup_dir / SETUP_FILE)
    size = canonical_size(meta)
    if size is None:
        raise DatasetError(f"{setup_dir / META_FILE}: no canonical width and height")
    sim = Simulator(setup, size, meta.get("fidelity"), meta.get("spp"), cache_dir=cache_dir(setup_dir),
                    max_depth=(meta.get("fidelity_choice") or {}).get("max_depth"),
                    exposure=meta.get("camera_exposure"))
    _check_same_hardware(setup_dir / META_FILE, meta, sim)
    return sim


def _check_same_hardware(path: Path, meta: dict, sim: Simulator) -> None:
    """Refuse a simulator that would not reproduce the dataset's captures: another Mitsuba variant
    (other Monte-Carlo samples), another exposure, or another registration than ``meta.json``
    records (each is re-derived from the seeds, so on the same variant they agree exactly)."""
    mismatch = []
    if meta.get("variant") and meta["variant"] != sim.renderer.variant:
        mismatch.append(f"Mitsuba variant {sim.renderer.variant!r} here, {meta['variant']!r} in the "
                        f"dataset (set PROCAM_VARIANT={meta['variant']} to use it)")
    record = meta.get("camera_exposure")
    recorded = record.get("exposure") if isinstance(record, dict) else None
    if recorded is not None and not isinstance(recorded, (int, float)):
        mismatch.append(f"camera_exposure.exposure = {recorded!r} in the dataset (expected a number)")
    elif recorded is not None and not math.isclose(recorded, sim.exposure["exposure"], rel_tol=1e-9):
        mismatch.append(f"camera exposure {sim.exposure['exposure']:.6g} here, {recorded:.6g} in the dataset")
    hom = ((meta.get("registration") or {}).get("homography") or {}).get("matrix")
    if hom is not None and (sim.registration.homography is None
                            or not np.allclose(sim.registration.homography, hom, rtol=1e-6, atol=1e-9)):
        mismatch.append("another estimated homography than the dataset's")
    if mismatch:
        raise DatasetError(f"{path}: the closed loop cannot reproduce this dataset's setup: "
                           + "; ".join(mismatch))


def project(sim: Simulator, frames: torch.Tensor, stream: int, start: int = 0) -> torch.Tensor:
    """Send projector frames through the simulated setup.

    Parameters
    ----------
    sim : Simulator
        The setup's simulator.
    frames : torch.Tensor
        float32 (N, 3, H, W) in [0, 1]; rounded to 8 bits as a projector input is.
    stream : int
        Seed stream of these captures (fresh noise per stream and frame).
    start : int
        Index in the stream of the first frame (frame k is capture ``start + k``).

    Returns
    -------
    torch.Tensor
        Captures in the canonical view, float32 (N, 3, H, W) in [0, 1].
    """
    stack = to_uint8(frames.permute(0, 2, 3, 1).cpu().numpy())
    caps = sim.capture(stack, stream, start)
    return torch.from_numpy(to_float(caps)).permute(0, 3, 1, 2).contiguous()


def reach_bounds(data: SetupData) -> tuple[torch.Tensor, torch.Tensor]:
    """The captures of the black (0001) and white (0125) plain frames, each (1, 3, H, W): at each
    pixel and channel, what the projector can show lies between them."""
    return data.ref.captures[0:1], data.ref.captures[124:125]


def reachable_mask(data: SetupData, desired: torch.Tensor) -> torch.Tensor:
    """Pixels whose desired value the projector can produce on that surface.

    A pixel is reachable when every channel of y lies between the captures of the black (0001)
    and white (0125) plain frames, within :data:`REACH_TOLERANCE`.

    Returns
    -------
    torch.Tensor
        bool (N, H, W).
    """
    black, white = reach_bounds(data)
    ok = (desired >= black - REACH_TOLERANCE) & (desired <= white + REACH_TOLERANCE)
    return ok.all(dim=1)


def closed_loop_target(data: SetupData, desired: torch.Tensor,
                       policy: TargetPolicy) -> tuple[torch.Tensor, dict]:
    """The targets y' of desired images under ``policy``, and their record (the policy, ``a``,
    ``b``: :func:`~compensation.experiments.targets.map_record`).

    Parameters
    ----------
    desired : torch.Tensor
        y, float32 (N, 3, H, W) in [0, 1].

    Returns
    -------
    torch.Tensor
        y', float32 (N, 3, H, W) in [0, 1] (``desired`` itself under ``none``).
    dict
        The record.
    """
    if policy.name == "none":
        return desired, map_record(policy, [IDENTITY] * len(desired))
    black, white = (b[0].double().numpy() for b in reach_bounds(data))
    target, record = map_targets(policy, desired.double().numpy(), black, white)
    return torch.from_numpy(target).float(), record


def reachable_overlay(desired: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """The desired images with their unreachable pixels tinted magenta (for figures).

    Parameters
    ----------
    desired : torch.Tensor
        y, float32 (N, 3, H, W) in [0, 1].
    mask : torch.Tensor
        bool (N, H, W) from :func:`reachable_mask`.

    Returns
    -------
    torch.Tensor
        float32 (N, 3, H, W): y where reachable, ``0.3 · y + 0.7 · magenta`` elsewhere.
    """
    magenta = torch.tensor([1.0, 0.0, 1.0]).view(1, 3, 1, 1)
    return torch.where(mask[:, None], desired, 0.3 * desired + 0.7 * magenta)


def closed_loop_scores(captured: torch.Tensor, y: torch.Tensor, mask: torch.Tensor, batch_size: int = 64) -> dict:
    """Closed-loop scores of captures against y: ``psnr``/``rmse``/``ssim`` over all pixels,
    ``psnr_reachable``/``rmse_reachable`` over the reachable ones (``mask``, bool (N, H, W)),
    ``reachable_fraction`` and ``psnr_per_image`` (each image's PSNR, for confidence intervals)."""
    reach = masked_scores(captured, y, mask)
    return {**evaluate(captured, y, batch_size=batch_size), "psnr_reachable": reach["psnr"],
            "rmse_reachable": reach["rmse"], "reachable_fraction": float(mask.float().mean()),
            "psnr_per_image": psnr_per_image(captured, y)}


def closed_loop(method, data: SetupData, sim: Simulator, desired: torch.Tensor | None = None,
                batch_size: int = 64, return_captures: bool = False,
                policy: TargetPolicy = TargetPolicy()) -> dict | tuple[dict, torch.Tensor]:
    """Closed-loop score of a fitted method: it compensates the target y' of each desired image
    (x* = π†(y')), and the capture of x* is scored against y'.

    Parameters
    ----------
    method : compensation.methods.Method
        A fitted method.
    data : SetupData
        The setup's data (surface s̃; test frames are the desired images by default).
    sim : Simulator
        The same setup's simulator.
    desired : torch.Tensor, optional
        Desired images y (N, 3, H, W); defaults to the test frames.
    return_captures : bool
        Also return the captures of the projected compensation images.
    policy : TargetPolicy
        How y is mapped to the target y' (:func:`closed_loop_target`).

    Returns
    -------
    dict
        ``psnr``, ``rmse``, ``ssim`` of the captured result against y'; ``psnr_reachable`` and
        ``rmse_reachable`` over the pixels of :func:`reachable_mask` (of y') only;
        ``reachable_fraction`` (share of pixels y' can be produced at), ``psnr_per_image``,
        ``projections``, ``infer_ms_per_frame`` (wall-clock of π† per frame, batched) and
        ``target`` (the policy and its map).
    torch.Tensor
        Only with ``return_captures``: the captures, float32 (N, 3, H, W) in [0, 1].
    """
    y, record = closed_loop_target(data, data.test.frames if desired is None else desired, policy)
    t0 = time.perf_counter()
    x_star = method.predict(y, data.surface, batch_size=batch_size)
    infer_ms = 1000 * (time.perf_counter() - t0) / y.shape[0]
    captured = project(sim, x_star, seeds.CLOSED_LOOP)
    scores = {**closed_loop_scores(captured, y, reachable_mask(data, y), batch_size),
              "projections": int(y.shape[0]), "infer_ms_per_frame": round(infer_ms, 3), "target": record}
    return (scores, captured) if return_captures else scores


def write_captures(run_dir: str | Path, captured: torch.Tensor, n: int = N_CAPTURES) -> Path:
    """Keep the closed-loop captures of the first ``n`` test images in ``run_dir/closed_loop`` as
    ``img_0001.png`` … (8 bit, canonical view), where reports find them.

    Parameters
    ----------
    captured : torch.Tensor
        float32 (N, 3, H, W) in [0, 1], as :func:`closed_loop` returns them.

    Returns
    -------
    Path
        The folder.
    """
    folder = Path(run_dir) / CAPTURES_DIR
    for i, image in enumerate(captured[:n].permute(0, 2, 3, 1).cpu().numpy(), start=1):
        write_png(folder / image_name(i), to_uint8(image))
    return folder


def projected_as_is(data: SetupData, sim: Simulator, y: torch.Tensor, own: bool) -> torch.Tensor:
    """Captures of the targets y projected as is: the dataset's test captures when y are its own
    test frames unchanged (``own``; they were captured already), else fresh ones (each image's
    noise drawn from its index in y, so the first images of y are captured as they are alone)."""
    return data.test.captures if own else project(sim, y, seeds.CLOSED_LOOP + 1)


def uncompensated(data: SetupData, sim: Simulator, desired: torch.Tensor | None = None,
                  policy: TargetPolicy = TargetPolicy()) -> tuple[dict, torch.Tensor]:
    """The uncompensated closed-loop row: the target y' projected as is, scored against y'.

    Under ``none`` on the dataset's own test images (``desired`` None) these are the dataset's
    test captures; otherwise y' is projected (the stream of the oracle's first capture, so the
    oracle's 0th row is this one).

    Returns
    -------
    dict
        The scores of :func:`closed_loop_scores` and ``target`` (the policy and its map).
    torch.Tensor
        The captures, float32 (N, 3, H, W).
    """
    y, record = closed_loop_target(data, data.test.frames if desired is None else desired, policy)
    captured = projected_as_is(data, sim, y, desired is None and policy.name == "none")
    return {**closed_loop_scores(captured, y, reachable_mask(data, y)), "target": record}, captured


def iterative_refinement(data: SetupData, sim: Simulator, desired: torch.Tensor | None = None,
                         gain: float = 1.0, report: tuple[int, ...] = (1, 2, 4, 8),
                         policy: TargetPolicy = TargetPolicy(),
                         return_frames: bool = False,
                         progress: bool = False) -> list[dict] | tuple[list[dict], torch.Tensor]:
    """Model-free feedback compensation (Nayar et al. 2003) aiming at the target y': the oracle row.

    Start from x₀ = y'; project xₖ, capture cₖ, correct xₖ₊₁ = clip(xₖ + gain · (y' − cₖ), 0, 1).
    c₀ is the capture of :func:`uncompensated` (the dataset's test capture under ``none`` on its own
    test images).

    Parameters
    ----------
    report : tuple of int
        Numbers of corrections k after which the capture cₖ is scored (0 = y' projected as is).
    policy : TargetPolicy
        How y is mapped to the target y' (:func:`closed_loop_target`).
    return_frames : bool
        Also return the frames xₖ of the last row (where the exact optimum may start).
    progress : bool
        Show a progress bar of the corrections (``<setup> · oracle``).

    Returns
    -------
    list[dict]
        One row per k in ``report``: ``iterations`` (k), the closed-loop scores of cₖ against y'
        (as :func:`closed_loop`'s) and ``projections`` spent so far ((k + 1) per frame).
    torch.Tensor
        Only with ``return_frames``: float32 (N, 3, H, W).
    """
    y, _ = closed_loop_target(data, data.test.frames if desired is None else desired, policy)
    mask = reachable_mask(data, y)
    x = y.clone()
    rows = []
    bar = tqdm(total=max(report), desc=f"{data.name} · oracle", unit="correction", disable=not progress)
    for k in range(max(report) + 1):
        if k == 0:
            captured = projected_as_is(data, sim, y, desired is None and policy.name == "none")
        else:
            captured = project(sim, x, seeds.CLOSED_LOOP + 1 + k)
            bar.update()
        if k in report:
            rows.append({"iterations": k, **closed_loop_scores(captured, y, mask),
                         "projections": int(y.shape[0]) * (k + 1)})
            last = x
        x = (x + gain * (y - captured)).clamp(0, 1)
    bar.close()
    return (rows, last) if return_frames else rows
