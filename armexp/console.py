"""What a stage shows in the terminal besides its one summary line: a progress bar while it runs,
and none of the warnings third-party code raises that armexp's users cannot act on."""

from __future__ import annotations

import re
import sys
import warnings
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Quiet:
    """One warning silenced: its message's start (literal), category, and the module it is
    attributed to (exactly)."""

    message: str
    category: type[Warning]
    module: str


#: Deprecations inside the libraries, about their own use of their dependencies.
QUIET = (
    # MLflow's SQLAlchemy store configures a loader strategy that SQLAlchemy 2 deprecates.
    Quiet(
        "The ``noload`` loader strategy is deprecated",
        DeprecationWarning,
        "mlflow.store.tracking.sqlalchemy_store",
    ),
    # MLflow's server mounts its Flask app with Starlette's WSGI middleware (`armexp ui`).
    Quiet("starlette.middleware.wsgi is deprecated", UserWarning, "mlflow.server.fastapi_app"),
)


def quiet_warnings() -> None:
    """Silence `QUIET` in this process; every other warning still shows."""
    for q in QUIET:
        warnings.filterwarnings(
            "ignore",
            message=re.escape(q.message),
            category=q.category,
            module=re.escape(q.module) + r"\Z",
        )


def quiet_environment(env: Mapping[str, str]) -> dict[str, str]:
    """``env`` with `QUIET` in ``PYTHONWARNINGS``, for a Python subprocess (the MLflow server);
    the user's own entries come after, so they win."""
    ours = [f"ignore:{q.message}:{q.category.__name__}:{q.module}" for q in QUIET]
    theirs = env.get("PYTHONWARNINGS")
    return {**env, "PYTHONWARNINGS": ",".join([*ours, *([theirs] if theirs else [])])}


def shows_progress(setting: bool | None) -> bool:
    """A stage's ``progress`` setting: true or false as set; null (the default) draws a bar
    when stderr is a terminal, so logs and captured output get the summary lines alone."""
    if setting is None:
        return sys.stderr.isatty()
    return bool(setting)


def progress_bar(setting: bool | None, total: int, desc: str, unit: str, initial: int = 0) -> Any:
    """A tqdm bar on stderr, or None when `shows_progress` says no. It is cleared when closed:
    the stage's summary line takes its place."""
    if not shows_progress(setting):
        return None
    from tqdm import tqdm

    return tqdm(total=total, initial=initial, desc=desc, unit=unit, leave=False, file=sys.stderr,
                dynamic_ncols=True)  # fmt: skip
