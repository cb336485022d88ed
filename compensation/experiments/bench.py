"""The surrogate benchmark of the CompenNet paper over a suite of simulated setups or a dataset.

suite → (render what is missing) → train each method × training size × setup → evaluate →
Table 1 (methods × training-set sizes, averaged over setups, with the uncompensated row),
Table 2 (pre-trained vs He-initialised CompenNet: 32 pairs, 500 iterations, batch 32),
Table 3 (training losses ℓ1, ℓ2, SSIM, ℓ1+SSIM), as Markdown and CSV, plus per-setup rows.
Without a suite, the setups are every folder holding ``cam/warp`` under the dataset root
(:func:`found_setups`, e.g. the official benchmark's ``light2/pos1/curves``) and nothing is rendered.
With ``closed_loop`` every run on a simulated setup (one with ``setup.toml``) is also scored by
projecting its compensation back through the setup, next to the iterative-refinement oracle.

Each run also leaves the official code's outputs, in the official layout under
``OUT/official/<setup>`` (never inside the dataset, which may be read-only)::

    cam/cmp/<tag>/img_XXXX.png    π†(x̃) for the test captures x̃ (what the surrogate metrics score)
    prj/cmp/<tag>/img_XXXX.png    π†(y) for the test images y: the frames to project

with the tag of :func:`~compensation.experiments.official.official_tag` (e.g.
``CompenNet_l1+ssim_500_64_1000``).

The bench is a study without axes: its renders, runs and baselines are the jobs of
:mod:`compensation.experiments.jobs`, run by an executor of :mod:`compensation.experiments.executors`, and its
folder holds the same ``study.json`` (kind ``bench``) and ``results.csv`` as a study's.
"""
from __future__ import annotations

import os
from dataclasses import asdict, dataclass, field
from pathlib import Path

from compensation.experiments.jobs import (BaselineJob, FitJob, RenderJob, baselines, fit, render,
                                          result_row, simulated, tasks, write_results, write_study_record)
from compensation.reports.tables import LOSSES, TABLE2, write_tables
from compensation.experiments.executors import LocalExecutor
from compensation.methods import applicable, get_method, make_config
from compensation.training.config import COMMON, PROFILES
from sim.dataset import FrameSpec
from sim.errors import ProcamError


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


def run_bench(suite: list | None, out: Path, cfg: BenchConfig, data_root: Path | None = None,
              white=None, progress: bool = True, limit: int | None = None,
              executor=None) -> dict[str, Path]:
    """Run the benchmark and write its tables.

    Resumable: a run whose ``metrics.json`` exists and whose configuration equals the job's is
    reused (:func:`~compensation.experiments.jobs.reusable`); any other run folder is trained
    again. A failing run is recorded in ``failures.json`` and in ``results.csv`` (status
    ``failed``) and does not lose the others.

    Parameters
    ----------
    suite : list of Setup, or None
        The setups (e.g. ``load_suite("scenes/suite.toml")``), rendered into ``data_root`` where
        missing; None: every setup found under ``data_root`` (:func:`found_setups`), as it is.
    out : Path
        Output folder: ``runs/``, ``official/``, ``table{1,2,3}.{md,csv}``, ``per_setup.csv``,
        ``failures.json``, ``results.csv`` (point 0, with the ``table`` and ``variant`` (run
        name) of each row) and ``study.json``.
    cfg : BenchConfig
        What to run.
    data_root : Path, optional
        Where datasets are rendered (default ``out/data``); existing ones are reused. Required
        without a suite.
    white : Setup, optional
        The white-surface setup used for pre-training (Table 2).
    limit : int, optional
        Only the first ``limit`` setups.
    executor : LocalExecutor or RayExecutor, optional
        Where the jobs run (default: in this process, one after the other).

    Returns
    -------
    dict
        Paths of the files written, by name.

    Raises
    ------
    ProcamError
        Without a suite: if ``data_root`` is not given or holds no setup, or ``cfg.size`` is set
        (found setups keep their own size); if a setup cannot be rendered or its test captures
        scored.
    """
    out = Path(out)
    executor = executor or LocalExecutor()
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
    table2_white = "2" in cfg.tables and white is not None
    renders = [RenderJob(data_root, s, spec, progress)
               for s in [*(suite or []), *([white] if table2_white else [])]]
    gpus = executor.gpus()
    for job, done in zip(renders, executor.run(tasks(render, renders, gpus))):
        if not done["ok"]:  # the bench's setups are all needed: a refused render stops it
            raise ProcamError(f"render {job.setup.name}: {done['error']}")
    pretrain, pretrain_error = None, None
    if table2_white:
        pretrain = out / "runs" / white.name / "compennet-pretrain"
        pre_job = FitJob(data_root / white.name, _train_config(cfg, "compennet", max(cfg.sizes)), pretrain,
                         closed_loop=False, progress=progress)
        done = executor.run(tasks(fit, [pre_job], gpus))[0]
        pretrain_error = None if done["ok"] else f"pre-training on {white.name} failed: {done['error']}"

    bench_jobs = _jobs(cfg, setups, pretrain)
    fits = []
    for job in bench_jobs:
        job_values = dict(job.extra, loss=job.loss, init=str(Path(job.init).resolve()) if job.init else None)
        fits.append(FitJob(data_root / job.setup, _train_config(cfg, job.method, job.n_train, **job_values),
                           out / "runs" / job.setup / job.run_name, closed_loop=cfg.closed_loop,
                           official=out / "official" / job.setup, pretrained=job.init is not None,
                           progress=progress))
    masks = out / "reachable" if cfg.closed_loop else None
    bases = [BaselineJob(data_root / s, cfg.tests, cfg.closed_loop, masks) for s in setups]
    todo = [i for i, job in enumerate(bench_jobs) if not (job.init and pretrain_error)]
    done = executor.run(tasks(fit, [fits[i] for i in todo], gpus) + tasks(baselines, bases, gpus))
    fitted = {i: {"run": str(fits[i].run_dir), "ok": False, "error": pretrain_error} for i in range(len(fits))}
    fitted.update({i: {"run": str(fits[i].run_dir), **d} for i, d in zip(todo, done)})
    base = dict(zip(setups, done[len(todo):]))

    rows, failures, results = [], [], []
    seed = cfg.overrides.get("seed", 0)
    for i, job in enumerate(bench_jobs):
        record = fitted[i]
        results.append({"point": 0, "setup": job.setup, "method": job.method, "n_train": job.n_train,
                        "seed": seed, "table": job.table, "variant": job.run_name,
                        **result_row(record, base[job.setup], out)})
        if not record["ok"]:
            failures.append({**asdict(job), "error": record["error"], "traceback": record.get("traceback", "")})
            continue
        rows.append({**asdict(job), "extra": dict(job.extra), "run": record["run"],
                     "official_tag": record["official_tag"], **record["metrics"]})
    write_results(out, (), results, extra=("table", "variant"))
    write_study_record(out, {
        "name": out.name, "question": f"The CompenNet paper's Tables {', '.join(cfg.tables)} on these setups",
        "kind": "bench", "base": None, "axes": [], "methods": list(cfg.methods), "seeds": [seed],
        "n_train": list(cfg.sizes), "n_test": cfg.tests, "size": [cfg.canonical] * 2 if suite else None,
        "overrides": cfg.overrides, "tables": list(cfg.tables), "profile": cfg.profile,
        "executor": executor.name,
        "setups": {s: os.path.relpath(data_root / s / "setup.toml", out) for s in setups
                   if simulated(data_root / s)}})

    uncompensated, oracle, sizes = {}, {}, set()
    for s in setups:
        if not base[s]["ok"]:
            raise ProcamError(f"setup {s}: scoring the uncompensated test captures failed: {base[s]['error']}")
        uncompensated[s], size = base[s]["uncompensated"], tuple(base[s]["size"])
        sizes.add(size)
        if base[s]["oracle"] is not None:
            oracle[s] = base[s]["oracle"]
    image_size = ", ".join(f"{w}x{h}" if w != h else f"{w}²" for h, w in sorted(sizes)) + " px"
    return write_tables(out, cfg, rows, failures, uncompensated, oracle, image_size)
