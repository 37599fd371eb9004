"""Reference scenarios for closed-loop runs without an agent (`armexp simulate`, the tuner).

A scenario is what the agent would produce: a sequence of joint-velocity commands q̇_d, each held
for an action period, starting from q_d(0) = q0 with the arm displaced by ``offset``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from armexp.sim.model import Array


@dataclass(frozen=True)
class Scenario:
    """q_d(0) = ``q0``; q(0) = q0 + ``offset``; q̇_d = ``commands[c]`` for ``hold_steps`` periods."""

    q0: Array
    offset: Array
    commands: Array  # (C, n)
    hold_steps: int

    @property
    def n_steps(self) -> int:
        return int(self.commands.shape[0] * self.hold_steps)


def hold_steps(period: float, dt: float) -> int:
    """Controller periods per command; ``period`` must be a whole number of them."""
    steps = round(period / dt)
    if steps < 1 or abs(steps * dt - period) > 1e-9:
        raise ValueError(
            f"switch_period={period} must be a whole number of controller periods {dt}."
        )
    return int(steps)


def command_count(duration: float, hold: int, dt: float) -> int:
    """Commands of ``hold`` periods needed to cover ``duration`` (at least one)."""
    return max(1, int(np.ceil(duration / (hold * dt) - 1e-9)))


def switching(
    rng: np.random.Generator,
    bound: Array,
    duration: float,
    period: float,
    dt: float,
    q0: Array,
    offset: Array,
    scale: float = 1.0,
) -> Scenario:
    """q̇_d uniform in ±scale·bound, redrawn every ``period`` s (the agent's action rate)."""
    hold = hold_steps(period, dt)
    n_cmd = command_count(duration, hold, dt)
    cmds = rng.uniform(-1.0, 1.0, size=(n_cmd, len(bound))) * scale * np.asarray(bound)
    return Scenario(np.asarray(q0, float), np.asarray(offset, float), cmds, hold)


def hold(duration: float, dt: float, q0: Array, offset: Array) -> Scenario:
    """q̇_d = 0: only the initial offset has to be removed."""
    n_steps = max(1, round(duration / dt))
    return Scenario(
        np.asarray(q0, float), np.asarray(offset, float), np.zeros((1, len(q0))), n_steps
    )


def sine(
    bound: Array,
    duration: float,
    period: float,
    dt: float,
    q0: Array,
    offset: Array,
    scale: float = 1.0,
) -> Scenario:
    """q̇_d = scale·bound·sin(2πt/period), updated every controller period."""
    n_steps = max(1, round(duration / dt))
    t = np.arange(n_steps) * dt
    cmds = scale * np.asarray(bound)[None, :] * np.sin(2 * np.pi * t / period)[:, None]
    return Scenario(np.asarray(q0, float), np.asarray(offset, float), cmds, 1)
