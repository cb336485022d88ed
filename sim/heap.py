"""Keeping freed memory in the process's heap while a loop allocates the same large arrays again.

glibc's ``malloc`` serves a request above its mmap threshold (128 KiB at first; glibc raises it up
to 32 MiB as mapped blocks are freed) with a fresh anonymous mapping, and gives the pages back to
the kernel on ``free``. A loop that allocates the same large arrays every iteration (a training
step's activations and gradients: 33 MB each at batch 16 and 128², 67 MB at batch 8 and 256²)
then has the kernel map and zero all of them again each time: ~37,000 page faults per CompenNet
training step at 128² and batch 16, and element-wise operations on fresh pages run at a fifth of
their speed (``benchmarks/train.py``). Inside :func:`retained_heap` every request comes from the
heap and freed memory stays there for the next iteration; the values computed are unchanged.

Elsewhere than on glibc (macOS, musl) :func:`retained_heap` changes nothing.
"""
from __future__ import annotations

import ctypes
import functools
import platform
import threading
from collections.abc import Iterator
from contextlib import contextmanager

M_TRIM_THRESHOLD = -1
"""``mallopt`` parameter: free memory at the heap's top above this many bytes goes back to the kernel."""
M_MMAP_THRESHOLD = -3
"""``mallopt`` parameter: requests of at least this many bytes get a mapping of their own."""
M_MMAP_MAX = -4
"""``mallopt`` parameter: at most this many such mappings at once (0: none, all from the heap)."""

KEEP = 2**31 - 1
"""Trim threshold inside the block, bytes (``mallopt`` takes an ``int``): in effect never trim."""
MMAP_MAX = 65536
"""glibc's default number of mappings, restored on exit."""
MMAP_THRESHOLD = 32 * 1024 * 1024
"""mmap threshold on exit, bytes: the largest that glibc's own adjustment reaches (32 MiB)."""
TRIM_THRESHOLD = 2 * MMAP_THRESHOLD
"""Trim threshold on exit, bytes: twice the mmap threshold, as glibc's adjustment keeps it."""

_lock = threading.Lock()
_depth = 0


@functools.cache
def _glibc() -> ctypes.CDLL | None:
    """The process's C library if it is glibc, else None (``platform.libc_ver`` reads the Python
    executable, so the answer is kept)."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return None
    return ctypes.CDLL(None)


def _set(libc: ctypes.CDLL, **params: int) -> None:
    """``mallopt`` each ``M_*`` name to its value; raise RuntimeError if glibc refuses one."""
    for name, value in params.items():
        if libc.mallopt(globals()[name], value) != 1:
            raise RuntimeError(f"mallopt({name}, {value}) failed")


@contextmanager
def retained_heap() -> Iterator[bool]:
    """While inside, large allocations come from the heap and freed memory is kept for reuse.

    On entry glibc is told to map no block of its own (``M_MMAP_MAX`` 0) and to keep freed memory
    at the heap's top (``M_TRIM_THRESHOLD`` 2 GiB). On exit of the outermost block (blocks nest;
    threads share one count) the freed memory goes back to the kernel (``malloc_trim``) and the
    policy becomes the steady state of glibc's own: requests of 32 MiB and more mapped, the
    heap's top trimmed above 64 MiB (glibc stops adjusting these itself once they are set).

    Yields
    ------
    bool
        Whether the policy applies (False where the C library is not glibc).

    Examples
    --------
    >>> import numpy as np
    >>> with retained_heap():
    ...     total = sum(float(np.ones(1 << 22).sum()) for _ in range(3))
    >>> total
    12582912.0
    """
    global _depth
    libc = _glibc()
    if libc is None:
        yield False
        return
    with _lock:
        if _depth == 0:
            _set(libc, M_MMAP_MAX=0, M_TRIM_THRESHOLD=KEEP)
        _depth += 1
    try:
        yield True
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                _set(libc, M_MMAP_MAX=MMAP_MAX, M_MMAP_THRESHOLD=MMAP_THRESHOLD,
                     M_TRIM_THRESHOLD=TRIM_THRESHOLD)
                libc.malloc_trim(0)
