"""Stability of the sampled closed loop at rest, over a pose grid (docs/design.md §5, the
stability constraint).

The core holds τ over each 1 ms period, so a loop whose continuous-time version is stable can
still diverge once its gains are large against the sampling rate. For the joint PID this depends
on the pose: its torque is not scaled by M(q), so the loop speed grows with M(q)⁻¹, largest when
the links line up (the straight arm). W sees only e1 at the samples and misses it.

**Prediction.** At a pose q* with the arm at rest and a constant reference q_d = q*, the plant
linearises to δq̈ = A_q δq + A_v δq̇ + M(q*)⁻¹ δτ with A_q = −M⁻¹ ∂G/∂q + ∂F/∂q and A_v = ∂F/∂q̇
(C q̇ is quadratic in q̇; the derivatives are central differences of the reference dynamics).
Its exact zero-order-hold step over dt is x⁺ = Φ x + Γ τ, x = [δq, δq̇]. The controllers
linearise to

* PID: τ = −Kp e − Ki z − Kd ė, z⁺ = z + dt·e (the core's Euler integrator; a joint with ki = 0
  has no integrator in the loop);
* computed torque: τ = −M(q*)(Kp e + Ki z + Kd ė), the same integrator (q̈_d = 0 at rest);
* adaptive (Algorithm 3 with the adaptive term σ = b1 ρ̂ frozen at a value ≥ 0):
  τ = −M(q*)[(¼ a0 (a1 + σ) + 1) e + ½ (a1 + σ) ė], and ρ̂⁺ = (1 − dt c1 r1) ρ̂. σ = 0 is the loop
  at the start of every run; the tuner also checks the largest σ its scenarios reach
  (`armexp.tune.objective`), so a candidate whose adaptation raises the loop gain past the
  sampling limit is rejected.

The loop is stable at q* when the spectral radius of its step matrix is below 1. A candidate
meets the constraint when its loop with every gain multiplied by ``gain_margin`` is stable at
every pose of the grid; its gain margin is the largest such factor.

**Grid.** q1 at the middle of its range (it enters only through the small gravity terms) and
``points`` values per joint 2..n spanning its range, always including 0: the straight arm.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass

import numpy as np
from scipy.linalg import expm

from armexp.sim import reference as dynamics
from armexp.sim.controllers import ADAPTIVE, PID
from armexp.sim.model import Array, Plant

_FD_STEP = 1e-6


def pose_grid(lower: Array, upper: Array, points: int) -> Array:
    """Poses (P, n): q1 mid-range, joints 2..n on ``points`` values each, the straight arm (0)
    included whenever it is inside a joint's range."""
    lower = np.asarray(lower, float)
    upper = np.asarray(upper, float)
    axes = [np.array([0.5 * (lower[0] + upper[0])])]
    for lo, hi in zip(lower[1:], upper[1:], strict=True):
        values = np.linspace(lo, hi, max(points, 1))
        if lo <= 0.0 <= hi:
            values = np.unique(np.append(values, 0.0))
        axes.append(values)
    return np.array(list(itertools.product(*axes)))


@dataclass(frozen=True)
class Linearised:
    """Per pose: the ZOH step (Φ, Γ) of the plant at rest and M(q*)."""

    poses: Array  # (P, n)
    phi: Array  # (P, 2n, 2n)
    gamma: Array  # (P, 2n, n)
    mass: Array  # (P, n, n)
    dt: float


def _accel(plant: Plant, q: Array, dq: Array, tau: Array) -> Array:
    return dynamics.acceleration(plant, q, dq, tau, 0.0, np.zeros(q.size))


def linearise(plant: Plant, poses: Array) -> Linearised:
    """Φ, Γ and M at each pose (see the module docstring)."""
    n = plant.arm.n
    dt = plant.dt
    phis, gammas, masses = [], [], []
    zero = np.zeros(n)
    for q in np.asarray(poses, float):
        m = dynamics.mass_matrix(plant, q)
        hold = dynamics.bias(plant, q, zero)  # τ that holds the pose (C q̇ = 0 at rest)
        a = np.zeros((2 * n, 2 * n))
        a[:n, n:] = np.eye(n)
        for j in range(n):
            d = np.zeros(n)
            d[j] = _FD_STEP
            a[n:, j] = (_accel(plant, q + d, zero, hold) - _accel(plant, q - d, zero, hold)) / (
                2 * _FD_STEP
            )
            a[n:, n + j] = (_accel(plant, q, d, hold) - _accel(plant, q, -d, hold)) / (2 * _FD_STEP)
        b = np.zeros((2 * n, n))
        b[n:] = np.linalg.inv(m)
        block = np.zeros((3 * n, 3 * n))
        block[: 2 * n, : 2 * n] = a
        block[: 2 * n, 2 * n :] = b
        step = expm(block * dt)
        phis.append(step[: 2 * n, : 2 * n])
        gammas.append(step[: 2 * n, 2 * n :])
        masses.append(m)
    return Linearised(
        np.asarray(poses, float), np.array(phis), np.array(gammas), np.array(masses), dt
    )


def _feedback(
    kind: int, gains: Array, lin: Linearised, sigma: Array | None = None
) -> tuple[Array, Array, np.ndarray]:
    """State feedback τ = −K [e, ė] − Ki z: K (C, P, n, 2n), Ki (C, P, n, n), and which joints
    have an integrator (C, n)."""
    n = lin.mass.shape[1]
    c = gains.shape[0]
    p = lin.mass.shape[0]
    if kind == ADAPTIVE:
        a0 = gains[:, 0]
        a1 = gains[:, 1] + (0.0 if sigma is None else np.asarray(sigma, float))
        kp = 0.25 * a0 * a1 + 1.0
        kd = 0.5 * a1
        k = np.concatenate(
            [kp[:, None, None, None] * lin.mass[None], kd[:, None, None, None] * lin.mass[None]],
            axis=-1,
        )
        return k, np.zeros((c, p, n, n)), np.zeros((c, n), bool)
    kp, ki, kd = gains[:, :n], gains[:, n : 2 * n], gains[:, 2 * n :]
    diagonal = np.zeros((c, p, n, 2 * n))
    idx = np.arange(n)
    diagonal[:, :, idx, idx] = kp[:, None, :]
    diagonal[:, :, idx, n + idx] = kd[:, None, :]
    integral = np.zeros((c, p, n, n))
    integral[:, :, idx, idx] = ki[:, None, :]
    integrates = np.asarray(ki > 0)
    if kind == PID:
        return diagonal, integral, integrates
    # Computed torque: the same gains acting through M(q*).
    return lin.mass[None] @ diagonal, lin.mass[None] @ integral, integrates


def spectral_radius(kind: int, gains: Array, lin: Linearised, sigma: Array | None = None) -> Array:
    """Spectral radius (C, P) of the sampled closed loop of each gain vector at each pose (the
    adaptive law with its adaptive term frozen at ``sigma`` (C,), default 0)."""
    gains = np.atleast_2d(np.asarray(gains, float))
    n = lin.mass.shape[1]
    k, ki, integrates = _feedback(kind, gains, lin, sigma)
    c, p = k.shape[:2]
    top = lin.phi[None] - lin.gamma[None] @ k  # (C, P, 2n, 2n)
    if kind == ADAPTIVE:
        radius = np.abs(np.linalg.eigvals(top)).max(axis=-1)
        # ρ̂'s own mode, ρ̂⁺ = (1 − dt c1 r1) ρ̂.
        rho = np.abs(1.0 - lin.dt * gains[:, 3] * gains[:, 4])
        return np.maximum(radius, rho[:, None])
    loop = np.zeros((c, p, 3 * n, 3 * n))
    loop[..., : 2 * n, : 2 * n] = top
    loop[..., : 2 * n, 2 * n :] = -lin.gamma[None] @ ki
    idx = np.arange(n)
    loop[..., 2 * n + idx, idx] = lin.dt
    # A joint without integral gain has a z that only listens: its eigenvalue is the diagonal,
    # 1 for the integrator, so it is set to 0 to leave that joint's integrator out.
    loop[..., 2 * n + idx, 2 * n + idx] = integrates.astype(float)[:, None, :]
    return np.abs(np.linalg.eigvals(loop)).max(axis=-1)


def scale_gains(kind: int, gains: Array, factor: float | Array) -> Array:
    """Every gain multiplied by ``factor`` (adaptive: a0, a1, b1 — the loop's gains; its adaptive
    term b1 ρ̂ scales with b1)."""
    gains = np.atleast_2d(np.asarray(gains, float)).copy()
    f = np.asarray(factor, float).reshape(-1, 1)
    if kind == ADAPTIVE:
        gains[:, :3] *= f
        return gains
    return gains * f


def stable_with_margin(
    kind: int, gains: Array, lin: Linearised, margin: float, sigma: Array | None = None
) -> Array:
    """Whether each candidate's loop, its gains × ``margin``, is stable at every pose (C,), with
    the adaptive term at ``sigma`` × ``margin``."""
    scaled = None if sigma is None else margin * np.asarray(sigma, float)
    radius = spectral_radius(kind, scale_gains(kind, gains, margin), lin, scaled)
    return np.all(radius < 1.0, axis=1)


def gain_margin(
    kind: int,
    gains: Array,
    lin: Linearised,
    upper: float = 1e3,
    iterations: int = 40,
    sigma: float | None = None,
) -> float:
    """The largest factor (up to ``upper``) by which every gain can be raised with the loop
    still stable at every pose (the adaptive term at ``sigma``): bisection on a log scale; 0
    when it is unstable as given."""
    g = np.atleast_2d(np.asarray(gains, float))[:1]
    s = None if sigma is None else np.array([sigma], float)
    if not stable_with_margin(kind, g, lin, 1.0, s)[0]:
        return 0.0
    if stable_with_margin(kind, g, lin, upper, s)[0]:
        return upper
    lo, hi = 0.0, float(np.log(upper))
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        if stable_with_margin(kind, g, lin, float(np.exp(mid)), s)[0]:
            lo = mid
        else:
            hi = mid
    return float(np.exp(lo))
