"""Pieces of one controller step that every loop shares: the reference generator, the Euler
integrals of q_d and ∫e1, and the divergence test."""

from __future__ import annotations

import numpy as np
from numba import njit

from armexp.sim.controllers import ADAPTIVE
from armexp.sim.model import Array
from armexp.sim.work import FASTMATH

#: Above this joint speed (rad/s) a run counts as diverged; no physical arm gets near it.
DIVERGENCE_SPEED = 1e4

#: Reference generators (docs/design.md §4): q̇_d ramps linearly from the previous command to the new
#: one across each command's period (first-order hold), or jumps to it (zero-order hold).
REFERENCES = ("ramp", "hold")


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def reference_velocity(
    ramp: bool, cmd: Array, prev: Array, j: int, hold: int, now: Array, end: Array
) -> None:
    """q̇_d at the start (``now``) and end (``end``) of step j of a command held ``hold`` steps.

    ramp: q̇_d moves linearly from ``prev`` to ``cmd`` across the hold, so q̈_d = Δcommand /
    period; hold: q̇_d = ``cmd`` throughout. q_d integrates the segment exactly (trapezoid).
    """
    if ramp:
        f0 = j / hold
        f1 = (j + 1) / hold
        for i in range(now.shape[0]):
            d = cmd[i] - prev[i]
            now[i] = prev[i] + d * f0
            end[i] = prev[i] + d * f1
    else:
        for i in range(now.shape[0]):
            now[i] = cmd[i]
            end[i] = cmd[i]


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def integrate_reference(state: Array, now: Array, end: Array, h: float, n: int) -> None:
    """q_d += ∫ q̇_d over the step (exact for the linear segment; h·q̇_d under a hold)."""
    for i in range(n):
        state[2 * n + i] += h * (0.5 * (now[i] + end[i]))


@njit(cache=True, error_model="numpy", fastmath=FASTMATH, inline="always")
def integrate_error(
    kind: int, state: Array, e1: Array, tau: Array, tau_limit: Array, h: float, n: int
) -> None:
    """∫e1 dt by explicit Euler, with the integral laws' anti-windup (PID, computed torque): a
    joint whose torque is at the limit does not integrate the error that would drive it further
    into saturation."""
    for i in range(n):
        if kind != ADAPTIVE and abs(tau[i]) >= tau_limit[i] and e1[i] * tau[i] < 0.0:
            continue
        state[3 * n + i] += h * e1[i]


@njit(cache=True)
def has_diverged(state: Array, n: int) -> bool:
    """Whether q, q̇ or ρ̂ is not finite or a joint speed exceeds `DIVERGENCE_SPEED`."""
    for i in range(2 * n):
        x = state[i]
        if not np.isfinite(x):
            return True
    for i in range(n, 2 * n):
        if abs(state[i]) > DIVERGENCE_SPEED:
            return True
    return not np.isfinite(state[4 * n])
