"""The surrogate benchmark of the CompenNet paper over a suite of simulated setups or a dataset.

suite → (render what is missing) → train each method × training size × setup → evaluate →
Table 1 (methods × training-set sizes, averaged over setups, with the uncompensated row),
Table 2 (pre-trained vs He-initialised CompenNet: 32 pairs, 500 iterations, batch 32),
Table 3 (training losses ℓ1, ℓ2, SSIM, ℓ1+SSIM), as Markdown and CSV, plus per-setup rows.
Without a suite, the setups are every folder holding ``cam/warp`` under the dataset root
(:func:`found_setups`, e.g. the official benchmark's ``light2/pos1/curves``) and nothing is rendered.
With ``closed_loop`` every run on a simulated setup (one with ``setup.toml``) is also scored by
projecting its compensation back through the setup, next to the iterative-refinement oracle, and
keeps the captures of the first test images in ``runs/<setup>/<run>/closed_loop/`` (for
``procam report``).

Each run also leaves the official code's outputs, in the official layout under
``OUT/official/<setup>`` (never inside the dataset, which may be read-only)::

    cam/cmp/<tag>/img_XXXX.png    π†(x̃) for the test captures x̃ (what the surrogate metrics score)
    prj/cmp/<tag>/img_XXXX.png    π†(y) for the test images y: the frames to project

with the tag of :func:`official_tag` (e.g. ``CompenNet_l1+ssim_500_64_1000``).
"""
from __future__ import annotations

import os
import time
import traceback
from dataclasses import asdict, dataclass, field
from pathlib import Path

from compensation.data import SetupData, load_setup_data
from compensation.evaluation.metrics import evaluate
from compensation.evaluation.tables import LOSSES, TABLE2, write_tables
from compensation.methods import get_method
from compensation.training.config import COMMON, PROFILES, TrainConfig, applicable, make_config
from compensation.training.loop import TrainingInterrupted
from compensation.training.runs import load_run, package_version, scores_are_current, train_run
from sim.dataset import FrameSpec, image_name, write_setup
from sim.errors import ProcamError
from sim.io import read_json, to_uint8, write_json, write_png

N_MASK_FIGURE = 4
"""Test images per setup in ``reachable/<setup>.png``."""


@dataclass(frozen=True)
class BenchConfig:
    """What ``procam bench`` runs."""

    profile: str = "quick"
    """Training profile (``quick`` or ``paper``); also gives the canonical size and test count."""
    methods: tuple[str, ...] = ("compennet", "compennet-nosurf")
    """Methods of Table 1 (registry names)."""
    sizes: tuple[int, ...] = (125, 250, 500)
    """Training-set sizes of Table 1."""
    tables: tuple[str, ...] = ("1", "2", "3")
    """Which tables to produce ("1", "2", "3")."""
    size: int | None = None
    """Canonical size override (pixels, square); None takes the profile's."""
    n_test: int | None = None
    """Test pairs override; None takes the profile's."""
    overrides: dict = field(default_factory=dict)
    """Training options applied to every run whose method takes them (common options such as
    ``seed`` or ``device`` to all runs, e.g. ``iters`` to the network methods)."""
    closed_loop: bool = False
    """Also score every run in closed loop and add the iterative-refinement oracle."""

    def __post_init__(self):
        for name in self.methods:
            get_method(name)
        if unknown := sorted(set(self.tables) - {"1", "2", "3"}):
            raise ProcamError(f"tables {', '.join(unknown)}: expected some of 1, 2, 3")
        used = set(self.methods) | ({"compennet"} if {"2", "3"} & set(self.tables) else set())
        for key in self.overrides:
            if key not in COMMON and not any(key in get_method(m).options.names() for m in used):
                raise ProcamError(f"option {key!r} is not used by any method of this bench "
                                  f"({', '.join(sorted(used))})")
        if "init" in self.overrides and "2" in self.tables:
            raise ProcamError("option 'init': Table 2 compares He initialisation with pre-training "
                              "on its own white setup; leave Table 2 out (--tables 1,3) to initialise "
                              "every run from one run")
        for name in used:  # every value is checked before any rendering or training
            make_config(self.profile, name, **applicable(name, self.overrides))

    @property
    def canonical(self) -> int:
        """Canonical square size in pixels."""
        return self.size or PROFILES[self.profile]["size"]

    @property
    def tests(self) -> int:
        """Test pairs per setup."""
        return self.n_test or PROFILES[self.profile]["n_test"]


@dataclass(frozen=True)
class Job:
    """One training run of the benchmark."""

    table: str
    setup: str
    method: str
    n_train: int
    loss: str | None = None
    init: str | None = None
    extra: tuple = ()

    @property
    def run_name(self) -> str:
        tag = f"{self.method}-n{self.n_train}" + (f"-{self.loss}" if self.loss else "")
        tag += "-pretrained" if self.init else ""
        return tag + "".join(f"-{k}{v}" for k, v in self.extra)


def _jobs(cfg: BenchConfig, setups: list[str], pretrain_run: Path | None) -> list[Job]:
    jobs = []
    if "1" in cfg.tables:
        jobs += [Job("1", s, m, n) for s in setups for m in cfg.methods for n in cfg.sizes]
    if "2" in cfg.tables:
        extra = tuple((k, v) for k, v in TABLE2.items() if k != "n_train")
        for s in setups:
            jobs.append(Job("2", s, "compennet", TABLE2["n_train"], extra=extra))
            if pretrain_run is not None:
                jobs.append(Job("2", s, "compennet", TABLE2["n_train"], init=str(pretrain_run),
                                extra=extra))
    if "3" in cfg.tables:
        jobs += [Job("3", s, "compennet", max(cfg.sizes), loss) for s in setups for loss in LOSSES]
    return jobs


def _train_config(cfg: BenchConfig, method: str, n_train: int, **job_values):
    """The run configuration of one job: the user's options that ``method`` takes, then the job's
    own values. The user's word wins over a table's iterations and batch; the loss and
    initialisation that a table compares are the job's."""
    values = applicable(method, cfg.overrides)
    values.update({k: v for k, v in job_values.items()
                   if v is not None and (k in ("loss", "init") or k not in cfg.overrides)})
    return make_config(cfg.profile, method, **{**values, "n_train": n_train, "n_test": cfg.tests})


def _reusable(run_dir: Path, train_cfg, setup_dir: Path) -> dict | None:
    """The metrics of a finished run made with exactly ``train_cfg`` (device aside) on the dataset
    ``setup_dir`` by this procam version and scored with today's metrics
    (:func:`~compensation.training.runs.scores_are_current`), else None."""
    if not (run_dir / "metrics.json").exists():
        return None
    try:
        config = read_json(run_dir / "config.json", "run configuration")
        done = config["train"]
    except (ProcamError, KeyError, TypeError):
        return None
    wanted = train_cfg.to_dict()
    if (config.get("dataset") != str(Path(setup_dir).resolve())
            or config.get("procam_version") != package_version()
            or not all(done.get(k) == v for k, v in wanted.items() if k != "device")):
        return None
    metrics = read_json(run_dir / "metrics.json", "run metrics")
    return metrics if scores_are_current(metrics) else None


def found_setups(root: Path) -> list[str]:
    """Every setup below ``root``: the folders holding ``cam/warp``, as paths relative to ``root``
    (``default``, ``light2/pos1/curves``), sorted.

    Raises
    ------
    ProcamError
        If ``root`` is not a folder or holds no setup.
    """
    root = Path(root)
    if not root.is_dir():
        raise ProcamError(f"{root}: dataset root not found")
    found = []
    for folder, subfolders, _ in os.walk(root):
        if (Path(folder) / "cam" / "warp").is_dir():
            found.append(Path(folder).relative_to(root).as_posix())
            subfolders.clear()  # a setup holds no other setup
        subfolders.sort()
    if not found:
        raise ProcamError(f"{root}: no setup found (a setup is a folder holding cam/warp/)")
    return sorted(found)


def official_tag(cfg: TrainConfig, pretrained: bool = False) -> str:
    """The official code's name of a run's output folder: ``<model>_<loss>_<ntrain>_<batch>_<iters>``.

    ``<model>`` is the method's ``official_name`` (``_pretrained`` appended for a pre-trained
    initialisation); a method without a ``loss``, ``batch`` or ``iters`` option leaves that field
    out (TPS: ``TPS_125``; pix2pix: ``pix2pix_125_1_10000``).

    Examples
    --------
    >>> official_tag(make_config("paper", "compennet"))
    'CompenNet_l1+ssim_500_64_1000'
    >>> official_tag(make_config("quick", "tps-textured", n_train=125))
    'TPS_textured_125'
    """
    options = cfg.options
    model = get_method(cfg.method).official_name + ("_pretrained" if pretrained else "")
    fields = [model] + ([options.loss] if hasattr(options, "loss") else []) + [str(cfg.n_train)]
    return "_".join(fields + [str(getattr(options, k)) for k in ("batch", "iters") if hasattr(options, k)])


def write_official_outputs(run_dir: Path, data: SetupData, dest: Path, tag: str) -> None:
    """Write a run's π†(x̃) of the test captures to ``dest/cam/cmp/<tag>`` and its π†(y) of the
    test images y (the test frames) to ``dest/prj/cmp/<tag>``, as ``img_XXXX.png`` (8 bit)."""
    method, config = load_run(run_dir)
    batch = config["train"].get("eval_batch", 64)
    for kind, inputs in (("cam", data.test.captures), ("prj", data.test.frames)):
        frames = method.predict(inputs, data.surface, batch_size=batch).permute(0, 2, 3, 1).numpy()
        for i, frame in enumerate(frames, start=1):
            write_png(dest / kind / "cmp" / tag / image_name(i), to_uint8(frame))


def _official_complete(dest: Path, tag: str, n: int) -> bool:
    return all(len(list((dest / kind / "cmp" / tag).glob("img_*.png"))) == n for kind in ("cam", "prj"))


def _simulated(setup_dir: Path) -> bool:
    """Whether procam rendered the setup (its ``setup.toml`` makes a closed loop possible)."""
    return (setup_dir / "setup.toml").exists()


def run_bench(suite: list | None, out: Path, cfg: BenchConfig, data_root: Path | None = None,
              white=None, progress: bool = True, limit: int | None = None) -> dict[str, Path]:
    """Run the benchmark and write its tables.

    Resumable: a run whose ``metrics.json`` exists and whose configuration equals the job's is
    reused; any other run folder is trained again. A failing run is recorded in
    ``failures.json`` and does not lose the others.

    Parameters
    ----------
    suite : list of Setup, or None
        The setups (e.g. ``load_suite("scenes/suite.toml")``), rendered into ``data_root`` where
        missing; None: every setup found under ``data_root`` (:func:`found_setups`), as it is.
    out : Path
        Output folder: ``runs/``, ``official/``, ``table{1,2,3}.{md,csv}``, ``per_setup.csv``,
        ``failures.json``.
    cfg : BenchConfig
        What to run.
    data_root : Path, optional
        Where datasets are rendered (default ``out/data``); existing ones are reused. Required
        without a suite.
    white : Setup, optional
        The white-surface setup used for pre-training (Table 2).
    limit : int, optional
        Only the first ``limit`` setups.

    Returns
    -------
    dict
        Paths of the files written, by name.

    Raises
    ------
    ProcamError
        Without a suite: if ``data_root`` is not given or holds no setup, or ``cfg.size`` is set
        (found setups keep their own size).
    """
    out = Path(out)
    if suite is None:
        if data_root is None:
            raise ProcamError("bench without a suite: give the dataset root whose setups to take (--data)")
        if cfg.size is not None:
            raise ProcamError(f"--size {cfg.size}: the setups found under {data_root} keep their own size")
        setups = found_setups(Path(data_root))[:limit]
    else:
        suite = suite[:limit]
        setups = [s.name for s in suite]
    data_root = Path(data_root or out / "data")
    spec = FrameSpec(max(max(cfg.sizes), TABLE2["n_train"]), cfg.tests, (cfg.canonical,) * 2)
    for s in suite or []:
        write_setup(data_root, s, spec, progress=progress)
    pretrain = None
    if "2" in cfg.tables and white is not None:
        write_setup(data_root, white, spec, progress=progress)
        pretrain = out / "runs" / white.name / "compennet-pretrain"
        pre_cfg = _train_config(cfg, "compennet", max(cfg.sizes))
        if _reusable(pretrain, pre_cfg, data_root / white.name) is None:
            train_run(data_root / white.name, pre_cfg, pretrain, progress, True)

    rows, failures = [], []
    test_data: dict[str, SetupData] = {}  # the current setup's test pairs, for the official outputs
    for job in _jobs(cfg, setups, pretrain):
        run_dir = out / "runs" / job.setup / job.run_name
        try:
            job_values = dict(job.extra, loss=job.loss,
                              init=str(Path(job.init).resolve()) if job.init else None)
            train_cfg = _train_config(cfg, job.method, job.n_train, **job_values)
            metrics = _reusable(run_dir, train_cfg, data_root / job.setup)
            trained = metrics is None
            if trained:
                metrics = train_run(data_root / job.setup, train_cfg, run_dir, progress, overwrite=True)
            tag, dest = official_tag(train_cfg, job.init is not None), out / "official" / job.setup
            if trained or not _official_complete(dest, tag, metrics["n_test"]):
                if job.setup not in test_data:
                    test_data = {job.setup: load_setup_data(data_root / job.setup, 1, cfg.tests)}
                write_official_outputs(run_dir, test_data[job.setup], dest, tag)
            if (cfg.closed_loop and _simulated(data_root / job.setup)
                    and "psnr_reachable" not in metrics.get("closed_loop", {})):
                metrics = _add_closed_loop(run_dir, data_root / job.setup, cfg.tests)
        except TrainingInterrupted:  # the user or a scheduler stops the whole bench
            raise
        except Exception as exc:  # one failure must not lose the others' results
            failures.append({**asdict(job), "error": f"{type(exc).__name__}: {exc}",
                             "traceback": traceback.format_exc(limit=3)})
            continue
        rows.append({**asdict(job), "extra": dict(job.extra), "run": str(run_dir), "official_tag": tag,
                     **metrics})

    masks = out / "reachable" if cfg.closed_loop else None
    uncompensated, oracle, sizes = {}, {}, set()
    for s in setups:
        setup_masks = masks if _simulated(data_root / s) else None
        uncompensated[s], oracle_rows, size = _setup_baselines(data_root / s, cfg.tests, setup_masks)
        sizes.add(size)
        if oracle_rows is not None:
            oracle[s] = oracle_rows
    image_size = ", ".join(f"{w}x{h}" if w != h else f"{w}²" for h, w in sorted(sizes)) + " px"
    return write_tables(out, cfg, rows, failures, uncompensated, oracle, image_size)


def _setup_baselines(setup_dir: Path, n_test: int,
                     masks: Path | None) -> tuple[dict, list[dict] | None, tuple[int, int]]:
    """The method-free rows of one setup: scores of the test captures x̃ against x, the oracle and
    the image size (height, width).

    With a ``masks`` folder (closed loop), the uncompensated scores also get the closed-loop scores
    of y projected as is (its captures are the test captures), ``masks/<setup>.png`` shows the
    first test images with their physically unreachable pixels tinted magenta, and the iterative
    refinement rows are returned (``None`` otherwise).
    """
    data = load_setup_data(setup_dir, n_train=1, n_test=n_test)
    captures, y = data.test.captures, data.test.frames
    scores = evaluate(captures, y)
    if masks is None:
        return scores, None, data.size
    from compensation.evaluation.closed_loop import (closed_loop_scores, iterative_refinement,
                                                     reachable_mask, reachable_overlay, simulator_for)

    mask = reachable_mask(data, y)
    scores["closed_loop"] = closed_loop_scores(captures, y, mask)
    k = min(N_MASK_FIGURE, y.shape[0])
    strip = reachable_overlay(y[:k], mask[:k]).permute(2, 0, 3, 1).reshape(y.shape[2], -1, 3)
    write_png(masks / f"{data.name}.png", to_uint8(strip.numpy()))
    return scores, iterative_refinement(data, simulator_for(setup_dir)), data.size


def _add_closed_loop(run_dir: Path, setup_dir: Path, n_test: int) -> dict:
    from compensation.evaluation.closed_loop import closed_loop, simulator_for, write_captures

    method, _ = load_run(run_dir)
    data = load_setup_data(setup_dir, n_train=1, n_test=n_test)
    t0 = time.perf_counter()
    scores, captured = closed_loop(method, data, simulator_for(setup_dir), return_captures=True)
    scores["seconds"] = round(time.perf_counter() - t0, 3)
    write_captures(run_dir, captured)
    metrics = read_json(run_dir / "metrics.json", "run metrics")
    metrics["closed_loop"] = scores
    write_json(run_dir / "metrics.json", metrics)
    return metrics
