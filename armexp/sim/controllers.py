"""Low-level joint controllers (docs/design.md §4), compiled, with their gain layouts.

The controller sees q, q̇, the reference q_d, q̇_d and M(q); never C, G, F or τ_d.

Subsystem-based adaptive controller (Algorithm 3), gains B = [a0, a1, b1, c1, r1]::

    e1 = q − q_d,  e2 = q̇ − q̇_d,  Υ1 = e1                    (eqs. 3, 4)
    τ0 = −½ a0 Υ1,  Υ2 = e2 − τ0                               (eqs. 4, 5)
    τ  = −½ M(q)(a1 + b1 ρ̂) Υ2 − M(q) Υ1                      (eq. 11)
    ρ̂' = −c1 r1 ρ̂ + ½ b1 c1 ‖Υ2‖²,  ρ̂(0) = 0                  (eq. 12)

Joint PID baseline, gains [kp_1..kp_n, ki_1..ki_n, kd_1..kd_n]::

    τ = −(kp ∘ e1 + ki ∘ ∫e1 dt + kd ∘ e2)

Computed-torque baseline with the proposed law's model knowledge (M(q) only, no C or G), gains laid
out as the PID's::

    τ = M(q) (q̈_d − kp ∘ e1 − ki ∘ ∫e1 dt − kd ∘ e2)

q̈_d is the reference generator's acceleration over the step (a ramp's slope; 0 under a hold). The
integral term takes the place of the gravity compensation the law may not use.

b1, c1 and r1 act on the closed loop only through λ = c1·r1 and γ = b1²·c1: with σ = b1 ρ̂, eq. 12
reads σ' = −λ σ + ½ γ ‖Υ2‖² and eq. 11 τ = −½ M(q)(a1 + σ) Υ2 − M(q) Υ1. The tuner searches
(a0, a1, λ, γ) (`adaptive_from_rates`). With b1 = 0, ρ̂ ≡ 0: the law without adaptation
(`without_adaptation`), a PD in M(q)-scaled coordinates.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from numba import njit

from armexp.paper import GAINS
from armexp.sim.model import Array

ADAPTIVE = 0
PID = 1
COMPUTED_TORQUE = 2
KINDS = {"subsystem_adaptive": ADAPTIVE, "pid": PID, "computed_torque": COMPUTED_TORQUE}
ADAPTIVE_GAIN_NAMES = ("a0", "a1", "b1", "c1", "r1")
#: Per-joint gain groups of the PID and of the computed-torque law.
PID_GAIN_NAMES = ("kp", "ki", "kd")
#: The adaptive law's search coordinates: a0, a1 and the rates λ = c1·r1, γ = b1²·c1.
ADAPTIVE_SEARCH_NAMES = ("a0", "a1", "lambda", "gamma")

#: Gains published in the paper (§V), found there by CSO (`armexp.paper` holds them).
PAPER_GAINS = GAINS


def adaptive_rates(gains: Array) -> tuple[float, float]:
    """(λ, γ) = (c1·r1, b1²·c1) of an adaptive gain vector [a0, a1, b1, c1, r1]."""
    _, _, b1, c1, r1 = (float(g) for g in gains)
    return c1 * r1, b1 * b1 * c1


def adaptive_from_rates(a0: Array, a1: Array, lam: Array, gamma: Array) -> Array:
    """Gain vectors [a0, a1, b1, c1, r1] (K, 5) with the given a0, a1, λ, γ: r1 = 1, c1 = λ,
    b1 = √(γ/λ). Any (b1, c1, r1) with the same λ and γ gives the same closed loop."""
    lam = np.asarray(lam, dtype=np.float64)
    gamma = np.asarray(gamma, dtype=np.float64)
    return np.stack(
        np.broadcast_arrays(a0, a1, np.sqrt(gamma / lam), lam, np.ones_like(lam)), axis=-1
    ).astype(np.float64)


def without_adaptation(gains: Mapping[str, float]) -> dict[str, float]:
    """The adaptive law's gains with b1 = 0, so ρ̂ ≡ 0: the ablation of its adaptation."""
    return {**{k: float(v) for k, v in gains.items()}, "b1": 0.0}


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
    ddqd: Array,
    mass: Array,
    tau_limit: Array,
    tau: Array,
    e1: Array,
    y2: Array,
) -> float:
    """Write the torque into ``tau`` and return the adaptive law's ρ̂' (0 for the others).

    ``state`` is [q, q̇, q_d, ∫e1, ρ̂] (see `armexp.sim.simulator`), ``dqd`` and ``ddqd`` the
    reference velocity and acceleration at the step's start; ``y2`` is scratch.
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
    elif kind == PID:
        for i in range(n):
            e1[i] = state[i] - state[2 * n + i]
            e2 = state[n + i] - dqd[i]
            tau[i] = -(gains[i] * e1[i] + gains[n + i] * state[3 * n + i] + gains[2 * n + i] * e2)
    else:
        for i in range(n):
            e1[i] = state[i] - state[2 * n + i]
            e2 = state[n + i] - dqd[i]
            y2[i] = ddqd[i] - (
                gains[i] * e1[i] + gains[n + i] * state[3 * n + i] + gains[2 * n + i] * e2
            )
        for i in range(n):
            s = 0.0
            for j in range(n):
                s += mass[i, j] * y2[j]
            tau[i] = s
    for i in range(n):
        if tau[i] > tau_limit[i]:
            tau[i] = tau_limit[i]
        elif tau[i] < -tau_limit[i]:
            tau[i] = -tau_limit[i]
    return rho_dot
