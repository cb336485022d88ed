"""Training a compensation method on one setup, the paper's recipe, into a run directory.

A run directory holds::

    config.json    fully resolved TrainConfig, dataset path, versions, device
    loss.csv       iteration, loss, learning rate
    loss.png       the loss curve
    model.pt       weights: a plain state dict (loaded with weights_only=True)
    metrics.json   test PSNR / RMSE / SSIM of π†(x̃) vs x on all test pairs, and uncompensated
    examples.png   rows of s̃, x̃, π†(x̃), x for a few test pairs
"""
from __future__ import annotations

import csv
import json
import math
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, fields, replace
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from compensation.data import SURFACE_NAME, SetupData, load_setup_data, to_tensor
from compensation.losses import LOSSES, get_loss
from compensation.methods import METHODS, Method, get_method, resolve_device
from compensation.metrics import evaluate
from sim.errors import ProcamError
from sim.io import read_png, to_uint8, write_png

PROFILES: dict[str, dict] = {
    # The paper's setting (design.md §7), meant for a GPU.
    "paper": dict(n_train=500, n_test=200, iters=1000, batch=64, size=256),
    # CPU-sized: one setup trains in about two minutes on 2 cores. Measured CompenNet training
    # throughput (forward + backward + Adam, l1+ssim, fp32, torch 2.13 CPU, 2 free cores):
    #   64² (batch 16) ~85-89 samples/s, 128² (batch 16) ~20, 256² (batch 8) ~3.4
    # (one thread on a busy machine: ~52, ~11, ~2.4). 500 iterations x 16 = 8000 samples is
    # ~95 s at 64² but ~400 s at 128², so 64². On the shipped `default` setup rendered at 64²
    # (250 train / 100 test pairs) test PSNR was 22.9 dB after 300 iterations and 24.4 dB after
    # 500 (uncompensated 14.2 dB): still improving, so 500. The learning-rate step keeps the
    # paper's proportion (decay after 80 % of the iterations).
    "quick": dict(n_train=250, n_test=100, iters=500, batch=16, lr_step=400, size=64),
}
"""Named settings: TrainConfig overrides plus ``size``, the canonical square image size (pixels)
the dataset is rendered at for that profile (training itself uses the dataset's size)."""


@dataclass(frozen=True)
class TrainConfig:
    """How to train one method on one setup.

    Attributes
    ----------
    method : str
        Registered method name (``compennet``, ``compennet-nosurf``, …).
    profile : str
        Profile the values came from (``paper`` or ``quick``); recorded only.
    n_train, n_test : int or None
        Use the first n training / test pairs; None uses all of them.
    iters : int
        Optimiser steps.
    batch : int
        Training pairs per step (at most ``n_train`` are used).
    lr : float
        Adam learning rate.
    weight_decay : float
        Adam L2 weight decay.
    lr_step : int
        Multiply the learning rate by ``lr_gamma`` every ``lr_step`` iterations.
    lr_gamma : float
        Learning-rate decay factor.
    loss : str
        Training loss name (``l1``, ``l2``, ``ssim``, ``l1+ssim``).
    seed : int
        Seeds weight initialisation and batch order.
    device : str
        ``auto`` (CUDA if available, else CPU), ``cpu`` or ``cuda[:N]``.
    amp : bool
        Mixed precision (bf16 autocast where supported, else fp16 with a gradient scaler); only
        effective on CUDA — the CPU path is plain fp32 either way.
    init : str or None
        Run directory whose weights initialise the network (pre-training); same architecture.
    eval_batch : int
        Images per forward pass when predicting.
    """

    method: str = "compennet"
    profile: str = "paper"
    n_train: int | None = 500
    n_test: int | None = 200
    iters: int = 1000
    batch: int = 64
    lr: float = 1e-3
    weight_decay: float = 1e-4
    lr_step: int = 800
    lr_gamma: float = 0.2
    loss: str = "l1+ssim"
    seed: int = 0
    device: str = "auto"
    amp: bool = False
    init: str | None = None
    eval_batch: int = 64

    def __post_init__(self):
        if self.method not in METHODS:
            raise ProcamError(f"method {self.method!r}: choose one of {', '.join(sorted(METHODS))}")
        if self.loss not in LOSSES:
            raise ProcamError(f"loss {self.loss!r}: choose one of {', '.join(sorted(LOSSES))}")
        for key in ("iters", "batch", "lr_step", "eval_batch", "n_train", "n_test"):
            value = getattr(self, key)
            if value is not None and (not isinstance(value, int) or value < 1):
                raise ProcamError(f"{key}={value!r}: expected a positive integer")
        for key in ("lr", "lr_gamma"):
            if not getattr(self, key) > 0:
                raise ProcamError(f"{key}={getattr(self, key)!r}: expected a positive number")
        if not self.weight_decay >= 0:
            raise ProcamError(f"weight_decay={self.weight_decay!r}: expected a number >= 0")


def make_config(profile: str = "paper", **overrides) -> TrainConfig:
    """A TrainConfig from a named profile, with keyword overrides (None values are ignored).

    Values are layered: :data:`PROFILES` ``[profile]``, then the method's own profile
    (``Method.profiles[profile]``, e.g. pix2pix's iterations at batch 1), then the overrides.

    Raises
    ------
    ProcamError
        If the profile or an override key is unknown, or a value is out of range.
    """
    if profile not in PROFILES:
        raise ProcamError(f"profile {profile!r}: choose one of {', '.join(PROFILES)}")
    names = {f.name for f in fields(TrainConfig)}
    if unknown := sorted(set(overrides) - names):
        raise ProcamError(f"unknown training option(s) {', '.join(unknown)}; "
                          f"expected some of {', '.join(sorted(names))}")
    values = {k: v for k, v in PROFILES[profile].items() if k in names}
    method = overrides.get("method") or TrainConfig.method
    if method in METHODS:  # an unknown name is reported by TrainConfig
        values.update(METHODS[method].profiles.get(profile, {}))
    values.update({k: v for k, v in overrides.items() if v is not None})
    return TrainConfig(profile=profile, **values)


def batch_indices(n: int, batch: int, generator: torch.Generator):
    """Endless batches of distinct indices in [0, n), drawn without replacement.

    Each epoch is a seeded permutation; a batch that straddles two epochs takes the rest of the
    old one and fills up with indices of the new one that it does not hold yet, so every index
    appears once per epoch and never twice in a batch.

    Parameters
    ----------
    n : int
        Number of samples.
    batch : int
        Batch size, at most ``n``.
    generator : torch.Generator
        Seeded generator of the permutations.

    Yields
    ------
    torch.Tensor
        int64 indices, shape (batch,).
    """
    pool = torch.randperm(n, generator=generator)
    while True:
        if len(pool) >= batch:
            out, pool = pool[:batch], pool[batch:]
        else:
            perm = torch.randperm(n, generator=generator)
            fresh = perm[~torch.isin(perm, pool)][:batch - len(pool)]
            out, pool = torch.cat([pool, fresh]), perm[~torch.isin(perm, fresh)]
        yield out


def _autocast_dtype() -> torch.dtype:
    """Mixed-precision type on CUDA: bf16 where the GPU supports it (no scaler needed), else fp16."""
    return torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16


def fit_network(model: torch.nn.Module, data: SetupData, cfg: TrainConfig, use_surface: bool,
                progress: bool = True) -> dict:
    """Train ``model`` (already on its device) on ``data.train`` with the paper's recipe.

    Adam(lr, weight_decay), StepLR(lr_step, lr_gamma), batches without replacement, loss from
    :func:`compensation.losses.get_loss`; with ``use_surface`` the network's surface branch is fed
    s̃ with batch 1, broadcast over the batch. On CUDA with ``cfg.amp``, autocast plus a gradient scaler
    (fp16 only); on the CPU the amp flag changes nothing.

    Returns
    -------
    dict
        ``seconds``, ``samples_per_second``, ``final_loss`` (mean of the last 10 iterations),
        ``batch`` (effective), ``loss_curve`` (list of (iteration, loss, learning rate)).

    Raises
    ------
    ProcamError
        If the loss becomes NaN or infinite.
    """
    device = next(model.parameters()).device
    use_amp = cfg.amp and device.type == "cuda"
    amp_dtype = _autocast_dtype() if use_amp else torch.float32
    scaler = torch.amp.GradScaler(device.type, enabled=use_amp and amp_dtype == torch.float16)
    optimizer = torch.optim.Adam(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=cfg.lr_step, gamma=cfg.lr_gamma)
    loss_fn = get_loss(cfg.loss)
    captures = data.train.captures.to(device)
    frames = data.train.frames.to(device)
    surface = data.surface.to(device) if use_surface else None
    batch = min(cfg.batch, len(data.train))
    batches = batch_indices(len(data.train), batch, torch.Generator().manual_seed(cfg.seed))
    losses = torch.zeros(cfg.iters, dtype=torch.float64, device=device)
    rates = []

    model.train()
    start = time.perf_counter()
    with tqdm(total=cfg.iters, desc=f"train {cfg.method} on {data.name}", unit="it",
              disable=not progress) as bar:
        for it in range(cfg.iters):
            idx = next(batches).to(device)
            x, y = captures[idx], frames[idx]
            with torch.autocast(device.type, dtype=amp_dtype, enabled=use_amp):
                pred = model(x, surface)
            loss = loss_fn(pred.float(), y)
            optimizer.zero_grad(set_to_none=True)
            scaler.scale(loss).backward()
            scaler.step(optimizer)
            scaler.update()
            rates.append(scheduler.get_last_lr()[0])
            scheduler.step()
            losses[it] = loss.detach()
            bar.update()
            if it % 10 == 9 or it == cfg.iters - 1:
                value = losses[it].item()
                if not math.isfinite(value):
                    raise ProcamError(f"training {cfg.method} diverged at iteration {it + 1} "
                                      f"(loss {value}); try a lower lr")
                rate = (it + 1) * batch / (time.perf_counter() - start)
                bar.set_postfix(loss=f"{value:.4f}", samples_per_s=f"{rate:.1f}")
    seconds = time.perf_counter() - start
    curve = losses.cpu().tolist()
    return {"seconds": seconds, "samples_per_second": cfg.iters * batch / seconds,
            "final_loss": float(np.mean(curve[-10:])), "batch": batch,
            "loss_curve": [(i + 1, loss, lr) for i, (loss, lr) in enumerate(zip(curve, rates))]}


def _package_version() -> str:
    try:
        return version("procam")
    except PackageNotFoundError:
        return "unknown"


def _device_name(device: torch.device) -> str:
    if device.type == "cuda":
        return f"{device} ({torch.cuda.get_device_name(device)})"
    return f"cpu ({torch.get_num_threads()} threads)"


def _write_json(path: Path, data: dict) -> None:
    path.write_text(json.dumps(data, indent=2) + "\n")


def _write_loss(run_dir: Path, curve: list[tuple[int, float, float]], title: str) -> None:
    """``loss.csv`` (iteration, loss, lr) and ``loss.png`` (Agg canvas, no pyplot state)."""
    with open(run_dir / "loss.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["iteration", "loss", "lr"])
        writer.writerows((i, f"{loss:.6g}", f"{lr:.6g}") for i, loss, lr in curve)
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
    fig.tight_layout()
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


def _check_out_dir(out_dir: Path, overwrite: bool) -> None:
    if out_dir.exists() and not overwrite:
        what = "a finished run" if (out_dir / "metrics.json").exists() else "a folder that is not a run"
        raise ProcamError(f"{out_dir}: {what} already exists; choose another output or pass overwrite")
    if out_dir.exists() and not (out_dir / "metrics.json").exists():
        raise ProcamError(f"{out_dir}: exists and is not a run directory (no metrics.json); "
                          "refusing to replace it")


def train_run(setup_dir: str | Path, cfg: TrainConfig, out_dir: str | Path, progress: bool = True,
              overwrite: bool = False) -> dict:
    """Train ``cfg.method`` on a setup, evaluate on all its test pairs and write a run directory.

    The run is written into ``<out_dir>.tmp-XXXX`` and renamed into place at the end, so an
    interrupted run never looks finished.

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

    Returns
    -------
    dict
        The contents of ``metrics.json``: ``method``, ``setup``, ``psnr`` (dB), ``rmse``,
        ``ssim`` of π†(x̃) vs x, ``uncompensated`` (the same for x̃ vs x), ``train_seconds``,
        ``samples_per_second``, ``final_loss``, ``n_train``, ``n_test``, ``iters``, ``batch``.

    Raises
    ------
    ProcamError
        If the output exists (and ``overwrite`` is not set, or it is not a run), the dataset is
        incomplete (DatasetError), or ``cfg.init`` does not fit the method.
    """
    setup_dir, out_dir = Path(setup_dir), Path(out_dir)
    _check_out_dir(out_dir, overwrite)
    device = resolve_device(cfg.device)
    data = load_setup_data(setup_dir, cfg.n_train, cfg.n_test)
    resolved = replace(cfg, n_train=len(data.train), n_test=len(data.test), device=str(device),
                       init=str(Path(cfg.init).resolve()) if cfg.init else None)
    method = get_method(cfg.method)()
    stats = method.fit(data, resolved, progress)
    predicted = method.predict(data.test.captures, data.surface, batch_size=cfg.eval_batch)
    scores = evaluate(predicted, data.test.frames, batch_size=cfg.eval_batch)
    plain = evaluate(data.test.captures, data.test.frames, batch_size=cfg.eval_batch)
    metrics = {"method": cfg.method, "setup": data.name,
               **{k: float(scores[k]) for k in ("psnr", "rmse", "ssim")},
               "uncompensated": {k: float(plain[k]) for k in ("psnr", "rmse", "ssim")},
               "train_seconds": round(stats["seconds"], 3),
               "samples_per_second": round(stats["samples_per_second"], 3),
               "final_loss": stats["final_loss"], "n_train": len(data.train),
               "n_test": len(data.test), "iters": cfg.iters, "batch": stats["batch"]}
    config = {"train": asdict(resolved), "dataset": str(setup_dir.resolve()), "setup": data.name,
              "image_size": list(data.size), "procam_version": _package_version(),
              "torch_version": torch.__version__, "device": _device_name(device)}

    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f"{out_dir.name}.tmp-", dir=out_dir.parent))
    try:
        _write_json(tmp / "config.json", config)
        _write_loss(tmp, stats["loss_curve"], f"{cfg.method} on {data.name}")
        method.save(tmp)
        write_png(tmp / "examples.png", example_grid(data.surface, data.test.captures, predicted,
                                                     data.test.frames))
        _write_json(tmp / "metrics.json", metrics)
        if out_dir.exists():
            _check_out_dir(out_dir, overwrite)
            old = Path(tempfile.mkdtemp(prefix=f"{out_dir.name}.old-", dir=out_dir.parent))
            out_dir.rename(old / "run")
            tmp.rename(out_dir)
            shutil.rmtree(old)
        else:
            tmp.rename(out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return metrics


def load_run(run_dir: str | Path, device: str = "auto") -> tuple[Method, dict]:
    """The fitted method of a run directory and its ``config.json``.

    Raises
    ------
    ProcamError
        If the folder, its config or its checkpoint is missing or unreadable, or the method is
        unknown.
    """
    run_dir = Path(run_dir)
    config_file = run_dir / "config.json"
    if not config_file.exists():
        raise ProcamError(f"{run_dir}: not a run directory (no config.json)")
    try:
        config = json.loads(config_file.read_text())
        name = config["train"]["method"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ProcamError(f"{config_file}: cannot read the run's method ({exc!r})") from None
    try:
        cls = get_method(name)
    except ValueError as exc:
        raise ProcamError(f"{config_file}: {exc}") from None
    return cls.load(run_dir, device), config


def compensate(run_dir: str | Path, desired: torch.Tensor, surface: torch.Tensor | None = None,
               device: str = "auto") -> torch.Tensor:
    """Projector frames x* = π†(y) that make the setup of a trained run show ``desired`` y.

    Parameters
    ----------
    run_dir : path-like
        A run directory written by :func:`train_run`.
    desired : torch.Tensor
        Desired appearance in the canonical projector view, float32 (N, 3, H, W) in [0, 1].
    surface : torch.Tensor, optional
        Surface image s̃ (1, 3, H, W); defaults to the s̃ of the dataset the run was trained on.
    device : str
        Torch device for the network.

    Returns
    -------
    torch.Tensor
        float32 (N, 3, H, W) in [0, 1], on the CPU.

    Raises
    ------
    ProcamError
        If the run is unreadable, the default surface image is gone, or the shapes do not fit.
    """
    method, config = load_run(run_dir, device)
    if surface is None:
        path = Path(config["dataset"]) / "cam" / "warp" / "ref" / SURFACE_NAME
        if not path.exists():
            raise ProcamError(f"{path}: the surface image of the dataset run {run_dir} was trained "
                              "on is gone; pass a surface image")
        surface = to_tensor(read_png(path)[None])
    if desired.ndim != 4 or desired.shape[1] != 3:
        raise ProcamError(f"desired images: expected shape (N, 3, H, W), got {tuple(desired.shape)}")
    if surface.ndim != 4 or surface.shape[:2] != (1, 3) or surface.shape[-2:] != desired.shape[-2:]:
        raise ProcamError(f"surface image: expected shape (1, 3, {desired.shape[2]}, {desired.shape[3]}) "
                          f"to match the desired images, got {tuple(surface.shape)}")
    if desired.shape[2] % 4 or desired.shape[3] % 4:
        raise ProcamError(f"desired images: {desired.shape[3]}x{desired.shape[2]} pixels; width and "
                          "height must be divisible by 4")
    return method.predict(desired.float(), surface.float(), batch_size=config["train"]["eval_batch"])
