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
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

from compensation.experiments.executors import LocalExecutor
from compensation.experiments.jobs import check_study_folder, simulated, write_results, write_study_record
from compensation.experiments.plans import (Plan, Point, Run, Scoring, execute, fit_sizes, result_rows,
                                           run_name)
from compensation.experiments.targets import TargetPolicy
from compensation.methods import applicable, check_runnable, get_method, make_config
from compensation.methods.compennet import CompenNetOptions
from compensation.training.config import COMMON, PROFILES
from sim.dataset import FrameSpec
from sim.errors import DatasetError, ProcamError
from sim.layout import SETUP_FILE, capture_dir


@dataclass(frozen=True)
class BenchConfig:
    """What ``procam bench`` runs."""

    profile: str = "quick"
    """Training profile (a key of :data:`~compensation.training.config.PROFILES`: ``quick``,
    ``faithful`` or ``paper``); also gives the canonical size and test count."""
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
    target: TargetPolicy = TargetPolicy()
    """What the closed loop scores against (:mod:`~compensation.experiments.targets`)."""
    test_frames: str = "mixed"
    """Kind of the rendered test frames (:data:`sim.images.FRAME_KINDS`: ``mixed`` or ``photo``)."""
    raw: bool = False
    """Keep the rendered setups' captures at camera resolution too (``cam/raw``)."""

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
            check_runnable(make_config(self.profile, name, **applicable(name, self.overrides)), None)

    @property
    def canonical(self) -> int:
        """Canonical square size in pixels."""
        return self.size or PROFILES[self.profile]["size"]

    @property
    def tests(self) -> int:
        """Test pairs per setup."""
        return self.n_test or PROFILES[self.profile]["n_test"]


LOSSES = ("l1", "l2", "ssim", "l1+ssim")
"""The training losses Table 3 compares."""
TABLE2 = dict(n_train=32, iters=500, batch=32)
"""The paper's fine-tuning setting for Table 2 (its run folders name the iterations and batch)."""
TABLE2_LR_STEP = 800
"""Table 2's learning-rate step: the official code's step schedule steps every 800 iterations
whatever their count, so not within the fine-tuning's 500 (whatever schedule the profile takes)."""
PRETRAIN = "compennet-pretrain"
"""Run folder name of Table 2's pre-training on the white setup."""


def _train_config(cfg: BenchConfig, method: str, n_train: int, **job_values):
    """The run configuration of one run: the user's options that ``method`` takes, then the run's
    own values. The user's word wins over a table's iterations and batch; the loss and
    initialisation that a table compares are the run's."""
    values = applicable(method, cfg.overrides)
    values.update({k: v for k, v in job_values.items()
                   if v is not None and (k in ("loss", "init") or k not in cfg.overrides)})
    return make_config(cfg.profile, method, **{**values, "n_train": n_train, "n_test": cfg.tests})


def table1_options(cfg: BenchConfig) -> dict[str, dict]:
    """Each Table 1 method's resolved options (profile, then the user's), as ``study.json``
    records them under ``options``: what a finished bench's rows were trained with."""
    return {m: asdict(_train_config(cfg, m, cfg.sizes[0]).options) for m in cfg.methods}


def bench_plan(cfg: BenchConfig, out: Path, suite: list | None, setups: list[str], white=None) -> Plan:
    """The runs of the bench's tables on ``setups`` (one point): Table 1's methods × sizes (a
    method on the plain colours fitted once per setup for all sizes),
    Table 2's He-initialised and pre-trained CompenNet (the pre-training on ``white`` first, run
    folder ``runs/<white>/compennet-pretrain``), Table 3's losses. Each run is labelled with its
    ``table`` and ``variant`` (the run folder's name)."""
    seed = cfg.overrides.get("seed", 0)
    point = Point(0)
    runs: list[Run] = []

    def add(table: str, setup: str, method: str, n: int, varied: dict, after: str | None = None,
            fixed: dict | None = None):
        fit_n, named_n = fit_sizes(method, n, min(cfg.sizes))
        name = run_name(method, named_n, seed, {**varied, **({"init": "pretrained"} if after else {})})
        train_cfg = _train_config(cfg, method, fit_n, **varied, **(fixed or {}),
                                  init=str((Path(out) / after).resolve()) if after else None)
        runs.append(Run(point, setup, method, n, seed, train_cfg, f"runs/{setup}/{name}",
                        {"table": table, "variant": name}, after))

    if "1" in cfg.tables:
        for s in setups:
            for m in cfg.methods:
                for n in cfg.sizes:
                    add("1", s, m, n, {})
    if "2" in cfg.tables:
        extra = {k: v for k, v in TABLE2.items() if k != "n_train"}
        pretrain = None
        if white is not None:
            pretrain = f"runs/{white.name}/{PRETRAIN}"
            runs.append(Run(point, white.name, "compennet", max(cfg.sizes), seed,
                            _train_config(cfg, "compennet", max(cfg.sizes)), pretrain,
                            {"table": "pretrain", "variant": PRETRAIN}, scored=False))
        # the official code's step schedule (lr_step selects it) at the paper's rate, unless the
        # user chose another
        fixed = ({"lr_step": TABLE2_LR_STEP, "lr": CompenNetOptions.lr}
                 if cfg.overrides.get("lr_schedule", "step") == "step" else {})
        for s in setups:
            add("2", s, "compennet", TABLE2["n_train"], extra, fixed=fixed)
            if pretrain is not None:
                add("2", s, "compennet", TABLE2["n_train"], extra, after=pretrain, fixed=fixed)
    if "3" in cfg.tables:
        for s in setups:
            for loss in LOSSES:
                add("3", s, "compennet", max(cfg.sizes), {"loss": loss})
    to_render = [*(suite or []), *([white] if "2" in cfg.tables and white is not None else [])]
    return Plan((point,), {s.name: s for s in to_render}, tuple(runs))


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
        if capture_dir(Path(folder)).is_dir():
            found.append(Path(folder).relative_to(root).as_posix())
            subfolders.clear()  # a setup holds no other setup
        subfolders.sort()
    if not found:
        raise ProcamError(f"{root}: no setup found (a setup is a folder holding cam/warp/)")
    return sorted(found)


@dataclass(frozen=True)
class BenchResult:
    """What a bench measured, as its tables need it (:func:`compensation.reports.tables.write_tables`)."""

    rows: list[dict]
    """One per finished run: its ``table``, ``setup``, ``method``, ``n_train``, ``loss`` (Table 3),
    ``init`` (Table 2's pre-trained runs), ``run``, ``official_tag`` and its ``metrics.json``."""
    failures: list[dict]
    """One per failed run: the same keys as a row (no metrics), ``error`` and ``traceback``."""
    uncompensated: dict
    """Setup name → scores of its test captures (with ``closed_loop`` scores when simulated)."""
    oracle: dict
    """Setup name → the iterative-refinement oracle's rows (closed loop, simulated setups)."""
    optimum: dict
    """Setup name → the exact optimum's scores (closed loop, simulated setups)."""
    image_size: str
    """The setups' image size for the titles (e.g. ``"64² px"``)."""


def run_bench(suite: list | None, out: Path, cfg: BenchConfig, data_root: Path | None = None,
              white=None, progress: bool = True, limit: int | None = None,
              executor=None) -> BenchResult:
    """Run the benchmark: render what is missing, fit and score every run of :func:`bench_plan`.

    Resumable: a run whose ``metrics.json`` exists and whose configuration equals the job's is
    reused (:func:`~compensation.experiments.jobs.reusable`); any other run folder is trained
    again. A failing run is recorded in ``results.csv`` (status ``failed``) and does not lose the
    others. The tables are written from the result by
    :func:`compensation.reports.tables.write_tables`.

    Parameters
    ----------
    suite : list of Setup, or None
        The setups (e.g. ``load_suite("scenes/suite.toml")``), rendered into ``data_root`` where
        missing; None: every setup found under ``data_root`` (:func:`found_setups`), as it is.
    out : Path
        Output folder: ``runs/``, ``official/``, ``baselines/``, ``results.csv`` (point 0, with the
        ``table`` and ``variant`` (run name) of each row) and ``study.json``.
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

    Raises
    ------
    ProcamError
        Without a suite: if ``data_root`` is not given or holds no setup, or ``cfg.size`` is set
        (found setups keep their own size); if ``out`` is not a folder this bench may write
        (:func:`~compensation.experiments.jobs.check_study_folder`); if a setup cannot be rendered
        or its test captures scored.
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
    plan = bench_plan(cfg, out, suite, setups, white)
    try:
        spec = FrameSpec(max(max(cfg.sizes), TABLE2["n_train"]), cfg.tests, (cfg.canonical,) * 2,
                         test_frames=cfg.test_frames)
    except DatasetError as e:  # named in the bench's terms: its training sizes are --sizes
        raise ProcamError(f"bench --sizes {','.join(map(str, cfg.sizes))} at {cfg.canonical}x{cfg.canonical} "
                          f"with {cfg.tests} test pairs: {e}") from None
    scoring = Scoring(cfg.tests, cfg.closed_loop, official=True, masks=cfg.closed_loop,
                      renders_required=True, target=cfg.target)
    check_study_folder(out, out.name, "bench")
    outcome = execute(plan, out, data_root, spec, scoring, executor, setups, progress, cfg.raw)
    seed = cfg.overrides.get("seed", 0)
    tabled = [r for r in plan.runs if r.labels["table"] != "pretrain"]
    write_results(out, (), result_rows(replace(plan, runs=tuple(tabled)), outcome, out),
                  extra=("table", "variant"))
    write_study_record(out, {
        "name": out.name, "question": f"The CompenNet paper's Tables {', '.join(cfg.tables)} on these setups",
        "kind": "bench", "base": None, "axes": [], "methods": list(cfg.methods), "seeds": [seed],
        "n_train": list(cfg.sizes), "n_test": cfg.tests, "size": [cfg.canonical] * 2 if suite else None,
        "overrides": cfg.overrides, "tables": list(cfg.tables), "profile": cfg.profile,
        "options": table1_options(cfg), "test_frames": cfg.test_frames,
        "target": cfg.target.record() if cfg.closed_loop else None, "executor": executor.name,
        "setups": {s: os.path.relpath(data_root / s / SETUP_FILE, out) for s in setups
                   if simulated(data_root / s)}})

    rows, failures = [], []
    for r in tabled:
        record = outcome.fitted[r.run]
        job = {"table": r.labels["table"], "setup": r.setup, "method": r.method, "n_train": r.n_train,
               "loss": r.cfg.options.loss if r.labels["table"] == "3" else None,
               "init": r.cfg.options.init if r.after else None, "run": record["run"]}
        if record["ok"]:
            # the row's size, not the fit's (a plain-colour run serves every size)
            rows.append({**job, "official_tag": record["official_tag"], **record["metrics"], "n_train": r.n_train})
        else:
            failures.append({**job, "error": record["error"], "traceback": record.get("traceback", "")})
    uncompensated, oracle, optimum, sizes = {}, {}, {}, set()
    for s in setups:
        base = outcome.base.get(s, {"ok": False, "error": "not run"})
        if not base["ok"]:
            raise ProcamError(f"setup {s}: scoring the uncompensated test captures failed: {base['error']}")
        uncompensated[s], size = base["uncompensated"], tuple(base["size"])
        sizes.add(size)
        if base["oracle"] is not None:
            oracle[s] = base["oracle"]
        if base.get("optimum") is not None:
            optimum[s] = base["optimum"]
    image_size = ", ".join(f"{w}x{h}" if w != h else f"{w}²" for h, w in sorted(sizes)) + " px"
    return BenchResult(rows, failures, uncompensated, oracle, optimum, image_size)
