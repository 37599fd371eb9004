"""Compiled rigid-body terms of the n-link arm: M(q), C(q, q̇)q̇ + G(q), tip kinematics, energy.

Formulas in `armexp.sim.model`. The kernels work from the cosines and sines of the absolute link
angles θ_a, which the closed loop (`armexp.sim.angle_cache`) keeps up to date by rotation instead of
calling libm; `mass_and_bias` is the self-contained entry point (it evaluates the trigonometry
itself). Every hot-loop function writes into caller-owned buffers so the 1 kHz loop never
allocates.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from armexp.sim.model import Array

_FAST = {"contract"}  # FMA contraction only: results move by rounding, never by reassociation.


@njit(cache=True)
def absolute_angles(q: Array, dq: Array, th: Array, om: Array) -> None:
    """θ_a = q_1 + … + q_a and ω_a = θ̇_a."""
    acc = 0.0
    accd = 0.0
    for a in range(q.shape[0]):
        acc += q[a]
        accd += dq[a]
        th[a] = acc
        om[a] = accd


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def mass_and_bias_cs(
    cth: Array,
    sth: Array,
    om: Array,
    weights: Array,
    gravity_coef: Array,
    mass: Array,
    bias: Array,
) -> None:
    """M(q) and C(q, q̇)q̇ + G(q) from cos θ_a, sin θ_a and ω_a = θ̇_a.

    cos(θ_a − θ_b) and sin(θ_a − θ_b) come from the angle-difference identities, so no
    trigonometric function is evaluated here.
    """
    n = cth.shape[0]
    # M = Aᵀ M_θ A is a 2-D suffix sum of M_θ = W ∘ cos(θ_a − θ_b); the two neighbours are added
    # first so that M comes out exactly symmetric.
    for j in range(n - 1, -1, -1):
        for k in range(n - 1, -1, -1):
            v = weights[j, j] if j == k else weights[j, k] * (cth[j] * cth[k] + sth[j] * sth[k])
            below = mass[j + 1, k] if j + 1 < n else 0.0
            right = mass[j, k + 1] if k + 1 < n else 0.0
            corner = mass[j + 1, k + 1] if j + 1 < n and k + 1 < n else 0.0
            mass[j, k] = v + (below + right) - corner
    # C q̇ + G = Aᵀ (h_θ + G_θ) is a suffix sum over links.
    run = 0.0
    for a in range(n - 1, -1, -1):
        v = gravity_coef[a] * cth[a]
        for b in range(n):
            if b != a:
                v += weights[a, b] * (sth[a] * cth[b] - cth[a] * sth[b]) * (om[b] * om[b])
        run += v
        bias[a] = run


@njit(cache=True)
def mass_and_bias(
    q: Array, dq: Array, weights: Array, gravity_coef: Array, mass: Array, bias: Array
) -> None:
    """Fill ``mass`` with M(q) and ``bias`` with C(q, q̇)q̇ + G(q) (eq. 1)."""
    n = q.shape[0]
    th = np.empty(n)
    om = np.empty(n)
    absolute_angles(q, dq, th, om)
    mass_and_bias_cs(np.cos(th), np.sin(th), om, weights, gravity_coef, mass, bias)


@njit(cache=True, error_model="numpy", fastmath=_FAST)
def cholesky_solve(mass: Array, rhs: Array, low: Array, out: Array) -> None:
    """out = M⁻¹ rhs for symmetric positive definite M (n is tiny: plain loops beat LAPACK)."""
    n = rhs.shape[0]
    for i in range(n):
        for j in range(i + 1):
            s = mass[i, j]
            for k in range(j):
                s -= low[i, k] * low[j, k]
            if i == j:
                low[i, i] = math.sqrt(s)
            else:
                low[i, j] = s / low[j, j]
    for i in range(n):
        s = rhs[i]
        for k in range(i):
            s -= low[i, k] * out[k]
        out[i] = s / low[i, i]
    for i in range(n - 1, -1, -1):
        s = out[i]
        for k in range(i + 1, n):
            s -= low[k, i] * out[k]
        out[i] = s / low[i, i]


@njit(cache=True)
def tip_position(q: Array, lengths: Array) -> tuple[float, float]:
    x = 0.0
    y = 0.0
    th = 0.0
    for a in range(q.shape[0]):
        th += q[a]
        x += lengths[a] * math.cos(th)
        y += lengths[a] * math.sin(th)
    return x, y


def tip_jacobian(q: Array, lengths: Array) -> Array:
    """∂tip/∂q, shape (2, n): column j sums the rotated levers of links j..n."""
    th = np.cumsum(q)
    jx = -lengths * np.sin(th)
    jy = lengths * np.cos(th)
    return np.stack([np.cumsum(jx[::-1])[::-1], np.cumsum(jy[::-1])[::-1]])


def energy(q: Array, dq: Array, weights: Array, gravity_coef: Array) -> float:
    """Total mechanical energy ½ ωᵀ M_θ ω + Σ g_a sin θ_a (potential zero at the base height)."""
    th = np.cumsum(q)
    om = np.cumsum(dq)
    m_theta = weights * np.cos(th[:, None] - th[None, :])
    return float(0.5 * om @ m_theta @ om + gravity_coef @ np.sin(th))
