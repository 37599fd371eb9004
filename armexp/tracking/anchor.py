"""Artifact locations that follow their SQLite store, so a store is a folder that can be copied
(``cp -a``), moved (``mv``), archived (``tar``) or replaced by a new folder at its old path.

MLflow keeps an experiment's artifact location, and each run's artifact URI below it, as
absolute paths in the database. An experiment whose artifacts armexp keeps in the store's own
``artifacts`` folder is tagged `ANCHOR_TAG` = `STORE`; whenever the store is opened at a path
where that folder is not the one named, its locations are rewritten to name this store's
``artifacts`` (which a copy or a move brought along). A location the user chose
(``tracking.artifact_root``) is tagged `GIVEN` and never rewritten.

Experiments made before the tag existed are classified once, on the first open, from where
their runs' folders are (`classify`), and tagged.

Nothing here knows about stages or runs (`armexp.tracking.stage_runs` does);
`armexp.tracking.store` calls `anchor_artifacts` under the store's lock.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sqlite3
from pathlib import Path
from urllib.parse import urlsplit
from urllib.request import url2pathname

from armexp.config import ConfigError
from armexp.tracking.tags import ANCHOR_TAG

#: Values of `ANCHOR_TAG`: in the store's own ``artifacts`` folder, or where the user chose.
STORE, GIVEN = "store", "given"
#: The folder beside the database that holds a store's artifacts.
ARTIFACTS = "artifacts"


def store_artifacts(db: Path) -> Path:
    """The artifacts folder of the SQLite store ``db``."""
    return db.parent / ARTIFACTS


def local_path(location: str) -> Path | None:
    """The folder a ``file:`` URI or an absolute path names (None: another scheme)."""
    parts = urlsplit(location)
    if parts.scheme == "file":
        return Path(url2pathname(parts.path))
    if not parts.scheme and location.startswith("/"):
        return Path(location)
    return None


def same_folder(a: Path, b: Path) -> bool:
    """``a`` and ``b`` are one folder (equal paths, or two paths to one existing folder)."""
    if a == b:
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def classify(con: sqlite3.Connection, experiment_id: int, location: str, db: Path) -> str:
    """`STORE` or `GIVEN` for an experiment made before `ANCHOR_TAG` existed: armexp then
    created experiments at ``<store folder>/artifacts`` unless ``tracking.artifact_root`` said
    otherwise. A location in this store's folder is the store's; one named ``artifacts`` elsewhere
    is the store's when its runs' folders came along with the database (a copy or a move), and the
    user's when they are there; with no run folder anywhere, it is the store's if it is another
    store's folder or no longer exists (nothing is lost either way)."""
    here = store_artifacts(db)
    path = local_path(location)
    if path is None:
        return GIVEN
    if same_folder(path, here):
        return STORE
    if path.name != ARTIFACTS:
        return GIVEN
    runs = [r for (r,) in con.execute(
        "SELECT run_uuid FROM runs WHERE experiment_id = ?", (experiment_id,))]  # fmt: skip
    if any((here / run).is_dir() for run in runs):
        return STORE
    if any((path / run).is_dir() for run in runs):
        return GIVEN
    return STORE if (path.parent / db.name).exists() or not path.exists() else GIVEN


def check_artifact_root(given: str | None, experiment: str, location: str) -> None:
    """MLflow fixes an experiment's artifact location when it creates it: a different
    ``tracking.artifact_root`` for the existing ``experiment`` would be recorded in its params
    but not used, so it is refused (`ConfigError`)."""
    from mlflow.utils.uri import resolve_uri_if_local

    if not given or resolve_uri_if_local(str(given)).rstrip("/") == location.rstrip("/"):
        return
    raise ConfigError(
        f"tracking.artifact_root={given} is not allowed: experiment '{experiment}' of this store "
        f"already keeps its artifacts in {location}, and an experiment's artifact location "
        "cannot change; drop the override, or give a new tracking.experiment for it."
    )


def anchor_artifacts(db: Path) -> list[str]:
    """Point every `STORE` experiment of the store ``db`` (and its runs and logged models) at
    this store's artifacts folder, after tagging the experiments made before `ANCHOR_TAG` (see
    `classify`). Returns one line per folder the store's locations named before.

    Called under the store's lock; the caller makes sure ``db`` can be written."""
    here = store_artifacts(db)
    notes: dict[Path, int] = {}
    with contextlib.closing(sqlite3.connect(db, timeout=30)) as con, con:
        query = "SELECT experiment_id, value FROM experiment_tags WHERE key = ?"
        tags = dict(con.execute(query, (ANCHOR_TAG,)).fetchall())
        rows = con.execute("SELECT experiment_id, artifact_location FROM experiments").fetchall()
        for experiment_id, location in rows:
            if not location:
                continue
            kind = tags.get(experiment_id)
            if kind is None:
                kind = classify(con, experiment_id, location, db)
                con.execute(
                    "INSERT OR REPLACE INTO experiment_tags (key, value, experiment_id) "
                    "VALUES (?, ?, ?)",
                    (ANCHOR_TAG, kind, experiment_id),
                )
            old = local_path(location)
            if kind != STORE or old is None or same_folder(old, here):
                continue
            copied = _reanchor(con, experiment_id, location, old, here)
            notes[old] = notes.get(old, 0) + copied
    return [
        f"the store {db} was copied or moved from {old.parent}; its artifact paths now point "
        f"into {here}" + (f" ({n} run folder(s) copied from there)" if n else "")
        for old, n in notes.items()
    ]


def _reanchor(con: sqlite3.Connection, experiment_id: int, location: str, old: Path,
              here: Path) -> int:  # fmt: skip
    """Rewrite one experiment's locations from ``location`` (the folder ``old``) to ``here``;
    a run's folder that is only in ``old`` (written there by a copy of the store before its
    locations followed it) is copied over. Returns how many folders were copied."""
    new = here.as_uri()
    prefix = location.rstrip("/") + "/"
    below = "WHERE experiment_id = ? AND substr({0}, 1, ?) = ?"
    copied = 0
    for (run,) in con.execute(
        "SELECT run_uuid FROM runs " + below.format("artifact_uri"),
        (experiment_id, len(prefix), prefix),
    ).fetchall():
        if not (here / run).exists() and (old / run).is_dir():
            shutil.copytree(old / run, here / run, symlinks=True)
            copied += 1
    con.execute(
        "UPDATE experiments SET artifact_location = ? WHERE experiment_id = ?",
        (new, experiment_id),
    )
    for table, column in (("runs", "artifact_uri"), ("logged_models", "artifact_location")):
        with contextlib.suppress(sqlite3.OperationalError):  # a table older stores lack
            con.execute(
                f"UPDATE {table} SET {column} = ? || substr({column}, ?) " + below.format(column),
                (new + "/", len(prefix) + 1, experiment_id, len(prefix), prefix),
            )
    return copied
