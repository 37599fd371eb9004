"""Cluster launchers: what a sweep on Ray or SLURM needs, checked before it starts.

The Ray launcher itself is `hydra_plugins.armexp_launcher.ray_launcher.RayLauncher` (Hydra
loads launchers only from the ``hydra_plugins`` namespace); `register_plugins` makes sure Hydra
knows it.
"""

from __future__ import annotations

import importlib.util
import logging
import os
import socket
from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

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


def register_plugins() -> None:
    """Register armexp's Ray launcher and Optuna sweeper with Hydra by their classes, before
    Hydra instantiates a launcher or sweeper.

    Hydra finds plugins by listing the folders of the ``hydra_plugins`` namespace package
    (``pkgutil.walk_packages``). In an editable install (``pip install -e``, the README's)
    setuptools puts the checkout on ``sys.path`` only for a plain layout, which
    ``armexp.conf`` in ``conf/`` is not; it serves the packages through an import hook
    (PEP 660) instead, so ``hydra_plugins.armexp_launcher`` is importable but in no folder the
    scan lists, and ``hydra/launcher=ray`` would stop with "Unknown plugin class" (hydra
    #2359). A regular install's scan finds the same class; registering it again changes
    nothing."""
    from hydra.core.plugins import Plugins

    # The scan first: it re-runs the plugin modules it finds, and the class registered must be
    # the one the scan left (one entry per launcher in Hydra's list).
    plugins = Plugins.instance()
    from hydra_plugins.armexp_launcher.ray_launcher import RayLauncher
    from hydra_plugins.armexp_sweeper.optuna_sweeper import OptunaSweeper

    plugins.register(RayLauncher)
    plugins.register(OptunaSweeper)


def _hydra_overrides(overrides: Sequence[str]) -> list[str]:
    return [o for o in overrides if o.lstrip("+~").partition("=")[0].split(".")[0]
            .split("/")[0] == "hydra"]  # fmt: skip


def check_settings(overrides: Sequence[str], search_path: Sequence[str] = ()) -> None:
    """One sentence (`ConfigError`) for a launcher option that does not exist, a launcher
    setting the chosen launcher does not have, or a setting's value it cannot use; Hydra would
    find the first two only once the sweep had started, the last only when launching."""
    from armexp.config import compose_unchecked

    ours = _hydra_overrides(overrides)
    if not ours:
        return
    settings = [o for o in ours if o.lstrip("+~").startswith(f"{LAUNCHER}.")]
    cfg = compose_unchecked([*search_path, *[o for o in ours if o not in settings]], hydra=True)
    name = str(cfg.hydra.runtime.choices.get("hydra/launcher"))
    for override in settings:
        key, _, value = override.lstrip("+~").partition("=")
        setting = key[len(LAUNCHER) + 1 :]
        if OmegaConf.select(cfg.hydra.launcher, setting, default=_ABSENT) is _ABSENT:
            raise ConfigError(
                f"{key}={value} is not allowed: the launcher hydra/launcher={name} has no "
                f"setting {setting}{_who_has(setting, search_path)}."
            )
    launcher = compose_unchecked([*search_path, *ours], hydra=True).hydra.launcher
    _check_values(launcher)


_ABSENT = object()
LAUNCHER = "hydra.launcher"
#: Settings of Hydra's submitit launchers (SLURM, local) that count something: 1 or more.
COUNTS = ("timeout_min", "cpus_per_task", "tasks_per_node", "nodes", "mem_gb",
          "array_parallelism")  # fmt: skip


def _check_values(launcher: DictConfig) -> None:
    target = str(launcher.get("_target_", ""))
    if target.endswith("JoblibLauncher"):
        n_jobs = launcher.get("n_jobs")
        if n_jobs is not None and int(n_jobs) == 0:
            raise ConfigError(
                f"{LAUNCHER}.n_jobs=0 is not allowed: give how many jobs run at once (1 or "
                "more), or -1 for one per core (-2 for all cores but one, and so on)."
            )
    if ".submitit_launcher." in target:
        for key in COUNTS:
            value = launcher.get(key)
            if value is not None and not value >= 1:
                raise ConfigError(f"{LAUNCHER}.{key}={value} is not allowed: it must be ≥ 1.")


#: Hydra's own launchers (its plugins'), beside those of ``conf/hydra/launcher``.
HYDRA_LAUNCHERS = ("basic", "joblib", "submitit_local", "submitit_slurm")


def _who_has(setting: str, search_path: Sequence[str]) -> str:
    """``; hydra/launcher=X and … have it`` (or that none does), from composing each launcher:
    this runs only to explain a refusal."""
    from armexp.config import compose_unchecked, group_options

    having = []
    for option in dict.fromkeys([*HYDRA_LAUNCHERS, *group_options("hydra/launcher")]):
        try:
            cfg = compose_unchecked([*search_path, f"hydra/launcher={option}"], hydra=True)
        except ConfigError:
            continue  # its plugin is not installed
        if OmegaConf.select(cfg.hydra.launcher, setting, default=_ABSENT) is not _ABSENT:
            having.append(f"hydra/launcher={option}")
    if not having:
        return "; no launcher has it"
    if len(having) == 1:
        return f"; {having[0]} has it"
    return f"; {', '.join(having[:-1])} and {having[-1]} have it"


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
