"""A store across the network (an `mlflow server`, a database server) held to a deadline.

``tracking.timeout_s`` bounds how long armexp waits for a store that does not answer. MLflow's
own HTTP retry settings (``MLFLOW_HTTP_REQUEST_MAX_RETRIES``, ``…_BACKOFF_FACTOR``,
``…_BACKOFF_JITTER``, ``…_TIMEOUT``) are derived from it (`configure`), so one request to a
server that stopped answering fails within it, after retries spread over it that outlast a
server's restart. A database is asked once, within it (`probe_database`), before MLflow makes
its engine: MLflow retries a refused connection there for about 100 s.

Once a store is found lost in the middle of a run (`is_lost`), or a signal asks armexp to stop
(`hurry`), each request gets one short attempt, so the writes that close a run end within
seconds whether or not they reach the store. The run a lost store stops is named by `StoreLost`;
when it could not be marked, the next command against that store marks it FAILED
(`armexp.tracking.stage_runs.close_orphans`: its process is gone).
"""

from __future__ import annotations

import logging
import os
import sys
import time
from typing import Any
from urllib.parse import urlsplit, urlunsplit

from armexp.config import ConfigError
from armexp.config.schema import TrackingConfig
from armexp.disk import chain

#: What a password shows as wherever a store's address is printed or logged.
HIDDEN = "***"


def hide_password(uri: str) -> str:
    """``uri`` with the password of its user info shown as ``***`` (unchanged without one)."""
    parts = urlsplit(uri)
    if parts.password is None:
        return uri
    host = parts.netloc.rpartition("@")[2]
    return urlunsplit(parts._replace(netloc=f"{parts.username}:{HIDDEN}@{host}"))


#: Retries after a request's first attempt: at least `RETRIES`, at most MLflow's limit. urllib3
#: waits before each retry but the first, 2·f, 4·f, 8·f … s, each at most `WAIT_MAX_S`.
RETRIES, RETRIES_MAX, WAIT_MAX_S = 4, 10, 120
#: Seconds an attempt may wait for an answer once armexp is stopping or has lost its store.
HURRY_S = 5
_ENV = ("MLFLOW_HTTP_REQUEST_MAX_RETRIES", "MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR",
        "MLFLOW_HTTP_REQUEST_BACKOFF_JITTER", "MLFLOW_HTTP_REQUEST_TIMEOUT")  # fmt: skip
#: The deadline `configure` last set (None: not yet), and whether `hurry` has cut it short.
_state: dict[str, Any] = {"timeout_s": None, "hurried": False, "noted": 0.0}
#: The user's own values of MLflow's settings, put back by `reset`.
_saved: dict[str, str | None] = {}


def schedule(timeout_s: float) -> tuple[int, int, int]:
    """MLflow's retries, backoff factor and per-attempt timeout (s) for a deadline: the waits
    between attempts take up to half of it, so a server that restarts is waited for, and the
    attempts share the rest, so a server that takes requests and never answers also fails
    within the deadline. MLflow reads the factor and the timeout as whole seconds."""
    half = timeout_s / 2
    factor = int(min(WAIT_MAX_S // 8, half // _waits(RETRIES, 1)))
    retries = RETRIES
    while factor and retries < RETRIES_MAX and _waits(retries + 1, factor) <= half:
        retries += 1
    attempt = max(1, int((timeout_s - _waits(retries, factor)) // (retries + 1)))
    return retries, factor, attempt


def _waits(retries: int, factor: int) -> int:
    """urllib3's waits between ``retries + 1`` attempts, in all."""
    return sum(min(WAIT_MAX_S, factor * 2**k) for k in range(1, retries))


def configure(timeout_s: float) -> None:
    """Hold MLflow's requests in this process (and the processes it starts) to ``timeout_s``;
    unchanged once `hurry` has cut them short."""
    if not _saved:
        _saved.update({k: os.environ.get(k) for k in _ENV})
    _state["timeout_s"] = float(timeout_s)
    if _state["hurried"]:
        return
    retries, factor, attempt = schedule(timeout_s)
    os.environ.update(zip(_ENV, (str(retries), str(factor), "0", str(attempt)), strict=True))
    _quiet_retries()


def hurry() -> None:
    """One short attempt per request from now on: armexp is stopping (a signal) or its store
    has been silent for the whole deadline, and the writes that close a run must not wait
    longer."""
    _state["hurried"] = True
    attempt = min(HURRY_S, schedule(timeout_s())[2])
    os.environ.update({_ENV[0]: "0", _ENV[3]: str(attempt)})


def reset() -> None:
    """MLflow's settings as they were before `configure`, and no deadline: a command has ended
    (several run in one process under tests and notebooks)."""
    for key, value in _saved.items():
        if value is None:
            os.environ.pop(key, None)
        else:
            os.environ[key] = value
    _saved.clear()
    _state.update(timeout_s=None, hurried=False, noted=0.0)


def timeout_s() -> float:
    """The deadline in force (``tracking.timeout_s``; its default before a config is read)."""
    return float(_state["timeout_s"] or DEFAULT_S)


#: ``tracking.timeout_s``'s default (the schema's).
DEFAULT_S = float(TrackingConfig.timeout_s)


# -------------------------------------------------------------------------------- lost stores
def is_lost(exc: BaseException | None) -> bool:
    """Whether ``exc`` (or one it came from) says the store stopped answering: a server that
    refuses connections or does not answer in time, or a database connection that failed (a
    SQLite store's errors are its file's, never a lost connection)."""
    import requests
    import sqlalchemy.exc

    for e in chain(exc):
        if isinstance(e, StoreLost):
            return True
        if isinstance(e, requests.exceptions.ConnectionError | requests.exceptions.Timeout):
            return True
        if isinstance(e, sqlalchemy.exc.OperationalError | sqlalchemy.exc.InterfaceError):
            orig = getattr(e, "orig", None)
            if not type(orig).__module__.startswith("sqlite3"):
                return True
    return False


def reason(exc: BaseException) -> str:
    """What went wrong with the store, in a few words: refused, no answer in time, or the
    innermost cause's first line."""
    causes = chain(exc)
    for e in causes:
        if isinstance(e, StoreLost):
            return e.reason
    texts = [f"{type(e).__name__}: {e}".lower() for e in causes]
    if any(isinstance(e, ConnectionRefusedError) for e in causes) or any(
        "connection refused" in t for t in texts
    ):
        return "connection refused"
    if any(m in t for t in texts for m in ("timed out", "timeout expired", "timeout:")):
        return "no answer in time"
    last = causes[-1]
    lines = str(getattr(last, "orig", None) or last).strip().splitlines()
    return (lines[0] if lines else type(last).__name__)[:200]


class StoreLost(RuntimeError):
    """A stage run stopped because its store stopped answering: ``run_id`` (None: no run was
    started), the store (``uri``, password hidden), ``reason``, and whether the run could be
    marked FAILED there after all (``marked``)."""

    def __init__(self, uri: str, reason: str, run_id: str | None, marked: bool) -> None:
        super().__init__(f"{uri}: {reason}")
        self.uri, self.reason, self.run_id, self.marked = uri, reason, run_id, marked

    def __reduce__(self) -> tuple[type[StoreLost], tuple[str, str, str | None, bool]]:
        return StoreLost, (self.uri, self.reason, self.run_id, self.marked)


def lost_sentence(exc: BaseException, uri: str | None = None) -> str:
    """What the command line says when a lost store (`is_lost`) stopped a stage."""
    found = next((e for e in chain(exc) if isinstance(e, StoreLost)), None)
    where = found.uri if found else hide_password(uri or "")
    why = reason(exc)
    head = f"the store tracking.uri={where} stopped answering ({why})"
    if where.startswith(("http://", "https://")):  # MLflow retried its requests (`configure`)
        head += f" and did not answer again within tracking.timeout_s={timeout_s():g} s"
    if found is None or found.run_id is None:
        return f"{head}; no run was started; run again when it answers."
    if found.marked:
        return f"{head}; run {found.run_id} is marked FAILED there with what it logged before."
    return (
        f"{head}; run {found.run_id} stays RUNNING there (its real status is unknown to the "
        "store) until the next armexp command against that store marks it FAILED."
    )


# ---------------------------------------------------------------------------------- databases
#: URI schemes MLflow stores in a database server (SQLAlchemy dialects, with or without a
#: driver: ``postgresql+psycopg2``).
DATABASES = ("postgresql", "mysql", "mssql")
#: What to install for a missing driver module.
DRIVERS = {
    "psycopg2": "psycopg2-binary (pip install 'armexp[server]')",
    "psycopg": "psycopg[binary], or write postgresql+psycopg2:// and pip install 'armexp[server]'",
    "MySQLdb": "mysqlclient",
    "pymysql": "PyMySQL",
}


def is_database(uri: str) -> bool:
    return uri.partition(":")[0].partition("+")[0] in DATABASES


def probe_database(uri: str, timeout: float) -> None:
    """Connect to the database of ``uri`` once, within ``timeout`` s, so a database that is
    not there, refuses armexp, or has no driver installed is one sentence (`ConfigError`)
    instead of MLflow's retries and traceback."""
    import sqlalchemy
    import sqlalchemy.exc

    shown = f"tracking.uri={hide_password(uri)}"
    try:
        engine = sqlalchemy.create_engine(uri, connect_args=_connect_timeout(uri, timeout))
    except sqlalchemy.exc.NoSuchModuleError:
        raise ConfigError(
            f"{shown} is not allowed: SQLAlchemy knows no database dialect "
            f"'{uri.partition(':')[0]}'; use postgresql+psycopg2://, mysql+pymysql:// or "
            "mssql+pyodbc://."
        ) from None
    except ImportError as exc:
        module = exc.name or str(exc)
        raise ConfigError(
            f"{shown} is not allowed here: its database driver {module} is not installed; "
            f"install {DRIVERS.get(module, module)} and run again."
        ) from None
    except Exception as exc:  # a malformed URI (a port that is not a number)
        raise ConfigError(
            f"{shown} is not allowed: SQLAlchemy cannot read it as a database URI "
            f"({str(exc).splitlines()[0]})."
        ) from None
    try:
        with engine.connect():
            pass
    except sqlalchemy.exc.DBAPIError as exc:
        why = reason(exc)
        why = f"no answer within {timeout:g} s" if why == "no answer in time" else why
        raise ConfigError(
            f"{shown} is not allowed now: armexp cannot connect to its database ({why}); "
            "start the database, or correct the address or the credentials."
        ) from None
    finally:
        engine.dispose()


def _connect_timeout(uri: str, timeout: float) -> dict[str, int]:
    """The driver's own connect timeout (whole seconds, at least 1)."""
    seconds = max(1, int(timeout))
    if uri.startswith(("postgresql", "mysql")):
        return {"connect_timeout": seconds}
    if uri.startswith("mssql"):
        return {"timeout": seconds}
    return {}


# ---------------------------------------------------------------------------- what is printed
class _RetryNote(logging.Filter):
    """urllib3 logs each retry of a request as a warning; an outage is one line instead, said
    again only for an outage that starts after a deadline's length without retries."""

    def filter(self, record: logging.LogRecord) -> bool:
        if not str(record.msg).startswith("Retrying"):
            return True
        now = time.monotonic()
        if now - _state["noted"] > timeout_s():
            print(
                f"armexp: the tracking server does not answer; trying again for up to "
                f"{timeout_s():g} s (tracking.timeout_s)",
                file=sys.stderr,
            )
        _state["noted"] = now
        return False


_note = _RetryNote()


def _quiet_retries() -> None:
    logger = logging.getLogger("urllib3.connectionpool")
    if _note not in logger.filters:
        logger.addFilter(_note)
