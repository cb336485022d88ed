"""The built wheel is complete: installed into a fresh virtual environment, away from the checkout,
it holds every module and shipped scene of the checkout, `procam render` writes a dataset and the
shipped scenes and studies resolve inside the installed package."""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SOURCES = ("pyproject.toml", "setup.py", "README.md", "sim", "compensation", "scenes")
"""What the wheel is built from."""


def build_wheel(folder: Path) -> Path:
    """The wheel of a copy of :data:`SOURCES` in ``folder`` (the build writes ``build/`` and
    ``*.egg-info`` beside its sources), built offline with this interpreter's setuptools."""
    source = folder / "source"
    source.mkdir(parents=True)
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(ROOT / name, source / name)
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--no-build-isolation",
                    "--wheel-dir", str(folder / "dist"), str(source)], check=True, capture_output=True)
    return next((folder / "dist").glob("procam-*.whl"))


def venv_with(wheel: Path, folder: Path) -> Path:
    """A fresh virtual environment in ``folder`` holding ``wheel`` alone, which sees this
    interpreter's packages for procam's dependencies (its ``bin`` folder is returned)."""
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(folder)], check=True)
    python = folder / "bin" / "python"
    subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet",
                    "--no-deps", "--no-index", str(wheel)], check=True, capture_output=True)
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    # After the install: pip would otherwise see this environment's procam as installed already.
    Path(site, "procam_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    return folder / "bin"


@pytest.mark.slow
def test_the_wheel_renders_outside_the_checkout(tmp_path):
    bin_dir = venv_with(build_wheel(tmp_path / "build"), tmp_path / "venv")
    work = tmp_path / "work"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env["OMP_WAIT_POLICY"] = "PASSIVE"

    def run(*argv: str) -> str:
        proc = subprocess.run(argv, cwd=work, env=env, capture_output=True, text=True, timeout=600)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout

    located = run(str(bin_dir / "python"), "-c", "import sim, compensation.cli\n"
                  "from sim.setup import scene_path\n"
                  "print(sim.__file__, scene_path('default'), scene_path('default').parent / 'studies')")
    package, default, studies = map(Path, located.split())
    site = tmp_path / "venv" / "lib"
    assert package.is_relative_to(site) and default.is_relative_to(site), located
    assert (studies / "noise.toml").is_file()
    installed = package.parent.parent  # the environment's site-packages
    for name in ("sim", "compensation"):  # every module, none left behind by the package list
        assert _files(ROOT / name, "*.py") == _files(installed / name, "*.py"), name
    assert _files(ROOT / "scenes", "*.toml") == _files(default.parent, "*.toml")

    # the `ideal` scene (256² panel and camera): a render of seconds through the installed console
    # script; the modules its stages do not import are checked above
    run(str(bin_dir / "procam"), "render", "ideal", "--size", "16", "--n-train", "2", "--n-test", "1",
        "--out", str(tmp_path / "data"), "--quiet")
    data = tmp_path / "data"
    for split, n in (("ref", 126), ("train", 2), ("test", 1)):
        assert len(list((data / split).glob("img_*.png"))) == n
        assert len(list((data / "ideal" / "cam" / "warp" / split).glob("img_*.png"))) == n
    assert not (data / "ideal" / "cam" / "raw").exists()  # kept only with --raw
    for name in ("frames.json", "ideal/setup.toml", "ideal/render.json", "ideal/meta.json",
                 "ideal/registration/exact_map.npz"):
        assert (data / name).is_file(), name


def _files(folder: Path, pattern: str) -> set[str]:
    """The paths under ``folder`` matching ``pattern``, relative to it."""
    return {p.relative_to(folder).as_posix() for p in folder.rglob(pattern) if "__pycache__" not in p.parts}
