"""`procam render SUITE --list` and `--only NAME[,NAME…]` of `procam render` and `procam bench`."""
from __future__ import annotations

from types import SimpleNamespace

import pytest

import compensation.experiments.bench
import compensation.reports.tables
from compensation.cli import main
from helpers import tiny_toml
from sim.setup import load_setups

SUITE = """
base = "base.toml"
[[setup]]
name = "alpha"
[[setup]]
name = "beta"
surface = {texture = "noise"}
[[setup]]
name = "gamma"
"""
BASE = tiny_toml("base", texture="uniform", projector={"resolution": [16, 16]},
                 render={"spp": 1, "ambient_spp": 1})


@pytest.fixture
def suite(tmp_path):
    (tmp_path / "base.toml").write_text(BASE)
    path = tmp_path / "suite.toml"
    path.write_text(SUITE)
    return path


def test_list_prints_the_names_and_renders_nothing(suite, tmp_path, capsys):
    assert main(["render", str(suite), "--list", "--out", str(tmp_path / "data")]) == 0
    assert capsys.readouterr().out.splitlines() == ["alpha", "beta", "gamma"]
    assert not (tmp_path / "data").exists()
    assert main(["render", str(suite), "--list", "--only", "gamma,alpha"]) == 0
    assert capsys.readouterr().out.splitlines() == ["alpha", "gamma"]  # in the suite's order
    assert main(["render", "suite", "--list"]) == 0  # a shipped suite by name
    assert capsys.readouterr().out.splitlines() == [s.name for s in load_setups("suite")]


@pytest.mark.slow
def test_only_renders_the_named_setups(suite, tmp_path, capsys):
    data = tmp_path / "data"
    assert main(["render", str(suite), "--only", "beta", "--out", str(data), "--size", "16",
                 "--n-train", "1", "--n-test", "1", "--quiet"]) == 0
    assert capsys.readouterr().out.strip() == f"procam: beta -> {data / 'beta'}"
    assert (data / "beta" / "meta.json").is_file()
    assert not (data / "alpha").exists() and not (data / "gamma").exists()


def test_only_selects_the_bench_setups(suite, tmp_path, monkeypatch):
    seen = {}

    def fake_run_bench(setups, out, cfg, data_root, white, progress, limit, executor=None):
        seen["names"], seen["limit"] = [s.name for s in setups], limit
        return SimpleNamespace(rows=[], failures=[])

    monkeypatch.setattr(compensation.experiments.bench, "run_bench", fake_run_bench)
    monkeypatch.setattr(compensation.reports.tables, "write_tables", lambda out, cfg, result: {})
    assert main(["bench", str(suite), "--only", "gamma,beta", "--out", str(tmp_path / "b"),
                 "--tables", "1", "--quiet"]) == 0
    assert seen == {"names": ["beta", "gamma"], "limit": None}


@pytest.mark.parametrize("command", [["render", "--list"], ["render"], ["bench", "--out", "unused"]])
def test_unknown_names_are_refused_with_the_valid_ones(suite, tmp_path, capsys, command):
    argv = [command[0], str(suite), *command[1:], "--only", "alpha,delta,", "--out", str(tmp_path / "o")]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert "--only alpha,delta,: no setup named 'delta', '' in" in err and str(suite) in err
    assert "its setups: alpha, beta, gamma" in err
    assert not (tmp_path / "o").exists()


def test_bench_only_needs_a_suite(tmp_path, capsys):
    assert main(["bench", "--data", str(tmp_path), "--out", str(tmp_path / "b"), "--only", "x"]) == 2
    assert "--only selects setups of a suite" in capsys.readouterr().err


def test_bench_raw_needs_a_suite_and_reaches_its_config(suite, tmp_path, monkeypatch, capsys):
    assert main(["bench", "--data", str(tmp_path), "--out", str(tmp_path / "b"), "--raw"]) == 2
    assert "--raw keeps the raw captures of the setups a bench renders" in capsys.readouterr().err
    seen = {}

    def fake_run_bench(setups, out, cfg, data_root, white, progress, limit, executor=None):
        seen["raw"] = cfg.raw
        return SimpleNamespace(rows=[], failures=[])

    monkeypatch.setattr(compensation.experiments.bench, "run_bench", fake_run_bench)
    monkeypatch.setattr(compensation.reports.tables, "write_tables", lambda out, cfg, result: {})
    for flag, raw in ((["--raw"], True), ([], False)):
        assert main(["bench", str(suite), *flag, "--out", str(tmp_path / "b"), "--tables", "1", "--quiet"]) == 0
        assert seen == {"raw": raw}


@pytest.mark.parametrize("argv, message", [
    (["study", "ambient", "--only", ","], "--only ',': expected one or more comma-separated names"),
    (["study", "ambient", "--methods", ","], "--methods ',': expected one or more comma-separated names"),
    (["bench", "suite", "--methods", " ,"], "--methods ' ,': expected one or more comma-separated names"),
    (["render", "suite", "--only", ",", "--list"], "--only ',': expected one or more comma-separated setup names"),
])
def test_an_empty_selection_is_refused_and_named(tmp_path, capsys, argv, message):
    """``--only ,`` selects nothing rather than everything, and each option names itself."""
    assert main([*argv, "--out", str(tmp_path / "out")] if argv[0] != "render" else argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("argv, message", [
    (["bench", "suite", "--size", "1"], "size '1': expected an integer >= 4 (pixels)"),
    (["bench", "suite", "--size", "3x3"], "size '3x3': expected an integer >= 4 (pixels)"),
    (["study", "ambient", "--size", "2"], "size '2': expected N or WxH, each >= 4 pixels"),
    (["render", "suite", "--size", "0x8"], "size '0x8': expected N or WxH, each >= 4 pixels"),
])
def test_a_canonical_size_render_refuses_is_refused_by_every_command(tmp_path, capsys, argv, message):
    """bench, study and render share the smallest canonical side: none accepts a size the renderer
    cannot use, before anything is written."""
    with pytest.raises(SystemExit) as exit_:
        main([*argv, "--out", str(tmp_path / "out")])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()
