"""Executors: a failing job is a record, not an abort; a tiny bench on a local Ray instance (2 CPUs)
gives the local executor's numbers, table for table."""
from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from helpers import compute_threads, tiny_toml
from compensation.experiments import executors
from compensation.experiments.bench import BenchConfig, run_bench
from compensation.experiments.executors import LocalExecutor, Task, attempt, make_executor
from compensation.reports.tables import write_tables
from sim.cores import usable_cores
from sim.errors import ProcamError
from sim.setup import load_suite

BASE = tiny_toml()
SUITE = """
base = "base.toml"
[[setup]]
name = "s1"
surface = { texture_seed = 1 }
[[setup]]
name = "s2"
surface = { texture = "stripes", texture_seed = 2 }
ambient = { radiance = [0.08, 0.08, 0.08] }
"""
TIMINGS = {"train s", "infer ms/frame", "fit_s", "infer_ms"}
"""Columns holding wall-clock times (the only ones allowed to differ)."""


def test_attempt_and_local_executor():
    failed = attempt(int, "x")
    assert not failed["ok"] and "int(" in failed["error"] and "Traceback" in failed["traceback"]
    done = LocalExecutor().run([Task(dict.fromkeys, ("a", "b")), Task(int, "x")])
    assert done[0] == {"ok": True, "a": None, "b": None}
    assert not done[1]["ok"] and done[1]["error"].startswith("ValueError: invalid literal")


def _running(pid: int) -> bool:
    """Whether process ``pid`` exists and has not exited (a zombie no one reaped has)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(") ")[-1][0] != "Z"
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="reads process states from /proc")
def test_worker_processes_end_with_a_stopped_run(tmp_path):
    """A study or bench stopped by a signal while its worker processes run jobs leaves none of
    them running on (they would write into the folder the next run resumes)."""
    script = ("from compensation.experiments.executors import LocalExecutor, Task\n"
              "from helpers import record_pid_and_wait\n"
              f"LocalExecutor(2).run([Task(record_pid_and_wait, {str(tmp_path)!r})] * 2)\n")
    tests = str(Path(__file__).parent)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [tests, os.environ.get("PYTHONPATH")])))
    main = subprocess.Popen([sys.executable, "-c", script], env=env)
    try:
        deadline = time.monotonic() + 120
        while len(pids := [int(p.name[4:]) for p in tmp_path.glob("pid-*")]) < 2:
            assert main.poll() is None and time.monotonic() < deadline, "the workers did not start"
            time.sleep(0.1)
        assert all(_running(pid) for pid in pids)
        main.send_signal(signal.SIGTERM)
        main.wait(30)
        deadline = time.monotonic() + 20
        while any(_running(pid) for pid in pids):
            assert time.monotonic() < deadline, f"worker processes {pids} still run their jobs"
            time.sleep(0.1)
    finally:
        main.kill()


@pytest.mark.parametrize("given", [None, "3"])
def test_pool_workers_share_the_cores_unless_told(given, monkeypatch):
    """--processes N: each worker computes on its share of the cores (one thread each on 2 cores
    with 2 workers), and an OMP_NUM_THREADS the user set is kept."""
    if given is None:
        monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    else:
        monkeypatch.setenv("OMP_NUM_THREADS", given)
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(Path(__file__).parent),
                                                                    os.environ.get("PYTHONPATH")])))
    records = LocalExecutor(2).run([Task(compute_threads, None)] * 2)
    if given is None:
        share = max(1, usable_cores() // 2)
        expected = {"torch": share, "omp": str(share)}
    else:  # as a process started with it computes
        alone = subprocess.run([sys.executable, "-c", "import torch; print(torch.get_num_threads())"],
                               capture_output=True, text=True, check=True)
        expected = {"torch": int(alone.stdout), "omp": given}
    assert records == [{"ok": True, **expected}] * 2, records


def test_executor_options_are_checked():
    with pytest.raises(ProcamError, match="expected one of local, ray"):
        make_executor("dask")
    with pytest.raises(ProcamError, match="--address: only with --executor ray"):
        make_executor("local", address="auto")
    with pytest.raises(ProcamError, match="--processes: only with --executor local"):
        make_executor("ray", workers=2)
    with pytest.raises(ProcamError, match="--processes 0"):
        make_executor("local", workers=0)


def _table(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return [{k: v for k, v in row.items() if k not in TIMINGS} for row in csv.DictReader(f)]


@pytest.mark.slow
def test_ray_bench_equals_local(tmp_path):
    ray = pytest.importorskip("ray")
    from compensation.experiments.executors import RayExecutor

    (tmp_path / "base.toml").write_text(BASE)
    (tmp_path / "suite.toml").write_text(SUITE)
    suite = load_suite(tmp_path / "suite.toml")
    cfg = BenchConfig(methods=("tps", "nayar"), sizes=(4,), tables=("1",), size=32, n_test=2,
                      closed_loop=True)
    write_tables(tmp_path / "local", cfg, run_bench(suite, tmp_path / "local", cfg, progress=False,
                                                    executor=LocalExecutor()))
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        executor = RayExecutor()  # joins the instance started here
        run_bench(suite, tmp_path / "ray", cfg, progress=False, executor=executor)
        assert ray.cluster_resources()["CPU"] == 2
        stamps = {p: p.stat().st_mtime_ns for p in (tmp_path / "ray").rglob("metrics.json")}
        result = run_bench(suite, tmp_path / "ray", cfg, progress=False, executor=executor)  # a new driver's run
        write_tables(tmp_path / "ray", cfg, result)
        assert {p: p.stat().st_mtime_ns for p in (tmp_path / "ray").rglob("metrics.json")} == stamps
    finally:
        ray.shutdown()
    for name in ("table1.csv", "per_setup.csv", "results.csv"):
        local, remote = _table(tmp_path / "local" / name), _table(tmp_path / "ray" / name)
        assert local == remote and len(local) >= 4, name
    rows = _table(tmp_path / "ray" / "results.csv")
    assert {r["status"] for r in rows} == {"ok"} and all(r["cl_psnr"] for r in rows)
    assert all((tmp_path / "ray" / r["run"] / "closed_loop" / "img_0002.png").exists() for r in rows)


@pytest.mark.parametrize("kind", ["closed port", "ray:// closed port", "unknown host", "malformed",
                                  "port above 65535", "port 0", "no host"])
def test_an_unreachable_ray_address_is_refused_at_once(kind, monkeypatch):
    """An address nothing listens at is refused with the address named, before Ray's own minutes of
    retries (the probe is a TCP connection with a timeout); Ray is never initialised."""
    import socket

    pytest.importorskip("ray")
    import ray

    with socket.socket() as probe:  # a port that was free a moment ago: nothing listens there
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
    address = {"closed port": f"127.0.0.1:{port}", "ray:// closed port": f"ray://127.0.0.1:{port}",
               "unknown host": "no-such-host.invalid:6379", "malformed": "127.0.0.1",
               "port above 65535": "127.0.0.1:99999", "port 0": "127.0.0.1:0", "no host": ":6379"}[kind]
    monkeypatch.setattr(ray, "init", lambda *a, **k: pytest.fail("ray.init called"))
    with pytest.raises(ProcamError, match=f"--address {address}: "):
        make_executor("ray", address)


@pytest.mark.parametrize("reply", [b"", b"HTTP/1.1 400 Bad Request\r\n\r\n"], ids=["silent", "HTTP/1.1"])
def test_an_address_where_no_ray_cluster_answers_is_refused_in_time(reply, monkeypatch):
    """A server that accepts the connection but does not answer as Ray's gRPC servers do (Ray itself
    would wait minutes on it) is refused once the timeout passes; Ray is never initialised."""
    import socket
    import threading

    pytest.importorskip("ray")
    import ray

    monkeypatch.setattr(ray, "init", lambda *a, **k: pytest.fail("ray.init called"))
    monkeypatch.setattr(executors, "CONNECT_TIMEOUT_S", 0.5)
    done = threading.Event()
    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()

        def answer():
            connection, _ = server.accept()
            with connection:
                connection.recv(64)
                connection.sendall(reply)
                done.wait(10)

        threading.Thread(target=answer, daemon=True).start()
        address = f"127.0.0.1:{server.getsockname()[1]}"
        with pytest.raises(ProcamError, match=f"--address {address}: a server listens there but does not answer "
                                              "as a Ray cluster"):
            make_executor("ray", address)
        done.set()
