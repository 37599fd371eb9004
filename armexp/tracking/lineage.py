"""What exactly ran: the code (git commit and whether the checkout had uncommitted changes) and
the installed versions of the packages a result depends on, as tags of every stage run."""

from __future__ import annotations

import functools
import subprocess
from importlib import metadata
from pathlib import Path

from armexp.tracking.tags import COMMIT_TAG, DIRTY_TAG, VERSION_TAG

PACKAGES = ("armexp", "torch", "stable-baselines3", "gymnasium", "mlflow", "hydra-core",
            "numba", "numpy")  # fmt: skip


def _git(*args: str) -> str | None:
    """``git <args>`` in the working directory's checkout, else in armexp's own."""
    for where in (Path.cwd(), Path(__file__).resolve().parent):
        try:
            res = subprocess.run(
                ["git", *args], cwd=where, capture_output=True, text=True, timeout=5
            )
        except (OSError, subprocess.SubprocessError):
            return None
        if res.returncode == 0:
            return res.stdout
    return None


def git_commit() -> str | None:
    out = _git("rev-parse", "HEAD")
    return out.strip() if out else None


def git_dirty() -> bool | None:
    """Whether tracked files differ from the commit (untracked files, such as a runs folder,
    do not count); None outside a checkout."""
    out = _git("status", "--porcelain", "--untracked-files=no")
    return None if out is None else bool(out.strip())


@functools.cache
def package_versions() -> dict[str, str]:
    """Installed versions of `PACKAGES` (those not installed are left out); fixed for the
    process's life, so looked up once."""
    found = {}
    for name in PACKAGES:
        try:
            found[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            continue
    return found


def lineage_tags() -> dict[str, str]:
    """The tags that say what ran: commit (also as MLflow's own source tag), dirty flag,
    package versions."""
    tags = {f"{VERSION_TAG}{k}": v for k, v in package_versions().items()}
    commit = git_commit()
    if commit:
        tags[COMMIT_TAG] = commit
        tags["mlflow.source.git.commit"] = commit
        tags[DIRTY_TAG] = str(git_dirty()).lower()
    return tags
