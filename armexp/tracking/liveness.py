"""Telling a live run from one whose process died: a heartbeat tag and the process's identity.

A running stage tags its run with its process (`PROCESS_TAG`, ``host:pid:start``) and rewrites
`HEARTBEAT_TAG` every `HEARTBEAT_S` seconds (`Heartbeat`). A RUNNING run is taken as dead when its
process is gone from this host, or, from another host, when it has been silent for `STALE_S`
(`is_alive`); `armexp.tracking.stage_runs.close_orphans` marks such runs FAILED.
"""

from __future__ import annotations

import logging
import os
import socket
import threading
import time
from pathlib import Path

from mlflow.entities import Run
from mlflow.tracking import MlflowClient

from armexp.tracking.tags import HEARTBEAT_TAG, PROCESS_TAG

log = logging.getLogger(__name__)

#: A running stage writes its heartbeat this often (s); a RUNNING run silent for STALE_S is
#: taken as one whose process died.
HEARTBEAT_S = 30.0
STALE_S = 150.0


class Heartbeat:
    """Writes the time into the run's ``armexp.heartbeat`` tag every `HEARTBEAT_S` seconds
    while the stage runs, so another process can tell a live run from one whose process died
    (`is_alive`, `close_orphans`)."""

    def __init__(self, run_id: str, uri: str) -> None:
        self.run_id, self.client = run_id, MlflowClient(uri)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, name="armexp-heartbeat", daemon=True)

    def _beat(self) -> None:
        while not self._stop.wait(HEARTBEAT_S):
            try:
                self.client.set_tag(self.run_id, HEARTBEAT_TAG, f"{time.time():.0f}")
            except Exception as exc:  # a busy store: the next beat tries again
                log.debug("heartbeat of %s not written: %s", self.run_id, exc)

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(self, exc_type: type[BaseException] | None, *exc: object) -> None:
        self._stop.set()
        # A stage that stops on an error or a signal does not wait for a beat its store may
        # never answer; a late beat on an ended run changes nothing (`is_alive` reads RUNNING).
        self._thread.join(timeout=5 if exc_type is None else 0.2)


def heartbeat_age(run: Run) -> float:
    """Seconds since the run's process last reported (its start when it never did)."""
    beat = run.data.tags.get(HEARTBEAT_TAG)
    last = float(beat) if beat else run.info.start_time / 1000.0
    return time.time() - last


def _process_start(pid: int) -> str | None:
    """The start time of process `pid` in clock ticks since boot (Linux), None elsewhere or when
    there is no such process; with the pid it names one process even after pids wrap round."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[1].split()[19]  # field 22; the name in (…) may hold spaces


def process_identity(pid: int | None = None) -> str:
    """Process ``pid`` of this host (this process when None) as ``host:pid:start``, the
    `PROCESS_TAG` value."""
    pid = os.getpid() if pid is None else pid
    return f"{socket.gethostname()}:{pid}:{_process_start(pid) or ''}"


def _running_here(identity: str | None) -> bool | None:
    """Whether `identity` names a process that runs on this host now; None when that cannot be
    told here (no identity, another host, a platform without /proc)."""
    if not identity:
        return None
    host, _, rest = identity.partition(":")
    pid_text, _, start = rest.partition(":")
    if host != socket.gethostname() or not pid_text.isdigit() or not start:
        return None
    if _process_start(os.getpid()) is None:
        return None  # this platform cannot look processes up
    return _process_start(int(pid_text)) == start


def process_gone(identity: str | None) -> bool:
    """True when `identity` names a process on this host that no longer runs. A process on
    another host, or one this platform cannot look up, is not known gone."""
    return _running_here(identity) is False


def is_alive(run: Run) -> bool:
    """A RUNNING run whose process still runs on this host, or, where that cannot be told (its
    process on another host), one that reported within `STALE_S`. A process on this host that is
    alive but silent (stopped with SIGSTOP, a suspended machine) is alive: silence alone is the
    evidence only from elsewhere."""
    if run.info.status != "RUNNING":
        return False
    here = _running_here(run.data.tags.get(PROCESS_TAG))
    if here is not None:
        return here
    return heartbeat_age(run) < STALE_S
