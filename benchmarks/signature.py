"""The paper's signature on paper-suite setups: TPS textured − TPS and CompenNet − TPS textured,
paired per test image, with the content-dependent processing of the projector and camera off (the
suite as it is), each effect alone and all of them together.

The paper's Table 1 (real captures, 125 pairs) has TPS textured 1.68 dB above TPS and CompenNet
1.73 dB above TPS textured. A per-pixel fit on plain colours goes wrong on textured frames only if
a pixel's capture depends on more than its own input; the content-dependent processing
(``benchmarks/effects.py``'s ``CONTENT``: the dynamic lamp, the DLP white segment, the camera's
adaptive tone and picture style) is such a dependence. Each variant is one ``procam bench``
(Table 1 at one training size) into ``OUT/<variant>/``, resumable: run the same command again to
go on, or with more variants or methods to add them. A variant is finished once its folder's
``study.json``, ``results.csv`` and ``per_image.csv`` hold every setup and method at these settings
(:func:`finished`); those three files are all the table needs, so a finished variant can be kept
(committed) without its datasets and runs and copied into a new ``OUT`` to measure the remaining
variants in later sittings::

    .venv/bin/python benchmarks/signature.py --out OUT [--suite paper] [--setups A,B,...]
        [--variants default,dynamic_lamp,...,all_content] [--methods tps,tps-textured,compennet]
        [--profile faithful] [--size N --n-train N --n-test N] [--test-frames mixed]

Writes ``OUT/signature.md`` and ``OUT/signature.csv``: per variant the mean PSNR of each method
over the setups and the paired differences with their 95 % interval (hierarchical bootstrap over
setups and images), the share of images where the first method is ahead and the sign-flip p-value
(:mod:`compensation.reports.paired`).
"""
from __future__ import annotations

import argparse
import math
import statistics
from pathlib import Path

from compensation.experiments.bench import BenchConfig, run_bench, table1_options
from compensation.methods import METHODS, get_method
from compensation.reports.paired import paired_comparison, paired_differences
from compensation.reports.summary import attach_per_image, read_results
from compensation.reports.tables import PAPER_TABLE1
from effects import CONTENT, with_values
from sim.errors import ProcamError
from sim.images import FRAME_KINDS
from sim.io import read_json, write_text
from sim.setup import load_setups

SIX = ("light1_pos5_curves", "light1_pos1_squares", "light1_pos2_stripes", "light1_pos3_lavender",
       "light1_pos4_cloud", "light1_pos5_cubes")
"""One setup per surface of the paper suite (the six of Table 1 at 256²)."""
VARIANTS = {"default": {}, **{name: values for name, values in zip(
    ("dynamic_lamp", "white_boost", "adaptive_tone", "picture_style"), CONTENT.values())},
    "all_content": {k: v for values in CONTENT.values() for k, v in values.items()}}
"""Variant name -> the ``{(section, key): value}`` set on every setup (``default``: none)."""
PAIRS = (("tps-textured", "tps"), ("compennet", "tps-textured"))
"""The signature's two differences, A − B."""
PAPER = {(a, b): PAPER_TABLE1[get_method(a).official_name, 125][0] - PAPER_TABLE1[get_method(b).official_name, 125][0]
         for a, b in PAIRS}
"""The paper's differences of mean PSNR at 125 pairs (Table 1, real captures), dB."""


def variant_setups(suite: list, variant: str) -> list:
    """The suite's setups with the variant's values (same names: each variant has its own folder)."""
    return [with_values(s, s.name, VARIANTS[variant]) for s in suite]


def finished(folder: Path, setups: list[str], cfg: BenchConfig, n_train: int) -> bool:
    """Whether ``folder`` holds a finished variant: a ``study.json`` of a Table-1 bench at ``cfg``'s
    profile, method options (as the profile resolves them now), canonical size, test count and test
    frames with ``n_train`` training pairs and these ``setups``, whose ``results.csv`` has an ok
    row for every setup and method of ``cfg`` and whose ``per_image.csv`` exists. Its datasets and
    runs need not be there."""
    try:
        study = read_json(folder / "study.json", "study record")
        rows = read_results(folder / "results.csv", [])
    except ProcamError:
        return False
    same = (study.get("kind") == "bench" and study.get("profile") == cfg.profile
            and study.get("options") == table1_options(cfg)
            and study.get("size") == [cfg.canonical] * 2 and study.get("n_test") == cfg.tests
            and study.get("n_train") == [n_train] and study.get("test_frames") == cfg.test_frames
            and set(setups) <= set(study.get("setups", {})))
    done = {(r["setup"], r["method"]) for r in rows if r["status"] == "ok" and r["table"] == "1"}
    return same and (folder / "per_image.csv").is_file() and all(
        (s, m) in done for s in setups for m in cfg.methods)


def summarise(out: Path, variant: str) -> dict:
    """One variant's row: per method its mean PSNR over the setups (``psnr:<method>``), and per pair
    of :data:`PAIRS` the paired comparison (``<A>-<B>``: ``mean``, ``lo``, ``hi``, ``share``,
    ``setups``, ``images``, ``p``), from the bench's ``results.csv`` and ``per_image.csv``."""
    folder = out / variant
    ok = [r for r in attach_per_image(read_results(folder / "results.csv", []), folder / "per_image.csv")
          if r["status"] == "ok" and r["table"] == "1"]
    row = {"variant": variant, "setups": len({r["setup"] for r in ok})}
    methods = list(dict.fromkeys(r["method"] for r in ok))
    for method in methods:
        row[f"psnr:{method}"] = statistics.fmean(r["psnr"] for r in ok if r["method"] == method)
    images = {m: {r["setup"]: r["per_image"].get("psnr", []) for r in ok if r["method"] == m} for m in methods}
    for a, b in PAIRS:
        groups = paired_differences(images.get(a, {}), images.get(b, {}))
        row[f"{a}-{b}"] = paired_comparison(groups) if groups else None
    return row


def write(out: Path, rows: list[dict], how: str) -> None:
    """``signature.csv`` and ``signature.md``."""
    methods = list(dict.fromkeys(k.split(":", 1)[1] for r in rows for k in r if k.startswith("psnr:")))
    cols = ["variant", "setups", *(f"PSNR {m}" for m in methods),
            *(f"{a} − {b} {k}" for a, b in PAIRS for k in ("mean", "lo", "hi", "share", "p"))]
    lines = [",".join(cols)]
    md = ["# The paper's signature: paired PSNR differences per variant", "", how, "",
          "| variant | setups | " + " | ".join(f"{m} PSNR" for m in methods) + " | "
          + " | ".join(f"{a} − {b} (paper {PAPER[a, b]:+.2f})" for a, b in PAIRS) + " |",
          "|---|---|" + "---|" * (len(methods) + len(PAIRS))]
    for r in rows:
        cells = [r["variant"], str(r["setups"]), *(f"{r.get(f'psnr:{m}', math.nan):.2f}" for m in methods)]
        shown = []
        for a, b in PAIRS:
            c = r.get(f"{a}-{b}")
            cells += ([f"{c[k]:.3f}" if k != "p" else f"{c[k]:.4f}" for k in ("mean", "lo", "hi", "share", "p")]
                      if c else [""] * 5)
            shown.append(f"{c['mean']:+.2f} ({c['lo']:+.2f} … {c['hi']:+.2f}; p {c['p']:.2f})" if c else "–")
        lines.append(",".join(cells))
        md.append(f"| {r['variant']} | {r['setups']} | "
                  + " | ".join(f"{r.get(f'psnr:{m}', math.nan):.2f}" for m in methods) + " | "
                  + " | ".join(shown) + " |")
    write_text(out / "signature.csv", "\n".join(lines) + "\n")
    md += ["", "PSNR: mean over the setups of each run's test-set PSNR (dB). A − B: the mean of the "
           "per-image PSNR differences pooled over the setups, its 95 % interval (hierarchical "
           "bootstrap: setups, then images) and the sign-flip p-value of the per-setup means; "
           "the paper's figure is its difference of Table 1 means."]
    write_text(out / "signature.md", "\n".join(md) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, type=Path)
    ap.add_argument("--suite", default="paper", help="a suite file or shipped suite name (default: paper)")
    ap.add_argument("--setups", default=",".join(SIX), help="comma-separated setups of the suite")
    ap.add_argument("--variants", default=",".join(VARIANTS), help=f"some of {', '.join(VARIANTS)}")
    ap.add_argument("--methods", default="tps,tps-textured,compennet")
    ap.add_argument("--profile", default="faithful", help="quick, faithful or paper")
    ap.add_argument("--size", type=int, default=None, help="canonical pixels (default: the profile's)")
    ap.add_argument("--n-train", type=int, default=125)
    ap.add_argument("--n-test", type=int, default=None, help="test pairs (default: the profile's)")
    ap.add_argument("--test-frames", choices=FRAME_KINDS, default="mixed",
                    help="the test frames (default mixed, whatever the suite asks for: the runs of "
                         "benchmarks/results/signature/ are on mixed frames)")
    args = ap.parse_args()
    variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    if not variants:
        ap.error(f"--variants {args.variants!r}: expected some of {', '.join(VARIANTS)}")
    if unknown := [v for v in variants if v not in VARIANTS]:
        ap.error(f"--variants: {', '.join(unknown)} unknown; expected some of {', '.join(VARIANTS)}")
    names = [s.strip() for s in args.setups.split(",") if s.strip()]
    if not names:
        ap.error(f"--setups {args.setups!r}: expected setups of the suite {args.suite}")
    try:
        suite = {s.name: s for s in load_setups(args.suite)}
        if missing := [n for n in names if n not in suite]:
            ap.error(f"--setups: {', '.join(missing)} not in the suite {args.suite}")
        methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
        if not methods:
            raise ProcamError(f"--methods {args.methods!r}: expected some of {', '.join(sorted(METHODS))}")
        cfg = BenchConfig(profile=args.profile, methods=methods,
                          sizes=(args.n_train,), tables=("1",), size=args.size, n_test=args.n_test,
                          test_frames=args.test_frames)
        if args.out.exists() and not args.out.is_dir():
            raise ProcamError(f"--out {args.out}: a file, expected a folder")
    except ProcamError as exc:
        ap.exit(2, f"signature: {exc}\n")
    try:
        for variant in variants:
            if finished(args.out / variant, names, cfg, args.n_train):
                print(f"signature: {variant}: finished in {args.out / variant}, not run again")
                continue
            run_bench(variant_setups([suite[n] for n in names], variant), args.out / variant, cfg)
        rows = [summarise(args.out, v) for v in variants]
    except ProcamError as exc:
        ap.exit(1, f"signature: {exc}\n")
    how = (f"`python benchmarks/signature.py --out OUT --suite {args.suite} --setups {','.join(names)} "
           f"--variants {','.join(variants)} --methods {','.join(cfg.methods)} --profile {args.profile}"
           + (f" --size {args.size}" if args.size else "") + f" --n-train {args.n_train}"
           + (f" --n-test {args.n_test}" if args.n_test else "") + f" --test-frames {args.test_frames}`: "
           f"{cfg.canonical}² canonical, {args.n_train} training / {cfg.tests} {args.test_frames} test pairs per setup.")
    write(args.out, rows, how)
    print((args.out / "signature.md").read_text())


if __name__ == "__main__":
    main()
