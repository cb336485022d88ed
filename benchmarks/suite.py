"""Test-suite benchmark: wall and CPU time of ``make test`` and ``make test-fast`` run in one pytest
process against one pytest-xdist worker per core (whole test files per worker, as the Makefile runs
them) — measured side by side in one run.

Each tier runs serially and in parallel, taking turns, in fresh pytest processes from the checkout
(passive OpenMP waiting, as the Makefile); the table gives wall and CPU seconds (children's user +
system time), the tests passed and skipped, and the parallel wall time as a ratio to the serial
one. A tier whose two runs do not pass the same tests, or that fails, stops the benchmark with
pytest's summary line.

    .venv/bin/python benchmarks/suite.py [--tiers whole,fast] [--rounds 1] [--workers auto] [PATH ...]

PATHs (test files or folders) narrow every run to them; by default the suite's own test paths.
"""
from __future__ import annotations

import argparse
import os
import re
import resource
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TIERS = {"whole": [], "fast": ["-m", "not slow"]}
"""pytest options of each tier: ``make test`` and ``make test-fast``."""
MODES = {"serial": [], "parallel": ["--dist", "loadfile"]}
"""pytest options of each way to run a tier (parallel also gets ``-n <workers>``)."""


def counts(summary: str) -> dict[str, int]:
    """The outcome counts of pytest's summary line.

    Examples
    --------
    >>> counts("1727 passed, 25 skipped, 52 warnings in 497.93s (0:08:17)")
    {'passed': 1727, 'skipped': 25, 'warnings': 52}
    """
    return {word: int(n) for n, word in re.findall(r"(\d+) (\w+)", summary.split(" in ")[0])}


def run_tier(options: list[str]) -> tuple[float, float, str]:
    """Wall seconds, CPU seconds and pytest's summary line of one pytest run from the checkout.

    Raises
    ------
    SystemExit
        If pytest fails, with its last lines.
    """
    env = {**os.environ, "OMP_WAIT_POLICY": "PASSIVE"}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", *options],
                          cwd=ROOT, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    lines = proc.stdout.strip().splitlines() or [""]
    if proc.returncode != 0:
        raise SystemExit(f"pytest {' '.join(options)} failed (exit {proc.returncode}):\n"
                         + "\n".join(lines[-15:]) + proc.stderr[-2000:])
    return wall, cpu, lines[-1].strip("= ")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tiers", default="whole,fast", help=f"comma-separated, of {', '.join(TIERS)}")
    ap.add_argument("--rounds", type=int, default=1, help="serial and parallel runs of each tier")
    ap.add_argument("--workers", default="auto", help="pytest-xdist workers of the parallel runs")
    ap.add_argument("paths", nargs="*", help="test files or folders (default: the suite's test paths)")
    args = ap.parse_args()
    tiers = args.tiers.split(",")
    if unknown := [t for t in tiers if t not in TIERS]:
        ap.error(f"--tiers: unknown tier(s) {', '.join(unknown)}; expected some of {', '.join(TIERS)}")
    print(f"{os.cpu_count()} CPUs, load average before {os.getloadavg()[0]:.1f}; pytest-xdist workers "
          f"{args.workers}, whole test files per worker")
    print(f"{'tier':<7}{'mode':<10}{'wall s':>9}{'CPU s':>9}  outcome")
    for tier in tiers:
        walls: dict[str, list[float]] = {mode: [] for mode in MODES}
        first = None  # the passed and skipped counts of the tier's first run
        for _ in range(args.rounds):
            for mode, extra in MODES.items():
                options = (TIERS[tier] + extra + (["-n", args.workers] if mode == "parallel" else [])
                           + args.paths)
                wall, cpu, summary = run_tier(options)
                walls[mode].append(wall)
                found = {k: v for k, v in counts(summary).items() if k in ("passed", "skipped")}
                if first is None:
                    first = found
                elif found != first:
                    raise SystemExit(f"tier {tier}: {mode} ran {found}, the first run {first}")
                print(f"{tier:<7}{mode:<10}{wall:>9.2f}{cpu:>9.2f}  {summary}", flush=True)
        serial, parallel = min(walls["serial"]), min(walls["parallel"])
        print(f"{tier:<7}parallel / serial wall (best of {args.rounds}): {parallel / serial:.2f}× "
              f"({serial / 60:.1f} → {parallel / 60:.1f} min)", flush=True)
    print(f"load average after {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
