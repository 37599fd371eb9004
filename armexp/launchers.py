"""Cluster launchers: what a sweep on Ray or SLURM needs, checked before it starts.

The Ray launcher itself is `hydra_plugins.armexp_launcher.ray_launcher.RayLauncher` (Hydra
loads launchers only from the ``hydra_plugins`` namespace).
"""

from __future__ import annotations

import importlib.util
import logging
import os
import socket
from collections.abc import Sequence
from pathlib import Path

from armexp.config import ConfigError

log = logging.getLogger(__name__)

#: Seconds to wait for a Ray head's GCS port before saying none answers.
RAY_PROBE_S = 5.0
#: Where a local `ray start --head` records its address (Ray 2.x).
RAY_CURRENT_CLUSTER = Path("/tmp/ray/ray_current_cluster")
#: The extra each launcher needs: launcher option -> (plugin module, what to install).
PLUGINS: dict[str, tuple[str, str]] = {
    "ray": ("hydra_plugins.hydra_ray_launcher", 'pip install "armexp[cluster]"'),
    "slurm": ("hydra_plugins.hydra_submitit_launcher", 'pip install "armexp[cluster]"'),
    "submitit_local": ("hydra_plugins.hydra_submitit_launcher", 'pip install "armexp[cluster]"'),
    "submitit_slurm": ("hydra_plugins.hydra_submitit_launcher", 'pip install "armexp[cluster]"'),
}


def chosen_launcher(overrides: Sequence[str]) -> str | None:
    """The ``hydra/launcher=<name>`` of a command line, if any."""
    return _override(overrides, "hydra/launcher")


def _override(overrides: Sequence[str], key: str) -> str | None:
    """The value ``key`` is given on a command line (``+``/``~`` prefixes aside), if any."""
    for override in overrides:
        k, eq, value = override.partition("=")
        if eq and k.lstrip("+~") == key:
            return value
    return None


def check_launcher(overrides: Sequence[str]) -> None:
    """One sentence (`ConfigError`) when the chosen launcher's plugin is not installed or, for
    Ray, no cluster answers at ``hydra.launcher.ray.init.address``, within `RAY_PROBE_S`."""
    name = chosen_launcher(overrides)
    if name not in PLUGINS:
        return
    module, install = PLUGINS[name]
    needed = [module, "ray"] if name == "ray" else [module]
    missing = [m for m in needed if not _importable(m)]
    if missing:
        raise ConfigError(
            f"hydra/launcher={name} is not allowed here: {' and '.join(missing)} "
            f"{'is' if len(missing) == 1 else 'are'} not installed; {install}."
        )
    if name == "ray":
        address = _override(overrides, "hydra.launcher.ray.init.address") or "auto"
        _probe_ray(address)


def _importable(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:
        return False


def ray_address(address: str) -> str | None:
    """``host:port`` of the Ray head that ``address`` names (``auto``: ``RAY_ADDRESS`` or the
    cluster `ray start --head` started on this machine); None when there is none to try."""
    if address in ("auto", ""):
        address = os.environ.get("RAY_ADDRESS", "")
        if not address and RAY_CURRENT_CLUSTER.exists():
            address = RAY_CURRENT_CLUSTER.read_text().strip()
    if not address or address == "local":
        return None
    return address.removeprefix("ray://").partition("/")[0]


def _probe_ray(address: str) -> None:
    """Ray's own connect retries for about a minute per attempt; a TCP connect to the head's
    port tells within seconds whether anything listens."""
    if address in ("local", "null", "None"):
        return  # Ray started inside this process on this machine: nothing to reach
    where = ray_address(address)
    start = "start one with `ray start --head` (README, Scaling out) or correct the address"
    if where is None:
        raise ConfigError(
            f"hydra.launcher.ray.init.address={address} is not allowed here: no Ray cluster is "
            f"running on this machine and RAY_ADDRESS is not set; {start}."
        )
    host, _, port = where.rpartition(":")
    try:
        socket.create_connection((host, int(port)), timeout=RAY_PROBE_S).close()
    except (OSError, ValueError) as exc:
        raise ConfigError(
            f"hydra.launcher.ray.init.address={address} is not allowed here: no Ray cluster "
            f"answers at {where} ({exc}); {start}."
        ) from None
