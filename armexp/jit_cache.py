"""Where numba keeps armexp's compiled kernels: a folder named by a digest of their sources.

numba's on-disk cache (``cache=True``) checks only the source file of the function it caches: a
kernel that inlines functions from other files (the environment step inlines the closed loop,
which inlines the controllers) keeps its old machine code after a callee changes. Naming the
cache folder by a digest of every compiled module's source makes any change to any of them a
fresh cache, and the same sources find their cache again (`numba-<digest>` under the package's
``__pycache__``, or under the user's cache folder where the package's is read-only).

`configure` runs on ``import armexp``, before any kernel is compiled; it sets
``NUMBA_CACHE_DIR`` (inherited by sweep workers and vectorised environments) or, when numba is
already imported, numba's config. A user's own ``NUMBA_CACHE_DIR`` is kept as the parent folder.

torch's inductor (``agent.gradients=compiled``, `armexp.agents.compiled`) keeps its generated
code in ``TORCHINDUCTOR_CACHE_DIR``, by default under the system's temporary folder, which a
reboot or a tmp cleaner empties, and then the next run compiles afresh (tens of seconds).
`configure` points it at ``inductor`` beside the numba folder unless the user set it; inductor
keys its entries by torch's version and the traced code itself, so one folder serves all.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import sys
from pathlib import Path

#: The packages whose modules hold compiled (numba) kernels.
COMPILED = ("sim", "envs")
PREFIX = "numba-"
#: inductor's cache folder, beside the numba folders (pruning keeps to ``numba-*``).
INDUCTOR = "inductor"
#: How many other digests' folders a package cache keeps (other checkouts' versions).
KEEP = 2


def digest(root: Path) -> str:
    """SHA-256 (16 hex digits) of the compiled packages' sources under the package ``root``."""
    h = hashlib.sha256()
    for package in COMPILED:
        for path in sorted((root / package).glob("*.py")):
            h.update(path.name.encode())
            h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _writable(folder: Path) -> bool:
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(folder, os.W_OK)


def _prune(parent: Path, current: str) -> None:
    """Remove all but the `KEEP` newest other ``numba-*`` folders beside ``current``."""
    others = [p for p in parent.glob(f"{PREFIX}*") if p.name != current and p.is_dir()]
    others.sort(key=lambda p: p.stat().st_mtime, reverse=True)
    for old in others[KEEP:]:
        shutil.rmtree(old, ignore_errors=True)


def cache_dir(root: Path, user: str | None = None) -> Path:
    """The cache folder for the sources under ``root``; ``user`` is a ``NUMBA_CACHE_DIR`` the
    user set (used as the parent folder)."""
    name = PREFIX + digest(root)
    if user:
        base = Path(user).expanduser()
        return base if base.name == name else base / name
    local = root / "__pycache__"
    if _writable(local):
        _prune(local, name)
        return local / name
    xdg = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(xdg) / "armexp" / name


def configure() -> None:
    """Point numba's cache at `cache_dir` for this process and the processes it starts."""
    root = Path(__file__).resolve().parent
    try:
        folder = cache_dir(root, os.environ.get("NUMBA_CACHE_DIR"))
    except OSError:  # unreadable sources: leave numba's default
        return
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    os.environ.setdefault("TORCHINDUCTOR_CACHE_DIR", str(folder.parent / INDUCTOR))
    numba = sys.modules.get("numba")
    if numba is not None:
        numba.config.CACHE_DIR = str(folder)
