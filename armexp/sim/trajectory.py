"""The logged trajectory: its columns (the `trajectory.parquet` contract) and the compiled
writers of one row."""

from __future__ import annotations

from numba import njit

from armexp.sim.dynamics import tip_position
from armexp.sim.model import Array


def trajectory_columns(n: int) -> list[str]:
    """Column names of a logged trajectory (the `trajectory.parquet` contract).

    ``tau_<j>`` is the torque the plant received (after saturation); ``sat_<j>`` is 1.0 when it
    was at the torque limit during that step.
    """
    j = range(1, n + 1)
    return (
        ["t"]
        + [f"q_{i}" for i in j]
        + [f"q_d_{i}" for i in j]
        + [f"dq_{i}" for i in j]
        + [f"dq_d_{i}" for i in j]
        + [f"tau_{i}" for i in j]
        + ["rho_hat", "tip_x", "tip_y"]
        + [f"sat_{i}" for i in j]
    )


def log_width(n: int) -> int:
    """Number of `trajectory_columns`."""
    return 4 + 6 * n


@njit(cache=True)
def log_row(row: Array, t: float, state: Array, dqd: Array, n: int, lengths: Array) -> None:
    """The columns known at a step's start (all but τ and the saturation flags) into ``row``."""
    row[0] = t
    for i in range(n):
        row[1 + i] = state[i]
        row[1 + n + i] = state[2 * n + i]
        row[1 + 2 * n + i] = state[n + i]
        row[1 + 3 * n + i] = dqd[i]
    row[1 + 5 * n] = state[4 * n]
    x, y = tip_position(state[0:n], lengths)
    row[2 + 5 * n] = x
    row[3 + 5 * n] = y


@njit(cache=True, inline="always")
def log_torque(row: Array, tau: Array, tau_limit: Array, n: int) -> None:
    """The applied torque and the saturation flag of a logged step."""
    for i in range(n):
        row[1 + 4 * n + i] = tau[i]
        row[4 + 5 * n + i] = 1.0 if abs(tau[i]) >= tau_limit[i] else 0.0
