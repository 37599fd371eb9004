"""A tracking server that stops answering during a run, and the signals that stop a stage: a
bounded wait (``tracking.timeout_s``), true messages naming the run, the exit codes a shell
expects (130 for SIGINT, 143 for SIGTERM), and the run closed when the server returns.

Each server is an `mlflow server` on 127.0.0.1 started here, in its own process group, with a
SQLite backend the test reads directly (the server may be dead by then)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest

from armexp.cli import main
from tests.cluster import free_port
from tests.helpers import stage_runs

SIMULATE = ["simulate", "scenario=hold", "scenario.duration=0.05"]


class Server:
    """An `mlflow server` on 127.0.0.1 whose backend is ``<folder>/server.db``; `kill` stops
    it as a crash would (SIGKILL), `start` brings it back on the same port."""

    def __init__(self, folder: Path) -> None:
        self.folder, self.port = folder, free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.backend = f"sqlite:///{folder / 'server.db'}"
        self.proc: subprocess.Popen[bytes] | None = None

    def start(self) -> None:
        command = [sys.executable, "-m", "mlflow", "server", "--host", "127.0.0.1",
                   "--port", str(self.port), "--backend-store-uri", self.backend,
                   "--artifacts-destination", str(self.folder / "artifacts"),
                   "--workers", "1"]  # fmt: skip
        env = {**os.environ, "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"}
        with (self.folder / "server.log").open("ab") as log:
            self.proc = subprocess.Popen(command, stdout=log, stderr=log, env=env,
                                         start_new_session=True)  # fmt: skip
        deadline = time.monotonic() + 120
        while True:
            with contextlib.suppress(OSError):
                urllib.request.urlopen(f"{self.url}/health", timeout=2).close()
                return
            if self.proc.poll() is not None or time.monotonic() > deadline:
                log_text = (self.folder / "server.log").read_text()[-2000:]
                raise RuntimeError(f"mlflow server did not start: {log_text}")
            time.sleep(0.3)

    def kill(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=30)


@pytest.fixture
def server(tmp_path: Path) -> Iterator[Server]:
    srv = Server(tmp_path)
    srv.start()
    try:
        yield srv
    finally:
        srv.kill()


def _on_server(srv: Server, tmp_path: Path, *extra: str) -> list[str]:
    return ["tracking=server", f"tracking.uri={srv.url}",
            f"tracking.runs_dir={tmp_path / 'runs'}", *extra]  # fmt: skip


def _when_simulating(monkeypatch: pytest.MonkeyPatch, then: Callable[[], Any]) -> None:
    """``then()`` once the simulate run has started, before the stage logs anything more."""
    from armexp.stages import simulate

    real = simulate.build_plant

    def build_plant(cfg: Any) -> Any:
        then()
        return real(cfg)

    monkeypatch.setattr(simulate, "build_plant", build_plant)


@pytest.mark.long
def test_a_server_that_dies_during_a_run_stops_it_within_tracking_timeout_s(
    server: Server, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    """Was: retries for over 10 minutes. Now the run stops once MLflow's retries, spread over
    ``tracking.timeout_s``, are spent: exit 1, one line while it waits (not urllib3's warning
    per retry) and one sentence naming the run, which stays RUNNING on the server."""
    _when_simulating(monkeypatch, server.kill)
    rc = main([*SIMULATE, *_on_server(server, tmp_path, "tracking.timeout_s=6")])
    err = capsys.readouterr().err.strip().splitlines()
    (run,) = stage_runs(server.backend, "simulate")
    assert rc == 1, err
    assert err == [
        "armexp: the tracking server does not answer; trying again for up to 6 s "
        "(tracking.timeout_s)",
        f"armexp simulate: the store tracking.uri={server.url} stopped answering (connection "
        f"refused) and did not answer again within tracking.timeout_s=6 s; run "
        f"{run.info.run_id} stays RUNNING there (its real status is unknown to the store) until "
        "the next armexp command against that store marks it FAILED.",
    ]
    assert run.info.status == "RUNNING"
    assert os.environ.get("MLFLOW_HTTP_REQUEST_MAX_RETRIES") is None  # put back after the command


@pytest.mark.long
@pytest.mark.parametrize(
    "sig",
    [signal.SIGTERM, pytest.param(signal.SIGINT, marks=pytest.mark.slow)],
    ids=["SIGTERM", "SIGINT"],
)
def test_a_signal_while_the_server_is_gone_stops_at_once_and_says_the_run_is_left_running(
    server: Server, tmp_path: Path, capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch, sig: signal.Signals,
) -> None:  # fmt: skip
    """Was: SIGTERM ignored for minutes (the writes that close the run retried), and SIGINT
    said "no run was started". The signal lands while MLflow waits to retry a write (the
    deadline is a minute, far longer than the test): the stage stops, exits 128 + the signal's
    number and names the run it could not mark."""
    previous, real = signal.getsignal(sig), signal.getsignal
    # A terminal's Ctrl-C, even where this test runs as a background job (SIGINT ignored).
    monkeypatch.setattr(
        signal, "getsignal", lambda s: signal.default_int_handler if s == signal.SIGINT else real(s)
    )
    timer = threading.Timer(1.0, os.kill, (os.getpid(), sig))

    def die_then_signal() -> None:
        server.kill()
        timer.start()

    _when_simulating(monkeypatch, die_then_signal)
    try:
        rc = main([*SIMULATE, *_on_server(server, tmp_path)])
    finally:
        timer.cancel()
        signal.signal(sig, previous)
    err = capsys.readouterr().err.strip().splitlines()
    (run,) = stage_runs(server.backend, "simulate")
    assert rc == 128 + sig, err
    word = "terminated" if sig == signal.SIGTERM else "interrupted"
    assert err[-1] == (
        f"armexp simulate: {word}; run {run.info.run_id} could not be marked KILLED (connection "
        "refused): it stays RUNNING in the store until the next armexp command against that "
        "store marks it FAILED."
    )
    assert run.info.status == "RUNNING"


def test_sigterm_ends_the_run_killed_and_exits_143(
    runs_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Was: exit 130, as for Ctrl-C; a shell and a scheduler read 143 as "terminated"."""
    _when_simulating(monkeypatch, lambda: os.kill(os.getpid(), signal.SIGTERM))
    previous = signal.getsignal(signal.SIGTERM)
    try:
        rc = main([*SIMULATE, f"tracking.runs_dir={runs_dir}"])
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert rc == 143
    err = capsys.readouterr().err.strip()
    assert err.endswith("armexp simulate: terminated; the MLflow run is marked KILLED.")
    (run,) = stage_runs(runs_dir, "simulate")
    assert run.info.status == "KILLED" and run.data.tags["armexp.error"] == "interrupted"
    assert signal.getsignal(signal.SIGTERM) is previous  # armexp's handler is gone again


#: `armexp simulate` in a process of its own whose server (the process group in argv[1]) dies
#: once its run has started.
SERVER_DIES = """
import os, signal, sys
from armexp.cli import main
from armexp.stages import simulate

real, server = simulate.build_plant, int(sys.argv[1])

def build_plant(cfg):
    os.killpg(server, signal.SIGKILL)
    return real(cfg)

simulate.build_plant = build_plant
sys.exit(main(sys.argv[2:]))
"""


@pytest.mark.slow
def test_the_run_a_dead_server_left_running_is_marked_failed_when_the_server_returns(
    server: Server, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The process whose server died has exited; when the server is back, the next command
    against it finds the run RUNNING with its process gone, and marks it FAILED."""
    assert server.proc is not None
    root = Path(__file__).resolve().parents[1]
    died = subprocess.run(
        [sys.executable, "-c", SERVER_DIES, str(server.proc.pid), *SIMULATE,
         *_on_server(server, tmp_path, "tracking.timeout_s=5")],
        capture_output=True, text=True, timeout=300, cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(root)},
    )  # fmt: skip
    assert died.returncode == 1, died.stderr[-2000:]
    (left,) = stage_runs(server.backend, "simulate")
    assert left.info.status == "RUNNING"
    server.proc.wait(timeout=30)
    server.start()  # the same port and store
    assert main([*SIMULATE, *_on_server(server, tmp_path)]) == 0
    err = capsys.readouterr().err
    assert (
        f"armexp: simulate run {left.info.run_id} was RUNNING but its process stopped; marked "
        "FAILED"
    ) in err
    closed, _ = stage_runs(server.url, "simulate", newest_first=False)
    assert closed.info.run_id == left.info.run_id and closed.info.status == "FAILED"
    assert closed.data.tags["armexp.error"].startswith("process stopped")


def _children(pid: int) -> list[int]:
    """The processes whose parent is ``pid``."""
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        with contextlib.suppress(OSError, IndexError, ValueError):
            if int(stat.read_text().rsplit(")", 1)[1].split()[1]) == pid:
                found.append(int(stat.parent.name))
    return found


def _command_line(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_text(errors="replace")
    except OSError:
        return ""


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


@pytest.mark.slow
def test_the_workers_of_a_joblib_sweep_whose_command_is_killed_exit_after_their_job(
    runs_dir: Path,
) -> None:
    """Was: loky's idle workers stayed 300 s, and one caught reading a half-written job stayed
    for good. Now each exits once the job in hand has ended (long before loky's idle timeout,
    the 300 s the loop below stays under); the jobs that ran are FINISHED."""
    command = [sys.executable, "-m", "armexp", "simulate", "-m", "seed=range(0,16)",
               "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "scenario.duration=40",
               f"tracking.runs_dir={runs_dir}"]  # fmt: skip
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers: list[int] = []
    try:
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and proc.poll() is None:
            workers = [p for p in _children(proc.pid) if "popen_loky" in _command_line(p)]
            with contextlib.suppress(Exception):  # the store may not exist yet
                if len(workers) == 2 and stage_runs(runs_dir, "simulate"):
                    break
            time.sleep(0.5)
        assert proc.poll() is None and len(workers) == 2, "the sweep did not start its workers"
        proc.kill()
        proc.wait(timeout=30)
        deadline = time.monotonic() + 240
        while any(_alive(w) for w in workers) and time.monotonic() < deadline:
            time.sleep(0.5)
        left = [w for w in workers if _alive(w)]
    finally:
        for pid in [*workers, proc.pid]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
    assert left == []
    runs = stage_runs(runs_dir, "simulate")
    assert runs and all(r.info.status in ("FINISHED", "RUNNING") for r in runs)
