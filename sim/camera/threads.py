"""The camera's blocks and worker threads. :func:`blockwise` runs an elementwise step (the 8-bit
encoder) on consecutive blocks of :data:`BLOCK` values on the calling thread, so its temporaries
stay in cache; :func:`run` runs tasks on the worker threads (one per usable core), which version 2
of the noise (:mod:`sim.camera.noise`) uses for its blocks: NumPy's samplers release the GIL, and
each block's result is written to its own slice, so the output is the same on any number of
threads. (The encoder on the worker threads measured 1.2-1.5x slower than on the calling thread,
at 0.2-1.8 M values on 2 cores: its many short NumPy calls contend for the GIL.)"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import Callable, Sequence

import numpy as np

from sim.cores import usable_cores

BLOCK = 1 << 15
"""Values per block of :func:`blockwise` (and of version 2's noise draws, :mod:`sim.camera.noise`):
a block's float64 temporaries stay in a core's cache."""

_pool: ThreadPoolExecutor | None = None
_pool_lock = threading.Lock()


def pool() -> ThreadPoolExecutor:
    """The camera's worker threads (one per usable core), started on first use."""
    global _pool
    with _pool_lock:
        if _pool is None:
            _pool = ThreadPoolExecutor(usable_cores(), thread_name_prefix="procam-camera")
        return _pool


def _forget_threads() -> None:
    """In a forked child: the parent's threads are not there, start new ones when needed."""
    global _pool, _pool_lock
    _pool, _pool_lock = None, threading.Lock()


os.register_at_fork(after_in_child=_forget_threads)


def run(tasks: Sequence[Callable[[], None]]) -> None:
    """Call every task, on the camera's threads when there are several, and wait for all of them;
    the first error is raised here."""
    if len(tasks) == 1:
        tasks[0]()
        return
    for done in [pool().submit(t) for t in tasks]:
        done.result()


def blockwise(fn: Callable[[np.ndarray], np.ndarray], x: np.ndarray, dtype) -> np.ndarray:
    """``fn`` on consecutive blocks of :data:`BLOCK` values of ``x`` (C order), on the calling
    thread; for an elementwise ``fn`` the result equals ``fn(x)`` bit for bit.

    Parameters
    ----------
    fn : callable
        1-D block -> 1-D block of the same length, of ``dtype``.
    x : numpy.ndarray
        Any shape.
    dtype : numpy dtype
        Of the result.

    Returns
    -------
    numpy.ndarray
        The shape of ``x``.

    Examples
    --------
    >>> x = np.arange(100_000, dtype=np.float32)
    >>> bool((blockwise(np.sqrt, x, np.float32) == np.sqrt(x)).all())
    True
    """
    flat = np.ascontiguousarray(x).ravel()
    out = np.empty(flat.shape, dtype)
    for i in range(0, flat.size, BLOCK):
        out[i:i + BLOCK] = fn(flat[i:i + BLOCK])
    return out.reshape(np.shape(x))
