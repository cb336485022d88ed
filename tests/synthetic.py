"""A tiny synthetic dataset in the dataset layout (docs/architecture.md), for tests of the compensation side.

The "setup" is a known invertible degradation, no rendering involved::

    capture = 0.15 + 0.7 · frame · albedo      (then 8-bit; the offset and gain can be chosen)

with a smooth coloured albedo pattern, so the ideal compensation is
``frame = (capture − 0.15) / (0.7 · albedo)``.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from sim.io import to_uint8, write_png

OFFSET = 0.15
"""Additive light in the synthetic captures (ambient + projector black), encoded units."""
GAIN = 0.7
"""Gain of the projected frame in the synthetic captures."""


def albedo_pattern(size: int) -> np.ndarray:
    """Smooth coloured surface pattern, float32 (size, size, 3) in [0.45, 1]."""
    y, x = np.mgrid[0:size, 0:size].astype(np.float32) / size
    r = 0.75 + 0.25 * np.cos(2 * np.pi * x)
    g = 0.75 + 0.25 * np.sin(2 * np.pi * (x + y) / 2)
    b = 0.75 + 0.25 * np.cos(2 * np.pi * y + 1.0)
    return np.stack([r, g, b], axis=-1).astype(np.float32) * 0.8 + 0.2


def random_frames(n: int, size: int, rng: np.random.Generator) -> np.ndarray:
    """Seeded smooth random colour frames (bilinearly upsampled 4×4 noise plus a gradient), uint8."""
    coarse = rng.random((n, 4, 4, 3)).astype(np.float32)
    t = np.linspace(0, 3, size, dtype=np.float32)
    i0 = np.minimum(t.astype(int), 2)
    w = (t - i0)[:, None]
    rows = coarse[:, i0] * (1 - w[None, :, :, None]) + coarse[:, i0 + 1] * w[None, :, :, None]
    img = rows[:, :, i0] * (1 - w[None, None, :, :]) + rows[:, :, i0 + 1] * w[None, None, :, :]
    return to_uint8(img)


def plain_frames(size: int) -> np.ndarray:
    """The 125 plain colours (5 levels per channel, black first, white last) and the gray frame."""
    levels = np.linspace(0, 1, 5)
    colours = [(r, g, b) for r in levels for g in levels for b in levels] + [(0.5, 0.5, 0.5)]
    return to_uint8(np.array(colours, dtype=np.float32)[:, None, None, :] * np.ones((size, size, 1)))


def capture(frames: np.ndarray, albedo: np.ndarray, offset: float = OFFSET, gain: float = GAIN) -> np.ndarray:
    """The synthetic setup's captures of uint8 ``frames``: ``offset + gain · frame · albedo``, uint8."""
    return to_uint8(offset + gain * frames.astype(np.float32) / 255.0 * albedo)


def make_dataset(root: Path, name: str = "synth", size: int = 32, n_train: int = 16,
                 n_test: int = 4, seed: int = 0, finished: bool = True, official: bool = False,
                 offset: float = OFFSET, gain: float = GAIN) -> Path:
    """Write a synthetic dataset root with one setup and return the setup folder.

    Called again with the same root, size, counts and seed, it adds another setup beside the first
    (the frames are the same).

    Parameters
    ----------
    root : Path
        Dataset root (created).
    name : str
        Setup folder name, possibly nested (``light2/pos1/curves``).
    size : int
        Canonical width = height in pixels.
    n_train, n_test : int
        Number of training and test pairs.
    seed : int
        Seed of the random frames.
    finished : bool
        Write ``meta.json`` (the marker of a finished setup); False leaves ``setup.toml`` without
        it, as an interrupted render does.
    official : bool
        The official CompenNet benchmark's layout instead: no ``meta.json`` nor ``setup.toml``, the
        gray frame and its capture named ``img_gray.png``.
    offset, gain : float
        The captures' additive light and the projected frame's gain (:func:`capture`).
    """
    root = Path(root)
    rng = np.random.default_rng(seed)
    albedo = albedo_pattern(size)
    splits = {"ref": plain_frames(size), "train": random_frames(n_train, size, rng),
              "test": random_frames(n_test, size, rng)}
    setup_dir = root / name
    for split, frames in splits.items():
        captures = capture(frames, albedo, offset, gain)
        for i, (frame, cap) in enumerate(zip(frames, captures), start=1):
            file = "img_gray.png" if official and split == "ref" and i == len(frames) else f"img_{i:04d}.png"
            write_png(root / split / file, frame)
            write_png(setup_dir / "cam" / "warp" / split / file, cap)
    if official:
        return setup_dir
    if not finished:
        (setup_dir / "setup.toml").write_text('name = "synth"\n')
    else:
        meta = {"size": [size, size], "counts": {k: len(v) for k, v in splits.items()}}
        (setup_dir / "meta.json").write_text(json.dumps(meta))
    return setup_dir
