"""The ``procam`` console script: one sub-command per task, on top of every other module."""
from __future__ import annotations

import argparse
import sys
import types
import typing
from pathlib import Path

from sim.errors import ProcamError
from sim.options import repeated
from sim.setup import load_setups, select_setups


MIN_SIDE = 4
"""Fewest canonical pixels along a side that ``render`` and ``bench`` take (a study takes 8, its
file's least, and says so)."""


def _side(text: str) -> int:
    """Parse a square canonical size ``256`` (>= :data:`MIN_SIDE`)."""
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < MIN_SIDE:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected an integer >= {MIN_SIDE} (pixels)")
    return value


def _size(text: str) -> tuple[int, int]:
    """Parse ``256`` or ``320x240`` into (width, height), each >= :data:`MIN_SIDE`."""
    try:
        parts = [int(p) for p in text.lower().split("x")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected N or WxH in pixels") from None
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or min(parts) < MIN_SIDE:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected N or WxH, each >= {MIN_SIDE} pixels")
    return parts[0], parts[1]


def cmd_render(args: argparse.Namespace) -> None:
    from sim.dataset import FrameSpec, check_counts, check_inputs, check_render, write_setup

    setups = select_setups(load_setups(args.setup), args.only, args.setup)
    if args.list:
        print("\n".join(s.name for s in setups))
        return
    # your own frames replace the generated ones, whatever kind the suite asks for
    kind = (args.test_frames or "mixed") if args.images else _test_frames(args, args.setup)
    spec = FrameSpec(args.n_train, args.n_test, args.size, args.frame_seed, args.images, kind)
    for setup in setups:  # every setup of a suite is checked before the first is rendered
        check_render(setup, spec, args.fidelity, args.spp)
    check_counts(Path(args.out), spec, [s.name for s in setups])
    textures = [s.surface.texture for s in setups if Path(s.surface.texture).is_file()]
    check_inputs(Path(args.out), [s.name for s in setups],
                 [p for p in (args.setup, *textures, args.images) if p and Path(p).exists()])
    for setup in setups:
        out = write_setup(Path(args.out), setup, spec, args.fidelity, args.spp,
                          progress=not args.quiet, overwrite=args.overwrite, raw=args.raw)
        print(f"procam: {setup.name} -> {out}")


def _test_frames_option(p) -> None:
    from sim.images import FRAME_KINDS

    p.add_argument("--test-frames", choices=FRAME_KINDS, default=None,
                   help="the generated test frames: mixed (photographs, patterns and blends, as the "
                        "training frames) or photo (natural images only, as in the paper's "
                        "datasets); default: what the suite file says (its test_frames), else mixed")


def _test_frames(args: argparse.Namespace, spec: str | None) -> str:
    """``--test-frames`` as given, else the suite's ``test_frames`` (:func:`sim.setup.suite_test_frames`),
    else ``mixed``."""
    from sim.setup import suite_test_frames

    return args.test_frames or (suite_test_frames(spec) if spec else None) or "mixed"


RAW_HELP = ("also keep every capture at camera resolution (cam/raw: 960x640 PNGs on the shipped "
            "scenes, before the warp into cam/warp), as the official layout has them; no method reads "
            "them")
"""Help of ``--raw`` (render, bench, study)."""


def add_render(sub) -> None:
    p = sub.add_parser("render", help="render a setup (or suite) into a dataset",
                       description="Render projector frames through a simulated setup into the "
                                   "dataset layout of docs/architecture.md (resumable).")
    p.add_argument("setup", help="setup or suite file, or a shipped scene name (default, white, …)")
    p.add_argument("--out", default="data", help="dataset root (default: data)")
    p.add_argument("--n-train", type=int, default=500, help="training frames (default 500)")
    p.add_argument("--n-test", type=int, default=200, help="test frames (default 200)")
    p.add_argument("--size", type=_size, default=(256, 256), help="canonical size N or WxH (default 256)")
    p.add_argument("--images", default=None, help="folder of your own projector frames (sorted by name)")
    p.add_argument("--frame-seed", type=int, default=0, help="seed of the frame generator (default 0)")
    _test_frames_option(p)
    p.add_argument("--fidelity", choices=["auto", "path", "direct", "transport"], default=None,
                   help="override the setup's rendering level (auto: measure and pick the cheapest "
                        "below the camera noise; transport: a light-transport operator calibrated "
                        "once from direct renders at --spp)")
    p.add_argument("--spp", type=int, default=None, help="override the setup's samples per pixel")
    p.add_argument("--overwrite", action="store_true",
                   help="render again a folder rendered from another setup, variant, fidelity, spp "
                        "or size (instead of refusing it); on a finished folder, check every file "
                        "and re-render the damaged ones")
    p.add_argument("--raw", action="store_true", help=RAW_HELP)
    p.add_argument("--only", metavar="NAME[,NAME…]", default=None,
                   help="render only these setups of the suite (comma-separated names)")
    p.add_argument("--list", action="store_true",
                   help="print the setup names (one per line, after --only) and render nothing")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_render)


def _twice(values: tuple) -> list[str]:
    """The values given more than once, as text (a list option runs each value once)."""
    return [str(v) for v in repeated(values)]


def _spp_list(text: str) -> tuple[int, ...]:
    """Parse ``1,4,16`` into samples per pixel (each >= 1, each once)."""
    try:
        values = tuple(int(t) for t in text.split(","))
    except ValueError:
        values = ()
    if not values or min(values) < 1 or _twice(values):
        raise argparse.ArgumentTypeError(f"spp {text!r}: expected comma-separated distinct integers >= 1")
    return values


def cmd_bench_sim(args: argparse.Namespace) -> None:
    from sim.bench_sim import bench_sim
    from sim.fidelity import PROBE_CLASSES

    classes = _names(args.classes, "--classes") if args.classes else PROBE_CLASSES
    unknown = [c for c in classes if c not in PROBE_CLASSES]
    if unknown:
        raise ProcamError(f"--classes {args.classes!r}: unknown {', '.join(unknown)}; expected "
                          f"some of {', '.join(PROBE_CLASSES)}")
    for setup in load_setups(args.setup):
        files = bench_sim(setup, Path(args.out), reference_spp=args.ref_spp, classes=classes,
                          window=args.window, spp=args.spp, repeats=args.repeats,
                          progress=not args.quiet)
        print(f"procam: {setup.name} -> {files['csv']}, {files['chart']}")
        print(f"procam: {files['sentence']}")


def add_bench_sim(sub) -> None:
    p = sub.add_parser("bench-sim", help="speed vs accuracy of every fidelity level of a setup",
                       description="Time every level x spp (path, direct, transport) and measure "
                                   "its error against a converged path-traced reference on probe "
                                   "frames (smooth, 1-2 px stripes, random pixels, natural); write "
                                   "a chart with the camera noise floor and the auto choice, and a "
                                   "CSV.")
    p.add_argument("setup", help="setup or suite file, or a shipped scene name (default, corner, …)")
    p.add_argument("--out", required=True, help="output folder for bench_sim_<setup>.{png,csv}")
    p.add_argument("--ref-spp", type=int, default=1024, help="samples per pixel of the reference (1024)")
    p.add_argument("--classes", default=None, help="comma-separated probe classes (default: all)")
    p.add_argument("--window", type=int, default=None,
                   help="render only a central camera window of N pixels a side (faster)")
    p.add_argument("--spp", type=_spp_list, default=(1, 4, 16, 64, 256),
                   help="comma-separated samples per pixel per level (default 1,4,16,64,256)")
    p.add_argument("--repeats", type=int, default=3, help="timed captures per level x spp (3)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=cmd_bench_sim)


def _positive(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive integer")
    return value


def _int_list(text: str) -> tuple[int, ...]:
    values = tuple(_positive(t) for t in text.split(","))
    if twice := _twice(values):
        raise argparse.ArgumentTypeError(f"{text!r}: {', '.join(twice)} given twice; expected distinct "
                                         "positive integers")
    return values


def _option_type(hint) -> dict:
    """argparse keywords (``type``, ``choices`` or ``action``) for a dataclass field's type hint."""
    args = [a for a in typing.get_args(hint) if a is not type(None)]
    if typing.get_origin(hint) is typing.Literal:
        return {"choices": list(typing.get_args(hint))}
    if args and typing.get_origin(hint) in (types.UnionType, typing.Union):
        return _option_type(args[0])
    if hint is bool:
        return {"action": argparse.BooleanOptionalAction}
    return {"type": hint}


def _help_text(doc: str) -> str:
    """A docstring as argparse help: its ``%`` escaped, since argparse formats help with ``%``.

    Examples
    --------
    >>> _help_text("after 80 % of iters")
    'after 80 %% of iters'
    """
    return doc.replace("%", "%%")


def _training_options(p: argparse.ArgumentParser) -> None:
    """The profile, the options common to every method and every registered method's own options,
    generated from their dataclasses (type, choices and the field's docstring as help)."""
    from compensation.methods import METHODS, option_owners
    from compensation.training.config import COMMON, PROFILES, TrainConfig, field_docs

    p.add_argument("--profile", choices=list(PROFILES), default="quick",
                   help="quick: CPU-sized (64²); faithful: the paper's 256² and 125 pairs on a CPU "
                        "(CompenNet on 64-px windows); paper: 256², 500 pairs, 1000 iterations, "
                        "batch 64")
    common = p.add_argument_group("options of every method")
    hints = typing.get_type_hints(TrainConfig)
    for name in COMMON:
        common.add_argument(f"--{name.replace('_', '-')}", dest=name, default=None,
                            help=_help_text(field_docs(TrainConfig)[name]),
                            **_option_type(hints[name]))
    own = p.add_argument_group("method options (refused for a method that does not use them)")
    for name, owners in option_owners().items():
        cls = METHODS[owners[0]].options
        own.add_argument(f"--{name.replace('_', '-')}", dest=name, default=None,
                         help=_help_text(f"[{', '.join(owners)}] {field_docs(cls)[name]}"),
                         **_option_type(typing.get_type_hints(cls)[name]))
    p.add_argument("--quiet", action="store_true", help="no progress bar")


def _given_options(args: argparse.Namespace) -> dict:
    """The training options given on the command line (common and method options)."""
    from compensation.methods import option_owners
    from compensation.training.config import COMMON

    names = (*COMMON, *option_owners())
    return {k: getattr(args, k) for k in names if getattr(args, k, None) is not None}


def _fraction(text: str) -> float:
    """Parse a share of pixels in [0, 1)."""
    try:
        value = float(text)
    except ValueError:
        value = -1.0
    if not 0 <= value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a fraction in [0, 1), e.g. 0.01")
    return value


def _target_options(p: argparse.ArgumentParser, default: str | None) -> None:
    """``--target-policy`` and ``--out-of-reach`` (None defaults: the study file's)."""
    from compensation.experiments.targets import DEFAULT_OUT_OF_REACH, POLICIES

    g = p.add_argument_group("closed-loop target")
    shown = f"default {default}" if default else "default: the study file's, else global"
    g.add_argument("--target-policy", choices=POLICIES, default=default,
                   help="what the desired image y is mapped to before it is compensated and "
                        "scored: none (y as is), global (one map y' = a·y + b per setup, the "
                        "largest contrast a that keeps all but --out-of-reach of the pixels within "
                        f"what the projector can show), image (that map per desired image); {shown}")
    g.add_argument("--out-of-reach", type=_fraction, default=None if default is None else DEFAULT_OUT_OF_REACH,
                   help=f"share of pixels a global or image map may leave out of reach (default "
                        f"{DEFAULT_OUT_OF_REACH:g})")


def _target(args: argparse.Namespace):
    from compensation.experiments.targets import TargetPolicy

    return TargetPolicy(args.target_policy, args.out_of_reach)


def cmd_train(args: argparse.Namespace) -> None:
    from compensation.experiments.runs import train_run
    from compensation.methods import make_config

    cfg = make_config(args.profile, args.method, **_given_options(args))
    metrics = train_run(args.setup_dir, cfg, args.out, progress=not args.quiet, overwrite=args.overwrite)
    print(f"procam: {args.method} on {metrics['setup']} -> {args.out}")
    print(f"  surrogate test: PSNR {metrics['psnr']:.2f} dB, RMSE {metrics['rmse']:.4f}, "
          f"SSIM {metrics['ssim']:.4f}, ΔE {metrics['deltaE']:.2f} "
          f"(uncompensated PSNR {metrics['uncompensated']['psnr']:.2f} dB)")


def add_train(sub) -> None:
    from compensation.methods import METHODS

    p = sub.add_parser("train", help="train a compensation method on a rendered setup",
                       description="Train a method on DATA_ROOT/<setup> and write a run directory. "
                                   "Each method takes the common options and its own; an option "
                                   "the method does not use is refused.")
    p.add_argument("setup_dir", help="a setup folder, e.g. data/default or the official benchmark's "
                                     "ROOT/light2/pos1/curves")
    p.add_argument("--method", default="compennet", choices=sorted(METHODS))
    p.add_argument("--out", required=True, help="run directory to create")
    p.add_argument("--overwrite", action="store_true", help="replace an existing run")
    _training_options(p)
    p.set_defaults(func=cmd_train)


def _compensate_outputs(out: Path, desired: list[str], names: list[str], inputs: list[str],
                        overwrite: bool) -> list[Path]:
    """The files ``procam compensate`` writes: ``out`` itself for one desired image and a ``.png``
    name, else ``out/<name>.png`` per image.

    Raises
    ------
    ProcamError
        Before anything is written: if an output would replace one of the inputs (a desired
        image, the surface, the run or checkpoint, the run's dataset), or (without ``overwrite``)
        an existing file, ``out`` names a file of another image type for one image, or ``out`` is
        an existing file for several.
    """
    if len(desired) == 1 and out.suffix.lower() == ".png":
        targets = [out]
    elif len(desired) == 1 and out.suffix and not out.is_dir():
        raise ProcamError(f"--out {out}: the projector frame is written as PNG; name it .png, or give "
                          "a folder")
    elif out.is_file():
        raise ProcamError(f"--out {out}: an existing file; {len(desired)} frames need a folder")
    else:
        targets = [out / n for n in names]
    kept = {Path(p).resolve(): p for p in [*desired, *inputs]}
    for target in targets:
        path = target.resolve()
        if owner := next((q for q in (path, *path.parents) if q in kept), None):
            where = "overwrite" if owner == path else "write inside"
            raise ProcamError(f"--out {out}: would {where} the input {kept[owner]}; choose another output")
        if target.exists() and not overwrite:
            raise ProcamError(f"--out {out}: {target} exists; pass --overwrite to replace it")
    return targets


def cmd_compensate(args: argparse.Namespace) -> None:
    import cv2
    import numpy as np
    import torch

    from compensation.experiments.runs import compensate, compensation_target, read_run_config, run_size
    from sim.io import read_png, to_float, to_uint8, write_png

    def tensor(images: list) -> torch.Tensor:
        return torch.from_numpy(to_float(np.stack(images))).permute(0, 3, 1, 2)

    names = [Path(p).with_suffix(".png").name for p in args.desired]
    if Path(args.run).is_file() and not args.surface:
        raise ProcamError(f"{args.run}: a state dict file needs --surface IMAGE (the capture of the "
                          "gray frame, e.g. cam/warp/ref/img_gray.png), which also gives the size")
    dataset = read_run_config(args.run).get("dataset") if Path(args.run).is_dir() else None
    targets = _compensate_outputs(Path(args.out), args.desired, names,
                                  [args.run, *([args.surface] if args.surface else []),
                                   *([dataset] if isinstance(dataset, str) else [])], args.overwrite)
    surface = read_png(args.surface) if args.surface else None
    if Path(args.run).is_file():
        h, w = surface.shape[:2]
    else:
        w, h = run_size(read_run_config(args.run))
    if len(args.desired) > 1 and len(set(names)) < len(names):
        clash = sorted({n for n in names if names.count(n) > 1})
        raise ProcamError(f"desired images {', '.join(clash)}: two inputs would write one output "
                          "file; rename them or compensate them separately")
    images = [read_png(path) for path in args.desired] + ([surface] if surface is not None else [])
    images = [img if img.shape[:2] == (h, w) else cv2.resize(img, (w, h), interpolation=cv2.INTER_AREA)
              for img in images]
    desired = tensor(images[:len(args.desired)])
    desired, mapped = compensation_target(args.run, desired, _target(args))
    frames = compensate(args.run, desired, tensor(images[-1:]) if surface is not None else None)
    if mapped["policy"] != "none":
        print(f"procam: compensating y' = a·y + b ({mapped['policy']} target, at most "
              f"{100 * mapped['out_of_reach']:g} % of the pixels out of reach): a = {mapped['a']:.4f}, "
              f"b = {mapped['b']:.4f}" + (" (means over the images)" if mapped["policy"] == "image" else ""))
    frames = frames.permute(0, 2, 3, 1).numpy()
    for target, frame in zip(targets, frames):
        write_png(target, to_uint8(frame))
        print(f"procam: projector frame -> {target}")


def add_compensate(sub) -> None:
    p = sub.add_parser("compensate", help="the projector frame that shows a desired image",
                       description="x* = π†(y): the frame to send to the projector so that the "
                                   "setup of a trained run (or an official CompenNet checkpoint) "
                                   "shows the desired image y (with --target-policy global or image: "
                                   "y mapped into what the run's setup can show, x* = π†(y')).")
    p.add_argument("run", help="a run directory written by `procam train`, or a CompenNet state dict "
                               "file (.pth, e.g. from the official code; needs --surface)")
    p.add_argument("desired", nargs="+", help="desired image(s) (PNG/JPEG), resized to the run's size "
                                              "(a .pth: the surface image's size)")
    p.add_argument("--surface", help="surface image s̃ (the capture of the gray frame in the projector "
                                     "view); required with a .pth, for a run it replaces the one of "
                                     "the dataset it was trained on")
    p.add_argument("--out", required=True, help="output PNG (one image) or folder")
    p.add_argument("--overwrite", action="store_true",
                   help="replace output files that exist (never an input: the run, its dataset, a "
                        "desired or surface image)")
    _target_options(p, "none")
    p.set_defaults(func=cmd_compensate)


def _executor_options(p: argparse.ArgumentParser) -> None:
    from compensation.experiments.executors import EXECUTORS

    g = p.add_argument_group("where the jobs run")
    g.add_argument("--executor", choices=EXECUTORS, default="local",
                   help="local: in this process (or --processes N); ray: one Ray task per job "
                        "(render, fit, score), on this machine or the cluster at --address")
    g.add_argument("--address", default=None,
                   help="Ray cluster to join: 'auto' (the one `ray start --head` runs here) or "
                        "ray://HOST:10001; default: a Ray instance started for this command")
    g.add_argument("--processes", type=_positive, default=1,
                   help="local executor: worker processes running jobs side by side (default 1), each "
                   "computing on its share of the cores unless OMP_NUM_THREADS is set")


def _executor(args: argparse.Namespace):
    from compensation.experiments.executors import make_executor

    return make_executor(args.executor, args.address, args.processes)


def cmd_bench(args: argparse.Namespace) -> None:
    from compensation.experiments.bench import BenchConfig, run_bench
    from compensation.reports.tables import write_tables

    options = _given_options(args)
    n_test = options.pop("n_test", None)
    if "n_train" in options:
        raise ProcamError("--n-train: the bench takes its training sizes from --sizes")
    cfg = BenchConfig(profile=args.profile, methods=_names(args.methods, "--methods"),
                      sizes=args.sizes, tables=_names(args.tables, "--tables"), size=args.size,
                      n_test=n_test, overrides=options, closed_loop=args.closed_loop, target=_target(args),
                      test_frames=_test_frames(args, args.suite), raw=args.raw)
    if args.only is not None and not args.suite:
        raise ProcamError("--only selects setups of a suite: give the suite (the setups found under "
                          "--data are all taken)")
    if args.raw and not args.suite:
        raise ProcamError("--raw keeps the raw captures of the setups a bench renders: give the suite "
                          "(the setups found under --data are taken as they are, not rendered)")
    suite = select_setups(load_setups(args.suite), args.only, args.suite) if args.suite else None
    white = load_setups(args.white)[0] if suite and "2" in cfg.tables else None
    executor = _executor(args)
    result = run_bench(suite, Path(args.out), cfg, Path(args.data) if args.data else None, white,
                       progress=not args.quiet and executor.name == "local", limit=args.limit,
                       executor=executor)
    files = write_tables(Path(args.out), cfg, result)
    for name, path in files.items():
        print(f"procam: {name} -> {path}")
    for name in ("table1", "table2", "table3"):
        if name in files:
            print(Path(files[name]).read_text())
    if result.failures:
        total = len(result.rows) + len(result.failures)
        if not result.rows:
            raise ProcamError(f"every one of the {total} runs failed (their errors are in {files['failures']}); "
                              "the tables hold no result")
        print(f"procam: warning: {len(result.failures)} of {total} runs failed (their errors are in "
              f"{files['failures']}); the tables average the runs that finished", file=sys.stderr)


def add_bench(sub) -> None:
    p = sub.add_parser("bench", help="the paper's tables over a suite of setups or a dataset",
                       description="Render what is missing, train every method x size x setup, "
                                   "evaluate, and write Tables 1-3 (Markdown, CSV and LaTeX) beside the "
                                   "paper's figures, and each run's outputs in the official layout "
                                   "(OUT/official/<setup>/{cam,prj}/cmp/<tag>). Without a suite, "
                                   "every setup found under --data (a folder holding cam/warp, "
                                   "e.g. the official benchmark's light2/pos1/curves) is taken as "
                                   "it is and nothing is rendered. Resumable.")
    p.add_argument("suite", nargs="?", help="suite or setup file, or a shipped scene name (suite); "
                                            "omitted: the setups found under --data")
    p.add_argument("--out", required=True, help="output folder (runs, tables, official outputs)")
    p.add_argument("--data", help="dataset root (default OUT/data; required without a suite)")
    p.add_argument("--methods", default="compennet,compennet-nosurf", help="comma-separated methods")
    p.add_argument("--sizes", type=_int_list, default=(125, 250, 500), help="training sizes, e.g. 125,250,500")
    p.add_argument("--tables", default="1,2,3", help="which tables (default 1,2,3)")
    p.add_argument("--size", type=_side, help=f"canonical size override (pixels, >= {MIN_SIDE})")
    p.add_argument("--white", default="white",
                   help="white-surface setup for pre-training (Table 2; with a suite only)")
    p.add_argument("--only", metavar="NAME[,NAME…]", default=None,
                   help="only these setups of the suite (comma-separated names)")
    p.add_argument("--limit", type=_positive, help="only the first N setups (after --only)")
    p.add_argument("--closed-loop", action="store_true",
                   help="also project every compensation back through the setup and score it "
                        "(simulated setups only: those with a setup.toml)")
    p.add_argument("--raw", action="store_true", help=RAW_HELP)
    _test_frames_option(p)
    _training_options(p)
    _target_options(p, "global")
    _executor_options(p)
    p.set_defaults(func=cmd_bench)


def _names(text: str, option: str) -> tuple[str, ...]:
    """The comma-separated names of ``option``; refused when none is given (``--only ,``) or one
    twice."""
    names = tuple(m.strip() for m in text.split(",") if m.strip())
    if not names:
        raise ProcamError(f"{option} {text!r}: expected one or more comma-separated names")
    if twice := _twice(names):
        raise ProcamError(f"{option} {text!r}: {', '.join(twice)} given twice; expected each once")
    return names


def cmd_study(args: argparse.Namespace) -> None:
    from compensation.experiments.studies import load_study, run_study, study_file, with_overrides

    study = with_overrides(load_study(study_file(args.study), args.profile), size=args.size, n_train=args.n_train,
                           n_test=args.n_test, iters=args.iters, seeds=args.seeds,
                           methods=_names(args.methods, "--methods") if args.methods is not None else None,
                           only=_names(args.only, "--only") if args.only is not None else None,
                           target_policy=args.target_policy, out_of_reach=args.out_of_reach,
                           closed_loop=False if args.surrogate_only else None,
                           raw=True if args.raw else None)
    executor = _executor(args)
    done = run_study(study, Path(args.out), executor, progress=not args.quiet and executor.name == "local")
    print(f"procam: study {study.name}: {done['jobs']} runs ({done['trained']} trained, "
          f"{done['reused']} reused), {done['failed']} of {done['rows']} result rows failed, "
          f"{done['setups']} setups")
    print(f"procam: study -> {done['study']}")
    print(f"procam: results -> {done['results']}")
    if done["failed"]:
        print(f"procam: warning: {done['failed']} of {done['rows']} result rows failed (their errors are in "
              f"results.csv and failures.csv)", file=sys.stderr)
    from compensation.reports.report import build_report

    page = build_report(Path(args.out))
    print(f"procam: summary, break points, failures -> {Path(args.out)}/*.csv; charts -> "
          f"{Path(args.out) / 'charts'}")
    print(f"procam: report -> {page}")
    if done["rows"] and done["failed"] == done["rows"]:
        raise ProcamError(f"every one of the {done['rows']} result rows failed (their errors are in "
                          f"{Path(args.out) / 'failures.csv'} and the report); the study holds no result")


def add_study(sub) -> None:
    from compensation.training.config import PROFILES

    p = sub.add_parser("study", help="how each method's scores change with a factor of the setup",
                       description="Run a declarative study (a TOML file: a base setup or suite, "
                                   "one or two axes over setup keys or training options, methods, "
                                   "seeds): render each point's setup, fit each method per seed, "
                                   "score it on held-out pairs and in closed loop, and write "
                                   "OUT/study.json, OUT/results.csv, the summary, break-point and "
                                   "failure CSVs, the charts and OUT/report.html. Resumable: a finished job "
                                   "with the same configuration is reused.")
    p.add_argument("study", help="study file, or the name of a shipped study (scenes/studies/)")
    p.add_argument("--out", required=True, help="study folder")
    p.add_argument("--profile", choices=list(PROFILES),
                   help="training profile instead of the study file's (its sizes apply where the "
                        "file gives none; faithful trains CompenNet on 64-px windows, so a size "
                        "of at least 64)")
    smoke = p.add_argument_group("overrides (smoke runs)")
    smoke.add_argument("--size", type=_size, help="canonical size N or WxH (pixels)")
    smoke.add_argument("--n-train", type=_int_list, help="training pairs, e.g. 16 or 8,32 (replaces an "
                                                         "n_train axis's values)")
    smoke.add_argument("--n-test", type=_positive, help="test pairs")
    smoke.add_argument("--iters", type=_positive, help="iterations of the network methods (replaces an "
                                                       "iters axis's values)")
    smoke.add_argument("--seeds", type=_positive, help="run the seeds 0 .. N-1")
    smoke.add_argument("--methods", help="comma-separated methods, e.g. tps,compennet")
    smoke.add_argument("--only", help="comma-separated point numbers or setup-name patterns "
                                      "(e.g. 0,2 or '*aperture-0p01*'); results.csv then holds "
                                      "their rows only")
    smoke.add_argument("--surrogate-only", action="store_true",
                       help="score the held-out pairs only, no closed loop (as closed_loop = false "
                            "in the study file)")
    p.add_argument("--raw", action="store_true", help=RAW_HELP + " (as raw = true in the study file)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    _target_options(p, None)
    _executor_options(p)
    p.set_defaults(func=cmd_study)


def cmd_demo(args: argparse.Namespace) -> None:
    from compensation.demo import run_demo

    run_demo(Path(args.out), progress=not args.quiet, target=_target(args))


def add_demo(sub) -> None:
    p = sub.add_parser("demo", help="the whole pipeline on embedded defaults (minutes on a CPU)",
                       description="Render the default setup (quick profile), fit CompenNet "
                                   "and TPS, evaluate them (surrogate and closed loop, beside the "
                                   "iterative-feedback oracle), print the table and write a figure.")
    p.add_argument("--out", default="out", help="output folder (default: out)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    _target_options(p, "global")
    p.set_defaults(func=cmd_demo)


def cmd_report(args: argparse.Namespace) -> None:
    from compensation.reports.report import build_report

    print(f"procam: report -> {build_report(Path(args.folder))}")


def add_report(sub) -> None:
    p = sub.add_parser("report", help="one self-contained HTML page for a study or bench folder",
                       description="Write DIR/report.html: each method's break point, a figure grid "
                                   "(surface, uncompensated, each method's closed-loop capture, "
                                   "desired, with zoomed patches), every chart, the tables, the "
                                   "failures and the provenance, images inline (no network needed). "
                                   "Also writes summary.csv, breakpoints.csv, failures.csv and "
                                   "charts/ from the folder's results.")
    p.add_argument("folder", help="a folder written by `procam study` or `procam bench`")
    p.set_defaults(func=cmd_report)


def cmd_compare(args: argparse.Namespace) -> None:
    from compensation.reports.compare import compare_folders, summary_lines

    result = compare_folders(Path(args.a), Path(args.b), Path(args.out) if args.out else None)
    for line in summary_lines(result):
        print(f"procam: compare: {line}")
    print(f"procam: compare -> {result['csv']}")
    print(f"procam: compare -> {result['md']}")


def add_compare(sub) -> None:
    p = sub.add_parser("compare", help="two study or bench folders side by side (B against A)",
                       description="Match the runs of A's and B's results.csv (a study: axis values, "
                                   "setup, method, n_train, seed; a bench: table, setup, method, "
                                   "n_train, variant, seed) and write compare.csv and compare.md: "
                                   "each score in A, in B and B - A with its 95 % bootstrap interval "
                                   "(over the paired test images where both have per_image.csv, else "
                                   "over setups and seeds), per point and method and per run; runs "
                                   "found in one folder only are listed.")
    p.add_argument("a", help="a folder written by `procam study` or `procam bench`")
    p.add_argument("b", help="another folder of the same study or bench")
    p.add_argument("--out", help="output folder (default: A/compare-<name of B>)")
    p.set_defaults(func=cmd_compare)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="procam", description="Physically simulated projector–camera "
                                     "testbed for projector photometric compensation.")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (add_render, add_bench_sim, add_train, add_compensate, add_bench, add_study, add_demo,
                add_report, add_compare):
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``procam`` console script; user errors exit with status 2.

    A file-system error that no command turned into a :class:`ProcamError` (a full disk, a folder
    that cannot be written) is reported the same way, naming the file, instead of a traceback;
    Ctrl-C ends with status 130 and a line saying that a rerun goes on.
    """
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except ProcamError as exc:
        print(f"procam: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        why = {FileExistsError: ": expected a folder (or nothing) there, found a file",
               NotADirectoryError: ": a part of this path is a file where a folder is expected"}
        print(f"procam: error: {where}{exc.strerror or exc}{why.get(type(exc), '')}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("procam: interrupted; what is finished is kept: run the same command again to go on",
              file=sys.stderr)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
