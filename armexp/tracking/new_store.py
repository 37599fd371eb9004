"""A new SQLite store made by copying an empty one, instead of MLflow migrating a new database.

MLflow creates a SQLite store by running every schema migration it has, one after the other:
about 2 s on a fast core, ten times more on a slow one, paid by every new ``runs/`` folder (and
by every test that writes a store of its own). The result is the same database each time for
one MLflow version, so the first store made with a version is kept as an empty template in the
user's cache (``$XDG_CACHE_HOME/armexp`` or ``~/.cache/armexp``, ``ARMEXP_CACHE_DIR`` to
choose), and later stores start as a copy of it (a few milliseconds).

A copy differs from a store MLflow makes in one place: the ``Default`` experiment's artifact
location, which MLflow sets to ``./mlruns/0`` under the working folder of the process that made
the store; `make` writes the one this process would have got (armexp does not use that
experiment). Where the cache cannot be written, MLflow creates each new store, beside it first.
"""

from __future__ import annotations

import contextlib
import fcntl
import os
import shutil
import sqlite3
import tempfile
import time
from pathlib import Path

import mlflow
from mlflow.tracking import MlflowClient

#: Where the templates are kept when ``ARMEXP_CACHE_DIR`` is not set.
CACHE_ENV = "ARMEXP_CACHE_DIR"


def cache_dir() -> Path:
    """The folder holding the templates."""
    given = os.environ.get(CACHE_ENV)
    if given:
        return Path(given)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "armexp"


def template_path() -> Path:
    """The empty store of the installed MLflow version."""
    return cache_dir() / f"mlflow-{mlflow.__version__}-empty.db"


def make(db: Path) -> bool:
    """Create the SQLite store ``db`` (which does not exist) whole: a copy of the template (made
    first if this MLflow version has none) or, where the cache cannot be used, a store MLflow
    creates beside ``db``. Either appears at ``db`` by one rename, so a reader that opens it
    never finds it half-migrated (and, by migrating it too, breaks it). False when neither
    could be made: then nothing was written at ``db`` and MLflow creates the store itself."""
    partial = db.with_name(db.name + ".new")
    try:
        with contextlib.suppress(FileNotFoundError):
            partial.unlink()  # left by a process that died making it
        try:
            template = _template()
        except Exception:  # an unwritable cache
            MlflowClient(f"sqlite:///{partial}").search_experiments(max_results=1)
        else:
            shutil.copyfile(template, partial)
            _as_made_here(partial)
        partial.replace(db)
    except Exception:  # MLflow then creates the store itself and says what is wrong
        with contextlib.suppress(OSError):
            partial.unlink()
        return False
    return True


def _template() -> Path:
    """The template, made under a lock by the first process that needs it."""
    path = template_path()
    if path.is_file():
        return path
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path.with_name(path.name + ".lock"), "a") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            if not path.is_file():
                with tempfile.TemporaryDirectory(dir=path.parent) as work:
                    fresh = Path(work) / "mlflow.db"
                    MlflowClient(f"sqlite:///{fresh}").search_experiments(max_results=1)
                    fresh.replace(path)
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)
    return path


def _as_made_here(db: Path) -> None:
    """The ``Default`` experiment as MLflow would have made it in this process: its artifact
    location under this working folder, its times now."""
    location = (Path.cwd() / "mlruns" / "0").as_posix()
    now = int(time.time() * 1000)
    with contextlib.closing(sqlite3.connect(db)) as con, con:
        con.execute(
            "UPDATE experiments SET artifact_location = ?, creation_time = ?, "
            "last_update_time = ? WHERE experiment_id = 0",
            (location, now, now),
        )
