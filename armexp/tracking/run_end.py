"""How a stage run ends: its status written truthfully, also when the stage stops on a signal, a
full disk or a store that stopped answering (`armexp.tracking.remote`).

The writes that end a run are made while it stops, so they never hide why it stopped: a
second Ctrl-C or a store that is gone leaves the run's status unwritten, and the exception that
stopped the stage says so (`RunInterrupted`, `armexp.tracking.remote.StoreLost`,
`armexp.disk.DiskFull`). A run left RUNNING is closed by the next command against its store
(`armexp.tracking.stage_runs.close_orphans`).
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from contextlib import contextmanager

import mlflow
from mlflow.tracking import MlflowClient

from armexp import disk
from armexp.tracking import remote
from armexp.tracking.store import is_locked, retry
from armexp.tracking.tags import ERROR_TAG

log = logging.getLogger(__name__)


class RunInterrupted(KeyboardInterrupt):
    """Ctrl-C or SIGTERM inside a stage run: the run ``run_id`` is marked KILLED, or, when
    ``unmarked`` says why not (its store did not answer), left RUNNING."""

    def __init__(self, run_id: str, unmarked: str = "") -> None:
        super().__init__(run_id, unmarked)
        self.run_id, self.unmarked = run_id, unmarked


def clear_error(client: MlflowClient, run_id: str) -> None:
    """Drop ``armexp.error`` from a run that ends FINISHED or is continued: a command that took
    its process for dead (`armexp.tracking.stage_runs.close_orphans`, from another host after a
    long silence) marked it FAILED with that tag and the run went on to finish, or a stopped
    run (a train run resumed, a sweep's run reopened) goes on under its new status."""
    if ERROR_TAG in retry(lambda: client.get_run(run_id)).data.tags:
        retry(lambda: client.delete_tag(run_id, ERROR_TAG))


def end_run(run_id: str, status: str) -> None:
    """`mlflow.end_run`, with the status write retried on a SQLite lock (a reader such as the
    MLflow UI, or another job, holding the store): end_run pops the active run before it writes,
    so a failed write is repeated through the client instead of calling end_run again. A run
    that ends FINISHED keeps no error tag (`clear_error`)."""
    if status == "FINISHED":
        clear_error(MlflowClient(), run_id)
    try:
        mlflow.end_run(status=status)
    except Exception as exc:
        if not is_locked(exc):
            raise
        retry(lambda: MlflowClient().set_terminated(run_id, status))


def note_error(message: str) -> None:
    """The error tag, best effort: when the failure is the store's (a full disk), the status
    write that follows matters more than this one."""
    try:
        retry(lambda: mlflow.set_tag(ERROR_TAG, message))
    except Exception as exc:
        log.warning("could not record the error on the run: %s", exc)


def close(run_id: str, status: str, message: str) -> str:
    """End the active run ``run_id`` with ``status`` and ``message`` as its error; '' when the
    status was written, else why not. Never raises, not even on a second Ctrl-C: it runs while a
    stage stops, and what stopped it must reach the command line."""
    try:
        retry(lambda: mlflow.set_tag(ERROR_TAG, message))
    except BaseException as exc:  # the status below matters more
        log.debug("could not record the error on run %s: %s", run_id, exc)
    try:
        end_run(run_id, status)
    except BaseException as exc:
        return "interrupted again" if isinstance(exc, KeyboardInterrupt) else remote.reason(exc)
    return ""


def interrupted(run_id: str, exc: KeyboardInterrupt) -> RunInterrupted:
    """Mark the run KILLED after Ctrl-C or SIGTERM; the `RunInterrupted` to raise names it (a
    nested stage's names its own run and passes on)."""
    unmarked = close(run_id, "KILLED", "interrupted")
    return exc if isinstance(exc, RunInterrupted) else RunInterrupted(run_id, unmarked)


def lost(uri: str, run_id: str, exc: BaseException) -> remote.StoreLost:
    """Try once more, briefly, to mark the run FAILED after its store stopped answering
    (`armexp.tracking.remote.is_lost`); the `StoreLost` to raise says whether that worked. A nested
    stage's names its own run and passes on."""
    remote.hurry()
    why = remote.reason(exc)
    marked = not close(run_id, "FAILED", f"the tracking store stopped answering: {why}")
    nested = next((e for e in disk.chain(exc) if isinstance(e, remote.StoreLost)), None)
    return nested or remote.StoreLost(uri, why, run_id, marked)


def fail_on_full_disk(uri: str, run_id: str, exc: BaseException) -> disk.DiskFull:
    """Mark the run FAILED after a write found its disk full, with the store's reserve freed
    first (`armexp.disk`) so there is room for it; the `DiskFull` to raise says whether that
    worked. A nested stage's `DiskFull` names its own run and passes on."""
    disk.release_reserve(uri)
    marked = True
    try:
        retry(lambda: mlflow.set_tag(ERROR_TAG, f"{type(exc).__name__}: {exc}"[:5000]))
    except Exception:
        marked = False
    try:
        end_run(run_id, "FAILED")
    except Exception:
        marked = False
    if isinstance(exc, disk.DiskFull):
        return exc
    return disk.DiskFull(disk.reason(exc), run_id, marked)


@contextmanager
def while_stopping(cause: BaseException) -> Iterator[None]:
    """Writes a stage makes as it stops (what it has so far, for a resume or a look): a
    failure is dropped when ``cause`` is an interrupt or a lost store, whose message would
    otherwise be lost, and raised after any other cause. After a lost store they get one short
    attempt each (`armexp.tracking.remote.hurry`)."""
    lost_store = remote.is_lost(cause)
    if lost_store:
        remote.hurry()
    try:
        yield
    except Exception as exc:
        if not (lost_store or isinstance(cause, KeyboardInterrupt)):
            raise
        log.debug("not written while stopping: %s", exc)
