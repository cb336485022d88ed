"""Choosing the Mitsuba variant once per process, with a child-process probe and a fallback.

Dr.Jit's LLVM backend needs LLVM >= 16 (Debian's ``libllvm19``). With an older LLVM the first
kernel *aborts the process* ("LLVM ERROR: Cannot select … fminimum"), which Python cannot catch, so
each candidate is first tried in a child process: a tiny ``dr.minimum`` kernel after
``mi.set_variant``. The first candidate that survives is used:

``cuda_ad_rgb`` (a GPU is present) → ``llvm_ad_rgb`` → ``scalar_rgb`` (with a warning).

Set ``PROCAM_VARIANT`` to skip the probe and force a variant: an RGB variant (procam's textures,
projector frames and camera are RGB) whose Dr.Jit backend this machine has (a CUDA driver and GPU
for ``cuda_*``, the LLVM library for ``llvm_*``); anything else is refused with a
:class:`~sim.errors.ProcamError`. After the probe the choice is exported in ``PROCAM_VARIANT`` so
that child processes (workers, CLI calls from tests) inherit it.

``python -m sim.variant --ensure-llvm`` installs ``libllvm19`` with apt-get when running as root
and the LLVM backend is not usable (used by the Makefile).
"""
from __future__ import annotations

import argparse
import functools
import os
import shutil
import subprocess
import sys
import warnings

from sim.errors import ProcamError

ENV_VAR = "PROCAM_VARIANT"
CANDIDATES = ("cuda_ad_rgb", "llvm_ad_rgb")
FALLBACK = "scalar_rgb"
LLVM_PACKAGE = "libllvm19"

_PROBE = """
import drjit as dr, mitsuba as mi
mi.set_variant({variant!r})
x = dr.minimum(mi.Float([1.0, 2.0]), mi.Float([1.5, 0.5]))
dr.eval(x)
assert abs(float(x[1]) - 0.5) < 1e-6
"""


def probe(variant: str, timeout: float = 120.0) -> bool:
    """Return True when ``variant`` can run a kernel, tried in a child process.

    Parameters
    ----------
    variant : str
        A Mitsuba variant name, e.g. ``"llvm_ad_rgb"``.
    timeout : float
        Seconds before the probe counts as failed.
    """
    try:
        proc = subprocess.run([sys.executable, "-c", _PROBE.format(variant=variant)],
                              capture_output=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return False
    return proc.returncode == 0


def check_forced(name: str) -> None:
    """Refuse a ``PROCAM_VARIANT`` that procam cannot render with.

    Raises
    ------
    ProcamError
        If ``name`` is not a Mitsuba variant, not an RGB one, or its Dr.Jit backend (CUDA, LLVM)
        is missing on this machine.
    """
    import drjit as dr
    import mitsuba as mi

    usable = ", ".join(v for v in mi.variants() if v.endswith("_rgb"))
    if name not in mi.variants():
        raise ProcamError(f"{ENV_VAR}={name!r}: not a Mitsuba variant; expected one of {usable} "
                          "(or leave it unset to choose automatically)")
    if not name.endswith("_rgb"):
        raise ProcamError(f"{ENV_VAR}={name!r}: procam renders RGB (textures, projector frames and "
                          f"camera are RGB); expected one of {usable}")
    backend, needs = {"cuda": (dr.JitBackend.CUDA, "a CUDA GPU and driver"),
                      "llvm": (dr.JitBackend.LLVM, "the LLVM library")}.get(name.split("_")[0], (None, ""))
    if backend is not None and not dr.has_backend(backend):
        raise ProcamError(f"{ENV_VAR}={name!r}: Dr.Jit's {backend.name} backend is not available "
                          f"here (it needs {needs}); use another of {usable} or leave it unset to "
                          "choose automatically")


@functools.cache
def choose_variant() -> str:
    """Pick the Mitsuba variant for this process (memoised) and export it in ``PROCAM_VARIANT``.

    Raises
    ------
    ProcamError
        If ``PROCAM_VARIANT`` forces a variant procam cannot use (:func:`check_forced`).
    """
    import mitsuba as mi

    forced = os.environ.get(ENV_VAR)
    if forced:
        check_forced(forced)
        return forced
    chosen = next((v for v in CANDIDATES if v in mi.variants() and probe(v)), None)
    if chosen is None:
        warnings.warn("Dr.Jit's LLVM backend is not usable (it needs LLVM >= 16: install Debian's "
                      f"{LLVM_PACKAGE}, or run `make` as root); rendering falls back to "
                      f"{FALLBACK}, 3–5x slower.", RuntimeWarning, stacklevel=2)
        chosen = FALLBACK
    os.environ[ENV_VAR] = chosen
    return chosen


@functools.cache
def llvm_usable() -> bool:
    """Whether Dr.Jit's LLVM backend runs kernels in this process (memoised): known when
    :func:`choose_variant` picks an LLVM variant, else (a CUDA, forced or fallback variant) probed
    in a child process of its own."""
    return choose_variant().startswith("llvm_") or probe("llvm_ad_rgb")


def use_variant(name: str | None = None) -> str:
    """Set a variant on Mitsuba (idempotent) and return its name.

    Parameters
    ----------
    name : str, optional
        A Mitsuba variant; defaults to :func:`choose_variant`'s choice.
    """
    import mitsuba as mi

    name = name or choose_variant()
    if mi.variant() != name:
        mi.set_variant(name)
    return name


def ensure_llvm() -> str:
    """Install ``libllvm19`` when the LLVM backend fails its probe and we may (root + apt-get)."""
    if probe("llvm_ad_rgb"):
        return "llvm_ad_rgb usable"
    if os.geteuid() != 0 or shutil.which("apt-get") is None:
        return (f"LLVM backend not usable and {LLVM_PACKAGE} cannot be installed here "
                f"(not root or no apt-get): procam will fall back to {FALLBACK}")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    subprocess.run(["apt-get", "update", "-qq"], check=False, env=env)
    subprocess.run(["apt-get", "install", "-y", "-qq", LLVM_PACKAGE], check=False, env=env)
    if probe("llvm_ad_rgb"):
        return f"installed {LLVM_PACKAGE}: llvm_ad_rgb usable"
    return f"installing {LLVM_PACKAGE} did not help: procam will fall back to {FALLBACK}"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m sim.variant", description=__doc__.split("\n")[0])
    parser.add_argument("--ensure-llvm", action="store_true",
                        help=f"install {LLVM_PACKAGE} if the LLVM backend is not usable")
    args = parser.parse_args(argv)
    if args.ensure_llvm:
        print(f"procam: {ensure_llvm()}")
    print(f"procam: Mitsuba variant {choose_variant()}")


if __name__ == "__main__":
    main()
