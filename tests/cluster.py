"""Real services for the scale tests, started on loopback and torn down even on failure: a Ray
cluster (head plus one worker node), PostgreSQL, and an `mlflow server` on it.

Ray advertises the machine's external interface even when told 127.0.0.1 (ray #26293), so these
run inside a network namespace of their own (`in_netns` re-runs a command under
``unshare --net`` with only loopback up); the file system and processes stay shared, so the test
outside reads what the command wrote.
"""

from __future__ import annotations

import contextlib
import glob
import os
import pwd
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

PG_USER = "postgres"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def in_netns(command: Sequence[str], timeout: float, **kw: Any) -> subprocess.CompletedProcess:
    """``command`` in a new network namespace with loopback up (needs root)."""
    script = 'ip link set lo up && exec "$@"'
    return subprocess.run(
        ["unshare", "--net", "--", "sh", "-c", script, "sh", *command], timeout=timeout, **kw
    )


def _stop_group(proc: subprocess.Popen, grace: float = 20) -> None:
    """SIGTERM to the process group ``proc`` leads, then SIGKILL to what is left."""
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGTERM)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=grace)
    with contextlib.suppress(ProcessLookupError):
        os.killpg(proc.pid, signal.SIGKILL)
    with contextlib.suppress(subprocess.TimeoutExpired):
        proc.wait(timeout=10)


def _wait_port(port: int, what: str, proc: subprocess.Popen, limit: float = 90) -> None:
    deadline = time.time() + limit
    while time.time() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"{what} exited with {proc.returncode} before it listened")
        with contextlib.suppress(OSError):
            socket.create_connection(("127.0.0.1", port), timeout=1).close()
            return
        time.sleep(0.5)
    raise RuntimeError(f"{what} did not listen on 127.0.0.1:{port} within {limit:.0f} s")


@contextlib.contextmanager
def ray_cluster(work: Path, worker_cpus: int = 1, head_cpus: int = 1) -> Iterator[str]:
    """A head node and one worker node on 127.0.0.1, each `ray start --block` in its own process
    group (so teardown stops exactly these processes); yields the head's address."""
    port = free_port()
    temp = Path(f"/tmp/rx{port}")  # Ray's socket paths must stay short
    ray = str(Path(sys.executable).with_name("ray"))
    common = ["--block", "--disable-usage-stats", "--node-ip-address=127.0.0.1"]
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0"}
    log = (work / "ray.log").open("a")
    procs: list[subprocess.Popen] = []
    address = f"127.0.0.1:{port}"
    try:
        head = [ray, "start", "--head", f"--port={port}", f"--num-cpus={head_cpus}",
                "--include-dashboard=false", f"--temp-dir={temp}", *common]  # fmt: skip
        procs.append(subprocess.Popen(head, stdout=log, stderr=log, env=env,
                                      start_new_session=True))  # fmt: skip
        _wait_port(port, "ray head", procs[0])
        worker = [ray, "start", f"--address={address}", f"--num-cpus={worker_cpus}", *common]
        procs.append(subprocess.Popen(worker, stdout=log, stderr=log, env=env,
                                      start_new_session=True))  # fmt: skip
        _wait_nodes(address, 2)
        yield address
    finally:
        for proc in reversed(procs):
            _stop_group(proc)
        log.close()
        shutil.rmtree(temp, ignore_errors=True)


def _wait_nodes(address: str, n: int, limit: float = 120) -> None:
    """Until the cluster has ``n`` live nodes (asked from a fresh interpreter: a driver in this
    process would stay connected)."""
    probe = (
        "import ray, sys; ray.init(address=sys.argv[1], logging_level='ERROR'); "
        "print(sum(1 for n in ray.nodes() if n['Alive']))"
    )
    deadline = time.time() + limit
    while time.time() < deadline:
        res = subprocess.run([sys.executable, "-c", probe, address], capture_output=True,
                             text=True, timeout=120)  # fmt: skip
        if res.returncode == 0 and int(res.stdout.strip().splitlines()[-1]) >= n:
            return
        time.sleep(1)
    raise RuntimeError(f"the Ray cluster at {address} did not reach {n} nodes in {limit:.0f} s")


def _pg_bin(name: str) -> str:
    found = sorted(glob.glob(f"/usr/lib/postgresql/*/bin/{name}"))
    if not found:
        raise RuntimeError(f"PostgreSQL's {name} is not installed (apt-get install postgresql)")
    return found[-1]


def _as_pg(command: Sequence[str], **kw: Any) -> subprocess.CompletedProcess:
    user = pwd.getpwnam(PG_USER)
    return subprocess.run(list(command), user=user.pw_uid, group=user.pw_gid, check=True, **kw)


@contextlib.contextmanager
def postgres(work: Path) -> Iterator[str]:
    """A PostgreSQL server on 127.0.0.1 in a fresh data directory, run as ``postgres`` (it
    refuses root); yields the SQLAlchemy URI of its database ``mlflow``. The data directory is
    made directly under the system's temporary folder: the ``postgres`` user cannot enter
    pytest's folders (mode 0700, root's)."""
    data = Path(tempfile.mkdtemp(prefix="armexp-pg-"))
    user = pwd.getpwnam(PG_USER)
    os.chown(data, user.pw_uid, user.pw_gid)
    port = free_port()
    try:
        _as_pg([_pg_bin("initdb"), "-D", str(data), "-A", "trust", "-U", PG_USER],
               capture_output=True)  # fmt: skip
        opts = f"-h 127.0.0.1 -p {port} -k {data}"
        _as_pg([_pg_bin("pg_ctl"), "-D", str(data), "-o", opts, "-l", str(data / "log"), "-w",
                "start"], capture_output=True)  # fmt: skip
        try:
            _as_pg([_pg_bin("createdb"), "-h", "127.0.0.1", "-p", str(port), "-U", PG_USER,
                    "mlflow"], capture_output=True)  # fmt: skip
            # SQLAlchemy 2.1 reads a bare postgresql:// as psycopg 3; the driver is psycopg2.
            yield f"postgresql+psycopg2://{PG_USER}@127.0.0.1:{port}/mlflow"
        finally:
            _as_pg([_pg_bin("pg_ctl"), "-D", str(data), "-m", "immediate", "-w", "stop"],
                   capture_output=True)  # fmt: skip
    finally:
        with contextlib.suppress(OSError):
            shutil.copy(data / "log", work / "postgres.log")
        shutil.rmtree(data, ignore_errors=True)


@contextlib.contextmanager
def mlflow_server(work: Path, backend: str) -> Iterator[str]:
    """`mlflow server` on 127.0.0.1 with ``backend`` as its store and a local artifact root."""
    port = free_port()
    log = (work / "mlflow-server.log").open("a")
    command = [sys.executable, "-m", "mlflow", "server", "--host", "127.0.0.1", "--port",
               str(port), "--backend-store-uri", backend, "--artifacts-destination",
               str(work / "server-artifacts"), "--workers", "2"]  # fmt: skip
    proc = subprocess.Popen(command, stdout=log, stderr=log, start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.time() + 120
        while True:
            try:
                with urllib.request.urlopen(f"{url}/health", timeout=2) as res:
                    if res.status == 200:
                        break
            except OSError:
                if proc.poll() is not None or time.time() > deadline:
                    raise RuntimeError(f"mlflow server did not start (see {log.name})") from None
                time.sleep(0.5)
        yield url
    finally:
        _stop_group(proc)
        log.close()
