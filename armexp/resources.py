"""What a run would allocate, estimated from its config, against the memory this machine has.

A few config values size a stage's largest allocations, and a value typed with one zero too many
passes every range check, then ends the run on memory (an OOM kill, or a traceback after the run
started). `check` refuses it first, in one sentence: the key, the value, the estimate, the memory
available and the largest value that fits. What is counted (the rest of a run, the interpreter
and torch, is a few hundred MB on top):

* ``simulate``: the trajectory, one row of `armexp.sim.trajectory.log_width` float64 columns per
  controller period over ``scenario.duration``, held about three times (the chunks, the joined
  array, the table written to Parquet);
* ``train`` and ``pipeline``: SB3's replay buffer, ``agent.buffer_size`` transitions of float32
  (observation and next observation of `armexp.envs.observation.ObservationLayout`, the action,
  reward, done and time-out flags), allocated whole when training starts (PPO: its rollout
  buffer, ``agent.ppo.n_steps`` × ``agent.n_envs`` such rows, about as large); and the
  ``agent.n_envs`` environments: `ENV_BYTES` each in one process, `PROCESS_BYTES` each as
  processes (``agent.vec_env=subproc``; both measured on the paper arm among five obstacles).
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from armexp.config import ConfigError

#: Copies of a simulate trajectory held at once.
TRAJECTORY_COPIES = 3
#: Memory of one environment stepped in the training process (measured: 14.6 KB).
ENV_BYTES = 16_000
#: Memory of one environment in its own process (measured: 210 MB private, 265 MB shared in).
PROCESS_BYTES = 250_000_000
#: Bytes of a float32 and a float64.
F32, F64 = 4, 8


@dataclass(frozen=True)
class Item:
    """One allocation: the config key that sizes it, its value, its bytes, the bytes per unit of
    the value (for the largest value that fits) and what it is, in words."""

    key: str
    value: Any
    bytes: int
    per_unit: float
    what: str


def estimate(cfg: DictConfig, stage: str) -> list[Item]:
    """The large allocations of ``stage`` run on ``cfg``."""
    items = []
    if stage == "simulate":
        items.append(_trajectory(cfg))
    if stage in ("train", "pipeline"):
        items += _training(cfg)
    return items


def _trajectory(cfg: DictConfig) -> Item:
    from armexp.sim.trajectory import log_width

    dt = float(cfg.controller.dt)
    row = TRAJECTORY_COPIES * log_width(len(cfg.robot.lengths)) * F64
    duration = float(cfg.scenario.duration)
    steps = math.ceil(duration / dt)
    rate = f"{1 / dt / 1000:g} kHz"
    return Item("scenario.duration", duration, steps * row, row / dt, f"its {rate} trajectory")


def _training(cfg: DictConfig) -> list[Item]:
    from armexp.envs.observation import ObservationLayout

    agent = cfg.agent
    n = len(cfg.robot.lengths)
    obs = ObservationLayout(n, len(cfg.obstacles.circles)).size
    transition = (2 * obs + n + 3) * F32
    n_envs, size = int(agent.n_envs), int(agent.buffer_size)
    rows = max(size // n_envs, 1) * n_envs
    buffer = Item("agent.buffer_size", size, rows * transition, transition, "its replay buffer")
    if agent.get("algo") == "ppo":  # no replay buffer: one rollout of n_steps per environment
        steps = int(agent.ppo.n_steps)
        each_row = n_envs * transition
        buffer = Item("agent.ppo.n_steps", steps, steps * each_row, each_row, "its rollout buffer")
    apart = str(agent.vec_env) == "subproc"
    each = PROCESS_BYTES if apart else ENV_BYTES
    what = f"{n_envs} environment{' processes' if apart else 's'}"
    return [buffer, Item("agent.n_envs", n_envs, n_envs * each, each, what)]


# --------------------------------------------------------------------------------- the machine
def available_bytes() -> int | None:
    """Memory a new allocation can have now: psutil's ``available`` when installed, else the
    kernel's ``MemAvailable``, else the free pages; no more than a cgroup limit leaves (a
    container's). None when none of these can be read."""
    try:
        import psutil

        found: int | None = int(psutil.virtual_memory().available)
    except ImportError:
        found = _meminfo("MemAvailable") or _sysconf_free()
    room = _cgroup_room()
    known = [v for v in (found, room) if v is not None]
    return min(known) if known else None


def _meminfo(name: str) -> int | None:
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith(f"{name}:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def _sysconf_free() -> int | None:
    try:
        return int(os.sysconf("SC_AVPHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (ValueError, OSError, AttributeError):
        return None


def _cgroup_room() -> int | None:
    """What the cgroup (v2) of this process may still take, when it has a limit."""
    folder = Path("/sys/fs/cgroup")
    try:
        limit = (folder / "memory.max").read_text().strip()
        if limit == "max":
            return None
        return max(int(limit) - int((folder / "memory.current").read_text()), 0)
    except (OSError, ValueError):
        return None


# ------------------------------------------------------------------------------------ the check
def size(n: float) -> str:
    """Bytes in decimal units, as free(1) -h and file managers show them."""
    for unit, scale in (("TB", 1e12), ("GB", 1e9), ("MB", 1e6)):
        if n >= scale:
            return f"{n / scale:.1f} {unit}"
    return f"{n / 1e3:.1f} KB"


def check(cfg: DictConfig, stage: str, overrides: Sequence[str] = ()) -> None:
    """A `ConfigError` naming the largest allocation when all of ``stage``'s would not fit in
    the memory available (``overrides``: the command's, to show a value as it was typed)."""
    items = estimate(cfg, stage)
    limit = available_bytes()
    total = sum(i.bytes for i in items)
    if not items or limit is None or total <= limit:
        return
    worst = max(items, key=lambda i: i.bytes)
    rest = total - worst.bytes
    fits = (limit - rest) / worst.per_unit
    whole = isinstance(worst.value, int)
    if fits >= 1 or (not whole and fits > 0):
        advice = f"give at most {_round_down(fits, whole)} (or free memory first)"
    else:
        advice = f"the rest of the run alone needs {size(rest)}; lower it and the others"
    also = f" ({size(total)} with the rest of the run)" if rest >= 0.05 * total else ""
    raise ConfigError(
        f"{worst.key}={_as_typed(worst, overrides)} is not allowed: {worst.what} would take "
        f"about {size(worst.bytes)}{also}, and this machine has {size(limit)} of memory "
        f"available; {advice}."
    )


def _round_down(x: float, whole: bool) -> str:
    """``x`` rounded down to three significant digits (an integer when ``whole``)."""
    step = 10 ** (math.floor(math.log10(x)) - 2)
    kept = math.floor(x / step) * step
    return str(int(kept)) if whole and kept >= 1 else f"{kept:g}"


def _as_typed(item: Item, overrides: Sequence[str]) -> str:
    for override in overrides:
        key, eq, value = override.lstrip("+~").partition("=")
        if eq and key == item.key:
            return value
    return str(item.value)


def device_here(device: str) -> str:
    """``agent.device`` where this machine has it: SB3 would fall back to the CPU without a word
    while the run records the device asked for."""
    if device in ("cpu", "auto"):
        return device
    import torch

    missing = (device.startswith("cuda") and not torch.cuda.is_available()) or (
        device == "mps" and not torch.backends.mps.is_available()
    )
    if missing:
        raise ConfigError(
            f"agent.device={device} is not allowed here: torch sees no such device on this "
            "machine; give cpu, or auto to take a GPU where there is one."
        )
    if device.startswith("cuda:") and int(device[5:]) >= torch.cuda.device_count():
        raise ConfigError(
            f"agent.device={device} is not allowed here: this machine has "
            f"{torch.cuda.device_count()} CUDA device(s), numbered from 0."
        )
    return device
