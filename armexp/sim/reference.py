"""Plain-numpy reference of the closed loop, written for clarity, not speed.

It implements the same equations as the compiled core (`armexp.sim.simulator`) directly from the
paper (eq. 1/2 plant, eq. 40 unknown terms, Algorithm 3 / eqs. 4–12 controller, joint PID) with
numpy array expressions and `numpy.linalg.solve`. Tests hold the compiled core to it within 1e-9,
and the speed benchmark measures against it.
"""

from __future__ import annotations

import numpy as np

from armexp.sim.controllers import ADAPTIVE, PID
from armexp.sim.model import SOURCE_Q, Array, Plant
from armexp.sim.noise import uniform_numpy
from armexp.sim.step import DIVERGENCE_SPEED


def mass_matrix(plant: Plant, q: Array) -> Array:
    """M(q) = Aᵀ (W ∘ cos(θ_a − θ_b)) A, A lower-triangular ones."""
    th = np.cumsum(q)
    a = np.tril(np.ones((q.size, q.size)))
    return a.T @ (plant.arm.weights * np.cos(th[:, None] - th[None, :])) @ a


def bias(plant: Plant, q: Array, dq: Array) -> Array:
    """C(q, q̇) q̇ + G(q) = Aᵀ (h_θ + G_θ)."""
    th = np.cumsum(q)
    om = np.cumsum(dq)
    w = plant.arm.weights
    h = (w * np.sin(th[:, None] - th[None, :])) @ (om**2)
    g = plant.arm.gravity_coef * np.cos(th)
    return np.cumsum((h + g)[::-1])[::-1]


def uncertainty(plant: Plant, q: Array, dq: Array, t: float, u: Array) -> Array:
    """F(q, q̇) + τ_d(t) of eq. 2 (eq. 40 for the paper arm)."""
    unc = plant.uncertainty
    out = unc.cos_amp * np.cos(unc.cos_freq * t) + unc.rand_amp * u
    for joint, amp, freq, source, src in unc.f_terms:
        x = q[int(src)] if int(source) == SOURCE_Q else dq[int(src)]
        out[int(joint)] += amp * np.cos(freq * x)
    return out


def acceleration(plant: Plant, q: Array, dq: Array, tau: Array, t: float, u: Array) -> Array:
    return np.linalg.solve(mass_matrix(plant, q), tau - bias(plant, q, dq)) + uncertainty(
        plant, q, dq, t, u
    )


def control(
    plant: Plant,
    kind: int,
    gains: Array,
    q: Array,
    dq: Array,
    qd: Array,
    dqd: Array,
    integral: Array,
    rho: float,
    ddqd: Array | None = None,
) -> tuple[Array, float]:
    """τ and ρ̂' (Algorithm 3), or the PID's or computed-torque law's torque and 0."""
    n = q.size
    e1 = q - qd
    e2 = dq - dqd
    if kind == ADAPTIVE:
        a0, a1, b1, c1, r1 = gains
        y1 = e1
        y2 = e2 + 0.5 * a0 * y1
        m = mass_matrix(plant, q)
        tau = -0.5 * (a1 + b1 * rho) * (m @ y2) - m @ y1
        rho_dot = -c1 * r1 * rho + 0.5 * b1 * c1 * float(y2 @ y2)
    elif kind == PID:
        kp, ki, kd = gains[:n], gains[n : 2 * n], gains[2 * n :]
        tau = -(kp * e1 + ki * integral + kd * e2)
        rho_dot = 0.0
    else:
        kp, ki, kd = gains[:n], gains[n : 2 * n], gains[2 * n :]
        acc = np.zeros(n) if ddqd is None else ddqd
        tau = mass_matrix(plant, q) @ (acc - kp * e1 - ki * integral - kd * e2)
        rho_dot = 0.0
    return np.clip(tau, -plant.torque_limit, plant.torque_limit), rho_dot


def simulate(
    plant: Plant,
    kind: int,
    gains: Array,
    q0: Array,
    qd0: Array,
    commands: Array,
    seed: int,
    hold: int = 1,
    ramp: bool = False,
) -> Array:
    """Run ``hold`` controller steps per row of ``commands`` from rest at q0, q̇_d(0) = 0.

    q̇_d is the command (``ramp=False``) or moves linearly from the previous command to it over
    the ``hold`` steps (``ramp=True``); q_d integrates it exactly. Returns the state
    [q, q̇, q_d, ∫e1, ρ̂] after every step, shape (K, 4n + 1); rows after a divergence are NaN.
    """
    n = plant.arm.n
    h = plant.dt
    q = np.array(q0, dtype=float)
    dq = np.zeros(n)
    qd = np.array(qd0, dtype=float)
    integral = np.zeros(n)
    rho = 0.0
    cmds = np.asarray(commands, dtype=float)
    prev = np.vstack([np.zeros((1, n)), cmds[:-1]])
    frac = np.arange(hold + 1) / hold if ramp else np.ones(hold + 1)
    # q̇_d at the start and the end of every step.
    start = (prev[:, None] + (cmds - prev)[:, None] * frac[None, :-1, None]).reshape(-1, n)
    end = (prev[:, None] + (cmds - prev)[:, None] * frac[None, 1:, None]).reshape(-1, n)
    steps = start.shape[0]
    noise = uniform_numpy(seed, np.arange(steps), n)
    out = np.full((steps, 4 * n + 1), np.nan)
    for k in range(steps):
        dqd = start[k]
        u = noise[k]
        t = k * h
        tau, rho_dot = control(
            plant, kind, gains, q, dq, qd, dqd, integral, rho, (end[k] - dqd) / h
        )
        e1 = q - qd
        k1v, k1a = dq, acceleration(plant, q, dq, tau, t, u)
        k2v = dq + 0.5 * h * k1a
        k2a = acceleration(plant, q + 0.5 * h * k1v, k2v, tau, t + 0.5 * h, u)
        k3v = dq + 0.5 * h * k2a
        k3a = acceleration(plant, q + 0.5 * h * k2v, k3v, tau, t + 0.5 * h, u)
        k4v = dq + h * k3a
        k4a = acceleration(plant, q + h * k3v, k4v, tau, t + h, u)
        q = q + h / 6.0 * (k1v + 2 * k2v + 2 * k3v + k4v)
        dq = dq + h / 6.0 * (k1a + 2 * k2a + 2 * k3a + k4a)
        qd = qd + h * 0.5 * (dqd + end[k])
        # PID anti-windup: no integration that drives a saturated torque further out.
        windup = (kind != ADAPTIVE) & (np.abs(tau) >= plant.torque_limit) & (e1 * tau < 0)
        integral = integral + np.where(windup, 0.0, h * e1)
        rho = rho + h * rho_dot
        if not (np.isfinite(q).all() and np.isfinite(dq).all()) or np.abs(dq).max() > (
            DIVERGENCE_SPEED
        ):
            break
        out[k] = np.concatenate([q, dq, qd, integral, [rho]])
    return out
