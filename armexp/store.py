"""Opening a tracking store safely: a SQLite store created and migrated under a lock, waited
for while another process writes to it, its artifact locations following its folder when it was
copied or moved (`armexp.anchor`); a tracking server or a database server asked once whether it
answers (`armexp.remote`); passwords
in a tracking URI kept out of everything armexp logs, prints or writes.

Nothing here knows about stages or runs (`armexp.tracking` does).
"""

from __future__ import annotations

import fcntl
import os
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar
from urllib.parse import unquote, urlsplit, urlunsplit

from mlflow.tracking import MlflowClient

from armexp import anchor, disk, new_store, remote
from armexp.config import ConfigError
from armexp.remote import hide_password

#: What a hidden password is shown as; `armexp.tracking.store_uri` restores it from
#: SECRET_URI_ENV.
SECRET_URI_ENV = "ARMEXP_TRACKING_URI"
#: Seconds to wait for a tracking server's first answer (at most ``tracking.timeout_s``).
PROBE_S = 10.0
#: How long to wait for a store that another process holds locked, and how often to try it.
BUSY_WAIT_S, BUSY_POLL_S = 60.0, 1.0
#: Stores this process has opened (a SQLite store created or migrated, a server that answered).
_opened: set[str] = set()
T = TypeVar("T")


def open_once(uri: str, reading: bool = False) -> None:
    """The first use of ``uri`` in this process: open a SQLite store under its lock, or ask a
    server whether it answers; nothing for other stores or later uses. ``reading``: for a
    command that only reads (`armexp.diff`), a SQLite store must exist and may be read-only."""
    if uri in _opened:
        return
    if uri.startswith("sqlite:///"):
        _open_sqlite(uri, reading)
    elif uri.startswith(("http://", "https://")):
        _probe_server(uri, min(PROBE_S, remote.timeout_s()))
    elif remote.is_database(uri):
        remote.probe_database(uri, remote.timeout_s())
        _opened.add(uri)
    elif not uri.startswith("databricks"):
        # MLflow's own answer is a traceback, and for file: (its old ./mlruns store, which
        # MLflow 3 refuses) one that names a folder the user never wrote.
        raise ConfigError(
            f"tracking.uri={hide_password(uri)} is not allowed: armexp's runs go to a SQLite "
            "store (sqlite:///<path>, or tracking.runs_dir), an MLflow server (http:// or "
            "https://) or a database (postgresql://, mysql://, mssql://); MLflow 3 no longer "
            "writes the file store (file: or a bare folder)."
        )


def is_locked(exc: BaseException) -> bool:
    """Whether ``exc`` is SQLite reporting a locked store (MLflow wraps sqlite3/SQLAlchemy
    errors in several types, so the message decides)."""
    return "locked" in str(exc).lower()


def retry(fn: Callable[[], T], attempts: int = 8, delay: float = 0.25) -> T:
    """Call ``fn`` again when SQLite reports a lock (several jobs writing one store)."""
    for i in range(attempts):
        try:
            return fn()
        except Exception as exc:
            if not is_locked(exc) or i == attempts - 1:
                raise
            time.sleep(delay * (2**i))
    raise AssertionError("unreachable")


def keep_credentials_out(uri: str) -> str:
    """The form of a ``tracking.uri`` that may be logged, printed and written to Hydra's folders.

    HTTP(S): the user and password go to MLflow's ``MLFLOW_TRACKING_USERNAME`` /
    ``MLFLOW_TRACKING_PASSWORD`` and the URI loses them. Other schemes (a database URI) need them
    in the URI: the URI is kept in ``ARMEXP_TRACKING_URI`` for this process and its children and
    logged with the password as ``***`` (`store_uri` puts it back)."""
    parts = urlsplit(uri)
    if parts.password is None:
        return uri
    if parts.scheme in ("http", "https"):
        os.environ["MLFLOW_TRACKING_USERNAME"] = unquote(parts.username or "")
        os.environ["MLFLOW_TRACKING_PASSWORD"] = unquote(parts.password)
        return urlunsplit(parts._replace(netloc=parts.netloc.rpartition("@")[2]))
    os.environ[SECRET_URI_ENV] = uri
    return hide_password(uri)


def _probe_server(uri: str, timeout: float) -> None:
    """Ask the server's ``/health`` once per process, so an address with no server behind it
    is one sentence now instead of MLflow's retries."""
    try:
        urllib.request.urlopen(f"{uri.rstrip('/')}/health", timeout=timeout).close()
    except urllib.error.HTTPError:
        pass  # it answered
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise ConfigError(
            f"tracking.uri={hide_password(uri)} is not allowed: no MLflow server answers there "
            f"({reason}); start one (README, Scaling out) or correct the address."
        ) from None
    _opened.add(uri)


def _open_sqlite(uri: str, reading: bool) -> None:
    """Open the SQLite store once with an exclusive lock on ``<db>.lock``: MLflow creates and
    migrates a new store's schema on first open, and processes doing that at the same time
    fail or leave it half-migrated. Under the lock its artifact locations follow the folder it
    is in now (`armexp.anchor`) and its reserve is kept (`armexp.disk`). ``reading``: a command
    that only reads, for which the store must exist and may be read-only."""
    db = Path(uri[len("sqlite:///") :]).resolve()
    if reading and not db.is_file():
        raise ConfigError(
            f"tracking.runs_dir={db.parent} is not allowed here: it holds no MLflow store (no "
            f"{db.name}); give the tracking.runs_dir of a store that holds your runs."
        )
    if reading and not (os.access(db, os.W_OK) and os.access(db.parent, os.W_OK)):
        _open_waiting(db, uri, lambda: None)
        _opened.add(uri)
        return
    try:
        db.parent.mkdir(parents=True, exist_ok=True)
        lock = open(db.with_name(db.name + ".lock"), "a")  # noqa: SIM115 (the with below)
    except OSError as exc:
        raise ConfigError(
            f"tracking.runs_dir={db.parent} is not allowed: armexp cannot write there "
            f"({exc.strerror}); give a folder you can write to."
        ) from None
    with lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not db.exists():
                new_store.make(db)
            _open_waiting(db, uri, lambda: _settle(db))
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    _opened.add(uri)


def _settle(db: Path) -> None:
    """What an opened, writable store gets: locations that follow it, and its reserve."""
    for note in anchor.anchor_artifacts(db):
        print(f"armexp: {note}", file=sys.stderr)
    disk.keep_reserve(db)


def _open_waiting(db: Path, uri: str, then: Callable[[], None]) -> None:
    """Open the store (MLflow creates or migrates its schema) and run ``then``, waiting up to
    `BUSY_WAIT_S` while another process holds the database locked; a store that cannot be
    opened, or stays locked, is one sentence (`ConfigError`)."""
    deadline = time.monotonic() + BUSY_WAIT_S
    told = False
    while True:
        try:
            MlflowClient(uri).search_experiments(max_results=1)
            then()
            return
        except Exception as exc:
            if not is_locked(exc):
                if isinstance(exc, OSError):
                    raise
                reason = str(exc).splitlines()[0][:200]
                raise ConfigError(
                    f"tracking.runs_dir={db.parent} is not allowed: its MLflow store {db.name} "
                    f"cannot be opened ({type(exc).__name__}: {reason}); move it aside to start "
                    "a new store, or restore it from a backup."
                ) from None
            if time.monotonic() >= deadline:
                raise ConfigError(
                    f"tracking.runs_dir={db.parent} is not allowed now: its MLflow store "
                    f"{db.name} is busy, locked by another process writing to it for over "
                    f"{BUSY_WAIT_S:.0f} s (it is not damaged); run again when that process is "
                    "done, or stop it."
                ) from None
        if not told:
            print(
                f"armexp: the store {db} is busy (another process is writing to it); waiting "
                f"up to {BUSY_WAIT_S:.0f} s",
                file=sys.stderr,
            )
            told = True
        time.sleep(BUSY_POLL_S)
