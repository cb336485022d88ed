"""One BLAS thread while many small LAPACK calls run: OpenBLAS's own thread pool, set through the
libraries this process has loaded.

OpenBLAS parallelises a level-3 call over all cores even at sizes where starting its threads costs
more than the work: a minimum-norm least squares (``gelsy``) of a 129 × 129 thin-plate spline
system took 30 ms with two threads against 1.1 ms with one on a 2-core machine (another job
running beside), and the spline fits of :mod:`compensation.methods.tps` run one worker process
per core on top. NumPy and SciPy each bundle their own OpenBLAS (their symbols prefixed
``scipy_`` and, for 64-bit integers, suffixed ``64_``); this module finds every OpenBLAS mapped
into the process (``/proc/self/maps``) and sets each one's thread count. Where there is none
(another BLAS, or no ``/proc``) it does nothing.
"""
from __future__ import annotations

import ctypes
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

_NAMES = [f"{prefix}openblas_{{}}_num_threads{suffix}" for prefix in ("", "scipy_") for suffix in ("", "64_")]
"""OpenBLAS's thread-count functions as its builds name them (``{}``: ``set`` or ``get``)."""


def _libraries() -> list[tuple[Callable, Callable]]:
    """(get, set) of every OpenBLAS loaded in this process."""
    try:
        maps = Path("/proc/self/maps").read_text().splitlines()
    except OSError:
        return []
    fields = (line.split(None, 5) for line in maps)  # address, perms, offset, dev, inode, path
    paths = dict.fromkeys(f[5] for f in fields if len(f) == 6 and "openblas" in Path(f[5]).name)
    found = []
    for path in paths:
        try:
            lib = ctypes.CDLL(path, mode=os.RTLD_NOLOAD | os.RTLD_LAZY)  # only if loaded, scope kept
        except OSError:
            continue
        for name in _NAMES:
            getter, setter = (getattr(lib, name.format(verb), None) for verb in ("get", "set"))
            if getter is not None and setter is not None:
                getter.restype = ctypes.c_int
                found.append((getter, setter))
                break
    return found


def openblas_threads() -> list[int]:
    """The thread count of every OpenBLAS loaded in this process (empty where there is none)."""
    return [get() for get, _ in _libraries()]


@contextmanager
def one_blas_thread() -> Iterator[int]:
    """While inside, every OpenBLAS of this process computes on one thread (worker processes
    forked inside inherit it); on exit each gets its thread count back.

    Yields
    ------
    int
        How many OpenBLAS libraries were set (0 where none is loaded).

    Examples
    --------
    >>> import scipy.linalg  # loads SciPy's OpenBLAS
    >>> before = openblas_threads()
    >>> with one_blas_thread() as changed:
    ...     inside = openblas_threads()
    >>> changed == len(inside) and all(n == 1 for n in inside) and openblas_threads() == before
    True
    """
    libraries = _libraries()
    before = [get() for get, _ in libraries]
    for _, set_threads in libraries:
        set_threads(ctypes.c_int(1))
    try:
        yield len(libraries)
    finally:
        for (_, set_threads), n in zip(libraries, before):
            set_threads(ctypes.c_int(n))
