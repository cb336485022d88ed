"""Writing a dataset in the CompenNet code's folder layout (below) — atomically and resumably.

```
DATA_ROOT/frames.json                     how the shared projector frames were made
DATA_ROOT/{ref,train,test}/img_XXXX.png   projector frames shared by all setups of the root
DATA_ROOT/<setup>/setup.toml              the fully resolved setup
DATA_ROOT/<setup>/cam/{raw,warp}/{ref,train,test}/img_XXXX.png
DATA_ROOT/<setup>/meta.json               written last: its presence marks a finished setup
```
Every PNG is written to a temporary file and renamed, so a killed run leaves no truncated image;
a re-run skips what exists and finishes the rest.
"""
from __future__ import annotations

import json
import time
from collections import defaultdict
from dataclasses import asdict, dataclass
from importlib.metadata import version
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sim import images, registration, seeds
from sim.capture import Simulator, capture_workers, pipelined
from sim.errors import DatasetError, SetupError
from sim.fidelity import check_level, check_spp, describe
from sim.io import read_png, write_json, write_png, write_text
from sim.setup import Setup, dump_setup, load_setup
from sim.variant import choose_variant

N_REF = 126
"""125 plain colours (0001 black … 0125 white) and the gray surface frame 0126."""
SURFACE_INDEX = 126


def image_name(index: int) -> str:
    """File name of the 1-based image ``index``: ``img_0001.png``."""
    return f"img_{index:04d}.png"


@dataclass(frozen=True)
class FrameSpec:
    """How a root's shared projector frames are made.

    Attributes
    ----------
    n_train, n_test : int
        Number of training and test frames.
    size : (int, int)
        Canonical (width, height) in pixels.
    seed : int
        Seed of the image generator.
    images_dir : str or None
        A folder of the user's own frames (train then test, sorted by name) instead of the
        generator.

    Raises
    ------
    DatasetError
        If a count or a side is below 1 or the seed is negative (named with its ``procam render``
        option).
    """

    n_train: int = 500
    n_test: int = 200
    size: tuple[int, int] = (256, 256)
    seed: int = 0
    images_dir: str | None = None

    def __post_init__(self):
        for name, option, value, least in (("n_train", "--n-train", self.n_train, 1),
                                           ("n_test", "--n-test", self.n_test, 1),
                                           ("seed", "--frame-seed", self.seed, 0),
                                           ("width", "--size", self.size[0], 1),
                                           ("height", "--size", self.size[1], 1)):
            if not isinstance(value, (int, np.integer)) or value < least:
                raise DatasetError(f"projector frames: {name} ({option}) = {value!r}: expected an "
                                   f"integer >= {least}")

    def source(self) -> dict:
        """What identifies the frames (counts excluded: a larger run extends a smaller one)."""
        return {"width": int(self.size[0]), "height": int(self.size[1]), "seed": self.seed,
                "images_dir": str(Path(self.images_dir).resolve()) if self.images_dir else None}


def canonical_size(record: dict) -> tuple[int, int] | None:
    """Canonical (width, height) in pixels recorded in a ``meta.json`` or a ``frames.json`` source:
    its ``width`` and ``height``, or the ``size`` [width, height] of files written before those;
    None if neither is there."""
    if "width" in record and "height" in record:
        return int(record["width"]), int(record["height"])
    if "size" in record:
        w, h = record["size"]
        return int(w), int(h)
    return None


def _same_source(old: dict, new: dict) -> bool:
    """Whether a ``frames.json`` source (possibly of the older ``size`` form) equals ``new``."""
    if not isinstance(old, dict):
        return False
    size = canonical_size(old)
    rest = {k: v for k, v in old.items() if k not in ("size", "width", "height")}
    return size == canonical_size(new) and rest == {k: v for k, v in new.items()
                                                    if k not in ("width", "height")}


def projector_frames(spec: FrameSpec) -> dict[str, np.ndarray]:
    """The uint8 projector frames of every split, (N, H, W, 3) each."""
    ref = np.stack([images.plain_frame(c, spec.size) for c in images.plain_colours()]
                   + [images.plain_frame(np.full(3, images.GRAY_LEVEL, np.uint8), spec.size)])
    if spec.images_dir:
        user = images.load_image_folder(spec.images_dir, spec.n_train + spec.n_test, spec.size)
        return {"ref": ref, "train": user[:spec.n_train], "test": user[spec.n_train:]}
    return {"ref": ref,
            "train": images.projector_frames(spec.n_train, spec.size, spec.seed, seeds.TRAIN_FRAMES),
            "test": images.projector_frames(spec.n_test, spec.size, spec.seed, seeds.TEST_FRAMES)}


def write_frames(root: Path, spec: FrameSpec, frames: dict[str, np.ndarray]) -> None:
    """Write (or check and extend) the shared projector frames of a root, :func:`projector_frames`
    of ``spec``.

    Raises
    ------
    DatasetError
        If the root already holds frames made differently (size, seed or image folder).
    """
    marker = root / "frames.json"
    if marker.exists():
        old = json.loads(marker.read_text())
        if not _same_source(old.get("source"), spec.source()):
            raise DatasetError(f"{marker}: this root's projector frames were made with "
                               f"{old.get('source')}, not {spec.source()}; use another --out")
    for split, stack in frames.items():
        for i, frame in enumerate(stack, start=1):
            path = root / split / image_name(i)
            if not path.exists():
                write_png(path, frame)
    counts = {k: len(v) for k, v in frames.items()}
    if marker.exists():
        old_counts = json.loads(marker.read_text()).get("counts", {})
        counts = {k: max(v, old_counts.get(k, 0)) for k, v in counts.items()}
    write_json(marker, {"source": spec.source(), "counts": counts})


def check_render(setup: Setup, spec: FrameSpec, fidelity: str | None = None,
                 spp: int | None = None) -> None:
    """Check what a render of ``setup`` can check without writing or rendering anything.

    The Mitsuba variant (``PROCAM_VARIANT``), the fidelity level and spp asked for, and that the
    camera sees enough of the projector image (:func:`sim.registration.check_visible`).

    Raises
    ------
    ProcamError
        Naming the setup key, option or environment variable at fault.
    """
    check_level(setup, fidelity or setup.render.fidelity)
    check_spp(setup, spp)
    registration.check_visible(setup, spec.size)
    choose_variant()


def _finish_capture(sim: Simulator, radiance: np.ndarray | None, raw: np.ndarray | None, stream: int,
                    index: int, raw_file: Path, warp_file: Path) -> dict[str, float]:
    """Camera model (unless ``raw`` was read back), warp and atomic PNG writes of one capture.

    The ``finish`` stage of :func:`sim.capture.pipelined`, on a worker thread; returns the seconds
    spent per phase (``camera``, ``registration``, ``png``) for the caller to add up.
    """
    seconds = {}
    t0 = time.perf_counter()
    if raw is None:
        raw = sim.expose(radiance, stream, index)
        seconds["camera"] = time.perf_counter() - t0
        write_png(raw_file, raw)
    t1 = time.perf_counter()
    warped = registration.warp(raw, sim.warp_map)
    t2 = time.perf_counter()
    write_png(warp_file, warped)
    seconds["registration"] = t2 - t1
    seconds["png"] = (t1 - t0 - seconds.get("camera", 0.0)) + time.perf_counter() - t2
    return seconds


def _same_setup(setup_file: Path, setup: Setup) -> bool:
    """True when ``setup_file`` exists and reads back to ``setup`` (whatever its formatting)."""
    if not setup_file.exists():
        return False
    try:
        return load_setup(setup_file) == setup
    except SetupError:
        return False


def write_setup(root: Path, setup: Setup, spec: FrameSpec, fidelity: str | None = None,
                spp: int | None = None, progress: bool = True, overwrite: bool = False) -> Path:
    """Render one setup into ``root/<setup.name>`` (resuming an interrupted run).

    Parameters
    ----------
    root : Path
        Dataset root (created if needed).
    setup : Setup
        Validated setup.
    spec : FrameSpec
        The shared projector frames.
    fidelity, spp : optional
        Override the setup's rendering level and samples per pixel (recorded in meta.json, with
        what ``auto`` measured; a ``transport`` operator is cached in ``<setup>/cache``).
    progress : bool
        Show a progress bar with captures per second.
    overwrite : bool
        Allow replacing a setup folder rendered from a different setup file.

    Returns
    -------
    Path
        The setup folder.
    """
    root = Path(root)
    check_render(setup, spec, fidelity, spp)
    frames = projector_frames(spec)  # reads --images: a bad file is refused before any write
    out = root / setup.name
    setup_file = out / "setup.toml"
    same_setup = _same_setup(setup_file, setup)
    if setup_file.exists() and not same_setup and not overwrite:
        raise DatasetError(f"{setup_file}: the folder holds captures of a different setup; "
                           "choose another --out or pass --overwrite")
    write_frames(root, spec, frames)
    counts = {k: len(v) for k, v in frames.items()}
    meta_file = out / "meta.json"
    if meta_file.exists():
        meta = json.loads(meta_file.read_text())
        if same_setup and canonical_size(meta) == tuple(spec.size) and all(
                meta.get("counts", {}).get(k, 0) >= n for k, n in counts.items()):
            return out
        meta_file.unlink()  # more captures asked for, or a different setup: no longer finished
    write_text(setup_file, dump_setup(setup))

    todo = [(split, i) for split, stack in frames.items() for i in range(1, len(stack) + 1)
            if not all((out / "cam" / kind / split / image_name(i)).exists() for kind in ("raw", "warp"))]
    t_start = time.perf_counter()
    sim = Simulator(setup, spec.size, fidelity, spp, cache_dir=out / "cache")
    workers = capture_workers()
    finish_seconds: dict[str, float] = defaultdict(float)

    def render(job: tuple[str, int]) -> tuple[np.ndarray | None, np.ndarray | None]:
        split, i = job
        raw_file = out / "cam" / "raw" / split / image_name(i)
        t0 = time.perf_counter()
        raw = read_png(raw_file) if raw_file.exists() else None  # written atomically: complete
        finish_seconds["png"] += time.perf_counter() - t0
        return (sim.linear(frames[split][i - 1], seeds.STREAMS[split], i) if raw is None else None), raw

    def finish(job: tuple[str, int], rendered) -> dict[str, float]:
        split, i = job
        return _finish_capture(sim, *rendered, seeds.STREAMS[split], i,
                               out / "cam" / "raw" / split / image_name(i),
                               out / "cam" / "warp" / split / image_name(i))

    with tqdm(total=len(todo), desc=f"render {setup.name}", unit="capture", disable=not progress) as bar:
        for seconds in pipelined(todo, render, finish, workers):
            for phase, sec in seconds.items():
                finish_seconds[phase] += sec
            bar.update()
    png_seconds = finish_seconds.pop("png", 0.0)  # phases are summed over the worker threads
    for phase, sec in finish_seconds.items():
        sim.timings[phase] += sec
    rendered_seconds = time.perf_counter() - t_start
    homography = sim.homography_check()
    r = sim.renderer
    meta = {
        "procam_version": version("procam"),
        "mitsuba_version": version("mitsuba"),
        "drjit_version": version("drjit"),
        "variant": r.variant,
        "fidelity": r.fidelity,
        "integrator": describe(setup, r.fidelity),
        "spp": r.spp,
        "fidelity_choice": sim.choice.as_dict(),
        "transport": ({**asdict(r.operator.info), "nonzeros": r.operator.nnz,
                       "loaded_from_cache": r.loaded_from_cache} if r.fidelity == "transport" else None),
        "ambient_spp": setup.render.ambient_spp,
        "seeds": {"render": setup.render.seed, "frames": spec.seed,
                  "streams": seeds.STREAMS},
        "width": int(spec.size[0]),  # canonical size, pixels
        "height": int(spec.size[1]),
        "camera_resolution": list(setup.camera.resolution),
        "counts": counts,
        "frames": spec.source(),
        "projector_defocus_px": r.defocus_px,
        "captures_this_run": len(todo),
        "capture_workers": workers,
        "timings_s": {**{k: round(v, 4) for k, v in sim.timings.items()}, "png": round(png_seconds, 4),
                      "total": round(rendered_seconds, 4)},
        "captures_per_second": round(len(todo) / rendered_seconds, 3) if todo else None,
        "registration": {"method": "exact (scene geometry)",
                         "visible_fraction": float(sim.warp_map.mask.mean()),
                         "homography": homography},
    }
    write_json(meta_file, meta)
    return out
