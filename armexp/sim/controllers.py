"""Low-level joint controllers (docs/design.md §4), compiled, with their gain layouts.

The controller sees q, q̇, the reference q_d, q̇_d and M(q); never C, G, F or τ_d.

Subsystem-based adaptive controller (Algorithm 3), gains B = [a0, a1, b1, c1, r1]::

    e1 = q − q_d,  e2 = q̇ − q̇_d,  Υ1 = e1                    (eqs. 3, 4)
    τ0 = −½ a0 Υ1,  Υ2 = e2 − τ0                               (eqs. 4, 5)
    τ  = −½ M(q)(a1 + b1 ρ̂) Υ2 − M(q) Υ1                      (eq. 11)
    ρ̂' = −c1 r1 ρ̂ + ½ b1 c1 ‖Υ2‖²,  ρ̂(0) = 0                  (eq. 12)

Joint PID baseline, gains [kp_1..kp_n, ki_1..ki_n, kd_1..kd_n]::

    τ = −(kp ∘ e1 + ki ∘ ∫e1 dt + kd ∘ e2)
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from armexp.sim.model import Array

ADAPTIVE = 0
PID = 1
KINDS = {"subsystem_adaptive": ADAPTIVE, "pid": PID}
ADAPTIVE_GAIN_NAMES = ("a0", "a1", "b1", "c1", "r1")
PID_GAIN_NAMES = ("kp", "ki", "kd")

#: Gains published in the paper (§V), found there by CSO.
PAPER_GAINS = {"a0": 668.0, "a1": 552.0, "b1": 1.8, "c1": 0.001, "r1": 0.69}


def gain_names(kind: int, n: int) -> list[str]:
    """Flat names of a gain vector: ``a0..r1`` or ``kp_1..kd_n`` (1-based joints)."""
    if kind == ADAPTIVE:
        return list(ADAPTIVE_GAIN_NAMES)
    return [f"{g}_{j + 1}" for g in PID_GAIN_NAMES for j in range(n)]


def gain_vector(kind: int, gains: Mapping[str, float | Sequence[float]], n: int) -> Array:
    """Flatten a gains mapping (config form) into the vector the compiled core takes."""
    if kind == ADAPTIVE:
        return np.array([float(gains[k]) for k in ADAPTIVE_GAIN_NAMES])  # type: ignore[arg-type]
    parts = []
    for k in PID_GAIN_NAMES:
        v = np.broadcast_to(np.asarray(gains[k], dtype=np.float64), (n,))
        parts.append(v)
    return np.concatenate(parts)


def gain_mapping(kind: int, vector: Array, n: int) -> dict[str, float | list[float]]:
    """Inverse of `gain_vector`: the config form of a gain vector."""
    v = [float(x) for x in vector]
    if kind == ADAPTIVE:
        return dict(zip(ADAPTIVE_GAIN_NAMES, v, strict=True))
    return {k: v[i * n : (i + 1) * n] for i, k in enumerate(PID_GAIN_NAMES)}


@njit(cache=True, inline="always")
def control(
    kind: int,
    gains: Array,
    state: Array,
    dqd: Array,
    mass: Array,
    tau_limit: Array,
    tau: Array,
    e1: Array,
    y2: Array,
) -> float:
    """Write the torque into ``tau`` and return the adaptive law's ρ̂' (0 for PID).

    ``state`` is [q, q̇, q_d, ∫e1, ρ̂]; see `armexp.sim.simulator`.
    """
    n = dqd.shape[0]
    rho_dot = 0.0
    if kind == ADAPTIVE:
        a0 = gains[0]
        a1 = gains[1]
        b1 = gains[2]
        c1 = gains[3]
        r1 = gains[4]
        rho = state[4 * n]
        sq = 0.0
        for i in range(n):
            e1[i] = state[i] - state[2 * n + i]
            y2[i] = state[n + i] - dqd[i] + 0.5 * a0 * e1[i]
            sq += y2[i] * y2[i]
        k = 0.5 * (a1 + b1 * rho)
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += mass[i, j] * (k * y2[j] + e1[j])
            tau[i] = -s
        rho_dot = -c1 * r1 * rho + 0.5 * b1 * c1 * sq
    else:
        for i in range(n):
            e1[i] = state[i] - state[2 * n + i]
            e2 = state[n + i] - dqd[i]
            tau[i] = -(gains[i] * e1[i] + gains[n + i] * state[3 * n + i] + gains[2 * n + i] * e2)
    for i in range(n):
        if tau[i] > tau_limit[i]:
            tau[i] = tau_limit[i]
        elif tau[i] < -tau_limit[i]:
            tau[i] = -tau_limit[i]
    return rho_dot
