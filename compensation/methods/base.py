"""What every compensation method π† is: captures x̃ (and the surface s̃) → projector frames x.

A method is a :class:`Method` subclass with a registry ``name`` and an
:class:`~compensation.training.config.Options` dataclass (its own training options, each field
documented with unit, range and the paper's value) and owns its training recipe. It fits
on a :class:`~compensation.data.SetupData`, predicts in batches, and saves to / loads from a run
directory. The helpers here (device choice, plain state dicts, ``.npz`` states) serve every method.
"""
from __future__ import annotations

import abc
import pickle
import re
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch

from compensation.training.config import Options, TrainConfig
from compensation.training.loop import LoopResult
from sim.errors import ProcamError

from compensation.data import N_PLAIN, PairSet, SetupData

CHECKPOINT = "model.pt"
"""File name of a run's weights: a plain state dict (tensors only)."""


def parse_device(device: str) -> torch.device | None:
    """The torch device a name gives, None for ``"auto"``, whatever this machine has (a run sent
    to a cluster may name a device only its workers have).

    >>> parse_device("cuda:1"), parse_device("auto")
    (device(type='cuda', index=1), None)

    Raises
    ------
    ProcamError
        If the name is not a torch device.
    """
    if device == "auto":
        return None
    try:
        return torch.device(device)
    except (RuntimeError, TypeError):
        raise ProcamError(f"device {device!r}: expected 'auto', 'cpu' or 'cuda[:N]'") from None


def resolve_device(device: str) -> torch.device:
    """``"auto"`` → CUDA if available, else CPU; otherwise the named torch device.

    Raises
    ------
    ProcamError
        If the name is not a torch device, or CUDA is asked for but not available.
    """
    dev = parse_device(device)
    if dev is None:
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ProcamError(f"device {device!r}: CUDA is not available in this torch build / machine")
    return dev


def save_state(model: torch.nn.Module, path: Path) -> None:
    """Save ``model``'s weights as a plain CPU state dict (``torch.save``)."""
    torch.save({k: v.detach().cpu() for k, v in model.state_dict().items()}, path)


def subnormal(t: torch.Tensor) -> torch.Tensor:
    """Where ``t`` (floating point) is subnormal: nonzero and below the smallest normal number of
    its type (1.2e-38 in float32).

    >>> subnormal(torch.tensor([0.0, 1e-40, -1e-40, 1e-30, 1.0])).tolist()
    [False, True, True, False, False]
    """
    return (t.abs() < torch.finfo(t.dtype).tiny) & (t != 0)


def flush_denormals(model: torch.nn.Module) -> None:
    """Set ``model``'s subnormal parameters (:func:`subnormal`; weights and biases, not buffers)
    to zero.

    Training can leave many: a ``faithful`` CompenNet at 256² ends with about one weight in seven
    subnormal. On the CPU every multiply with one takes a slow path, so float32 prediction with
    such weights ran about 5× slower (``benchmarks/predict.py``: its ``float32, subnormals kept``
    row). The terms they contribute are negligible at the networks' activation scale: the
    predictions were bit-identical on the runs measured. Zeroing the weights, unlike the CPU's
    flush-to-zero mode (``torch.set_flush_denormal``), changes no global state and holds on every
    thread.

    >>> layer = torch.nn.Linear(2, 1)
    >>> _ = layer.weight.data.copy_(torch.tensor([[1e-40, 0.5]]))
    >>> flush_denormals(layer)
    >>> layer.weight.tolist()
    [[0.0, 0.5]]
    """
    with torch.no_grad():
        for p in model.parameters():
            if p.is_floating_point():
                p.masked_fill_(subnormal(p), 0)


def load_state(path: Path) -> dict[str, torch.Tensor]:
    """Load a plain state dict with ``torch.load(weights_only=True)`` — never arbitrary pickles.

    A state dict saved under ``torch.nn.DataParallel`` (every key prefixed ``module.``, as the
    official CompenNet code's multi-GPU checkpoints are) is returned without the prefix.

    Raises
    ------
    ProcamError
        If the file is missing, holds pickled objects other than tensors and containers, or is
        not a mapping of parameter names to tensors.
    """
    path = Path(path)
    if not path.exists():
        raise ProcamError(f"{path}: checkpoint not found")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        if found := re.search(r"Unsupported global: GLOBAL ([\w.]+)", str(exc)):
            raise ProcamError(f"{path}: refused to load: it holds a pickled {found.group(1)}, not "
                              "only tensors (a checkpoint must be a plain state dict; it is loaded "
                              "with weights_only=True)") from None
        reason = re.search(r"Unsupported [^\n]*", str(exc))
        raise ProcamError(f"{path}: cannot read checkpoint (not a torch state dict file: "
                          f"{reason.group(0) if reason else type(exc).__name__})") from None
    except (OSError, RuntimeError, EOFError) as exc:
        raise ProcamError(f"{path}: cannot read checkpoint ({exc})") from None
    if not isinstance(state, dict) or not all(
            isinstance(k, str) and isinstance(v, torch.Tensor) for k, v in state.items()):
        raise ProcamError(f"{path}: expected a state dict (parameter name → tensor), "
                          f"found {type(state).__name__}")
    if state and all(k.startswith("module.") for k in state):
        state = {k[len("module."):]: v for k, v in state.items()}
    return state


def weights_file(init: str | Path) -> Path:
    """The weights an ``init`` option names: a run directory's ``model.pt``, or a state dict file
    itself (``.pth``, e.g. a checkpoint of the official CompenNet code).

    >>> str(weights_file("runs/white"))  # not a file: a run directory
    'runs/white/model.pt'
    """
    init = Path(init)
    return init if init.is_file() else init / CHECKPOINT


def load_arrays(path: Path, keys: tuple[str, ...], what: str) -> dict[str, np.ndarray]:
    """Arrays ``keys`` of a method's ``.npz`` state, read without unpickling.

    Raises
    ------
    ProcamError
        If the file is missing, unreadable, holds pickled objects or lacks one of ``keys``;
        the message names the file and ``what`` it should hold.
    """
    path = Path(path)
    if not path.exists():
        raise ProcamError(f"{path}: {what} not found")
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: f[k] for k in keys}
    except KeyError as exc:
        raise ProcamError(f"{path}: missing array {exc}; expected {', '.join(keys)}") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise ProcamError(f"{path}: cannot read {what} ({exc})") from None


def load_weights(model: torch.nn.Module, path: Path, what: str) -> None:
    """Copy the weights of checkpoint ``path`` into ``model`` (same architecture only), subnormal
    weights as zeros (:func:`flush_denormals`).

    Parameters
    ----------
    model : torch.nn.Module
        Destination network.
    path : Path
        A ``model.pt`` file.
    what : str
        Name of the destination architecture for messages (e.g. ``"compennet"``).

    Raises
    ------
    ProcamError
        If a parameter is missing, unexpected or of another shape.
    """
    state = load_state(path)
    own = model.state_dict()
    problems = []
    if missing := [k for k in own if k not in state]:
        problems.append(f"missing {', '.join(missing[:4])}{' …' if len(missing) > 4 else ''}")
    if extra := [k for k in state if k not in own]:
        problems.append(f"unexpected {', '.join(extra[:4])}{' …' if len(extra) > 4 else ''}")
    if shapes := [f"{k} {tuple(state[k].shape)} vs {tuple(v.shape)}" for k, v in own.items()
                  if k in state and state[k].shape != v.shape]:
        problems.append(f"shape mismatch {', '.join(shapes[:4])}")
    if problems:
        raise ProcamError(f"{path}: weights do not fit the {what} architecture ({'; '.join(problems)})")
    model.load_state_dict(state)
    flush_denormals(model)


@dataclass(frozen=True)
class FitResult:
    """What fitting a method measured (``Method.fit``'s result; a run records it)."""

    seconds: float
    """Wall-clock time of the fit."""
    samples_per_second: float
    """Training pairs processed per second."""
    final_loss: float
    """The fit's last training loss (a network: mean of the last 10 iterations; a closed-form fit:
    its residual at the samples)."""
    batch: int
    """Samples per step (a network's effective batch; a per-pixel fit: samples per pixel)."""
    loss_curve: list[tuple[int, float, float]]
    """Per iteration: (iteration, loss, learning rate); one row for a closed-form fit."""
    extra: dict = field(default_factory=dict)
    """Method-specific statistics (e.g. TPS's ``degenerate_pixels``, pix2pix's ``gan_curve``)."""

    @classmethod
    def of_loop(cls, result: LoopResult, **extra) -> FitResult:
        """The fit of a network trained by :func:`~compensation.training.loop.train_loop`, whose
        step returned (loss, learning rate, …)."""
        return cls(result.seconds, result.samples_per_second, result.final_loss, result.batch,
                   [(i + 1, v[0], v[1]) for i, v in enumerate(result.values)], extra)


def plain_colour_pairs(data: SetupData, method: str) -> PairSet:
    """The 125 plain-colour pairs a method fits (TPS, Nayar).

    Raises
    ------
    ProcamError
        If the dataset root holds no ``ref`` frames (they are optional: CompenNet does without).
    """
    if data.ref is None:
        raise ProcamError(f"{data.setup_dir}: {method} fits the {N_PLAIN} plain colours, but the dataset "
                          f"root holds no ref/img_0001.png … img_{N_PLAIN:04d}.png (projector frames of "
                          "the plain colours; the official code does not need them, TPS and Nayar do)")
    return PairSet(data.ref.captures[:N_PLAIN], data.ref.frames[:N_PLAIN])


class Method(abc.ABC):
    """A compensation method π†: captures in the projector view → projector input frames.

    Attributes
    ----------
    name : str
        Registry name (class attribute), e.g. ``"compennet"``.
    """

    name: ClassVar[str]
    options: ClassVar[type[Options]]
    """The method's options dataclass."""
    official_name: ClassVar[str]
    """The model's name in the official CompenNet code's output folders and the paper's tables
    (``CompenNet``, ``TPS_textured``, …): no spaces or slashes."""
    state_file: ClassVar[str] = CHECKPOINT
    """The file of a run directory :meth:`save` writes the fitted state to."""
    plain_colours: ClassVar[bool] = False
    """The method fits the 125 plain-colour pairs of ``ref`` whatever the number of training pairs
    (TPS, Nayar); its official tag then names 125."""
    surface: ClassVar[bool] = False
    """The method takes the surface image s̃ (the capture of the plain gray frame) as an input."""

    @classmethod
    def fit_captures(cls, n_train: int) -> int:
        """Captures a fit with ``n_train`` training pairs needs: the 125 plain colours
        (:attr:`plain_colours`) or the ``n_train`` training captures, plus the surface image where
        the method takes it (:attr:`surface`). The registration's checkerboards, which every method
        needs alike, are not counted.

        >>> from compensation.methods import METHODS
        >>> {name: method.fit_captures(500) for name, method in sorted(METHODS.items())}
        {'compennet': 501, 'compennet-nosurf': 500, 'nayar': 125, 'pix2pix': 500, 'tps': 125, 'tps-textured': 500}
        """
        return (N_PLAIN if cls.plain_colours else int(n_train)) + int(cls.surface)

    @classmethod
    def seeded(cls, cfg: TrainConfig) -> bool:
        """Whether the fit with ``cfg`` depends on ``cfg.seed`` (initialisation, batch order or a
        random subset of the pairs); a fit that does not gives the same result for every seed, and
        a study fits it once. True by default."""
        return True

    @classmethod
    def check_image_size(cls, options: Options, width: int, height: int) -> None:
        """Raise :class:`ProcamError` unless the method, with ``options``, takes ``width`` ×
        ``height`` images (pixels); every size by default."""

    @abc.abstractmethod
    def fit(self, data: SetupData, cfg: TrainConfig, progress: bool = True,
            checkpoint: Path | None = None) -> FitResult:
        """Fit on ``data.train`` (and ``data.ref`` / ``data.surface`` as the method needs).

        ``cfg.options`` is an instance of the method's :attr:`options`; ``cfg.seed`` and
        ``cfg.device`` are common to every method. An iterative method resumes from and saves its
        training state to ``checkpoint`` (see :func:`compensation.training.loop.train_loop`);
        a closed-form fit of seconds may ignore it.

        Returns
        -------
        FitResult
            What the fit measured.
        """

    @abc.abstractmethod
    def predict(self, captures: torch.Tensor, surface: torch.Tensor, batch_size: int = 64) -> torch.Tensor:
        """Projector frames for ``captures``.

        Parameters
        ----------
        captures : torch.Tensor
            float32 (N, 3, H, W) in [0, 1], in the canonical projector view (for compensation:
            the desired appearance).
        surface : torch.Tensor
            Surface image s̃, float32 (1, 3, H, W) in [0, 1].
        batch_size : int
            Images per forward pass.

        Returns
        -------
        torch.Tensor
            float32 (N, 3, H, W) in [0, 1] on the CPU; computed without gradients.
        """

    def adopt_options(self, recorded: dict) -> None:
        """Take from the options a run recorded (its ``config.json``'s ``train.options``) those
        that change how the fitted method predicts; none by default. :meth:`load` restores the
        fitted state only; :func:`compensation.experiments.runs.load_run` calls this after it, so
        that a loaded run predicts as it did after :meth:`fit`.

        Raises
        ------
        ProcamError
            If such an option's recorded value is not one the method takes (naming the option).
        """

    @abc.abstractmethod
    def save(self, run_dir: Path) -> None:
        """Write the fitted state into ``run_dir`` (which exists)."""

    @classmethod
    @abc.abstractmethod
    def load(cls, run_dir: Path, device: str = "auto") -> Method:
        """A fitted method restored from ``run_dir`` (its fitted state; the options that change
        how it predicts come from :meth:`adopt_options`)."""
