"""Physical description of the planar arm and of the plant's unknown terms (docs/design.md §3).

The arm is a serial chain of uniform slender rods in a vertical plane. Everything the compiled core
needs is derived once here, as small float arrays, so the hot loop never touches Python objects.

Absolute link angles θ_a = q_1 + … + q_a make the dynamics compact. With r_ia the lever of link a
inside link i's centre-of-mass position (l_a for a < i, l_i/2 for a = i)::

    W_ab  = Σ_{i ≥ max(a,b)} m_i r_ia r_ib  (+ I_a on the diagonal)
    M_θ   = W ∘ cos(θ_a − θ_b)                        (inertia in absolute angles)
    h_θ,a = Σ_b W_ab sin(θ_a − θ_b) ω_b²                (Coriolis/centrifugal, ω = θ̇)
    G_θ,a = g_a cos θ_a,  g_a = g (m_a l_a/2 + l_a Σ_{i>a} m_i)
    V     = Σ_a g_a sin θ_a                             (potential energy, y up)

and, since θ = A q with A lower-triangular ones, M = Aᵀ M_θ A, C q̇ = Aᵀ h_θ, G = Aᵀ G_θ
(eq. 1 of the paper without friction and load, which eq. 2 folds into F and τ_d).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

# Source of an uncertainty term's argument (column 3 of `Uncertainty.f_terms`).
SOURCE_Q = 0
SOURCE_DQ = 1


@dataclass(frozen=True)
class ArmModel:
    """Link lengths (m), masses (kg) and gravity (m/s²) of an n-link planar arm."""

    lengths: tuple[float, ...]
    masses: tuple[float, ...]
    gravity: float = 9.81
    weights: Array = field(init=False, repr=False, compare=False)
    gravity_coef: Array = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        n = len(self.lengths)
        if n < 1 or len(self.masses) != n:
            raise ValueError(
                f"an arm needs as many masses as lengths; got {n} lengths and "
                f"{len(self.masses)} masses."
            )
        if min(self.lengths) <= 0 or min(self.masses) <= 0:
            raise ValueError("every link length and mass must be > 0.")
        lengths = np.asarray(self.lengths, dtype=np.float64)
        masses = np.asarray(self.masses, dtype=np.float64)
        lc = lengths / 2.0
        inertia = masses * lengths**2 / 12.0
        w = np.zeros((n, n))
        for i in range(n):
            lever = lengths.copy()
            lever[i] = lc[i]
            for a in range(i + 1):
                for b in range(i + 1):
                    w[a, b] += masses[i] * (lever[a] * lever[b])  # symmetric to the last bit
        w[np.diag_indices(n)] += inertia
        tail_mass = np.concatenate([np.cumsum(masses[::-1])[::-1][1:], [0.0]])
        g_coef = self.gravity * (masses * lc + lengths * tail_mass)
        object.__setattr__(self, "weights", w)
        object.__setattr__(self, "gravity_coef", g_coef)

    @property
    def n(self) -> int:
        return len(self.lengths)

    @property
    def lengths_array(self) -> Array:
        return np.asarray(self.lengths, dtype=np.float64)


@dataclass(frozen=True)
class Uncertainty:
    """The unknown terms of eq. 2, added at acceleration level (eq. 40 for the paper's arm).

    ``F_i(q, q̇) = Σ amp · cos(freq · x)`` over the rows of `f_terms` whose joint is i, where x is
    q_j (source 0) or q̇_j (source 1); ``τ_d,i(t) = cos_amp_i cos(cos_freq_i t) + rand_amp_i u``
    with u ~ U(0, 1) drawn afresh every controller period.
    """

    f_terms: Array  # rows: joint, amp, freq, source, source_joint
    cos_amp: Array
    cos_freq: Array
    rand_amp: Array

    @classmethod
    def off(cls, n: int) -> Uncertainty:
        z = np.zeros(n)
        return cls(np.zeros((0, 5)), z, z.copy(), z.copy())

    @classmethod
    def paper(cls) -> Uncertainty:
        """Eq. 40: F = [0.5 cos(0.7 q̇2), −1.1 cos(1.8 q2) + 1.8 cos(0.3 q2)],
        τ_d = [3 cos(2t), −0.2 u]."""
        f_terms = np.array(
            [
                [0, 0.5, 0.7, SOURCE_DQ, 1],
                [1, -1.1, 1.8, SOURCE_Q, 1],
                [1, 1.8, 0.3, SOURCE_Q, 1],
            ],
            dtype=np.float64,
        )
        return cls(f_terms, np.array([3.0, 0.0]), np.array([2.0, 0.0]), np.array([0.0, -0.2]))

    def check(self, n: int) -> None:
        for name in ("cos_amp", "cos_freq", "rand_amp"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"uncertainty.{name} must have one entry per joint ({n}).")
        if self.f_terms.size:
            joints = self.f_terms[:, [0, 4]]
            if joints.min() < 0 or joints.max() >= n:
                raise ValueError(f"uncertainty.f_terms name a joint outside 0..{n - 1}.")
            if not np.isin(self.f_terms[:, 3], (SOURCE_Q, SOURCE_DQ)).all():
                raise ValueError("uncertainty.f_terms source must be 0 (q) or 1 (dq).")


@dataclass(frozen=True)
class Plant:
    """Arm + unknown terms + actuator limit + controller period: everything the core integrates."""

    arm: ArmModel
    uncertainty: Uncertainty
    torque_limit: Array  # per joint, +inf when off
    dt: float = 1e-3

    def __post_init__(self) -> None:
        self.uncertainty.check(self.arm.n)
        if self.torque_limit.shape != (self.arm.n,) or (self.torque_limit <= 0).any():
            raise ValueError("torque_limit needs one positive entry per joint (inf for none).")
        if not self.dt > 0:
            raise ValueError(f"dt={self.dt} must be > 0.")

    @classmethod
    def build(
        cls,
        arm: ArmModel,
        uncertainty: Uncertainty | None = None,
        torque_limit: Array | None = None,
        dt: float = 1e-3,
    ) -> Plant:
        n = arm.n
        unc = uncertainty if uncertainty is not None else Uncertainty.off(n)
        lim = np.full(n, np.inf) if torque_limit is None else np.asarray(torque_limit, float)
        return cls(arm, unc, lim, dt)

    def packed(self) -> tuple[Array, Array, Array, Array, Array, Array]:
        """The arrays the compiled core takes (its ``model`` tuple), in order."""
        u = self.uncertainty
        return (
            self.arm.weights,
            self.arm.gravity_coef,
            self.arm.lengths_array,
            np.ascontiguousarray(u.f_terms, dtype=np.float64),
            np.stack([u.cos_amp, u.cos_freq, u.rand_amp]).astype(np.float64),
            self.torque_limit.astype(np.float64),
        )


TWO_LINK_PAPER = ArmModel(lengths=(1.0, 0.8), masses=(20.0, 15.0))
THREE_LINK = ArmModel(lengths=(0.8, 0.6, 0.4), masses=(15.0, 10.0, 5.0))
