"""Files on disk: atomic writes (bytes, text, JSON, PNG) and 8-bit RGB image reading.

Every file procam writes goes through :func:`atomic_write`: the content lands in a uniquely named
temporary file beside the destination, which is then renamed over it, so a reader (or a resumed
run) never sees a truncated file, even when the writer is killed. Files get the permissions the
process umask allows (as ``open`` would give them): the temporary file is created with mode 0666,
which the kernel masks, so no thread ever changes the process umask.

>>> import tempfile, pathlib
>>> folder = pathlib.Path(tempfile.mkdtemp())
>>> write_json(folder / "a.json", {"size": [64, 48]})
>>> read_json(folder / "a.json")
{'size': [64, 48]}
>>> image = np.zeros((2, 3, 3), np.uint8)
>>> write_png(folder / "img.png", image)
>>> read_png(folder / "img.png").shape
(2, 3, 3)
"""
from __future__ import annotations

import fnmatch
import json
import os
import secrets
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from sim.errors import DatasetError

_PNG_END = b"\x00\x00\x00\x00IEND\xaeB`\x82"
"""The last 12 bytes of every PNG file: the empty ``IEND`` chunk and its CRC."""
TEMP_SUFFIX = ".tmp"
"""Suffix of :func:`atomic_write`'s temporary files (``.<name>.<random>.tmp``)."""


def atomic_write(path: str | os.PathLike, data: bytes | str) -> None:
    """Write ``data`` to ``path`` atomically: a unique temporary file in the same folder, renamed.

    No fsync: the rename is atomic against a killed process (not against power loss), and an
    fsync per file would cost more than rendering a capture.

    Parameters
    ----------
    path : path-like
        Destination; its folder is created if needed.
    data : bytes or str
        Content; ``str`` is written as UTF-8.

    Raises
    ------
    OSError
        If the folder cannot be created or written (the temporary file is removed).
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    while True:
        tmp = path.parent / f".{path.name}.{secrets.token_hex(4)}{TEMP_SUFFIX}"
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
            break
        except FileExistsError:
            continue
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data.encode() if isinstance(data, str) else data)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def check_output_folder(folder: str | os.PathLike, known: Iterable[str], what: str) -> None:
    """Refuse to write the outputs of ``what`` into ``folder`` where it is a file or holds an entry
    whose name matches none of the ``known`` patterns (:mod:`fnmatch`; the temporary files a
    killed :func:`atomic_write` leaves are known too): the user's own files are never written over,
    beside, or (by a later ``--overwrite``) deleted. A folder that does not exist is accepted.

    Raises
    ------
    DatasetError
        Naming the folder and up to five of the entries.

    Examples
    --------
    >>> import tempfile, pathlib
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> (folder / "thesis.tex").write_text("mine")
    4
    >>> check_output_folder(folder, ("results.csv", "runs"), "study")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    sim.errors.DatasetError: ...: holds thesis.tex, which no study writes; refusing to write there (move those files or choose another output)
    """
    folder = Path(folder)
    if folder.exists() and not folder.is_dir():
        raise DatasetError(f"{folder}: exists and is a file; the output of {what} is a folder")
    patterns = (*known, f".*{TEMP_SUFFIX}")
    foreign = sorted(p.name for p in folder.iterdir()
                     if not any(fnmatch.fnmatchcase(p.name, k) for k in patterns)) if folder.is_dir() else []
    if foreign:
        raise DatasetError(f"{folder}: holds {', '.join(foreign[:5])}{' …' if len(foreign) > 5 else ''}, "
                           f"which no {what} writes; refusing to write there (move those files or "
                           "choose another output)")


def remove_temporaries(folder: str | os.PathLike) -> None:
    """Delete the temporary files that killed :func:`atomic_write` calls left in ``folder`` and
    below (``.<name>.<random>.tmp``). Only safe while no other process writes there."""
    for tmp in Path(folder).rglob(f".*{TEMP_SUFFIX}"):
        if tmp.is_file():
            tmp.unlink(missing_ok=True)


def write_text(path: str | os.PathLike, text: str) -> None:
    """Write a text file atomically; an identical file is left untouched (a resumed run
    rewrites nothing)."""
    path = Path(path)
    if path.is_file() and path.read_text() == text:
        return
    atomic_write(path, text)


def write_json(path: str | os.PathLike, data) -> None:
    """Write ``data`` as indented JSON atomically (see :func:`write_text`)."""
    write_text(path, json.dumps(data, indent=2) + "\n")


def read_json(path: str | os.PathLike, what: str = "JSON file") -> dict:
    """Read a JSON object.

    Raises
    ------
    DatasetError
        If the file is missing, unreadable, not JSON or not an object; the message names the file.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise DatasetError(f"{path}: {what} not found") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DatasetError(f"{path}: cannot read {what} ({exc})") from None
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected a JSON object in the {what}, found {type(data).__name__}")
    return data


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
    import imageio.v3 as iio
    from PIL.Image import DecompressionBombError

    path = Path(path)
    try:
        img = iio.imread(path)
    except (OSError, ValueError, SyntaxError, DecompressionBombError) as exc:  # Pillow's errors
        reason = (str(exc).splitlines() or [type(exc).__name__])[0]  # not imageio's install hints
        raise DatasetError(f"{path}: cannot read image ({reason})") from None
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


def intact_png(path: str | os.PathLike, shape: tuple[int, ...]) -> np.ndarray | None:
    """A PNG that :func:`write_png` wrote, or None unless it is complete and of ``shape``.

    A file truncated or damaged after it was written (it lacks the final ``IEND`` chunk, fails
    to decode or has another size) gives None, so that a resumed run writes it again.

    >>> import tempfile, pathlib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "img.png"
    >>> write_png(path, np.zeros((2, 3, 3), np.uint8))
    >>> intact_png(path, (2, 3, 3)).shape, intact_png(path, (3, 2, 3))
    ((2, 3, 3), None)
    >>> path.write_bytes(path.read_bytes()[:-1]) and intact_png(path, (2, 3, 3)) is None
    True
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            f.seek(0, os.SEEK_END)
            f.seek(max(0, f.tell() - len(_PNG_END)))
            complete = f.read() == _PNG_END
    except OSError:
        return None
    if not complete:
        return None
    try:
        image = read_png(path)
    except DatasetError:
        return None
    return image if image.shape == tuple(shape) else None


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write an 8-bit RGB PNG atomically (:func:`atomic_write`).

    Parameters
    ----------
    path : path-like
        Destination; its folder is created if needed.
    image : numpy.ndarray
        ``uint8`` array (H, W, 3).
    """
    import cv2

    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"write_png expects uint8 (H, W, 3), got {image.dtype} {image.shape}")
    ok, encoded = cv2.imencode(".png", np.ascontiguousarray(image[..., ::-1]))  # OpenCV is BGR
    if not ok:
        raise OSError(f"{path}: PNG encoding failed")
    atomic_write(path, encoded.tobytes())


def to_float(image: np.ndarray) -> np.ndarray:
    """Convert 8-bit encoded values to float32 in [0, 1] (still encoded, not linearised).

    >>> [round(v, 6) for v in to_float(np.array([0, 51, 255], np.uint8)).tolist()]
    [0.0, 0.2, 1.0]
    """
    return np.asarray(image, dtype=np.float32) / 255.0


def to_uint8(image: np.ndarray) -> np.ndarray:
    """Round float values in [0, 1] to 8-bit (values outside are clipped).

    >>> to_uint8(np.array([-0.1, 0.5, 1.2])).tolist()
    [0, 128, 255]
    """
    return np.clip(np.rint(np.asarray(image, dtype=np.float64) * 255.0), 0, 255).astype(np.uint8)

