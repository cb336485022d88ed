"""One registry of compensation methods π†: captures x̃ (and the surface s̃) → projector frames x.

Every method fits on a :class:`~compensation.data.SetupData`, predicts in batches, and saves to /
loads from a run directory. Add a method by subclassing :class:`Method` and decorating it with
:func:`register`::

    @register
    class MyMethod(Method):
        name = "my-method"
        ...
"""
from __future__ import annotations

import abc
import pickle
import re
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import torch

from compensation.models import CompenNet
from sim.errors import ProcamError

if TYPE_CHECKING:
    from compensation.data import SetupData
    from compensation.train import TrainConfig

CHECKPOINT = "model.pt"
"""File name of a run's weights: a plain state dict (tensors only)."""


def resolve_device(device: str) -> torch.device:
    """``"auto"`` → CUDA if available, else CPU; otherwise the named torch device.

    Raises
    ------
    ProcamError
        If the name is not a torch device, or CUDA is asked for but not available.
    """
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        dev = torch.device(device)
    except RuntimeError:
        raise ProcamError(f"device {device!r}: expected 'auto', 'cpu' or 'cuda[:N]'") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ProcamError(f"device {device!r}: CUDA is not available in this torch build / machine")
    return dev


def save_state(model: torch.nn.Module, path: Path) -> None:
    """Save ``model``'s weights as a plain CPU state dict (``torch.save``)."""
    torch.save({k: v.detach().cpu() for k, v in model.state_dict().items()}, path)


def load_state(path: Path) -> dict[str, torch.Tensor]:
    """Load a plain state dict with ``torch.load(weights_only=True)`` — never arbitrary pickles.

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
    return state


def load_arrays(path: Path, keys: tuple[str, ...], what: str) -> dict[str, "np.ndarray"]:
    """Arrays ``keys`` of a method's ``.npz`` state, read without unpickling.

    Raises
    ------
    ProcamError
        If the file is missing, unreadable, holds pickled objects or lacks one of ``keys``;
        the message names the file and ``what`` it should hold.
    """
    import numpy as np

    path = Path(path)
    if not path.exists():
        raise ProcamError(f"{path}: {what} not found")
    try:
        with np.load(path, allow_pickle=False) as f:
            return {k: f[k] for k in keys}
    except KeyError as exc:
        raise ProcamError(f"{path}: missing array {exc}; expected {', '.join(keys)}") from None
    except (OSError, ValueError) as exc:
        raise ProcamError(f"{path}: cannot read {what} ({exc})") from None


def load_weights(model: torch.nn.Module, path: Path, what: str) -> None:
    """Copy the weights of checkpoint ``path`` into ``model`` (same architecture only).

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


class Method(abc.ABC):
    """A compensation method π†: captures in the projector view → projector input frames.

    Attributes
    ----------
    name : str
        Registry name (class attribute), e.g. ``"compennet"``.
    """

    name: ClassVar[str]
    profiles: ClassVar[dict[str, dict]] = {}
    """The method's own TrainConfig values per profile, layered over the common profile by
    :func:`compensation.train.make_config` (empty: the common profile as it is)."""

    @abc.abstractmethod
    def fit(self, data: SetupData, cfg: TrainConfig, progress: bool = True) -> dict:
        """Fit on ``data.train`` (and ``data.ref`` / ``data.surface`` as the method needs).

        Returns
        -------
        dict
            Statistics: ``seconds`` (wall-clock training time), ``samples_per_second``,
            ``final_loss``, ``loss_curve`` (list of (iteration, loss, learning rate)).
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

    @abc.abstractmethod
    def save(self, run_dir: Path) -> None:
        """Write the fitted state into ``run_dir`` (which exists)."""

    @classmethod
    @abc.abstractmethod
    def load(cls, run_dir: Path, device: str = "auto") -> Method:
        """A fitted method restored from ``run_dir``."""


METHODS: dict[str, type[Method]] = {}
"""Registered methods by name."""


def register(cls: type[Method]) -> type[Method]:
    """Class decorator adding a :class:`Method` subclass to :data:`METHODS` under ``cls.name``."""
    if cls.name in METHODS:
        raise ValueError(f"method {cls.name!r} is already registered ({METHODS[cls.name].__name__})")
    METHODS[cls.name] = cls
    return cls


def get_method(name: str) -> type[Method]:
    """The method class registered as ``name``.

    Raises
    ------
    ValueError
        If no method has that name; the message lists the registered names.
    """
    try:
        return METHODS[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; choose one of: {', '.join(sorted(METHODS))}") from None


@register
class CompenNetMethod(Method):
    """CompenNet (Huang & Ling, CVPR 2019) with the surface branch fed s̃, trained end to end.

    Parameters
    ----------
    device : str
        Torch device for prediction (``"auto"``: CUDA if available); ``fit`` uses the config's.
    """

    name = "compennet"
    surface: ClassVar[bool] = True
    """Whether the network has the surface branch."""

    def __init__(self, device: str = "auto"):
        self.device = resolve_device(device)
        self.model: CompenNet | None = None

    def fit(self, data: SetupData, cfg: TrainConfig, progress: bool = True) -> dict:
        # Imported here: compensation.train imports this registry to resolve method names.
        from compensation.train import fit_network

        self.device = resolve_device(cfg.device)
        torch.manual_seed(cfg.seed)  # He init of the new network is seeded
        model = CompenNet(surface=self.surface)
        if cfg.init is not None:
            load_weights(model, Path(cfg.init) / CHECKPOINT, self.name)
        self.model = model.to(self.device)
        return fit_network(self.model, data, cfg, self.surface, progress)

    @torch.no_grad()
    def predict(self, captures: torch.Tensor, surface: torch.Tensor, batch_size: int = 64) -> torch.Tensor:
        if self.model is None:
            raise ProcamError(f"{self.name}: predict called before fit or load")
        self.model.eval()
        features = self.model.surface_features(surface.to(self.device)) if self.surface else None
        out = [self.model(captures[i:i + batch_size].to(self.device), features=features).float().cpu()
               for i in range(0, captures.shape[0], batch_size)]
        return torch.cat(out)

    def save(self, run_dir: Path) -> None:
        if self.model is None:
            raise ProcamError(f"{self.name}: nothing to save before fit or load")
        save_state(self.model, Path(run_dir) / CHECKPOINT)

    @classmethod
    def load(cls, run_dir: Path, device: str = "auto") -> CompenNetMethod:
        method = cls(device)
        model = CompenNet(surface=cls.surface)
        load_weights(model, Path(run_dir) / CHECKPOINT, cls.name)
        method.model = model.to(method.device)
        return method


@register
class CompenNetNoSurfMethod(CompenNetMethod):
    """CompenNet without the surface branch ("CompenNet w/o surf" of the paper)."""

    name = "compennet-nosurf"
    surface = False

