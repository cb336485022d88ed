"""Where the jobs of a study or benchmark run: in this process (``local``, optionally a pool of
worker processes) or as Ray tasks (``ray``: this machine's CPUs and GPUs, or a cluster).

A job is a module-level function and one picklable argument (a frozen dataclass of paths and
configurations); it reads and writes only the files under the study folder and the dataset root,
so every executor gives the same files and the same numbers, and a job already finished is reused
whoever ran it. :func:`attempt` runs one job and turns its failure into a record, so one failing
job never stops the others; :func:`timed` also measures it, for the executors' ``on_done``
callback (each job's record and duration as it finishes).
"""
from __future__ import annotations

import os
import socket
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import dataclass
from multiprocessing import get_context

from sim.cores import usable_cores
from sim.errors import ProcamError

EXECUTORS = ("local", "ray")
"""Names accepted by :func:`make_executor` (and ``--executor``)."""


@dataclass(frozen=True)
class Task:
    """One job and what it needs.

    Attributes
    ----------
    fn : callable
        A module-level function (pickled by reference) taking ``job``.
    job : object
        Its picklable argument.
    num_cpus : float
        CPU cores the job uses (a Ray resource request).
    num_gpus : float
        GPUs the job uses (0 on the CPU).
    """

    fn: Callable
    job: object
    num_cpus: float = 1.0
    num_gpus: float = 0.0


def attempt(fn: Callable, job) -> dict:
    """``{"ok": True, **fn(job)}``, or ``{"ok": False, "error": …, "traceback": …}`` if it raises.

    An interruption (:class:`KeyboardInterrupt`, or the training loop's own
    :class:`~compensation.training.loop.TrainingInterrupted`) is not a job's failure: it stops the
    whole run (what is finished is kept).

    >>> attempt(int, "3x")["error"]
    "ValueError: invalid literal for int() with base 10: '3x'"
    """
    from compensation.training.loop import TrainingInterrupted

    try:
        return {"ok": True, **fn(job)}
    except TrainingInterrupted:
        raise
    except Exception as exc:  # one failure must not lose the others' results
        return {"ok": False, "error": f"{type(exc).__name__}: {exc}",
                "traceback": traceback.format_exc(limit=4)}


def timed(fn: Callable, job) -> tuple[dict, float]:
    """The :func:`attempt` record of ``fn(job)`` and its wall time (seconds).

    >>> record, seconds = timed(dict.fromkeys, "ab")
    >>> record, seconds >= 0
    ({'ok': True, 'a': None, 'b': None}, True)
    """
    t0 = time.perf_counter()
    record = attempt(fn, job)
    return record, time.perf_counter() - t0


def end_with(parent: int, poll: float = 1.0) -> None:
    """A worker process's initializer: a daemon thread ends this process (exit status 1) once
    ``parent``, the process that started its pool, is gone, checked every ``poll`` seconds.

    A study or bench stopped by a signal to its main process alone (``kill``, a scheduler's time
    limit; Ctrl-C in a terminal reaches the workers too) ends with its main process; the
    pool's workers would otherwise run their jobs on, unseen, and write files into a folder the
    next run resumes. A job a worker did not finish leaves no record, so the next run does it
    again.
    """
    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll)
        os._exit(1)

    threading.Thread(target=watch, name="end-with-parent", daemon=True).start()


def worker_threads(workers: int) -> int:
    """Threads each of ``workers`` pool processes computes with: its share of the usable cores.

    Two one-thread training jobs side by side on 2 cores train 1.26-1.45x the samples of one
    two-thread job (``benchmarks/results/train/``); jobs of more threads than their share would
    contend for the cores.

    >>> worker_threads(1) == usable_cores(), worker_threads(10 * usable_cores())
    (True, 1)
    """
    return max(1, usable_cores() // workers)


def start_worker(parent: int, threads: int) -> None:
    """A pool worker's initializer: it ends with ``parent`` (:func:`end_with`) and, unless
    ``OMP_NUM_THREADS`` says otherwise, computes on ``threads`` threads (torch's intra-op pool,
    and OpenMP in libraries loaded later). Dr.Jit's own thread pool is left as it is."""
    end_with(parent)
    if "OMP_NUM_THREADS" not in os.environ:
        os.environ["OMP_NUM_THREADS"] = str(threads)
        import torch

        torch.set_num_threads(threads)


DoneCallback = Callable[[int, dict, float], None]
"""``on_done(index, record, seconds)``: called by an executor's ``run`` in this process as each
task finishes, with the task's index in the list given, its :func:`attempt` record and its wall
time."""


class LocalExecutor:
    """Jobs in this process, in order (``workers`` 1), or in a pool of ``workers`` processes that
    end with this one and share the cores (:func:`start_worker`).

    Parameters
    ----------
    workers : int
        Worker processes (>= 1); 1 runs each job here, one after the other.
    """

    name = "local"

    def __init__(self, workers: int = 1):
        if not isinstance(workers, int) or workers < 1:
            raise ProcamError(f"--processes {workers!r}: expected a positive integer")
        self.workers = workers

    def run(self, tasks: Sequence[Task], on_done: DoneCallback | None = None) -> list[dict]:
        """The :func:`attempt` record of every task, in the order given; ``on_done`` is called
        as each finishes (:data:`DoneCallback`)."""
        records: list[dict] = [{}] * len(tasks)

        def finished(i: int, record: dict, seconds: float) -> None:
            records[i] = record
            if on_done is not None:
                on_done(i, record, seconds)

        if self.workers == 1 or len(tasks) < 2:
            for i, t in enumerate(tasks):
                finished(i, *timed(t.fn, t.job))
            return records
        # spawn: a fresh interpreter per worker (no forked torch or Mitsuba thread state)
        workers = min(self.workers, len(tasks))
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn"), initializer=start_worker,
                                 initargs=(os.getpid(), worker_threads(workers))) as pool:
            futures = {pool.submit(timed, t.fn, t.job): i for i, t in enumerate(tasks)}
            for future in as_completed(futures):
                finished(futures[future], *future.result())
        return records

    def gpus(self) -> float:
        """GPUs visible to the jobs."""
        import torch

        return float(torch.cuda.device_count())


CONNECT_TIMEOUT_S = 10.0
"""Seconds to wait for a Ray cluster's address to accept a connection before giving up (Ray itself
retries an unreachable address for minutes)."""


HTTP2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes(3) + b"\x04" + bytes(5)
"""An HTTP/2 client's first bytes: the connection preface, then an empty SETTINGS frame. A gRPC
server (Ray's GCS and its client server) answers with a frame of its own, a SETTINGS frame
(type 4, the frame header's fourth byte)."""


def _check_reachable(address: str | None) -> None:
    """Refuse, within :data:`CONNECT_TIMEOUT_S` for each step, a ``host:port`` or
    ``ray://host:port`` address that accepts no TCP connection, or whose server does not answer
    :data:`HTTP2_PREFACE` as a gRPC server does (Ray itself waits for minutes on a port where
    another program listens); None and ``auto`` are left to Ray: a local lookup.

    Raises
    ------
    ProcamError
        If the address is malformed, nothing listens there, or what listens is not a Ray cluster.
    """
    if address in (None, "auto", "local"):
        return
    target = address.split("://", 1)[1] if "://" in address else address
    host, _, port = target.rpartition(":")
    if not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ProcamError(f"--address {address}: expected auto, HOST:PORT or ray://HOST:PORT (a port "
                          "from 1 to 65535)")
    try:
        with socket.create_connection((host, int(port)), timeout=CONNECT_TIMEOUT_S) as connection:
            try:
                connection.sendall(HTTP2_PREFACE)
                answer = connection.recv(9)
            except OSError:
                answer = b""
    except OSError as exc:
        raise ProcamError(f"--address {address}: cannot connect to a Ray cluster there within "
                          f"{CONNECT_TIMEOUT_S:g} s ({exc}); start one with 'ray start --head' or "
                          "check the address") from None
    if answer[3:4] != b"\x04":
        raise ProcamError(f"--address {address}: a server listens there but does not answer as a Ray "
                          f"cluster (gRPC) within {CONNECT_TIMEOUT_S:g} s; check the address and port "
                          "(ray start --head prints them)")


class RayExecutor:
    """Each job one Ray task declaring its ``num_cpus`` and ``num_gpus``.

    Connects to the cluster at ``address`` (``"auto"``: the one ``ray start --head`` started on
    this machine; ``ray://host:10001``: a remote one) or, without an address, to the instance
    already initialised in this process, else starts a local one on this machine's cores and GPUs.
    The jobs share data through the filesystem: on a cluster the study folder (and the dataset
    root) must be on a filesystem every node mounts at the same path, with procam installed in
    the same version on every node.
    """

    name = "ray"

    def __init__(self, address: str | None = None):
        try:
            import ray
        except ImportError:
            raise ProcamError("--executor ray: Ray is not installed; install procam's extra: "
                              "pip install 'procam[ray]'") from None
        self.ray = ray
        if not ray.is_initialized():
            # the workers import procam from the same place as this process
            path = os.pathsep.join(p for p in (os.getcwd(), os.environ.get("PYTHONPATH", "")) if p)
            env = {"PYTHONPATH": path, "OMP_WAIT_POLICY": os.environ.get("OMP_WAIT_POLICY", "PASSIVE")}
            if "PROCAM_VARIANT" in os.environ:  # the Mitsuba variant this process was told to use
                env["PROCAM_VARIANT"] = os.environ["PROCAM_VARIANT"]
            _check_reachable(address)
            try:
                ray.init(address=address, include_dashboard=False, log_to_driver=False,
                         runtime_env={"env_vars": env})
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise ProcamError(f"--address {address}: cannot connect to a Ray cluster ({exc})") from None

    def run(self, tasks: Sequence[Task], on_done: DoneCallback | None = None) -> list[dict]:
        """The :func:`attempt` record of every task, in the order given; ``on_done`` is called
        for each in that order, as its result arrives (:data:`DoneCallback`)."""
        remote = self.ray.remote(timed)
        refs = [remote.options(num_cpus=t.num_cpus, num_gpus=t.num_gpus).remote(t.fn, t.job)
                for t in tasks]
        records = []
        for i, ref in enumerate(refs):
            record, seconds = self._result(ref)
            records.append(record)
            if on_done is not None:
                on_done(i, record, seconds)
        return records

    def _result(self, ref) -> tuple[dict, float]:
        """A task's record and wall time; a task lost by Ray (its worker or node died) is a failed
        job, of unknown duration (0)."""
        try:
            return self.ray.get(ref)
        except self.ray.exceptions.RayError as exc:
            return {"ok": False, "error": f"{type(exc).__name__}: {exc}".strip(), "traceback": ""}, 0.0

    def gpus(self) -> float:
        """GPUs of the cluster."""
        return float(self.ray.cluster_resources().get("GPU", 0))


def make_executor(name: str = "local", address: str | None = None,
                  workers: int = 1) -> LocalExecutor | RayExecutor:
    """The executor called ``name`` (:data:`EXECUTORS`).

    Raises
    ------
    ProcamError
        If the name is unknown, ``address`` is given to the local executor, ``workers`` (more
        than 1, ``--processes``) to Ray,
        or Ray is missing or unreachable.
    """
    if name not in EXECUTORS:
        raise ProcamError(f"--executor {name!r}: expected one of {', '.join(EXECUTORS)}")
    if name == "local":
        if address is not None:
            raise ProcamError("--address: only with --executor ray")
        return LocalExecutor(workers)
    if workers != 1:
        raise ProcamError("--processes: only with --executor local (Ray places its tasks itself)")
    return RayExecutor(address)
