"""Config keys that name a local folder: a leading ``~`` on the command line is a home folder,
as a shell would have made it, and a path the file system cannot hold is refused before any
folder is made."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from armexp.config.checks import ConfigError

#: The keys whose values are local folders (``tracking.artifact_root`` when it is not a URI).
PATH_KEYS = ("tracking.runs_dir", "tracking.artifact_root", "report.out_dir")
#: Used where the file system does not say (``pathconf``): Linux's NAME_MAX and PATH_MAX.
NAME_MAX, PATH_MAX = 255, 4096


def _quoted(text: str) -> str:
    """``text`` as a quoted value of Hydra's override grammar (which has no unquoted ``~``)."""
    if "'" not in text:
        return f"'{text}'"
    if '"' not in text:
        return f'"{text}"'
    return text


def expand_home(override: str) -> str:
    """``tracking.runs_dir=~/x`` (quoted or not) as ``tracking.runs_dir='/home/me/x'``: the
    shell leaves a ``~`` after ``=`` (or inside quotes) as it is. Other overrides are returned
    unchanged, and so is a ``~user`` with no such user (validation names it)."""
    key, eq, value = override.partition("=")
    if not eq or key.lstrip("+") not in PATH_KEYS:
        return override
    quoted = len(value) >= 2 and value[0] == value[-1] and value[0] in "'\""
    raw = value[1:-1] if quoted else value
    if not raw.startswith("~"):
        return override
    return f"{key}={_quoted(os.path.expanduser(raw))}"


def _limit(path: Path, name: str, default: int) -> int:
    """The file system's limit ``name`` (``PC_NAME_MAX``…) where ``path`` would be made."""
    probe = path
    while not os.path.exists(probe) and probe != probe.parent:
        probe = probe.parent
    try:
        return int(os.pathconf(probe, name))
    except (OSError, ValueError):
        return default


def path_problem(value: str) -> str | None:
    """Why the folder ``value`` cannot be used (an unexpanded ``~``, a name or a path longer than
    the file system holds, or none at all), as the end of a one-sentence error; None when it
    can."""
    if not value.strip():
        return "it names no folder (Hydra's folders would go to /hydra); give a folder"
    if value.startswith("~"):
        user = value[1:].split("/", 1)[0]
        if user and os.path.expanduser(f"~{user}") == f"~{user}":
            return (
                f"there is no user {user} on this machine to expand ~{user} for; write the "
                "folder's full path"
            )
        return (
            "a leading ~ is expanded on the command line only; in a config file write the full "
            "path (or ${oc.env:HOME}/...)"
        )
    path = Path(value).absolute()
    name_max = _limit(path, "PC_NAME_MAX", NAME_MAX)
    for part in path.parts:
        size = len(os.fsencode(part))
        if size > name_max:
            return (
                f"its name {part[:24]}... is {size} bytes long, and this file system allows "
                f"{name_max} bytes for a name; give a shorter path"
            )
    path_max = _limit(path, "PC_PATH_MAX", PATH_MAX)
    size = len(os.fsencode(str(path)))
    if size >= path_max:
        return (
            f"it is {size} bytes long, and this file system allows {path_max} bytes for a "
            "path; give a shorter path"
        )
    return None


def check_paths(cfg: Any) -> None:
    """Every `PATH_KEYS` value that is set and local can be a folder (`path_problem`); an empty
    ``report.out_dir`` or ``tracking.artifact_root`` is unset (the default folder), an empty
    ``tracking.runs_dir`` is refused."""
    from omegaconf import OmegaConf

    for key in PATH_KEYS:
        value = OmegaConf.select(cfg, key, default=None)
        if value is None or urlsplit(str(value)).scheme not in ("", "file"):
            continue
        if value == "" and key != "tracking.runs_dir":
            continue
        text = str(value)
        if text.startswith("file:"):
            text = urlsplit(text).path
        problem = path_problem(text)
        if problem:
            raise ConfigError(f"{key}={value or repr(value)} is not allowed: {problem}.")
