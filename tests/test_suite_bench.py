"""benchmarks/suite.py on one small test file, so that the script cannot rot: each tier runs
serially and on pytest-xdist workers, both pass the same tests, the ratio printed is the ratio of
the wall times printed, and a failing run stops it with pytest's summary, not exit 0."""
from __future__ import annotations

import re

import pytest
from helpers import BENCHMARKS, run_benchmark

SMALL = "tests/test_seeds.py"
"""A test file of three sub-second tests."""


def suite(*args: str):
    return run_benchmark("suite.py", *args)


@pytest.mark.slow
def test_each_tier_serial_against_parallel():
    proc = suite("--tiers", "fast", "--workers", "2", SMALL)
    assert proc.returncode == 0, proc.stderr
    rows = re.findall(r"^fast\s+(serial|parallel)\s+([\d.]+)\s+([\d.]+)\s+(.*)$", proc.stdout, re.M)
    assert [r[0] for r in rows] == ["serial", "parallel"]
    (_, s_wall, s_cpu, s_out), (_, p_wall, p_cpu, p_out) = rows
    assert all(float(v) > 0 for v in (s_wall, s_cpu, p_wall, p_cpu))
    assert s_out.startswith("3 passed") and p_out.startswith("3 passed")
    ratio = re.search(r"^fast\s+parallel / serial wall \(best of 1\): ([\d.]+)×", proc.stdout, re.M)
    # the ratio of the unrounded times; the printed ones are rounded to 0.01 s
    assert ratio and float(ratio[1]) == pytest.approx(float(p_wall) / float(s_wall), rel=0.03, abs=0.01)


def test_a_failing_run_stops_the_benchmark(tmp_path):
    failing = tmp_path / "test_fails.py"
    failing.write_text("def test_fails():\n    assert 1 == 2\n")
    proc = suite("--tiers", "fast", str(failing))
    assert proc.returncode != 0
    assert "failed (exit 1)" in proc.stderr and "1 failed" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_an_unknown_tier_is_named():
    proc = suite("--tiers", "whole,nightly")
    assert proc.returncode == 2 and "unknown tier(s) nightly" in proc.stderr


def test_counts_reads_the_summary_line(monkeypatch):
    monkeypatch.syspath_prepend(str(BENCHMARKS))
    from suite import counts
    assert counts("3 passed, 1 skipped, 2 warnings in 1.20s") == {"passed": 3, "skipped": 1, "warnings": 2}
    assert counts("1 failed, 2 passed in 0.5s (0:00:00)") == {"failed": 1, "passed": 2}
