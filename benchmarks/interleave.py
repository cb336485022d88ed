"""Timing steps side by side, each in a process of its own: the steps take turns, one call each per
round with a short pause before each, so a machine shared with other jobs slows them alike, and no
step's memory policy or allocations touch another's (glibc's heap state alone moved a CompenNet
step's speed by 25 % when the steps shared a process).

The step processes are forked from one server process that has imported the benchmark script (and
so torch and procam) once, before any computation: each starts in a fraction of a second, where a
fresh interpreter took about 3.5 s of CPU per step and run to import torch and what its optimiser
imports on first use, and every step starts from the same heap."""
from __future__ import annotations

import multiprocessing
import time
from collections.abc import Callable
from contextlib import nullcontext

from sim.heap import retained_heap

WARM_UP = 3
"""Untimed calls of each step first: glibc's heap (its mmap threshold adapts to the sizes freed)
settles over the first calls; after one call the naive CompenNet loop measured 15-20 % slower
than after three."""


def _serve(conn, build: Callable[..., Callable[[], object]], args: tuple, heap: bool) -> None:
    """In a process of its own: ``build(*args)`` the step, warm it up (:data:`WARM_UP` calls),
    then time one call per request. A failure to build or warm up is sent back as its message."""
    with retained_heap() if heap else nullcontext():
        try:
            run = build(*args)
            for _ in range(WARM_UP):  # allocator, oneDNN primitives, compilation
                run()
        except Exception as exc:  # reported by the driver, which stops
            conn.send(f"{type(exc).__name__}: {exc}")
            return
        conn.send(None)
        while conn.recv():
            start = time.perf_counter()
            run()
            conn.send(time.perf_counter() - start)


def interleaved(steps: dict[str, tuple], rounds: int, pause: float = 0.05) -> dict[str, list[float]]:
    """Seconds of each call of each step, the steps taking turns for ``rounds`` rounds.

    Parameters
    ----------
    steps : dict
        Name → (``build``, ``args``, ``heap``) or (``build``, ``args``, ``heap``, ``copies``):
        ``build(*args)`` returns the step (a callable of no argument), built in the step's own
        process (so ``build`` must be importable: a module-level function); with ``heap`` the step
        runs inside :func:`sim.heap.retained_heap`. With ``copies`` > 1 that many processes of the
        step are called at once, and a call's seconds are the mean of theirs (each copy's own
        time, the others computing beside it: what jobs running side by side each take a step).
    rounds : int
        Timed calls of each step.
    pause : float
        Seconds of rest before each call (the previous step's threads go idle).
    """
    forks = multiprocessing.get_context("forkserver")
    # before the server starts (the first call's setting holds); torch's optimisers import
    # torch._dynamo on their first construction, 1.6 s of a step's start
    forks.set_forkserver_preload(["__main__", "torch._dynamo"])
    workers: dict[str, list] = {}
    try:
        for name, (build, args, heap, *copies) in steps.items():
            workers[name] = []
            for _ in range(copies[0] if copies else 1):
                here, there = forks.Pipe()
                proc = forks.Process(target=_serve, args=(there, build, args, heap), daemon=True)
                proc.start()
                workers[name].append((proc, here))
        for name, copies in workers.items():
            for _, conn in copies:
                if (failed := conn.recv()) is not None:
                    raise SystemExit(f"benchmark step {name!r} failed: {failed}")
        seconds = {name: [] for name in steps}
        for _ in range(rounds):
            for name, copies in workers.items():
                time.sleep(pause)
                for _, conn in copies:
                    conn.send(True)
                seconds[name].append(sum(conn.recv() for _, conn in copies) / len(copies))
        for copies in workers.values():
            for _, conn in copies:
                conn.send(False)
    finally:
        for proc, _ in (w for copies in workers.values() for w in copies):
            proc.join(timeout=30)
            if proc.is_alive():
                proc.terminate()
    return seconds
