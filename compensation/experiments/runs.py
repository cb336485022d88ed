"""Run directories: train a method on one setup, record everything, load it back, compensate (also
with an official CompenNet checkpoint).

A run directory holds::

    config.json    the fully resolved TrainConfig (every option the method used), the dataset path,
                   the image size (width, height), versions, device
    loss.csv       iteration, loss, learning rate
    loss.png       the loss curve
    model.pt       network weights: a plain state dict (loaded with weights_only=True), or the
                   method's own state file (``tps.npz``, ``nayar.npz``)
    metrics.json   test PSNR / RMSE / SSIM / ΔE of π†(x̃) vs x on all test pairs (and each pair's
                   PSNR), and uncompensated
    examples.png   rows of s̃, x̃, π†(x̃), x for a few test pairs
"""
from __future__ import annotations

import csv
import hashlib
import io
import os
import shutil
import subprocess
from dataclasses import replace
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
import torch

from compensation.data import load_setup_data, surface_path, to_tensor
from compensation.experiments.targets import IDENTITY, TargetPolicy, map_record, map_targets
from compensation.experiments.closed_loop import CAPTURES_DIR
from compensation.methods import METHODS, check_config, get_method
from compensation.methods.base import Method, load_state, resolve_device
from compensation.scores.metrics import evaluate, psnr_per_image
from compensation.training.config import NOT_IDENTITY, TrainConfig
from sim.dataset import MAX_SIDE
from sim.errors import DatasetError, ProcamError
from sim.io import (atomic_write, check_output_folder, read_json, read_png, to_float, to_uint8, write_json,
                    write_png)
from sim.layout import N_PLAIN, REF, capture_dir, image_name

CHECKPOINT_FILE = "checkpoint.pt"
"""Training state of an unfinished run, inside its :func:`partial_dir`."""
SCORES = ("psnr", "rmse", "ssim", "deltaE")
"""The scores ``metrics.json`` records (of :func:`~compensation.scores.metrics.evaluate`)."""
SSIM_CONVENTION = "official"
"""The SSIM convention of ``metrics.json`` (recorded there as ``ssim_convention``)."""
_UNCOMPENSATED: dict[tuple, dict[str, float]] = {}
"""Scores of :func:`uncompensated_scores` kept in this process, by the images' digests."""
_UNCOMPENSATED_KEPT = 64
"""At most this many test sets' uncompensated scores are kept (the oldest dropped first)."""


def scores_are_current(metrics: dict) -> bool:
    """Whether a run's ``metrics.json`` holds every score of :data:`SCORES` with SSIM in
    :data:`SSIM_CONVENTION` (runs scored before are not reused by the bench and the demo).

    >>> scores_are_current({"psnr": 20.0, "rmse": 0.2, "ssim": 0.7})
    False
    """
    return metrics.get("ssim_convention") == SSIM_CONVENTION and all(k in metrics for k in SCORES)


def package_version() -> str:
    """The installed procam version (``unknown`` when run from a source tree without install)."""
    try:
        return version("procam")
    except PackageNotFoundError:
        return "unknown"


@cache
def source_revision() -> str:
    """What identifies the code that runs: ``git <commit>`` (``(modified)`` when tracked files
    differ from it) in a git checkout, else ``sha256 <digest>`` of the installed ``sim`` and
    ``compensation`` sources (a version number alone does not tell two builds apart)."""
    import compensation
    import sim

    packages = [Path(sim.__file__).resolve().parent, Path(compensation.__file__).resolve().parent]
    root = packages[0].parent
    if root == packages[1].parent and (root / ".git").exists():
        try:
            git = ["git", "-C", str(root)]
            commit = subprocess.run([*git, "rev-parse", "HEAD"], capture_output=True, text=True,
                                    timeout=30, check=True).stdout.strip()
            changed = subprocess.run([*git, "status", "--porcelain", "--untracked-files=no"],
                                     capture_output=True, text=True, timeout=30, check=True).stdout.strip()
            return f"git {commit}" + (" (modified)" if changed else "")
        except (OSError, subprocess.SubprocessError):
            pass  # no git: the sources' digest
    digest = hashlib.sha256()
    for package in packages:
        for path in sorted(package.rglob("*.py")):
            digest.update(f"{package.name}/{path.relative_to(package)}\n".encode())
            digest.update(path.read_bytes())
    return f"sha256 {digest.hexdigest()[:16]}"


def _digest(images: torch.Tensor) -> tuple:
    """A tensor's shape, dtype and a digest of its values (a key for its content)."""
    values = images.detach().cpu().contiguous().numpy()
    return values.shape, str(values.dtype), hashlib.blake2b(values, digest_size=16).hexdigest()


def uncompensated_scores(captures: torch.Tensor, frames: torch.Tensor, batch_size: int = 64) -> dict[str, float]:
    """The uncompensated scores: :func:`~compensation.scores.metrics.evaluate` of the test
    captures x̃ against their projector inputs x under :data:`SSIM_CONVENTION`, computed once per
    process for the same images (every run on a dataset and its baseline job score the same test
    set; a copy is returned).

    Examples
    --------
    >>> x = torch.zeros(2, 3, 16, 16)
    >>> y = torch.full((2, 3, 16, 16), 0.5)
    >>> uncompensated_scores(x, y) == evaluate(x, y, convention=SSIM_CONVENTION)
    True
    """
    key = (_digest(captures), _digest(frames), batch_size)
    if key not in _UNCOMPENSATED:
        while len(_UNCOMPENSATED) >= _UNCOMPENSATED_KEPT:
            del _UNCOMPENSATED[next(iter(_UNCOMPENSATED))]
        _UNCOMPENSATED[key] = evaluate(captures, frames, batch_size, SSIM_CONVENTION)
    return dict(_UNCOMPENSATED[key])


def _device_name(device: torch.device) -> str:
    if device.type == "cuda":
        return f"{device} ({torch.cuda.get_device_name(device)})"
    return f"cpu ({torch.get_num_threads()} threads)"


def _write_loss(run_dir: Path, curve: list[tuple[int, float, float]], title: str) -> None:
    """``loss.csv`` (iteration, loss, lr) and ``loss.png`` (Agg canvas, no pyplot state; fixed
    margins, which fit the labels of a 6×4 in figure and take half the time of a computed layout)."""
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(["iteration", "loss", "lr"])
    writer.writerows((i, f"{loss:.6g}", f"{lr:.6g}") for i, loss, lr in curve)
    atomic_write(run_dir / "loss.csv", text.getvalue())
    from matplotlib.figure import Figure

    fig = Figure(figsize=(6, 4), dpi=100)
    ax = fig.add_subplot()
    its, values = [c[0] for c in curve], [c[1] for c in curve]
    ax.plot(its, values, lw=0.8)
    ax.set_xlabel("iteration")
    ax.set_ylabel("training loss")
    ax.set_yscale("log")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    fig.subplots_adjust(left=0.12, right=0.97, bottom=0.12, top=0.92)
    fig.savefig(run_dir / "loss.png")


def example_grid(surface: torch.Tensor, captures: torch.Tensor, predicted: torch.Tensor,
                 frames: torch.Tensor, rows: int = 4, gap: int = 2, min_size: int = 128) -> np.ndarray:
    """Image grid, one row per test pair: s̃ | x̃ | π†(x̃) | x, separated by white gaps.

    Images smaller than ``min_size`` pixels are enlarged by an integer factor (nearest neighbour).

    Returns
    -------
    numpy.ndarray
        uint8 (H', W', 3).
    """
    n = min(rows, captures.shape[0])
    scale = max(1, min_size // min(captures.shape[-2:]))
    surface, captures, predicted, frames = (
        t[:n].repeat_interleave(scale, -2).repeat_interleave(scale, -1)
        for t in (surface, captures, predicted, frames))
    h, w = captures.shape[-2:]
    grid = np.ones((n * (h + gap) - gap, 4 * (w + gap) - gap, 3), np.float32)
    for r in range(n):
        for c, img in enumerate((surface[0], captures[r], predicted[r], frames[r])):
            grid[r * (h + gap):r * (h + gap) + h, c * (w + gap):c * (w + gap) + w] = \
                img.permute(1, 2, 0).numpy()
    return to_uint8(grid)


RUN_ENTRIES = ("config.json", "loss.csv", "loss.png", "metrics.json", "examples.png", CHECKPOINT_FILE,
               CAPTURES_DIR)
"""What a run directory holds besides its method's state file (``Method.state_file``)."""


def _check_out_dir(out_dir: Path, overwrite: bool) -> None:
    """Refuse an output that is not a run this command may replace: a file, a finished run without
    ``overwrite``, a folder that is not a run, or a run folder holding anything a run does not
    write (the user's own files are never deleted), or a symbolic link (replacing the link would
    leave its target as it was and the run beside it)."""
    if out_dir.is_symlink():
        raise ProcamError(f"{out_dir}: is a symbolic link (to {os.readlink(out_dir)}); give the folder "
                          "itself as the output")
    if out_dir.exists() and not out_dir.is_dir():
        raise ProcamError(f"{out_dir}: exists and is a file; a run directory is a folder")
    if out_dir.exists() and not overwrite:
        what = "a finished run" if (out_dir / "metrics.json").exists() else "a folder that is not a run"
        raise ProcamError(f"{out_dir}: {what} already exists; choose another output or pass overwrite")
    if out_dir.exists() and not (out_dir / "metrics.json").exists():
        raise ProcamError(f"{out_dir}: exists and is not a run directory (no metrics.json); "
                          "refusing to replace it")
    check_output_folder(out_dir, (*RUN_ENTRIES, *(m.state_file for m in METHODS.values())), "run")


def partial_dir(out_dir: Path) -> Path:
    """Where a run is built before it is renamed into place: ``.<name>.partial`` beside it.

    It holds the run's ``config.json`` and, while a network trains, ``checkpoint.pt``; a run
    started again with the same configuration resumes from it, another configuration replaces it.
    """
    return out_dir.parent / f".{out_dir.name}.partial"


def _identity(config: dict) -> dict:
    """What makes a partial run's ``config.json`` the same run: all of it but the device's name
    (its thread count) and the training options of ``NOT_IDENTITY``, except the device's type
    (``train.device``): a training state resumes only on the kind of device that saved it."""
    train = config.get("train")
    if isinstance(train, dict):
        train = {k: v for k, v in train.items() if k == "device" or k not in NOT_IDENTITY}
    return {**{k: v for k, v in config.items() if k != "device"}, "train": train}


def _prepare_partial(partial: Path, config: dict) -> Path:
    """The checkpoint path inside a fresh or resumable ``partial`` folder holding ``config``."""
    if partial.exists():
        try:
            old = read_json(partial / "config.json", "run configuration")
            same = _identity(old) == _identity(config)
        except (ProcamError, AttributeError):  # unreadable, or not a run configuration
            same = False
        if not same:
            shutil.rmtree(partial)
    partial.mkdir(parents=True, exist_ok=True)
    write_json(partial / "config.json", config)
    return partial / CHECKPOINT_FILE


def train_run(setup_dir: str | Path, cfg: TrainConfig, out_dir: str | Path, progress: bool = True,
              overwrite: bool = False, return_predicted: bool = False) -> dict | tuple[dict, torch.Tensor]:
    """Train ``cfg.method`` on a setup, evaluate on all its test pairs and write a run directory.

    The run is built in :func:`partial_dir` and renamed into place at the end, so an interrupted
    run never looks finished; run again with the same configuration, it resumes from its last
    training checkpoint (bit-identical to an uninterrupted run on the CPU).

    Parameters
    ----------
    setup_dir : path-like
        ``DATA_ROOT/<setup>`` (a finished setup).
    cfg : TrainConfig
        Training configuration.
    out_dir : path-like
        Run directory to create.
    progress : bool
        Show a progress bar with the loss and samples per second.
    overwrite : bool
        Replace an existing finished run at ``out_dir``.
    return_predicted : bool
        Also return the run's π†(x̃) of the test captures, (N, 3, H, W) in [0, 1].

    Returns
    -------
    dict
        The contents of ``metrics.json``: ``method``, ``setup``, ``psnr`` (dB), ``rmse``,
        ``ssim``, ``deltaE`` of π†(x̃) vs x, ``ssim_convention``, ``psnr_per_image`` (each test
        pair's PSNR), ``uncompensated`` (the same
        scores for x̃ vs x), ``train_seconds``,
        ``samples_per_second``, ``final_loss``, ``n_train``, ``n_test``, ``iters``, ``batch``;
        with ``return_predicted``, the pair (metrics, π†(x̃)).

    Raises
    ------
    ProcamError
        If the output exists (and ``overwrite`` is not set, or it is not a run), holds the weights
        ``init`` names, its folder cannot be written, the dataset is incomplete (DatasetError),
        ``init`` does not fit the method, or training is interrupted (its state is kept for a
        resume).
    """
    setup_dir, out_dir = Path(setup_dir), Path(out_dir)
    check_config(cfg)
    _check_out_dir(out_dir, overwrite)
    init = getattr(cfg.options, "init", None)
    if init and out_dir.resolve() in (Path(init).resolve(), *Path(init).resolve().parents):
        raise ProcamError(f"{out_dir}: holds the weights option init = {init} starts from, which "
                          "replacing the run would delete; choose another output")
    device = resolve_device(cfg.device)
    data = load_setup_data(setup_dir, cfg.n_train, cfg.n_test)
    options = cfg.options
    if getattr(options, "init", None):
        options = replace(options, init=str(Path(options.init).resolve()))
    resolved = replace(cfg, n_train=len(data.train), n_test=len(data.test), device=str(device),
                       options=options)
    height, width = data.size
    config = {"train": resolved.to_dict(), "dataset": str(setup_dir.resolve()), "setup": data.name,
              "image_size": {"width": width, "height": height}, "procam_version": package_version(),
              "torch_version": torch.__version__, "device": _device_name(device)}
    partial = partial_dir(out_dir)
    try:
        checkpoint = _prepare_partial(partial, config)
    except OSError as exc:
        raise ProcamError(f"{partial}: cannot write the run there ({exc.strerror or exc})") from None

    method = get_method(cfg.method)()
    stats = method.fit(data, resolved, progress, checkpoint)
    predicted = method.predict(data.test.captures, data.surface, batch_size=cfg.eval_batch)
    scores = evaluate(predicted, data.test.frames, cfg.eval_batch, SSIM_CONVENTION)
    plain = uncompensated_scores(data.test.captures, data.test.frames, cfg.eval_batch)
    metrics = {"method": cfg.method, "setup": data.name,
               **{k: float(scores[k]) for k in SCORES}, "ssim_convention": SSIM_CONVENTION,
               "psnr_per_image": psnr_per_image(predicted, data.test.frames),
               "uncompensated": {k: float(plain[k]) for k in SCORES},
               "train_seconds": round(stats.seconds, 3),
               "samples_per_second": round(stats.samples_per_second, 3),
               "final_loss": stats.final_loss, "n_train": len(data.train),
               "n_test": len(data.test), "iters": getattr(cfg.options, "iters", 1),
               "batch": stats.batch}
    try:
        _write_loss(partial, stats.loss_curve, f"{cfg.method} on {data.name}")
        method.save(partial)
        write_png(partial / "examples.png", example_grid(data.surface, data.test.captures, predicted,
                                                         data.test.frames))
        write_json(partial / "metrics.json", metrics)
        if out_dir.exists():
            _check_out_dir(out_dir, overwrite)
            old = out_dir.parent / f".{out_dir.name}.old"
            if old.is_symlink():  # left by a run that failed here: only ever the run's own folder
                old.unlink()
            shutil.rmtree(old, ignore_errors=True)
            out_dir.rename(old)
            partial.rename(out_dir)
            shutil.rmtree(old)
        else:
            partial.rename(out_dir)
        (out_dir / CHECKPOINT_FILE).unlink(missing_ok=True)
    except OSError as exc:
        raise ProcamError(f"{exc.filename or out_dir}: cannot write the run ({exc.strerror or exc}); "
                          f"the training state is kept in {partial}: run the same command again "
                          "to finish without training again") from None
    return (metrics, predicted) if return_predicted else metrics


def read_run_config(run_dir: str | Path) -> dict:
    """A run directory's ``config.json``, checked for the keys a run is loaded by (method, size).

    Raises
    ------
    ProcamError
        If the folder or its config is missing or unreadable, a key is missing, or the method is
        unknown; the message names the file and the key.
    """
    run_dir = Path(run_dir)
    config_file = run_dir / "config.json"
    if not config_file.exists():
        raise ProcamError(f"{run_dir}: not a run directory (no config.json)")
    config = read_json(config_file, "run configuration")
    try:
        get_method(config["train"]["method"])
        run_size(config)
    except (KeyError, TypeError) as exc:
        raise ProcamError(f"{config_file}: missing or malformed key {exc}") from None
    except ProcamError as exc:
        raise ProcamError(f"{config_file}: {exc}") from None
    return config


def load_run(run_dir: str | Path, device: str = "auto") -> tuple[Method, dict]:
    """The fitted method of a run directory and its ``config.json`` (:func:`read_run_config`),
    predicting as it did when trained (the recorded options handed to
    :meth:`~compensation.methods.base.Method.adopt_options`).

    Raises
    ------
    ProcamError
        If the config is unreadable (:func:`read_run_config`), its ``train.options`` is not an
        object or holds a value the method cannot predict with, or the checkpoint is missing or
        unreadable.
    """
    config = read_run_config(run_dir)
    config_file = Path(run_dir) / "config.json"
    recorded = config["train"].get("options") or {}  # runs of older versions may record none
    if not isinstance(recorded, dict):
        raise ProcamError(f"{config_file}: train.options = {recorded!r}: expected an object of "
                          "the method's options")
    method = get_method(config["train"]["method"]).load(Path(run_dir), device)
    try:
        method.adopt_options(recorded)
    except ProcamError as exc:
        raise ProcamError(f"{config_file}: {exc}") from None
    return method, config


def run_size(config: dict) -> tuple[int, int]:
    """(width, height) in pixels of the images a run was trained on, from its ``config.json``.

    Raises
    ------
    KeyError
        If ``image_size`` is missing.
    ProcamError
        If it is not an object whose ``width`` and ``height`` are integers from 1 to
        :data:`~sim.dataset.MAX_SIDE` (the sizes a dataset is rendered at): checked before an
        image is resized to it.
    """
    size = config["image_size"]
    sides = (size.get("width"), size.get("height")) if isinstance(size, dict) else ()
    if not sides or not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= MAX_SIDE
                            for v in sides):
        raise ProcamError(f"image_size = {size!r}: expected a width and height in pixels, each an "
                          f"integer from 1 to {MAX_SIDE}")
    return sides


def load_checkpoint(path: str | Path, device: str = "auto") -> Method:
    """A fitted CompenNet from a state dict file alone (``.pth``, e.g. an official checkpoint, with
    or without DataParallel's ``module.`` prefix): with the surface branch when the file holds its
    weights (``conv1_s`` …), else CompenNet w/o surf.

    Raises
    ------
    ProcamError
        If the file is missing, unreadable or not a CompenNet state dict.
    """
    state = load_state(Path(path))
    name = "compennet" if "conv1_s.weight" in state else "compennet-nosurf"
    return get_method(name).from_weights(Path(path), device)


def compensate(source: str | Path, desired: torch.Tensor, surface: torch.Tensor | None = None,
               device: str = "auto") -> torch.Tensor:
    """Projector frames x* = π†(y) that make the setup of a trained model show ``desired`` y.

    Parameters
    ----------
    source : path-like
        A run directory written by :func:`train_run`, or a CompenNet state dict file (``.pth``,
        :func:`load_checkpoint`).
    desired : torch.Tensor
        Desired appearance in the canonical projector view, float32 (N, 3, H, W) in [0, 1].
    surface : torch.Tensor, optional
        Surface image s̃ (1, 3, H, W); for a run, defaults to the s̃ of the dataset it was trained
        on; required for a state dict file.
    device : str
        Torch device for the network.

    Returns
    -------
    torch.Tensor
        float32 (N, 3, H, W) in [0, 1], on the CPU.

    Raises
    ------
    ProcamError
        If the run or file is unreadable, the surface image is missing or gone, or the shapes do
        not fit.
    """
    source = Path(source)
    if source.is_file():
        if surface is None:
            raise ProcamError(f"{source}: a state dict file holds no surface image; pass the surface "
                              "image s̃ (the capture of the gray frame)")
        method, batch = load_checkpoint(source, device), 64
    else:
        method, config = load_run(source, device)
        batch = config["train"].get("eval_batch", 64)
    if surface is None:
        try:
            path = surface_path(Path(config["dataset"]))
        except DatasetError as exc:
            raise ProcamError(f"{exc}: the surface image of the dataset run {source} was trained "
                              "on is gone; pass a surface image") from None
        surface = to_tensor(read_png(path)[None])
    if desired.ndim != 4 or desired.shape[1] != 3:
        raise ProcamError(f"desired images: expected shape (N, 3, H, W), got {tuple(desired.shape)}")
    if surface.ndim != 4 or surface.shape[:2] != (1, 3) or surface.shape[-2:] != desired.shape[-2:]:
        raise ProcamError(f"surface image: expected shape (1, 3, {desired.shape[2]}, {desired.shape[3]}) "
                          f"to match the desired images, got {tuple(surface.shape)}")
    if desired.shape[2] % 4 or desired.shape[3] % 4:
        raise ProcamError(f"desired images: {desired.shape[3]}x{desired.shape[2]} pixels; width and "
                          "height must be divisible by 4")
    return method.predict(desired.float(), surface.float(), batch_size=batch)


def compensation_target(source: str | Path, desired: torch.Tensor,
                        policy: TargetPolicy) -> tuple[torch.Tensor, dict]:
    """The targets y' to compensate instead of ``desired`` y under ``policy``, from the captures of
    the black and white plain frames of the dataset the run ``source`` was trained on, and their
    record (:func:`~compensation.experiments.targets.map_record`).

    Parameters
    ----------
    source : path-like
        A run directory (a state dict file holds no dataset: only the policy ``none``).
    desired : torch.Tensor
        y, float32 (N, 3, H, W) in [0, 1], at the run's size.

    Raises
    ------
    ProcamError
        If the policy needs the dataset and ``source`` is a state dict file or its dataset is gone,
        or no map keeps enough pixels in reach.
    """
    if policy.name == "none":
        return desired, map_record(policy, [IDENTITY] * len(desired))
    if Path(source).is_file():
        raise ProcamError(f"{source}: a state dict file holds no dataset, whose black and white "
                          f"captures the target policy {policy.name!r} needs; use --target-policy none")
    ref = capture_dir(Path(read_run_config(source)["dataset"]), REF)
    try:
        black, white = (to_float(read_png(ref / image_name(i))).transpose(2, 0, 1) for i in (1, N_PLAIN))
    except (OSError, ProcamError) as exc:
        raise ProcamError(f"{ref}: the black and white captures the target policy {policy.name!r} "
                          f"needs are not readable ({exc})") from None
    if black.shape[1:] != tuple(desired.shape[2:]):
        raise ProcamError(f"{ref}: captures of {black.shape[2]}x{black.shape[1]} pixels, desired images "
                          f"of {desired.shape[3]}x{desired.shape[2]}")
    target, record = map_targets(policy, desired.double().numpy(), black.astype(np.float64),
                                 white.astype(np.float64))
    return torch.from_numpy(target).float(), record
