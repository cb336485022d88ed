"""The dataset layout: every folder and file name of a rendered dataset, for its writer
(:mod:`sim.dataset`) and its readers alike.

```
DATA_ROOT/.lock                                   held by the one process writing the root
DATA_ROOT/.cache/transport_<key>.npz              transport operators, shared by the root's setups
DATA_ROOT/frames.json                             how the shared projector frames are made
DATA_ROOT/{ref,train,test}/img_XXXX.png           projector frames shared by all setups
DATA_ROOT/<setup>/setup.toml                      the fully resolved setup
DATA_ROOT/<setup>/render.json                     how its captures are rendered
DATA_ROOT/<setup>/registration/exact_map.npz      ground truth: the exact map's xy and mask
DATA_ROOT/<setup>/registration/registration.json  the map used, the homography and its error
DATA_ROOT/<setup>/cam/warp/{ref,train,test}/img_XXXX.png  captures in the canonical view
DATA_ROOT/<setup>/cam/raw/{ref,train,test}/img_XXXX.png   at camera resolution (only when asked for)
DATA_ROOT/<setup>/meta.json                       written last: marks a finished setup
```
``ref`` holds the :data:`N_PLAIN` plain colours (``img_0001.png`` black … ``img_0125.png``
white), then the plain gray frame whose capture is the surface image (file number
:data:`SURFACE_NUMBER`). Images are numbered from 1 (:func:`image_name`).
"""
from __future__ import annotations

import re
from pathlib import Path

LOCK_FILE = ".lock"
"""A root's lock file, held by the one process writing it."""
CACHE_DIR = ".cache"
"""A root's calibrated transport operators (:mod:`sim.transport`), one file per light transport:
setups of the root that differ only in what the transport does not see share one."""
FRAMES_FILE = "frames.json"
"""A root's record of how its projector frames are made."""
SETUP_FILE = "setup.toml"
"""A setup folder's fully resolved setup."""
RECORD_FILE = "render.json"
"""A setup folder's record of how its captures are rendered, written before the first."""
META_FILE = "meta.json"
"""A setup folder's metadata, written last: its presence marks a finished setup."""
REGISTRATION_DIR = "registration"
"""A setup folder's registration records."""
EXACT_MAP_FILE = "exact_map.npz"
"""The exact camera map (ground truth) in :data:`REGISTRATION_DIR`."""
REGISTRATION_FILE = "registration.json"
"""The registration record in :data:`REGISTRATION_DIR`."""
CAM = "cam"
"""A setup folder's captures."""
RAW = "raw"
"""Captures at camera resolution, below :data:`CAM`."""
WARP = "warp"
"""Captures in the canonical projector view, below :data:`CAM`."""
REF, TRAIN, TEST = "ref", "train", "test"
"""The splits: plain colours and the surface frame, training frames, test frames."""
SPLITS = (REF, TRAIN, TEST)
"""Every split, in the order they are rendered."""
N_PLAIN = 125
"""Plain colour frames at the start of :data:`REF` (5³ levels, black … white)."""
SURFACE_NUMBER = N_PLAIN + 1
"""File number of the plain gray frame in :data:`REF`, whose capture is the surface image."""
SURFACE_INDEX = SURFACE_NUMBER - 1
"""0-based position of the surface image in the sorted PNG names of ``cam/warp/ref`` (a dataset
made elsewhere may name it otherwise, e.g. ``img_gray.png``)."""
_IMAGE = re.compile(r"img_(\d{4,})\.png")


def image_name(number: int) -> str:
    """File name of the 1-based image ``number``.

    Examples
    --------
    >>> image_name(SURFACE_NUMBER)
    'img_0126.png'
    """
    return f"img_{number:04d}.png"


def image_number(name: str) -> int | None:
    """The 1-based number of an image file name of :func:`image_name`'s form, else None.

    Examples
    --------
    >>> image_number("img_0126.png"), image_number("img_gray.png")
    (126, None)
    """
    m = _IMAGE.fullmatch(name)
    return int(m.group(1)) if m else None


def cache_dir(setup_dir: Path) -> Path:
    """The transport cache a setup folder uses: its root's :data:`CACHE_DIR`.

    Examples
    --------
    >>> cache_dir(Path("data/default")).as_posix()
    'data/.cache'
    """
    return Path(setup_dir).parent / CACHE_DIR


def capture_dir(setup_dir: Path, split: str | None = None, kind: str = WARP) -> Path:
    """``<setup>/cam/<kind>[/<split>]``: a setup's captures of one kind (:data:`WARP` or
    :data:`RAW`), of one split or all.

    Examples
    --------
    >>> capture_dir(Path("data/default"), TEST).as_posix()
    'data/default/cam/warp/test'
    """
    folder = Path(setup_dir) / CAM / kind
    return folder if split is None else folder / split
