"""A full disk ends a stage with one sentence and a FAILED run, never a cut-off file.

Artifacts are written under a temporary name and renamed when complete (MLflow's local
artifact store does so for each file armexp logs; `armexp.tracking.artifacts.log_folder` logs
folders file by file), so a write that fails leaves the previous file or none. A SQLite store
keeps `RESERVE_BYTES` of room beside its database (`keep_reserve`); when a run fails on a full
disk, that room is given back first (`release_reserve`) so the error and the FAILED status can
still be written (`armexp.tracking.stage_runs.stage_run` raises `DiskFull` once it has), and the
command line prints one sentence (`sentence`). A disk with less than `MIN_FREE_BYTES` left is
refused before a stage starts (`armexp.cli`).
"""

from __future__ import annotations

import contextlib
import errno
import os
from pathlib import Path

#: Room kept beside a SQLite store for the last writes of a run stopped by a full disk
#: (an error tag and a status take a few pages of the database and of its journal).
RESERVE_BYTES = 256 * 1024
#: The least room a stage starts with: Hydra writes its job folder (about 16 KB) before armexp
#: can catch a failed write.
MIN_FREE_BYTES = 32 * 1024
#: Errors that say a write found no room (EFBIG: over the file size limit, ``ulimit -f``).
FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})
#: The same, as SQLite (through SQLAlchemy and MLflow) words it.
FULL_MESSAGES = ("database or disk is full", "no space left on device", "disk quota exceeded")


class DiskFull(RuntimeError):
    """A stage run stopped by a full disk: ``run_id``, whether it could be marked FAILED
    (``marked``), and ``detail``, what failed to be written."""

    def __init__(self, detail: str, run_id: str, marked: bool) -> None:
        super().__init__(detail)
        self.detail, self.run_id, self.marked = detail, run_id, marked

    def __reduce__(self) -> tuple[type[DiskFull], tuple[str, str, bool]]:
        return DiskFull, (self.detail, self.run_id, self.marked)


def chain(exc: BaseException | None) -> list[BaseException]:
    """``exc`` and the exceptions it was raised from or while handling, each once."""
    seen: list[BaseException] = []
    while exc is not None and exc not in seen:
        seen.append(exc)
        exc = exc.__cause__ or exc.__context__
    return seen


def is_full(exc: BaseException | None) -> bool:
    """Whether ``exc`` (or one it came from) is a write that found no room on its disk."""
    for e in chain(exc):
        if isinstance(e, DiskFull):
            return True
        if isinstance(e, OSError) and e.errno in FULL_ERRNOS:
            return True
        if any(m in str(e).lower() for m in FULL_MESSAGES):
            return True
    return False


#: What each of `FULL_ERRNOS` means for the user.
_MEANING = {
    errno.ENOSPC: "the disk is full",
    errno.EDQUOT: "the disk quota is used up",
    errno.EFBIG: "a file went over this process's file size limit (ulimit -f)",
}


def reason(exc: BaseException) -> str:
    """What stopped the write, as the start of a sentence: the OS's error (and its file), else
    SQLite's, e.g. ``the disk is full (No space left on device: /runs/…/model.zip)``."""
    for e in chain(exc):
        if isinstance(e, DiskFull):
            return e.detail
        if isinstance(e, OSError) and e.errno in FULL_ERRNOS:
            where = f": {e.filename}" if e.filename else ""
            return f"{_MEANING[e.errno]} ({e.strerror}{where})"
    return "the disk is full (the MLflow store: database or disk is full)"


def sentence(exc: BaseException) -> str:
    """What the command line says when ``exc`` (`is_full`) stopped a stage: which run it
    stopped and whether that run is marked FAILED, or that none was started."""
    found = next((e for e in chain(exc) if isinstance(e, DiskFull)), None)
    if found is None:
        return f"{reason(exc)} and no run was started; free space and run again."
    if found.marked:
        what = (
            f"run {found.run_id} is marked FAILED with what it logged before, and no file was "
            "left half-written"
        )
    else:
        what = (
            f"run {found.run_id} could not be marked FAILED (its store is on the full disk), so "
            "the next armexp command will"
        )
    return f"{found.detail}; {what}; free space and run again."


def free_bytes(folder: Path) -> int:
    """The room left to this user on the file system of ``folder``."""
    st = os.statvfs(folder)
    return st.f_bavail * st.f_frsize


def reserve_path(db: Path) -> Path:
    return db.with_name(db.name + ".reserve")


def keep_reserve(db: Path) -> None:
    """Make the room kept beside the SQLite store ``db`` when it is missing; a disk without
    that room is left as it is (the run's own writes will say so)."""
    path = reserve_path(db)
    if path.exists():
        return
    partial = path.with_name(f".{path.name}.{os.getpid()}")
    try:
        with open(partial, "wb") as f:
            f.write(bytes(RESERVE_BYTES))
        partial.replace(path)
    except OSError:
        with contextlib.suppress(OSError):
            partial.unlink()


def release_reserve(uri: str) -> bool:
    """Free the room kept beside the SQLite store of ``uri``; whether any was freed."""
    if not uri.startswith("sqlite:///"):
        return False
    try:
        reserve_path(Path(uri[len("sqlite:///") :])).unlink()
    except OSError:
        return False
    return True
