"""The ``procam`` console script: the one place that wires the simulator and the learning side."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sim.errors import ProcamError


def _size(text: str) -> tuple[int, int]:
    """Parse ``256`` or ``320x240`` into (width, height)."""
    try:
        parts = [int(p) for p in text.lower().split("x")]
    except ValueError:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected N or WxH in pixels") from None
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or min(parts) < 4:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected N or WxH, each >= 4 pixels")
    return parts[0], parts[1]


def load_setups(spec: str) -> list:
    """Setups named on the command line: a setup file, a suite file or a shipped scene name."""
    from sim.setup import load_setup, load_suite, scene_path

    path = Path(spec)
    if not path.exists():
        path = scene_path(spec)
    import tomllib

    try:
        is_suite = "setup" in tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise ProcamError(f"{path}: cannot read setup file ({exc})") from None
    return load_suite(path) if is_suite else [load_setup(path)]


def cmd_render(args: argparse.Namespace) -> None:
    from sim.dataset import FrameSpec, write_setup

    setups = load_setups(args.setup)
    spec = FrameSpec(args.n_train, args.n_test, args.size, args.frame_seed, args.images)
    for setup in setups:
        out = write_setup(Path(args.out), setup, spec, args.fidelity, args.spp,
                          progress=not args.quiet, overwrite=args.overwrite)
        print(f"procam: {setup.name} -> {out}")


def add_render(sub) -> None:
    p = sub.add_parser("render", help="render a setup (or suite) into a dataset",
                       description="Render projector frames through a simulated setup into the "
                                   "dataset layout of design.md §5 (resumable).")
    p.add_argument("setup", help="setup or suite file, or a shipped scene name (default, white, …)")
    p.add_argument("--out", default="data", help="dataset root (default: data)")
    p.add_argument("--n-train", type=int, default=500, help="training frames (default 500)")
    p.add_argument("--n-test", type=int, default=200, help="test frames (default 200)")
    p.add_argument("--size", type=_size, default=(256, 256), help="canonical size N or WxH (default 256)")
    p.add_argument("--images", default=None, help="folder of your own projector frames (sorted by name)")
    p.add_argument("--frame-seed", type=int, default=0, help="seed of the frame generator (default 0)")
    p.add_argument("--fidelity", choices=["auto", "path", "direct", "transport"], default=None,
                   help="override the setup's rendering level (auto: measure and pick the cheapest "
                        "below the camera noise; transport: a light-transport operator calibrated "
                        "once from direct renders at --spp)")
    p.add_argument("--spp", type=int, default=None, help="override the setup's samples per pixel")
    p.add_argument("--overwrite", action="store_true", help="replace a folder rendered from another setup")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_render)


def _spp_list(text: str) -> tuple[int, ...]:
    """Parse ``1,4,16`` into samples per pixel (each >= 1)."""
    try:
        values = tuple(int(t) for t in text.split(","))
    except ValueError:
        values = ()
    if not values or min(values) < 1:
        raise argparse.ArgumentTypeError(f"spp {text!r}: expected comma-separated integers >= 1")
    return values


def cmd_bench_sim(args: argparse.Namespace) -> None:
    from sim.bench_sim import bench_sim
    from sim.fidelity import PROBE_CLASSES

    classes = tuple(args.classes.split(",")) if args.classes else PROBE_CLASSES
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="procam", description="Physically simulated projector–camera "
                                     "testbed for projector photometric compensation.")
    sub = parser.add_subparsers(dest="command", required=True)
    for add in (add_render, add_bench_sim):
        add(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``procam`` console script; user errors exit with status 2."""
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except ProcamError as exc:
        print(f"procam: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
