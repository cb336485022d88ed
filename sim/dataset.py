"""Writing a dataset in the CompenNet code's folder layout (:mod:`sim.layout`) — atomically and
resumably.

The root's lock is held (flock) by the one render writing it; ``frames.json`` is written before
the shared projector frames, a setup's ``render.json`` before its first capture and its
``meta.json`` last. Every input is checked before anything is written (:func:`check_render`, the
projector frames read); a render that fails before its first capture (what only rendering finds)
leaves no record that blocks the corrected run. Every PNG is written to a temporary file and renamed, so a killed run leaves no truncated
image; a re-run refuses a root or setup folder whose records (``frames.json``, ``setup.toml``,
``render.json``) differ from what it would write, rewrites any file that is damaged or missing and
finishes the rest. The captures at camera resolution (``cam/raw``) are kept only when asked for
(``raw``): no reader of a dataset needs them, and a resume needs only the warped captures.
"""
from __future__ import annotations

import fcntl
import io
import os
import shutil
import time
import zipfile
from collections import defaultdict
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from dataclasses import asdict, dataclass
from importlib.metadata import version
from pathlib import Path

import numpy as np
from tqdm import tqdm

from sim import camera, images, layout, registration, seeds
from sim.capture import Simulator, capture_workers, pipelined
from sim.errors import DatasetError, ProcamError, SetupError
from sim.fidelity import check_level, check_spp, describe, resolve
from sim.io import (atomic_write, intact_png, read_json, read_png, remove_temporaries, write_json,
                    write_png, write_text)
from sim.layout import REF, TEST, TRAIN, image_name
from sim.setup import Setup, dump_setup, load_setup
from sim.variant import choose_variant

MAX_SIDE = 4096
"""Largest canonical side in pixels (the projector panels procam models are at most 4096 wide)."""


def _memory() -> int:
    """This machine's physical memory in bytes."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


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
    test_frames : str
        Kind of the generated test frames (:data:`sim.images.FRAME_KINDS`: ``"mixed"``, the
        training frames' kind, or ``"photo"``, natural images only).

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
    test_frames: str = "mixed"

    def __post_init__(self):
        if self.test_frames not in images.FRAME_KINDS:
            raise DatasetError(f"projector frames: test_frames (--test-frames) = {self.test_frames!r}: "
                               f"expected one of {', '.join(images.FRAME_KINDS)}")
        if self.test_frames != "mixed" and self.images_dir:
            raise DatasetError("projector frames: --test-frames and --images exclude each other "
                               "(your own frames are taken as they are)")
        for name, option, value, least, most in (("n_train", "--n-train", self.n_train, 1, None),
                                                 ("n_test", "--n-test", self.n_test, 1, None),
                                                 ("seed", "--frame-seed", self.seed, 0, 2 ** 32 - 1),
                                                 ("width", "--size", self.size[0], 1, MAX_SIDE),
                                                 ("height", "--size", self.size[1], 1, MAX_SIDE)):
            if (not isinstance(value, (int, np.integer)) or value < least
                    or (most is not None and value > most)):
                raise DatasetError(f"projector frames: {name} ({option}) = {value!r}: expected an "
                                   f"integer >= {least}" + (f" and <= {most}" if most is not None else ""))
        frames = layout.N_PLAIN + 1 + self.n_train + self.n_test
        need = frames * self.size[0] * self.size[1] * 3
        if need > (limit := _memory() // 2):
            raise DatasetError(f"projector frames: {frames} frames of {self.size[0]}x{self.size[1]} "
                               f"(n_train / --n-train {self.n_train}, n_test / --n-test {self.n_test}, "
                               "size / --size) take "
                               f"{need / 2**30:.1f} GiB in memory; at most {limit / 2**30:.1f} GiB, half "
                               "of this machine's memory, can be held")

    def source(self) -> dict:
        """What identifies the frames (counts excluded: a larger run extends a smaller one); the
        test frames' kind only when not ``"mixed"``."""
        return {"width": int(self.size[0]), "height": int(self.size[1]), "seed": self.seed,
                "images_dir": str(Path(self.images_dir).resolve()) if self.images_dir else None,
                **({"test_frames": self.test_frames} if self.test_frames != "mixed" else {})}


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
        return {REF: ref, TRAIN: user[:spec.n_train], TEST: user[spec.n_train:]}
    return {REF: ref,
            TRAIN: images.projector_frames(spec.n_train, spec.size, spec.seed, seeds.TRAIN_FRAMES),
            TEST: images.projector_frames(spec.n_test, spec.size, spec.seed, seeds.TEST_FRAMES,
                                          spec.test_frames)}


def _read_frames_manifest(marker: Path) -> dict:
    """A root's ``frames.json``, its ``source`` and ``counts`` checked.

    Raises
    ------
    DatasetError
        If the file is not JSON, or a key is missing or of the wrong type (named).
    """
    manifest = read_json(marker, "frames manifest")
    source, counts = manifest.get("source"), manifest.get("counts")
    try:
        size = canonical_size(source) if isinstance(source, dict) else None
    except (TypeError, ValueError):
        size = None
    if size is None:
        raise DatasetError(f"{marker}: key 'source' = {source!r}: expected an object with the "
                           "frames' width, height, seed and images_dir")
    if not isinstance(counts, dict) or not all(isinstance(n, int) and n >= 0 for n in counts.values()):
        raise DatasetError(f"{marker}: key 'counts' = {counts!r}: expected an object of frame "
                           "counts per split")
    return manifest


def _frames_in_use(root: Path) -> bool:
    """Whether any setup folder of a root holds captures (its ``render.json`` or ``meta.json``
    exists): only then do the root's frames belong to a dataset."""
    return any((d / layout.RECORD_FILE).exists() or (d / layout.META_FILE).exists()
               for d in root.iterdir() if d.is_dir())


def _check_frames_manifest(root: Path, spec: FrameSpec) -> dict | None:
    """The root's ``frames.json`` (None if there is none yet, or if its frames were made otherwise
    but no setup captured them: a render that failed before its first capture, whose frames are
    removed here so that the corrected run starts afresh), refused unless its frames are made as
    ``spec`` makes them."""
    marker = root / layout.FRAMES_FILE
    if not marker.exists():
        return None
    manifest = _read_frames_manifest(marker)
    if not _same_source(manifest["source"], spec.source()):
        if not _frames_in_use(root):
            for split in layout.SPLITS:
                for path in (root / split).glob("img_*.png"):
                    path.unlink()
            marker.unlink()
            return None
        raise DatasetError(f"{marker}: this root's projector frames were made with "
                           f"{manifest['source']}, not {spec.source()}; use another --out")
    return manifest


def write_frames(root: Path, spec: FrameSpec, frames: dict[str, np.ndarray]) -> None:
    """Write (or check and extend) the shared projector frames of a root.

    ``frames.json`` (source and counts) is written first, so that a run killed while writing the
    frames leaves a record that a resumed run checks. A frame file that is damaged is written
    again.

    Parameters
    ----------
    root : Path
        Dataset root.
    spec : FrameSpec
        How the frames are made.
    frames : dict
        :func:`projector_frames` of ``spec``.

    Raises
    ------
    DatasetError
        If the root's frames are made differently (size, seed or image folder), or a frame file
        holds another image than the one ``spec`` makes.
    """
    manifest = _check_frames_manifest(root, spec)
    counts = {k: len(v) for k, v in frames.items()}
    if manifest is not None and _frames_in_use(root):
        counts = {k: max(v, manifest["counts"].get(k, 0)) for k, v in counts.items()}
    else:  # no captures depend on the frames: exactly this render's, none left over
        for split, n in counts.items():
            for path in (root / split).glob("img_*.png"):
                if (number := layout.image_number(path.name)) is not None and number > n:
                    path.unlink()
    write_json(root / layout.FRAMES_FILE, {"source": spec.source(), "counts": counts})
    for split, stack in frames.items():
        for i, frame in enumerate(stack, start=1):
            path = root / split / image_name(i)
            old = intact_png(path, frame.shape)
            if old is None:
                write_png(path, frame)
            elif not np.array_equal(old, frame):
                raise DatasetError(f"{path}: holds another frame than {root / layout.FRAMES_FILE} "
                                   f"describes ({spec.source()}); use another --out")


def check_render(setup: Setup, spec: FrameSpec, fidelity: str | None = None,
                 spp: int | None = None) -> dict:
    """Check what a render of ``setup`` can check without writing or rendering anything.

    The Mitsuba variant (``PROCAM_VARIANT``), the fidelity level and spp asked for, and that the
    camera sees enough of the projector image (:func:`sim.registration.check_visible`).

    Returns
    -------
    dict
        What identifies the captures, as :data:`~sim.layout.RECORD_FILE` holds it: ``variant``, ``width``,
        ``height``, ``frames``, ``noise_version`` (of the camera-noise streams), with a thin-lens
        camera ``camera_lens`` (``camera.defocus``: how its blur is rendered) and, unless the
        level is ``auto`` (resolved by measuring), ``fidelity`` and ``spp``.

    Raises
    ------
    ProcamError
        Naming the setup key, option or environment variable at fault.
    """
    level = fidelity or setup.render.fidelity
    check_level(setup, level)
    check_spp(setup, spp)
    registration.check_visible(setup, spec.size)
    record = {"variant": choose_variant(), "width": int(spec.size[0]), "height": int(spec.size[1]),
              "frames": spec.source(), "noise_version": camera.noise_version()}
    if setup.camera.aperture_radius > 0:
        record["camera_lens"] = setup.camera.defocus
    if level != "auto":
        choice = resolve(setup, fidelity, spp)
        record.update(fidelity=choice.level, spp=choice.spp)
    return record


def check_inputs(root: Path, names: list[str], inputs: list[Path]) -> None:
    """Refuse a render of the setups ``names`` into ``root`` that would write over or clear one of
    its ``inputs`` (the setup file, texture files, the folder of ``--images``): an input that is,
    or lies in, the root's frames or records or a setup folder's records, captures or
    registration.

    Raises
    ------
    DatasetError
        Naming the root, the path the render writes and the input.
    """
    root = Path(root).resolve()
    entries = (layout.SETUP_FILE, layout.RECORD_FILE, layout.META_FILE, layout.CAM, layout.REGISTRATION_DIR)
    written = [root / layout.FRAMES_FILE, root / layout.LOCK_FILE, root / layout.CACHE_DIR,
               *(root / split for split in layout.SPLITS),
               *(root / name / entry for name in names for entry in entries)]
    for given in inputs:
        path = Path(given).resolve()
        if hit := next((w for w in written if w == path or w in path.parents), None):
            raise DatasetError(f"--out {root}: the render writes {hit}, which is or holds its input "
                               f"{given}; choose another --out")


def check_counts(root: Path, spec: FrameSpec, names: list[str]) -> None:
    """Refuse a render that would leave setups of a root with fewer captures than its frames.

    The official CompenNet loader reads every frame of ``ROOT/train`` and ``ROOT/test`` against
    each setup's captures, so the frames of a root and the captures of each of its setups must
    agree in number. A render of ``names`` with ``spec`` brings the root's frames to the larger of
    its own and ``spec``'s counts and captures ``spec``'s counts for ``names``: it is refused when
    that leaves behind a finished setup of the root that it does not render, or the setups it
    renders.

    Parameters
    ----------
    root : Path
        Dataset root (it need not exist).
    spec : FrameSpec
        The frames of the render.
    names : list of str
        The setups the render writes.

    Raises
    ------
    DatasetError
        Naming the setups left behind, the counts and what to do.
    """
    root = Path(root)
    want = {TRAIN: spec.n_train, TEST: spec.n_test}
    marker = root / layout.FRAMES_FILE
    if marker.exists() and _frames_in_use(root):
        held = _read_frames_manifest(marker)["counts"]
        if any(held.get(split, 0) > n for split, n in want.items()):
            raise DatasetError(
                f"{marker}: this root holds {held.get(TRAIN, 0)} training and {held.get(TEST, 0)} test "
                f"frames; capturing {spec.n_train} and {spec.n_test} would leave the setups rendered now "
                "with fewer captures than the root's frames, which the official loader cannot read; "
                "use --n-train/--n-test of at least the root's counts, or another --out")
    behind = []
    for meta in sorted(root.glob(f"*/{layout.META_FILE}")):
        if meta.parent.name in names:
            continue
        counts = _meta_counts(meta)
        if any(counts.get(split, 0) < n for split, n in want.items()):
            behind.append(f"{meta.parent.name} ({counts.get(TRAIN, 0)} training, {counts.get(TEST, 0)} test)")
    if behind:
        raise DatasetError(
            f"{root}: rendering {spec.n_train} training and {spec.n_test} test frames would leave "
            f"{', '.join(behind)} with fewer captures than the root's frames, which the official "
            "loader cannot read; render those setups in the same command (a suite, or --only), "
            "or use another --out")


def _read_record(path: Path) -> dict:
    """The :data:`~sim.layout.RECORD_FILE` keys of a ``render.json`` (or of the ``meta.json`` of a setup rendered
    before render.json was written), a size of the older form as ``width`` and ``height``,
    ``noise_version`` 1 where the file predates the versioned camera noise, and ``camera_lens``
    ``"ray"`` where it predates the key (a thin lens was then always traced; the key is compared
    only for a camera with an aperture).

    Raises
    ------
    DatasetError
        If the file is not JSON, or a key is missing or of the wrong type (named).
    """
    data = read_json(path, "render record")
    try:
        size = canonical_size(data)
    except (TypeError, ValueError):
        size = None
    if size is None:
        raise DatasetError(f"{path}: keys 'width', 'height' = {data.get('width')!r}, "
                           f"{data.get('height')!r}: expected the canonical size in pixels")
    for key, kind, what in (("variant", str, "a Mitsuba variant"), ("fidelity", str, "a level"),
                            ("spp", int, "samples per pixel"), ("frames", dict, "the frames' source")):
        if not isinstance(data.get(key), kind):
            raise DatasetError(f"{path}: key {key!r} = {data.get(key)!r}: expected {what}")
    meta_seeds = data.get("seeds") if isinstance(data.get("seeds"), dict) else {}
    return {"variant": data["variant"], "fidelity": data["fidelity"], "spp": data["spp"],
            "width": size[0], "height": size[1], "frames": data["frames"],
            "noise_version": data.get("noise_version", meta_seeds.get("noise_version", 1)),
            "camera_lens": data.get("camera_lens", "ray")}


def _differences(path: Path, record: dict, expected: dict) -> list[str]:
    """What in a setup's record differs from what this render would write (empty: nothing), as
    one message naming the file and each key."""
    keys = [key for key, value in expected.items()
            if not (_same_source(record[key], value) if key == "frames" else record[key] == value)]
    if not keys:
        return []
    return [f"{path}: the captures were rendered with " + ", ".join(
        f"{key} = {record[key]!r} (this render: {expected[key]!r})" for key in keys)]


def _meta_counts(meta_file: Path) -> dict[str, int]:
    """The captures per split a finished setup's ``meta.json`` lists.

    Raises
    ------
    DatasetError
        If the file is not JSON or its ``counts`` is not an object of counts (named).
    """
    counts = read_json(meta_file, "setup metadata").get("counts")
    if not isinstance(counts, dict) or not all(isinstance(n, int) for n in counts.values()):
        raise DatasetError(f"{meta_file}: key 'counts' = {counts!r}: expected an object of "
                           "capture counts per split; delete the file to finish the render again")
    return counts


def _holds_raw(meta_file: Path) -> bool:
    """Whether a finished setup's ``meta.json`` records its raw captures as kept (``raw``; a file
    without the key was written when they always were)."""
    return read_json(meta_file, "setup metadata").get("raw", True) is not False


def read_raw(setup_dir: Path, split: str, number: int) -> np.ndarray:
    """A capture of a rendered setup at camera resolution, before its warp into the canonical view:
    ``<setup>/cam/raw/<split>/img_XXXX.png`` (:func:`write_setup` with ``raw``).

    Parameters
    ----------
    setup_dir : Path
        The setup folder.
    split : str
        :data:`~sim.layout.REF`, :data:`~sim.layout.TRAIN` or :data:`~sim.layout.TEST`.
    number : int
        The 1-based image number.

    Returns
    -------
    numpy.ndarray
        uint8 (Hc, Wc, 3).

    Raises
    ------
    DatasetError
        If the file is not there, naming the folder, whether the setup was rendered without its raw
        captures, and ``--raw``.
    """
    path = layout.capture_dir(Path(setup_dir), split, layout.RAW) / image_name(number)
    if not path.is_file():
        meta_file = Path(setup_dir) / layout.META_FILE
        why = ("the setup was rendered without its raw captures"
               if meta_file.exists() and not _holds_raw(meta_file) else "no such file")
        raise DatasetError(f"{path.parent}: no raw capture {path.name} ({why}); render the setup with "
                           "--raw (procam render --raw, bench --raw, or raw = true in a study file) to "
                           "keep the captures at camera resolution")
    return read_png(path)


def _same_setup(setup_file: Path, setup: Setup) -> bool:
    """True when ``setup_file`` exists and reads back to ``setup`` (whatever its formatting)."""
    if not setup_file.exists():
        return False
    try:
        return load_setup(setup_file) == setup
    except SetupError:
        return False


def _changes(out: Path, setup: Setup, expected: dict) -> list[str]:
    """Why the captures in a setup folder cannot be resumed by this render (empty: they can)."""
    setup_file = out / layout.SETUP_FILE
    changes = []
    if setup_file.exists() and not _same_setup(setup_file, setup):
        changes.append(f"{setup_file}: the folder holds captures of a different setup")
    record_file = next((f for f in (out / layout.RECORD_FILE, out / layout.META_FILE) if f.exists()), None)
    if record_file is not None:
        changes += _differences(record_file, _read_record(record_file), expected)
    elif (out / layout.CAM).exists():
        changes.append(f"{out / layout.CAM}: captures without a record ({layout.RECORD_FILE}) of how they "
                       "were rendered")
    return changes


def _check_procam_folders(root: Path, out: Path) -> None:
    """Refuse, before anything is written, a root whose frame folders hold frames without the
    root's ``frames.json`` (e.g. the official benchmark's root: a render would prune and replace
    them), or a setup folder ``out`` holding captures without a record of procam's
    (``setup.toml``, ``render.json`` or ``meta.json``), which not even ``--overwrite`` clears."""
    if not (root / layout.FRAMES_FILE).exists():
        for split in layout.SPLITS:
            if next((root / split).glob("img_*.png"), None) is not None:
                raise DatasetError(f"{root / split}: holds frames procam did not write ({root} has no "
                                   f"{layout.FRAMES_FILE}); render into another --out")
    records = (layout.SETUP_FILE, layout.RECORD_FILE, layout.META_FILE)
    if (out / layout.CAM).exists() and not any((out / name).exists() for name in records):
        raise DatasetError(f"{out / layout.CAM}: captures procam did not render (no {', '.join(records)} "
                           "beside them); render into another --out")


def _clear(out: Path) -> None:
    """Remove a setup folder's captures and records (the root's transport cache stays: it is keyed
    by what the light transport sees). ``meta.json`` goes first and the record last, so that a run
    killed here leaves a folder that is unfinished and still refused without ``--overwrite``."""
    (out / layout.META_FILE).unlink(missing_ok=True)
    for folder in (layout.CAM, layout.REGISTRATION_DIR):
        if (out / folder).exists():
            shutil.rmtree(out / folder)
    (out / layout.RECORD_FILE).unlink(missing_ok=True)


@contextmanager
def root_lock(root: Path) -> Iterator[None]:
    """Hold ``root/.lock`` (an exclusive ``flock``, released when the process ends however it ends)
    while writing a dataset root; the root is created if needed.

    Raises
    ------
    DatasetError
        If the root cannot be created or written, or another process holds the lock.
    """
    lock = root / layout.LOCK_FILE
    try:
        root.mkdir(parents=True, exist_ok=True)
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError as exc:
        raise DatasetError(f"{root}: cannot write the dataset root ({exc.strerror or exc}); "
                           "choose another --out") from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise DatasetError(f"{lock}: another procam process is writing this dataset root; "
                               "wait for it to finish or choose another --out") from None
        yield
    finally:
        os.close(fd)


def _holds_map(path: Path, wmap: registration.WarpMap) -> bool:
    """True when ``path`` is an intact ``exact_map.npz`` holding ``wmap``."""
    try:
        with np.load(path) as saved:
            return np.array_equal(saved["xy"], wmap.xy) and np.array_equal(saved["mask"], wmap.mask)
    except (OSError, ValueError, KeyError, zipfile.BadZipFile):
        return False


def write_registration(folder: Path, setup: Setup, reg: registration.Registration) -> dict:
    """Write a setup's registration records (atomically; identical files are left untouched) and
    return the record.

    ``folder/exact_map.npz`` holds the exact map, the ground truth, whatever map the captures
    were warped with: ``xy`` float32 (H, W, 2) camera pixel coordinates (column, row; pixel
    centres at integer + 0.5) of each canonical pixel and ``mask`` bool (H, W), the pixels the
    camera sees. ``folder/registration.json`` holds
    :meth:`sim.registration.Registration.record`.
    """
    if not _holds_map(folder / layout.EXACT_MAP_FILE, reg.exact):
        buffer = io.BytesIO()
        np.savez(buffer, xy=reg.exact.xy, mask=reg.exact.mask)
        atomic_write(folder / layout.EXACT_MAP_FILE, buffer.getvalue())
    record = reg.record(setup)
    write_json(folder / layout.REGISTRATION_FILE, record)
    return record


def _finish_capture(sim: Simulator, radiance: np.ndarray | None, raw: np.ndarray | None, stream: int,
                    index: int, raw_file: Path | None, warp_file: Path) -> dict[str, float]:
    """Camera model (unless ``raw`` was read back), warp and atomic PNG writes of one capture (the
    capture at camera resolution only with a ``raw_file``).

    The ``finish`` stage of :func:`sim.capture.pipelined`, on a worker thread; returns the seconds
    spent per phase (``camera``, ``registration``, ``png``) for the caller to add up.
    """
    seconds = {}
    t0 = time.perf_counter()
    if raw is None:
        raw = sim.expose(radiance, stream, index)
        seconds["camera"] = time.perf_counter() - t0
        if raw_file is not None:
            write_png(raw_file, raw)
    t1 = time.perf_counter()
    warped = registration.warp(raw, sim.warp_map)
    t2 = time.perf_counter()
    write_png(warp_file, warped)
    seconds["registration"] = t2 - t1
    seconds["png"] = (t1 - t0 - seconds.get("camera", 0.0)) + time.perf_counter() - t2
    return seconds


def write_setup(root: Path, setup: Setup, spec: FrameSpec, fidelity: str | None = None,
                spp: int | None = None, progress: bool = True, overwrite: bool = False,
                raw: bool = False) -> Path:
    """Render one setup into ``root/<setup.name>`` (resuming an interrupted run).

    Nothing is written before every input is checked (:func:`check_render`, the projector frames
    made or read). Under the root's lock (:func:`root_lock`) the root's and the folder's records
    are compared with this render; then ``frames.json`` and ``render.json`` are written before the
    files they describe, and a capture is kept only if its file is intact
    (:func:`sim.io.intact_png`).

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
        what ``auto`` measured; a ``transport`` operator is cached in the root's
        :data:`~sim.layout.CACHE_DIR`).
    progress : bool
        Show a progress bar with captures per second.
    overwrite : bool
        Re-render a setup folder whose captures were rendered from another setup file, Mitsuba
        variant, fidelity, spp, size or frames, instead of refusing it; for a finished setup of
        the same configuration, check every file again and re-render the damaged ones.
    raw : bool
        Also keep each capture at camera resolution (``cam/raw``, the official layout's; a
        960x640 PNG where the warped one is 256²), which no reader of the dataset needs.
        ``meta.json`` records whether every capture's is there (``raw``). Not part of what
        identifies the captures: a setup finished with them is finished without, and one
        finished without them renders its captures again to add them (the warped ones come
        out the same bytes).

    Returns
    -------
    Path
        The setup folder.

    Raises
    ------
    ProcamError
        If an input is refused (:func:`check_render`, :func:`projector_frames`), the root or the
        setup folder holds frames or captures procam did not write (even with ``overwrite``),
        another process writes the root, the root's frames differ, or (without ``overwrite``) the
        setup folder holds captures rendered differently; the message names the file or key.
    """
    root = Path(root)
    out = root / setup.name
    expected = check_render(setup, spec, fidelity, spp)
    frames = projector_frames(spec)
    counts = {k: len(v) for k, v in frames.items()}
    _check_procam_folders(root, out)
    with root_lock(root):
        _check_frames_manifest(root, spec)
        changes = _changes(out, setup, expected)
        if changes and not overwrite:
            raise DatasetError("; ".join(changes) + "; choose another --out or pass --overwrite to "
                               "render it again")
        meta_file = out / layout.META_FILE
        if not changes and not overwrite and meta_file.exists() and all(
                _meta_counts(meta_file).get(k, 0) >= n for k, n in counts.items()) and (
                not raw or _holds_raw(meta_file)):
            write_frames(root, spec, frames)
            return out
        for folder in (*(root / split for split in layout.SPLITS), out):
            remove_temporaries(folder)
        if changes:
            _clear(out)
        meta_file.unlink(missing_ok=True)  # more captures asked for: no longer finished
        write_frames(root, spec, frames)
        write_text(out / layout.SETUP_FILE, dump_setup(setup))
        try:
            return _render(out, setup, spec, frames, fidelity, spp, expected, overwrite, progress, raw)
        except BaseException:  # a refusal, a crash or Ctrl-C
            if not (out / layout.RECORD_FILE).exists() and not (out / layout.CAM).exists():
                # nothing rendered: the corrected setup may start
                (out / layout.SETUP_FILE).unlink(missing_ok=True)
                with suppress(OSError):  # the folder, when nothing else is in it
                    out.rmdir()
            raise


MIN_RESPONSE = 2 / 255
"""Least mean difference (encoded units) between the captures of plain white and plain black for a
dataset to be rendered, on average and in each colour channel: below two 8-bit levels the captures
(or a channel of them) do not depend on the projector (no light reaches the camera, or every pixel
clips), and no method can learn from them."""


class NoResponse(DatasetError):
    """A setup whose captures do not respond to the projector (:func:`_check_response`)."""


def _check_response(sim: Simulator, ref_frames: np.ndarray, name: str) -> float:
    """The mean white − black capture difference of a setup (canonical view, encoded units).

    Raises
    ------
    NoResponse
        If it, or its mean in one colour channel, is below :data:`MIN_RESPONSE`, with the measured
        contrast.
    """
    probe = sim.capture(np.stack([ref_frames[0], ref_frames[layout.N_PLAIN - 1]]), seeds.RESPONSE)
    channels = (probe[1].astype(np.float64) - probe[0]).mean(axis=(0, 1)) / 255
    response = float(channels.mean())
    if response < MIN_RESPONSE:
        raise NoResponse(f"setup {name!r}: the captures do not respond to the projector: plain white and "
                           f"plain black differ by {response * 255:.2f} 8-bit levels on average (at least "
                           f"{MIN_RESPONSE * 255:.0f} needed); check the projector's brightness and mixing, "
                           "the camera's exposure and the registration")
    if (dead := [c for c, r in zip("RGB", channels) if r < MIN_RESPONSE]):
        raise NoResponse(f"setup {name!r}: the captures' {' and '.join(dead)} channel(s) do not respond to "
                           "the projector: plain white and plain black differ there by "
                           + ", ".join(f"{r * 255:.2f}" for c, r in zip("RGB", channels) if c in dead)
                           + f" 8-bit levels on average (at least {MIN_RESPONSE * 255:.0f} needed in "
                           "each channel); check the projector's mixing, the camera's white balance "
                           "and exposure")
    return response


def _render(out: Path, setup: Setup, spec: FrameSpec, frames: dict[str, np.ndarray],
            fidelity: str | None, spp: int | None, expected: dict, overwrite: bool,
            progress: bool, raw: bool) -> Path:
    """The captures a setup folder lacks, then its ``meta.json`` (see :func:`write_setup`). A
    capture is done when its warped file is intact (and, with ``raw``, its raw file); a missing
    warped capture whose raw file is intact is warped from it, not rendered again."""
    counts = {k: len(v) for k, v in frames.items()}
    t_start = time.perf_counter()
    sim = Simulator(setup, spec.size, fidelity, spp, cache_dir=layout.cache_dir(out))
    record = {**expected, "fidelity": sim.choice.level, "spp": sim.choice.spp}
    record_file = out / layout.RECORD_FILE
    if record_file.exists():  # ``auto``: the resolved level and spp are known only now
        if changes := _differences(record_file, _read_record(record_file), record):
            if not overwrite:
                raise DatasetError("; ".join(changes) + "; choose another --out or pass "
                                   "--overwrite to render it again")
            _clear(out)
    _check_response(sim, frames[layout.REF], setup.name)
    write_json(record_file, record)
    registration_record = write_registration(out / layout.REGISTRATION_DIR, setup, sim.registration)

    w, h = spec.size
    raw_shape, warp_shape = (*setup.camera.resolution[::-1], 3), (h, w, 3)

    def files(split: str, i: int) -> tuple[Path, Path]:
        return (layout.capture_dir(out, split, layout.RAW) / image_name(i),
                layout.capture_dir(out, split) / image_name(i))

    every = [(split, i) for split, stack in frames.items() for i in range(1, len(stack) + 1)]
    todo = [(split, i) for split, i in every if intact_png(files(split, i)[1], warp_shape) is None
            or (raw and intact_png(files(split, i)[0], raw_shape) is None)]
    workers = capture_workers()
    finish_seconds: dict[str, float] = defaultdict(float)

    def render(job: tuple[str, int]) -> tuple[np.ndarray | None, np.ndarray | None]:
        split, i = job
        t0 = time.perf_counter()
        kept = intact_png(files(split, i)[0], raw_shape)
        finish_seconds["png"] += time.perf_counter() - t0
        return (sim.linear(frames[split][i - 1], seeds.STREAMS[split], i) if kept is None else None), kept

    def finish(job: tuple[str, int], rendered) -> dict[str, float]:
        split, i = job
        raw_file, warp_file = files(split, i)
        return _finish_capture(sim, *rendered, seeds.STREAMS[split], i, raw_file if raw else None,
                               warp_file)

    with tqdm(total=len(todo), desc=f"{setup.name} · render", unit="capture", disable=not progress) as bar:
        for seconds in pipelined(todo, render, finish, workers):
            for phase, sec in seconds.items():
                finish_seconds[phase] += sec
            bar.update()
    png_seconds = finish_seconds.pop("png", 0.0)  # phases are summed over the worker threads
    for phase, sec in finish_seconds.items():
        sim.timings[phase] += sec
    rendered_seconds = time.perf_counter() - t_start
    r = sim.renderer
    meta = {
        "procam_version": version("procam"),
        "mitsuba_version": version("mitsuba"),
        "drjit_version": version("drjit"),
        "variant": r.variant,
        "fidelity": r.fidelity,
        "integrator": describe(r.setup, r.fidelity),
        "spp": r.spp,
        "fidelity_choice": sim.choice.as_dict(),
        "transport": ({**asdict(r.operator.info), "nonzeros": r.operator.nnz,
                       "loaded_from_cache": r.loaded_from_cache} if r.fidelity == "transport" else None),
        "ambient_spp": setup.render.ambient_spp,
        "seeds": {"render": setup.render.seed, "frames": spec.seed,
                  "streams": seeds.STREAMS, "noise_version": camera.noise_version()},
        "width": int(spec.size[0]),  # canonical size, pixels
        "height": int(spec.size[1]),
        "camera_resolution": list(setup.camera.resolution),
        "camera_exposure": sim.exposure,
        "counts": counts,
        "raw": raw or all(files(split, i)[0].exists() for split, i in every),
        "frames": spec.source(),
        "projector_defocus_px": r.defocus_px,
        "captures_this_run": len(todo),
        "capture_workers": workers,
        "timings_s": {**{k: round(v, 4) for k, v in sim.timings.items()}, "png": round(png_seconds, 4),
                      "total": round(rendered_seconds, 4)},
        "captures_per_second": round(len(todo) / rendered_seconds, 3) if todo else None,
        "registration": {**registration_record,
                         "ground_truth": f"{layout.REGISTRATION_DIR}/{layout.EXACT_MAP_FILE}"},
    }
    write_json(out / layout.META_FILE, meta)
    return out
