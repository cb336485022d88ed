"""The one training loop of every network method: batches, progress, divergence checks, timing.

A method supplies a *step*: given the indices of this iteration's batch it updates its networks
and returns the iteration's loss values (a 1-D tensor, the first being the one reported). The loop
draws the batches (:func:`batch_indices`), records the values, stops with a clear error when one
becomes NaN or infinite, shows a progress bar and times the whole fit.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import torch
from tqdm import tqdm

from compensation.evaluation.losses import get_loss
from sim.errors import ProcamError

if TYPE_CHECKING:
    from compensation.data import SetupData
    from compensation.training.config import TrainConfig

CHECK_EVERY = 10
"""Iterations between divergence checks (each check synchronises with the device)."""


def batch_indices(n: int, batch: int, generator: torch.Generator) -> Iterator[torch.Tensor]:
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

    Examples
    --------
    >>> batches = batch_indices(5, 2, torch.Generator().manual_seed(0))
    >>> seen = torch.cat([next(batches) for _ in range(5)])  # two epochs of 5
    >>> sorted(seen[:5].tolist()), sorted(seen[5:].tolist())
    ([0, 1, 2, 3, 4], [0, 1, 2, 3, 4])
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


@dataclass(frozen=True)
class LoopResult:
    """What :func:`train_loop` measured."""

    seconds: float
    """Wall-clock time of the whole loop."""
    samples_per_second: float
    """Training pairs processed per second (iterations × batch / seconds)."""
    batch: int
    """Effective batch size (at most the number of training pairs)."""
    values: list[list[float]]
    """Per iteration, the values the step returned."""

    @property
    def final_loss(self) -> float:
        """Mean of the first value over the last 10 iterations."""
        return float(np.mean([v[0] for v in self.values[-10:]]))


def train_loop(step: Callable[[torch.Tensor], torch.Tensor], n: int, batch: int, iters: int,
               seed: int, device: torch.device, names: tuple[str, ...], desc: str,
               progress: bool = True) -> LoopResult:
    """Run ``iters`` steps on batches of distinct training indices.

    Parameters
    ----------
    step : callable
        ``step(indices)`` performs one update on the training pairs ``indices`` (on ``device``)
        and returns a detached 1-D tensor of ``len(names)`` loss values.
    n : int
        Number of training pairs.
    batch : int
        Requested batch size; at most ``n`` are used.
    iters : int
        Number of steps.
    seed : int
        Seeds the batch order.
    device : torch.device
        Where the indices (and the recorded values) live.
    names : tuple of str
        Names of the step's values, for the progress bar and error messages.
    desc : str
        Progress-bar label and the subject of a divergence message.
    progress : bool
        Show the progress bar.

    Raises
    ------
    ProcamError
        If a value becomes NaN or infinite (checked every :data:`CHECK_EVERY` iterations).
    """
    batch = min(batch, n)
    batches = batch_indices(n, batch, torch.Generator().manual_seed(seed))
    values = torch.zeros(iters, len(names), dtype=torch.float64, device=device)
    start = time.perf_counter()
    with tqdm(total=iters, desc=desc, unit="it", disable=not progress) as bar:
        for it in range(iters):
            values[it] = step(next(batches).to(device))
            bar.update()
            if it % CHECK_EVERY == CHECK_EVERY - 1 or it == iters - 1:
                current = values[it].tolist()
                if not all(math.isfinite(v) for v in current):
                    shown = ", ".join(f"{k} {v}" for k, v in zip(names, current))
                    raise ProcamError(f"{desc} diverged at iteration {it + 1} ({shown}); try a lower lr")
                rate = (it + 1) * batch / (time.perf_counter() - start)
                bar.set_postfix({names[0]: f"{current[0]:.4f}", "samples_per_s": f"{rate:.1f}"})
    seconds = time.perf_counter() - start
    return LoopResult(seconds, iters * batch / seconds, batch, values.cpu().tolist())


def _autocast_dtype() -> torch.dtype:
    """Mixed-precision type on CUDA: bf16 where the GPU supports it (no scaler needed), else fp16."""
    return torch.bfloat16 if torch.cuda.is_bf16_supported() else torch.float16


def fit_network(model: torch.nn.Module, data: SetupData, cfg: TrainConfig, use_surface: bool,
                progress: bool = True) -> dict:
    """Train a CompenNet-style ``model`` (already on its device) on ``data.train``: the paper's recipe.

    Adam(lr, weight_decay), StepLR(lr_step, lr_gamma), batches without replacement, the loss
    named by ``cfg.options.loss``; with ``use_surface`` the network's surface branch is fed s̃ with
    batch 1, broadcast over the batch. On CUDA with ``cfg.options.amp``, autocast plus a gradient
    scaler (fp16 only); on the CPU the amp flag changes nothing.

    Returns
    -------
    dict
        ``seconds``, ``samples_per_second``, ``final_loss`` (mean of the last 10 iterations),
        ``batch`` (effective), ``loss_curve`` (list of (iteration, loss, learning rate)).
    """
    opt = cfg.options
    device = next(model.parameters()).device
    use_amp = opt.amp and device.type == "cuda"
    amp_dtype = _autocast_dtype() if use_amp else torch.float32
    scaler = torch.amp.GradScaler(device.type, enabled=use_amp and amp_dtype == torch.float16)
    optimizer = torch.optim.Adam(model.parameters(), lr=opt.lr, weight_decay=opt.weight_decay)
    scheduler = torch.optim.lr_scheduler.StepLR(optimizer, step_size=opt.lr_step, gamma=opt.lr_gamma)
    loss_fn = get_loss(opt.loss)
    captures = data.train.captures.to(device)
    frames = data.train.frames.to(device)
    surface = data.surface.to(device) if use_surface else None
    rates = []

    def step(idx: torch.Tensor) -> torch.Tensor:
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
        return loss.detach()[None]

    model.train()
    result = train_loop(step, len(data.train), opt.batch, opt.iters, cfg.seed, device, ("loss",),
                        f"train {cfg.method} on {data.name}", progress)
    return {"seconds": result.seconds, "samples_per_second": result.samples_per_second,
            "final_loss": result.final_loss, "batch": result.batch,
            "loss_curve": [(i + 1, v[0], lr) for i, (v, lr) in enumerate(zip(result.values, rates))]}
