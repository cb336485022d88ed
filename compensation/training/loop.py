"""The one generic training loop of every network method: batches, progress, divergence checks,
timing, checkpoints. It knows no method: each method's recipe (optimiser, loss, what a step does)
lives with the method and hands the loop its *step*.

A method supplies a *step*: given the indices of this iteration's batch it updates its networks
and returns the iteration's loss values (a 1-D tensor, the first being the one reported). The loop
draws the batches (:class:`BatchSampler`), records the values, stops with a clear error when one
becomes NaN or infinite, shows a progress bar, times the whole fit, and checkpoints so that a
killed or interrupted fit resumes bit for bit. While it runs, freed memory stays in the process's
heap for the next step (:func:`sim.heap.retained_heap`): the steps allocate the same large arrays
again and again.
"""
from __future__ import annotations

import io
import math
import pickle
import signal
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from compensation.training.config import CHECKPOINT_EVERY
from sim.errors import ProcamError
from sim.heap import retained_heap
from sim.io import atomic_write

CHECK_EVERY = 10
"""Iterations between divergence checks (each check synchronises with the device)."""


class BatchSampler:
    """Endless batches of distinct indices in [0, n); checkpointable.

    ``epoch`` mode: each epoch is a seeded permutation; a batch that straddles two epochs takes
    the rest of the old one and fills up with indices of the new one that it does not hold yet,
    so every index appears once per epoch and never twice in a batch. ``random`` mode: every
    batch is a fresh random draw of distinct indices (the official CompenNet code's sampler).

    Parameters
    ----------
    n : int
        Number of samples.
    batch : int
        Batch size, at most ``n``.
    seed : int
        Seed of the permutations.
    mode : {"epoch", "random"}
        How batches are drawn.

    Examples
    --------
    >>> batches = BatchSampler(5, 2, seed=0)
    >>> seen = torch.cat([next(batches) for _ in range(5)])  # two epochs of 5
    >>> sorted(seen[:5].tolist()), sorted(seen[5:].tolist())
    ([0, 1, 2, 3, 4], [0, 1, 2, 3, 4])
    >>> again = BatchSampler(5, 2, seed=0)
    >>> again.load_state_dict(batches.state_dict())
    >>> torch.equal(next(again), next(batches))
    True
    """

    def __init__(self, n: int, batch: int, seed: int, mode: str = "epoch"):
        if mode not in ("epoch", "random"):
            raise ValueError(f"sampler mode {mode!r}: expected 'epoch' or 'random'")
        self.n, self.batch, self.mode = n, batch, mode
        self.generator = torch.Generator().manual_seed(seed)
        self.pool = torch.randperm(n, generator=self.generator)

    def __iter__(self) -> Iterator[torch.Tensor]:
        return self

    def __next__(self) -> torch.Tensor:
        """The next batch: int64 indices, shape (batch,)."""
        if self.mode == "random":
            return torch.randperm(self.n, generator=self.generator)[:self.batch]
        if len(self.pool) >= self.batch:
            out, self.pool = self.pool[:self.batch], self.pool[self.batch:]
        else:
            perm = torch.randperm(self.n, generator=self.generator)
            fresh = perm[~torch.isin(perm, self.pool)][:self.batch - len(self.pool)]
            out, self.pool = torch.cat([self.pool, fresh]), perm[~torch.isin(perm, fresh)]
        return out

    def state_dict(self) -> dict:
        """The generator state and the rest of the current epoch."""
        return {"generator": self.generator.get_state(), "pool": self.pool.clone()}

    def load_state_dict(self, state: dict) -> None:
        """Continue exactly where :meth:`state_dict` was taken."""
        self.generator.set_state(state["generator"])
        self.pool = state["pool"].clone()


CROP_STREAM = 1
"""Second seed word of the crop windows of patch training (the first is the training seed), so
that they never share a random state with the batch order."""


class CropSampler:
    """Endless random square windows of one side inside an image, seeded; checkpointable.

    Every window lies fully inside the image and every position is equally likely. Patch
    training cuts the same window out of the captures, the frames and the surface of a batch, so
    the pixel correspondence between them is kept.

    Parameters
    ----------
    height, width : int
        Image size in pixels.
    side : int
        Window side in pixels, at most ``min(height, width)``.
    seed : int
        The training seed (combined with :data:`CROP_STREAM`).

    Examples
    --------
    >>> crops = CropSampler(8, 12, 4, seed=0)
    >>> windows = [next(crops) for _ in range(100)]
    >>> all(0 <= top <= 4 and 0 <= left <= 8 for top, left in windows)
    True
    >>> again = CropSampler(8, 12, 4, seed=0)
    >>> [next(again) for _ in range(100)] == windows
    True
    """

    def __init__(self, height: int, width: int, side: int, seed: int):
        if not 1 <= side <= min(height, width):
            raise ValueError(f"crop side {side}: expected 1 to {min(height, width)} pixels for "
                             f"{width}x{height} (W x H) images")
        self.height, self.width, self.side = height, width, side
        words = np.random.SeedSequence([seed, CROP_STREAM]).generate_state(2, np.uint32)
        self.generator = torch.Generator().manual_seed(int(words[0]) << 32 | int(words[1]))

    def __iter__(self) -> Iterator[tuple[int, int]]:
        return self

    def __next__(self) -> tuple[int, int]:
        """The next window's (top, left) corner in pixels."""
        top = torch.randint(self.height - self.side + 1, (), generator=self.generator)
        left = torch.randint(self.width - self.side + 1, (), generator=self.generator)
        return int(top), int(left)

    def state_dict(self) -> dict:
        """The generator state."""
        return {"generator": self.generator.get_state()}

    def load_state_dict(self, state: dict) -> None:
        """Continue exactly where :meth:`state_dict` was taken."""
        self.generator.set_state(state["generator"])


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


class TrainingInterrupted(ProcamError):
    """Training stopped by SIGINT/SIGTERM (its state saved when a checkpoint path was given)."""


class _Interrupt:
    """Turns SIGINT/SIGTERM into a flag the loop checks after each step (main thread only)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM)

    def __init__(self):
        self.signum: int | None = None
        self._previous = {}

    def __enter__(self) -> _Interrupt:
        if threading.current_thread() is threading.main_thread():
            for sig in self.SIGNALS:
                self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum, frame) -> None:
        self.signum = signum

    def __exit__(self, *exc) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)


def _save_checkpoint(path: Path, it: int, values: torch.Tensor, sampler: BatchSampler,
                     stateful: dict, seconds: float) -> None:
    """Everything needed to continue bit for bit after iteration ``it`` (atomic ``torch.save``)."""
    state = {"iteration": it, "values": values[:it].cpu(), "sampler": sampler.state_dict(),
             "rng": torch.get_rng_state(), "seconds": seconds,
             "states": {k: v.state_dict() for k, v in stateful.items()}}
    if torch.cuda.is_available():
        state["cuda_rng"] = torch.cuda.get_rng_state_all()
    buffer = io.BytesIO()
    torch.save(state, buffer)
    atomic_write(path, buffer.getvalue())


def _load_checkpoint(path: Path, values: torch.Tensor, sampler: BatchSampler, stateful: dict) -> tuple[int, float]:
    """Restore a checkpoint of :func:`_save_checkpoint`; returns (iterations done, seconds spent).

    Raises
    ------
    ProcamError
        If the file cannot be read or does not fit this training (other networks, more
        iterations than asked for).
    """
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
        it = int(state["iteration"])
        if it > values.shape[0] or state["values"].shape[1] != values.shape[1]:
            raise ValueError(f"it holds {it} iterations of {state['values'].shape[1]} values")
        values[:it] = state["values"].to(values.device)
        sampler.load_state_dict(state["sampler"])
        for k, v in stateful.items():
            v.load_state_dict(state["states"][k])
        torch.set_rng_state(state["rng"])
        if "cuda_rng" in state and torch.cuda.is_available():
            torch.cuda.set_rng_state_all(state["cuda_rng"])
    except (OSError, RuntimeError, KeyError, ValueError, TypeError, pickle.UnpicklingError) as exc:
        raise ProcamError(f"{path}: cannot resume from this training checkpoint ({exc}); delete it "
                          "to start again") from None
    return it, float(state["seconds"])


def fit_label(setup: str, method: str, seed: int, n_train: int) -> str:
    """The label of a fit's progress bar and of its messages: the setup, method, training pairs and
    seed it works for (a study over the training pairs fits one setup at several sizes).

    >>> fit_label("light1_pos1_squares", "compennet", 0, 125)
    'light1_pos1_squares · compennet · 125 pairs · seed 0 · fit'
    """
    return f"{setup} · {method} · {n_train} pairs · seed {seed} · fit"


def train_loop(step: Callable[[torch.Tensor], torch.Tensor], n: int, batch: int, iters: int,
               seed: int, device: torch.device, names: tuple[str, ...], desc: str,
               progress: bool = True, stateful: dict | None = None, checkpoint: Path | None = None,
               every: int = CHECKPOINT_EVERY, sampler: str = "epoch") -> LoopResult:
    """Run ``iters`` steps on batches of distinct training indices, resumable.

    With a ``checkpoint`` path, the loop resumes from that file when it exists, saves it every
    ``every`` iterations and after the last, and on SIGINT/SIGTERM saves it and stops with a
    :class:`ProcamError`;
    a resumed run gives bit-identical results to an uninterrupted one on the CPU (the objects in
    ``stateful``, the batch order, the values and torch's random state are all restored).

    Parameters
    ----------
    step : callable
        ``step(indices)`` performs one update on the training pairs ``indices`` (on ``device``)
        and returns a detached 1-D tensor of ``len(names)`` values (the first is the loss).
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
        Progress-bar label and the subject of a divergence message (:func:`fit_label`).
    progress : bool
        Show the progress bar.
    stateful : dict, optional
        Objects with ``state_dict``/``load_state_dict`` that the step changes (networks,
        optimisers, schedulers), by name.
    checkpoint : Path, optional
        Training-state file to resume from and save to.
    every : int
        Iterations between checkpoints (the run's ``checkpoint_every``).
    sampler : {"epoch", "random"}
        How batches are drawn (:class:`BatchSampler`).

    Raises
    ------
    ProcamError
        If a value becomes NaN or infinite (checked every :data:`CHECK_EVERY` iterations), or the
        process is asked to stop (the checkpoint is saved first).
    """
    stateful = stateful or {}
    batch = min(batch, n)
    batches = BatchSampler(n, batch, seed, sampler)
    values = torch.zeros(iters, len(names), dtype=torch.float64, device=device)
    done, spent = 0, 0.0
    if checkpoint is not None and Path(checkpoint).exists():
        done, spent = _load_checkpoint(Path(checkpoint), values, batches, stateful)
    start = time.perf_counter() - spent
    with tqdm(total=iters, initial=done, desc=desc, unit="it", disable=not progress) as bar, \
            _Interrupt() as interrupt, retained_heap():
        for it in range(done, iters):
            values[it] = step(next(batches).to(device))
            bar.update()
            if it % CHECK_EVERY == CHECK_EVERY - 1 or it == iters - 1:
                current = values[it].tolist()
                if not all(math.isfinite(v) for v in current):
                    shown = ", ".join(f"{k} {v}" for k, v in zip(names, current))
                    raise ProcamError(f"{desc} diverged at iteration {it + 1} ({shown}); try a lower lr")
                rate = (it + 1 - done) * batch / max(time.perf_counter() - start - spent, 1e-9)
                bar.set_postfix({names[0]: f"{current[0]:.4f}", "samples_per_s": f"{rate:.1f}"})
            if checkpoint is not None and (interrupt.signum is not None or (it + 1) % every == 0
                                           or it + 1 == iters):
                _save_checkpoint(Path(checkpoint), it + 1, values, batches, stateful,
                                 time.perf_counter() - start)
            if interrupt.signum is not None:
                where = f"; training state saved to {checkpoint}, run the same command to resume" \
                    if checkpoint is not None else ""
                raise TrainingInterrupted(f"{desc} stopped by {signal.Signals(interrupt.signum).name} after "
                                  f"iteration {it + 1}{where}")
    seconds = time.perf_counter() - start
    return LoopResult(seconds, iters * batch / max(seconds, 1e-9), batch, values.cpu().tolist())
