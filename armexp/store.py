"""Opening a tracking store safely: a SQLite store created and migrated under a lock, and
followed when its folder was moved; a tracking server asked once whether it answers; passwords
in a tracking URI kept out of everything armexp logs, prints or writes.

Nothing here knows about stages or runs (`armexp.tracking` does).
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import sys
import urllib.error
import urllib.request
from pathlib import Path
from urllib.parse import unquote, urlsplit, urlunsplit

from mlflow.tracking import MlflowClient

from armexp.config import ConfigError

#: What a hidden password is shown as; `armexp.tracking.store_uri` restores it from
#: SECRET_URI_ENV.
HIDDEN = "***"
SECRET_URI_ENV = "ARMEXP_TRACKING_URI"
#: Seconds to wait for a tracking server's first answer.
PROBE_S = 10.0
#: Stores this process has opened (a SQLite store created or migrated, a server that answered).
_opened: set[str] = set()


def open_once(uri: str) -> None:
    """The first use of ``uri`` in this process: open a SQLite store under its lock, or ask a
    server whether it answers; nothing for other stores or later uses."""
    if uri in _opened:
        return
    if uri.startswith("sqlite:///"):
        _open_sqlite(uri)
    elif uri.startswith(("http://", "https://")):
        _probe_server(uri)


def hide_password(uri: str) -> str:
    """``uri`` with the password of its user info shown as ``***`` (unchanged without one)."""
    parts = urlsplit(uri)
    if parts.password is None:
        return uri
    host = parts.netloc.rpartition("@")[2]
    return urlunsplit(parts._replace(netloc=f"{parts.username}:{HIDDEN}@{host}"))


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


def _follow_move(db: Path) -> None:
    """A store whose folder was moved (``mv proj proj2``) still names its artifacts by the old
    absolute path; when that path's store is gone, its artifact locations are moved to the
    ``artifacts`` folder beside ``db``, where they now are."""
    import sqlite3

    here = f"file://{db.parent / 'artifacts'}"
    with contextlib.closing(sqlite3.connect(db)) as con:
        locations = [r[0] for r in con.execute("SELECT artifact_location FROM experiments")]
        for location in locations:
            if not location.startswith("file://") or location.rstrip("/") == here:
                continue
            old = Path(location[len("file://") :].rstrip("/"))
            if old.name != "artifacts" or (old.parent / db.name).exists():
                continue  # a location of the user's choosing, or its store is still there
            prefix = f"file://{old}"
            with con:
                con.execute(
                    "UPDATE experiments SET artifact_location = ? || substr(artifact_location, ?)"
                    " WHERE artifact_location LIKE ? || '%'",
                    (here, len(prefix) + 1, prefix),
                )
                con.execute(
                    "UPDATE runs SET artifact_uri = ? || substr(artifact_uri, ?)"
                    " WHERE artifact_uri LIKE ? || '%'",
                    (here, len(prefix) + 1, prefix),
                )
            print(
                f"armexp: the store {db} was moved from {old.parent}; its artifact paths now "
                f"point into {db.parent / 'artifacts'}",
                file=sys.stderr,
            )


def _probe_server(uri: str) -> None:
    """Ask the server's ``/health`` once per process, so an address with no server behind it
    is one sentence now instead of MLflow's minutes of retries."""
    try:
        urllib.request.urlopen(f"{uri.rstrip('/')}/health", timeout=PROBE_S).close()
    except urllib.error.HTTPError:
        pass  # it answered
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise ConfigError(
            f"tracking.uri={hide_password(uri)} is not allowed: no MLflow server answers there "
            f"({reason}); start one (README, Scaling out) or correct the address."
        ) from None
    _opened.add(uri)


def _open_sqlite(uri: str) -> None:
    """Open the SQLite store once with an exclusive lock on ``<db>.lock``: MLflow creates and
    migrates a new store's schema on first open, and processes doing that at the same time
    fail or leave it half-migrated."""
    db = Path(uri[len("sqlite:///") :])
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
            MlflowClient(uri).search_experiments(max_results=1)
            _follow_move(db)
        except Exception as exc:
            reason = str(exc).splitlines()[0][:200]
            raise ConfigError(
                f"tracking.runs_dir={db.parent} is not allowed: its MLflow store {db.name} cannot "
                f"be opened ({type(exc).__name__}: {reason}); move it aside to start a new "
                "store, or restore it from a backup."
            ) from None
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    _opened.add(uri)
