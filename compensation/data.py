"""Loading one setup (layout: docs/architecture.md) as torch tensors for training and evaluation.

```
DATA_ROOT/{ref,train,test}/img_XXXX.png               projector frames x, shared by all setups
DATA_ROOT/<setup>/cam/warp/{ref,train,test}/img_XXXX.png   captures x̃ in the projector view
DATA_ROOT/<setup>/meta.json                           written last: marks a finished setup
```
Setups may be nested (``DATA_ROOT/light2/pos1/curves``, as in the official CompenNet benchmark): the
frames are read from the nearest folder above the setup that holds ``train/`` and ``test/``
(:func:`frames_root`), and the setup's name is its path below that folder. A setup with neither
``meta.json`` nor ``setup.toml`` is a dataset made elsewhere (the official benchmark's setups hold
only ``cam/warp``): its pairs are counted from the frames. A ``setup.toml`` without ``meta.json`` is
a procam render that did not finish.

The surface image s̃ is the capture of the plain gray frame: the 126th PNG of ``cam/warp/ref`` in
sorted order, as the official loader takes it (``img_0126.png`` in procam's datasets,
``img_gray.png`` in the official benchmark).
"""
from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from sim.errors import DatasetError
from sim.io import read_png
from sim.layout import (META_FILE, N_PLAIN, REF, SETUP_FILE, SURFACE_INDEX, TEST, TRAIN, capture_dir,
                        image_name, image_number)

SPLITS = (TRAIN, TEST)


@dataclass(frozen=True)
class PairSet:
    """Captures and the projector frames that produced them, index-aligned.

    Attributes
    ----------
    captures : torch.Tensor
        Camera captures x̃ warped to the projector view, float32 (N, 3, H, W), encoded values
        in [0, 1].
    frames : torch.Tensor
        Projector input frames x, float32 (N, 3, H, W) in [0, 1].
    """

    captures: torch.Tensor
    frames: torch.Tensor

    def __len__(self) -> int:
        return self.captures.shape[0]


@dataclass(frozen=True)
class SetupData:
    """Everything a compensation method needs from one finished setup.

    Attributes
    ----------
    name : str
        Setup name: its path below the dataset root (``default``, ``light2/pos1/curves``).
    setup_dir : Path
        The setup folder ``DATA_ROOT/<setup>``.
    train, test : PairSet
        Training and test pairs (the first ``n_train`` / ``n_test`` of the dataset).
    ref : PairSet or None
        The 125 plain colour frames and their captures (the samples of TPS and Nayar); None
        where the dataset root holds no ``ref`` frames (the official code never reads them).
    surface : torch.Tensor
        Surface image s̃, float32 (1, 3, H, W) in [0, 1].
    """

    name: str
    setup_dir: Path
    train: PairSet
    test: PairSet
    ref: PairSet | None
    surface: torch.Tensor

    @property
    def size(self) -> tuple[int, int]:
        """Canonical image size (height, width) in pixels."""
        return tuple(self.surface.shape[-2:])


def image_indices(folder: Path) -> set[int]:
    """1-based indices of the ``img_XXXX.png`` files in ``folder`` (empty if it is missing)."""
    if not folder.is_dir():
        return set()
    return {n for name in os.listdir(folder) if (n := image_number(name)) is not None}


def _names(indices) -> str:
    """``img_0007.png, img_0311.png`` (at most ten names, then a count)."""
    indices = sorted(indices)
    text = ", ".join(image_name(i) for i in indices[:10])
    return text + (f" and {len(indices) - 10} more" if len(indices) > 10 else "")


def frames_root(setup_dir: Path) -> Path:
    """The dataset root of a setup: the nearest folder above it with ``train/`` and ``test/``.

    Raises
    ------
    DatasetError
        If no folder above ``setup_dir`` holds both.
    """
    for folder in Path(setup_dir).absolute().parents:
        if (folder / TRAIN).is_dir() and (folder / TEST).is_dir():
            return folder
    raise DatasetError(f"{setup_dir}: no folder above it holds the projector frames (train/ and "
                       "test/ beside ref/: the dataset root)")


def setup_name(setup_dir: Path) -> str:
    """A setup's name: its path below :func:`frames_root` (``default``, ``light2/pos1/curves``)."""
    return Path(setup_dir).absolute().relative_to(frames_root(setup_dir)).as_posix()


def surface_path(setup_dir: Path) -> Path:
    """The surface image s̃ of a setup: the 126th PNG of ``cam/warp/ref`` in sorted order.

    Raises
    ------
    DatasetError
        If the folder holds fewer than 126 PNG files.
    """
    ref = capture_dir(setup_dir, REF)
    names = sorted(n for n in os.listdir(ref) if n.endswith(".png")) if ref.is_dir() else []
    if len(names) <= SURFACE_INDEX:
        raise DatasetError(f"{ref}: {len(names)} PNG images; the surface image s̃ (capture of the "
                           f"gray frame) is the {SURFACE_INDEX + 1}th in sorted order, after the "
                           f"{N_PLAIN} plain colours")
    return ref / names[SURFACE_INDEX]


def check_finished(setup_dir: Path) -> dict:
    """Check that ``setup_dir`` is a finished setup and return its ``meta.json`` (``{}`` for a
    setup made elsewhere, with neither ``meta.json`` nor ``setup.toml``).

    Raises
    ------
    DatasetError
        If the folder is missing, holds no ``cam/warp`` captures, or is a procam render without
        ``meta.json`` (written last), or ``meta.json`` is unreadable.
    """
    if not setup_dir.is_dir():
        raise DatasetError(f"{setup_dir}: setup folder not found (render it with `procam render`)")
    meta_file = setup_dir / META_FILE
    if not meta_file.exists():
        if (setup_dir / SETUP_FILE).exists():
            raise DatasetError(f"{setup_dir}: setup is not finished (no meta.json); "
                               "re-run `procam render` to complete it")
        if not capture_dir(setup_dir).is_dir():
            raise DatasetError(f"{setup_dir}: not a setup (no cam/warp captures, no meta.json)")
        return {}
    try:
        meta = json.loads(meta_file.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{meta_file}: cannot read ({exc})") from None
    if not isinstance(meta, dict) or not isinstance(meta.get("counts", {}), dict):
        raise DatasetError(f"{meta_file}: expected a JSON object with a 'counts' object per split")
    return meta


def available_pairs(setup_dir: Path, split: str, meta: dict, root: Path) -> int:
    """Number of complete (capture, frame) pairs of ``split``, checked against the frames in ``root``.

    A setup holds captures of frames 1 … n, where n is ``meta.json``'s count for the split (the
    root may hold more frames, rendered later for a larger setup) or, without a count, every frame
    of the root.

    Raises
    ------
    DatasetError
        Naming the folder and the missing files if a capture or a frame of 1 … n is absent.
    """
    frame_dir = root / split
    captures_dir = capture_dir(setup_dir, split)
    frames = image_indices(frame_dir)
    captures = image_indices(captures_dir)
    if not frames:
        raise DatasetError(f"{frame_dir}: no projector frames (img_XXXX.png) found")
    counted = meta.get("counts", {}).get(split)
    expected = int(counted) if counted is not None else max(frames)
    wanted = set(range(1, expected + 1))
    if missing := wanted - frames:
        source = (f"{setup_dir / META_FILE} lists {expected}" if counted is not None
                  else f"they are numbered up to {expected}")
        raise DatasetError(f"{frame_dir}: {len(frames)} frames but {source}; missing {_names(missing)}")
    if missing := wanted - captures:
        have = len(captures & wanted)
        source = (f"{frame_dir} has {expected} frames" if counted is None or expected == len(frames)
                  else f"{setup_dir / META_FILE} lists {expected}")
        raise DatasetError(f"{captures_dir}: {have} captures but {source}; missing {_names(missing)}")
    return expected


def to_tensor(images: np.ndarray) -> torch.Tensor:
    """uint8 (N, H, W, 3) images to a float32 (N, 3, H, W) tensor in [0, 1]."""
    return torch.from_numpy(images).permute(0, 3, 1, 2).float().div_(255.0).contiguous()


def read_png_like(path: Path, reference: Path, shape: tuple[int, ...]) -> np.ndarray:
    """The PNG at ``path``, of ``shape`` (H, W, 3), the shape of the image ``reference``.

    Raises
    ------
    DatasetError
        If it cannot be read or its shape differs; the message names both files.
    """
    img = read_png(path)
    if img.shape != shape:
        raise DatasetError(f"{path}: {img.shape[1]}x{img.shape[0]} pixels but {reference} is "
                           f"{shape[1]}x{shape[0]} (all images of a dataset must have one size)")
    return img


def _read_stack(paths: list[Path], reference: Path, shape: tuple[int, ...]) -> torch.Tensor:
    """Decode PNGs in a thread pool straight into one float32 (N, 3, H, W) tensor in [0, 1].

    Raises
    ------
    DatasetError
        If an image's shape (H, W, 3) differs from ``shape``, the shape of ``reference``.
    """
    out = torch.empty((len(paths), 3, shape[0], shape[1]), dtype=torch.float32)

    def load(i: int) -> None:
        img = read_png_like(paths[i], reference, shape)
        out[i].copy_(torch.from_numpy(img).permute(2, 0, 1)).div_(255.0)

    workers = max(1, min(4, os.cpu_count() or 1, len(paths)))
    with ThreadPoolExecutor(max_workers=workers) as pool:
        list(pool.map(load, range(len(paths))))
    return out


def load_setup_data(setup_dir: str | os.PathLike, n_train: int | None = None,
                    n_test: int | None = None) -> SetupData:
    """Load a finished setup's training, test and reference pairs and its surface image.

    Parameters
    ----------
    setup_dir : path-like
        ``DATA_ROOT/<setup>`` (possibly nested); the projector frames are read from ``DATA_ROOT``
        (:func:`frames_root`).
    n_train, n_test : int or None
        Use the first ``n`` pairs of each split; None uses all of them.

    Returns
    -------
    SetupData
        Tensors float32 (N, 3, H, W) in [0, 1]; H and W are divisible by 4.

    Raises
    ------
    DatasetError
        If the setup is missing or unfinished, a capture or frame is missing (of the plain
        colours too, unless the root holds none: then ``ref`` is None), more pairs are asked for
        than exist, images differ in size, or the size is not divisible by 4. The message names
        the path and what is missing or mismatched.
    """
    setup_dir = Path(setup_dir)
    meta = check_finished(setup_dir)
    root = frames_root(setup_dir)

    wanted = {TRAIN: n_train, TEST: n_test}
    counts = {}
    for split in SPLITS:
        have = available_pairs(setup_dir, split, meta, root)
        n = have if wanted[split] is None else wanted[split]
        if n < 1:
            raise DatasetError(f"{setup_dir}: n_{split}={n}: expected at least 1 pair")
        if n > have:
            raise DatasetError(f"{capture_dir(setup_dir, split)}: n_{split}={n} asked for but "
                               f"the setup has only {have} {split} pairs")
        counts[split] = n
    ref_frames = image_indices(root / REF)
    ref_captures = image_indices(capture_dir(setup_dir, REF))
    plain = set(range(1, N_PLAIN + 1))
    with_ref = bool(ref_frames & plain)  # no plain frames at all: a root without ref/ (optional)
    for folder, present in ((root / REF, ref_frames),
                            (capture_dir(setup_dir, REF), ref_captures)):
        if with_ref and (missing := plain - present):
            raise DatasetError(f"{folder}: {len(present & plain)} of the {N_PLAIN} plain colour "
                               f"images; missing {_names(missing)}")

    surface_file = surface_path(setup_dir)
    surface = read_png(surface_file)
    height, width = surface.shape[:2]
    if height % 4 or width % 4:
        raise DatasetError(f"{surface_file}: {width}x{height} pixels; CompenNet needs width and "
                           "height divisible by 4 (render at another --size)")

    def pairs(split: str, n: int) -> PairSet:
        names = [image_name(i) for i in range(1, n + 1)]
        return PairSet(_read_stack([capture_dir(setup_dir, split) / f for f in names],
                                   surface_file, surface.shape),
                       _read_stack([root / split / f for f in names], surface_file, surface.shape))

    return SetupData(name=setup_name(setup_dir), setup_dir=setup_dir,
                     train=pairs(TRAIN, counts[TRAIN]), test=pairs(TEST, counts[TEST]),
                     ref=pairs(REF, N_PLAIN) if with_ref else None, surface=to_tensor(surface[None]))
