"""Helpers shared by the test modules: the tiny setups the physics and end-to-end tests build on,
as validated setups (:func:`tiny_setup`) or as setup files (:func:`tiny_toml`,
:func:`tiny_setup_file`), a study whose renders all fail (:func:`failing_study_file`), ``mi.render`` ended by Ctrl-C
(:func:`interrupted_render`), the options of the tiny rendered dataset (:data:`TINY_RENDER`),
the rows of the CSV files procam writes (:func:`csv_rows`), a script of ``benchmarks/`` run in
a child process (:func:`run_benchmark`), and a job that waits in a worker process
(:func:`record_pid_and_wait`)."""
from __future__ import annotations

import copy
import csv
import os
import subprocess
import sys
import time
from pathlib import Path

import tomli_w

from sim.setup import Setup, parse_setup

TINY = {
    "name": "tiny",
    "surface": {"geometry": "plane", "size": [1.2, 1.0], "texture": "uniform", "albedo_scale": 0.8},
    "projector": {"resolution": [64, 64], "fov": 30.0, "position": [0.0, 0.0, 1.0],
                  "black_level": 0.0},
    "camera": {"resolution": [64, 64], "fov": 40.0, "position": [0.25, 0.0, 1.0],
               "shot_noise": 0.0, "read_noise": 0.0},
    "ambient": {"radiance": [0.0, 0.0, 0.0]},
    "render": {"fidelity": "direct", "spp": 4, "ambient_spp": 16, "seed": 0},
}
"""A small, fast noiseless setup (64² camera, 64² projector): the physics tests build variations of it."""


def _overridden(data: dict, sections: dict) -> dict:
    """A copy of the setup table ``data`` with ``sections`` applied: a dict updates the keys of that
    section, any other value replaces the entry."""
    out = copy.deepcopy(data)
    for section, values in sections.items():
        if isinstance(values, dict):
            out.setdefault(section, {}).update(values)
        else:
            out[section] = values
    return out


def tiny_setup(**sections) -> Setup:
    """The validated :data:`TINY` setup; keyword arguments override keys per section, e.g.
    ``tiny_setup(camera={"position": [0, 0, 1]})``."""
    return parse_setup(_overridden(TINY, sections), source="<tiny>")


def tiny_toml(name: str = "base", side: int = 32, texture: str = "noise", **sections) -> str:
    """A tiny setup file's text (side² projector and camera, direct light at 4 spp, the default
    camera noise), the base of the setups, suites and studies the end-to-end tests write to disk;
    keyword arguments override keys per section, as in :func:`tiny_setup`."""
    data = {"name": name, "surface": {"texture": texture, "texture_resolution": 64},
            "projector": {"resolution": [side, side]}, "camera": {"resolution": [side, side]},
            "render": {"fidelity": "direct", "spp": 4, "ambient_spp": 16}}
    return tomli_w.dumps(_overridden(data, sections))


def tiny_setup_file(folder: Path, file: str = "tiny.toml", **keys) -> Path:
    """The setup file ``folder / file`` (``folder`` created) holding the setup ``tiny``: :func:`tiny_toml`
    at 64² with ``keys`` (its texture and per-section overrides)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / file
    path.write_text(tiny_toml("tiny", 64, **keys))
    return path


def failing_study_file(folder: Path, name: str = "allfail") -> Path:
    """The study file ``folder / <name>.toml`` (with its base ``base.toml``) whose every render is
    refused, its projector too dim to be seen: ``procam study`` runs it in seconds into a study
    folder of failed rows."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "base.toml").write_text(tiny_toml("base", 16, projector={"brightness": 1e-30},
                                                registration={"method": "exact"}))
    path = folder / f"{name}.toml"
    path.write_text(f'name = "{name}"\nbase = "base.toml"\nmethods = ["tps"]\nn_train = 4\nn_test = 2\n'
                    'size = 16\n\n[[axis]]\nkey = "ambient.radiance"\nvalues = [0.02, 0.1]\n')
    return path


def interrupted_render(*args, **kwargs):
    """``mi.render`` ended by Ctrl-C, as Dr.Jit reports it: a RuntimeError raised from the
    KeyboardInterrupt."""
    try:
        raise KeyboardInterrupt
    except KeyboardInterrupt as exc:
        raise RuntimeError("drjit.custom(<mitsuba.python.util._RenderOp>): error while performing a "
                           "custom differentiable operation. (see above).") from exc


TINY_RENDER = ["--size", "32", "--n-train", "2", "--n-test", "1", "--quiet"]
"""`procam render` options of the tiny rendered dataset (the session fixture ``tiny_render``)."""


def csv_rows(path: Path) -> list[dict]:
    """The rows of the CSV file at ``path``, each a dict keyed by the header."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def refuse_renders(monkeypatch, suffix: str) -> None:
    """Make every render job of a setup whose name ends with ``suffix`` fail with a ProcamError
    ("simulated refusal"); the others render as usual."""
    import compensation.experiments.jobs as jobs
    from sim.errors import ProcamError

    real = jobs.write_setup

    def refuse(root, setup, *args, **kwargs):
        if setup.name.endswith(suffix):
            raise ProcamError("simulated refusal")
        return real(root, setup, *args, **kwargs)

    monkeypatch.setattr(jobs, "write_setup", refuse)


BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
"""The checkout's ``benchmarks/`` folder."""


def run_benchmark(script: str, *args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    """``benchmarks/<script> args`` in a child process (procam importable from the checkout, passive
    OpenMP waiting), run in ``cwd`` (default: the checkout), its output captured as text."""
    env = dict(os.environ, PYTHONPATH=str(BENCHMARKS.parent), OMP_WAIT_POLICY="PASSIVE")
    return subprocess.run([sys.executable, str(BENCHMARKS / script), *args], capture_output=True,
                          text=True, timeout=600, env=env, cwd=cwd or BENCHMARKS.parent)


def record_pid_and_wait(folder: str) -> dict:
    """A job for a worker process: writes ``pid-<its process id>`` into ``folder``, then waits a
    minute (long past any test's patience) and returns nothing of note."""
    (Path(folder) / f"pid-{os.getpid()}").touch()
    time.sleep(60)
    return {}


def compute_threads(_: object) -> dict:
    """A job for a worker process: the threads it computes with (torch's, and OMP_NUM_THREADS)."""
    import torch

    return {"torch": torch.get_num_threads(), "omp": os.environ.get("OMP_NUM_THREADS")}
