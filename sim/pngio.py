"""Reading and atomically writing the 8-bit RGB PNG files of a dataset."""
from __future__ import annotations

import os
import tempfile
from pathlib import Path

import cv2
import imageio.v3 as iio
import numpy as np

from sim.errors import DatasetError


def read_png(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as 8-bit RGB.

    Parameters
    ----------
    path : path-like
        PNG (or any format imageio reads) file.

    Returns
    -------
    numpy.ndarray
        ``uint8`` array of shape (H, W, 3), encoded values 0–255. Gray images are repeated to
        three channels; an alpha channel is dropped.

    Raises
    ------
    DatasetError
        If the file is missing or cannot be decoded.
    """
    path = Path(path)
    try:
        img = iio.imread(path)
    except (OSError, ValueError) as exc:
        raise DatasetError(f"{path}: cannot read image ({exc})") from None
    if img.dtype != np.uint8:
        if img.dtype == np.uint16:
            img = (img.astype(np.float64) / 257.0).round().astype(np.uint8)
        else:
            raise DatasetError(f"{path}: expected an 8-bit image, found dtype {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[..., None], 3, axis=2)
    elif img.ndim == 3 and img.shape[2] == 4:
        img = img[..., :3]
    elif img.ndim != 3 or img.shape[2] != 3:
        raise DatasetError(f"{path}: expected an RGB image, found shape {img.shape}")
    return np.ascontiguousarray(img)


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an 8-bit RGB PNG atomically (temporary file in the same folder, then rename).

    A reader never sees a truncated file, even when the writer is killed: either the old file
    (or none) or the complete new one. (No fsync: that would guard against power loss too, at
    ~70 ms a file — twice the cost of rendering a capture.)

    Parameters
    ----------
    path : path-like
        Destination; its folder is created if needed.
    image : numpy.ndarray
        ``uint8`` array (H, W, 3).
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"write_png expects uint8 (H, W, 3), got {image.dtype} {image.shape}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        ok, encoded = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))  # OpenCV is BGR
        if not ok:
            raise OSError(f"{path}: PNG encoding failed")
        with os.fdopen(fd, "wb") as f:
            f.write(encoded.tobytes())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def to_float(image: np.ndarray) -> np.ndarray:
    """Convert 8-bit encoded values to float32 in [0, 1] (still encoded, not linearised)."""
    return np.asarray(image, dtype=np.float32) / 255.0


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Round float values in [0, 1] to 8-bit (values outside are clipped)."""
    return np.clip(np.rint(np.asarray(image, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)
