"""Physics of the compiled arm model (docs/design.md §3): M, C, G, energy, tip kinematics.

Every check compares the compiled terms (`armexp.sim.dynamics`) with a formulation written here,
independently of `armexp.sim.model`'s absolute-angle form.
"""

from __future__ import annotations

import numpy as np
import pytest

from armexp.sim.dynamics import energy, mass_and_bias, tip_jacobian, tip_position
from armexp.sim.model import THREE_LINK, TWO_LINK_PAPER, ArmModel, Plant
from armexp.sim.simulator import Simulator

ARMS = [
    pytest.param(TWO_LINK_PAPER, id="two_link_paper"),
    pytest.param(THREE_LINK, id="three_link"),
]


def core_terms(arm: ArmModel, q: np.ndarray, dq: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """M(q) and C(q, q̇)q̇ + G(q) from the compiled kernel."""
    n = arm.n
    mass = np.empty((n, n))
    bias = np.empty(n)
    mass_and_bias(
        np.ascontiguousarray(q, dtype=float),
        np.ascontiguousarray(dq, dtype=float),
        arm.weights,
        arm.gravity_coef,
        mass,
        bias,
    )
    return mass, bias


def mass_textbook(arm: ArmModel, q: np.ndarray) -> np.ndarray:
    """M = Σ_i m_i J_viᵀ J_vi + I_i J_ωiᵀ J_ωi with explicit centre-of-mass Jacobians.

    Works for complex q too (complex-step differentiation). Link i's centre of mass is
    p_ci = Σ_{a<i} l_a u(θ_a) + (l_i/2) u(θ_i), u(θ) = (cos θ, sin θ), θ_a = q_1 + … + q_a; its
    Jacobian column j (j ≤ i) is Σ_{j≤a<i} l_a u'(θ_a) + (l_i/2) u'(θ_i); ω_i = Σ_{j≤i} q̇_j.
    """
    n = arm.n
    lengths = np.asarray(arm.lengths)
    masses = np.asarray(arm.masses)
    theta = np.cumsum(q)
    dtype = np.result_type(q, float)
    mass = np.zeros((n, n), dtype=dtype)
    for i in range(n):
        jv = np.zeros((2, n), dtype=dtype)
        for j in range(i + 1):
            for a in range(j, i + 1):
                lever = lengths[a] if a < i else lengths[i] / 2.0
                jv[0, j] += -lever * np.sin(theta[a])
                jv[1, j] += lever * np.cos(theta[a])
        jw = np.array([1.0 if j <= i else 0.0 for j in range(n)])
        inertia = masses[i] * lengths[i] ** 2 / 12.0
        mass += masses[i] * jv.T @ jv + inertia * np.outer(jw, jw)
    return mass


def mass_derivatives(arm: ArmModel, q: np.ndarray) -> np.ndarray:
    """∂M/∂q_k by complex step (exact to rounding): shape (n, n, n), last index k."""
    n = arm.n
    step = 1e-30
    out = np.empty((n, n, n))
    for k in range(n):
        qc = q.astype(complex)
        qc[k] += 1j * step
        out[:, :, k] = mass_textbook(arm, qc).imag / step
    return out


def coriolis(arm: ArmModel, q: np.ndarray, dq: np.ndarray) -> np.ndarray:
    """C(q, q̇) from Christoffel symbols: C_kj = Σ_i ½(∂_i M_kj + ∂_j M_ki − ∂_k M_ij) q̇_i."""
    d = mass_derivatives(arm, q)  # d[a, b, c] = ∂M_ab/∂q_c
    n = arm.n
    c = np.zeros((n, n))
    for k in range(n):
        for j in range(n):
            for i in range(n):
                c[k, j] += 0.5 * (d[k, j, i] + d[k, i, j] - d[i, j, k]) * dq[i]
    return c


def random_states(n: int, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.uniform(-np.pi, np.pi, (count, n)), rng.uniform(-3.0, 3.0, (count, n))


@pytest.mark.parametrize("arm", ARMS)
def test_mass_matrix_spd_and_equal_to_textbook_form(arm: ArmModel) -> None:
    qs, dqs = random_states(arm.n, 250, seed=1)
    for q, dq in zip(qs, dqs, strict=True):
        mass, _ = core_terms(arm, q, dq)
        assert np.array_equal(mass, mass.T)
        eig = np.linalg.eigvalsh(mass)
        assert eig.min() > 1e-3 * eig.max() > 0.0
        expected = mass_textbook(arm, q)
        np.testing.assert_allclose(mass, expected, rtol=0, atol=1e-12 * np.abs(expected).max())


@pytest.mark.parametrize("arm", ARMS)
def test_christoffel_coriolis_matches_bias_and_skew_symmetry(arm: ArmModel) -> None:
    n = arm.n
    qs, dqs = random_states(n, 40, seed=2)
    for q, dq in zip(qs, dqs, strict=True):
        mass, bias = core_terms(arm, q, dq)
        _, gravity = core_terms(arm, q, np.zeros(n))
        c = coriolis(arm, q, dq)
        scale = np.abs(bias).max() + np.abs(c @ dq).max()
        np.testing.assert_allclose(c @ dq + gravity, bias, rtol=0, atol=1e-12 * scale)
        # Ṁ − 2C is skew-symmetric.
        mdot = mass_derivatives(arm, q) @ dq
        skew = mdot - 2.0 * c
        assert np.abs(skew + skew.T).max() <= 1e-12 * np.abs(mdot).max()
        # The compiled M has the same derivatives (central differences of the compiled kernel).
        h = 1e-6
        for k in range(n):
            e = np.zeros(n)
            e[k] = h
            fd = (core_terms(arm, q + e, dq)[0] - core_terms(arm, q - e, dq)[0]) / (2 * h)
            np.testing.assert_allclose(fd, mass_derivatives(arm, q)[:, :, k], atol=1e-7 * scale)
        assert np.abs(mass - mass_textbook(arm, q)).max() <= 1e-12 * np.abs(mass).max()


@pytest.mark.parametrize("arm", ARMS)
def test_gravity_is_gradient_of_potential(arm: ArmModel) -> None:
    n = arm.n
    qs, _ = random_states(n, 50, seed=3)
    zero = np.zeros(n)
    h = 1e-5
    for q in qs:
        _, gravity = core_terms(arm, q, zero)
        grad = np.empty(n)
        for k in range(n):
            e = np.zeros(n)
            e[k] = h
            hi = energy(q + e, zero, arm.weights, arm.gravity_coef)
            lo = energy(q - e, zero, arm.weights, arm.gravity_coef)
            grad[k] = (hi - lo) / (2 * h)
        np.testing.assert_allclose(
            gravity, grad, rtol=0, atol=1e-7 * np.abs(arm.gravity_coef).sum()
        )


def test_potential_is_mgh_of_the_centres_of_mass() -> None:
    """energy(q, 0) = Σ m_i g y_ci, and the kinetic part is ½ q̇ᵀ M q̇ (independent form)."""
    for arm in (TWO_LINK_PAPER, THREE_LINK):
        qs, dqs = random_states(arm.n, 30, seed=4)
        lengths = np.asarray(arm.lengths)
        for q, dq in zip(qs, dqs, strict=True):
            theta = np.cumsum(q)
            y = np.concatenate([[0.0], np.cumsum(lengths * np.sin(theta))])[:-1]
            y_c = y + lengths / 2.0 * np.sin(theta)
            potential = arm.gravity * float(np.dot(arm.masses, y_c))
            zero = np.zeros(arm.n)
            assert energy(q, zero, arm.weights, arm.gravity_coef) == pytest.approx(
                potential, rel=1e-12, abs=1e-10
            )
            kinetic = 0.5 * dq @ mass_textbook(arm, q) @ dq
            total = energy(q, dq, arm.weights, arm.gravity_coef)
            assert total == pytest.approx(kinetic + potential, rel=1e-12, abs=1e-10)


@pytest.mark.parametrize(
    ("arm", "q0", "measured"),
    [
        pytest.param(TWO_LINK_PAPER, [0.9, -0.7], 1.2e-8, id="two_link_paper"),
        pytest.param(THREE_LINK, [0.5, -0.4, 0.6], 1.8e-7, id="three_link"),
    ],
)
def test_energy_conserved_without_torque(arm: ArmModel, q0: list[float], measured: float) -> None:
    """τ = 0 (PID with zero gains), F = τ_d = 0: RK4 at 1 ms keeps the total energy over 10 s.

    Drift is measured relative to the largest kinetic energy of the run (the energy swing); the
    measured values (``measured``) are RK4 truncation, far below the 1e-6 bound.
    """
    n = arm.n
    sim = Simulator(Plant.build(arm), "pid", np.zeros(3 * n), q0=q0, seed=0)
    rows = sim.advance(np.zeros(n), 10_001, log=True)
    assert rows is not None and not sim.diverged
    assert np.all(rows[:, 1 + 4 * n : 1 + 5 * n] == 0.0)  # τ is exactly zero
    q = rows[:, 1 : 1 + n]
    dq = rows[:, 1 + 2 * n : 1 + 3 * n]
    total = np.array(
        [energy(a, b, arm.weights, arm.gravity_coef) for a, b in zip(q, dq, strict=True)]
    )
    zero = np.zeros(n)
    potential = np.array([energy(a, zero, arm.weights, arm.gravity_coef) for a in q])
    swing = (total - potential).max()
    assert swing > 100.0  # the arm really swings (hundreds of joules)
    drift = np.abs(total - total[0]).max() / swing
    assert drift < 1e-6
    assert drift < 10 * measured


@pytest.mark.parametrize("arm", ARMS)
def test_tip_position_and_jacobian(arm: ArmModel) -> None:
    n = arm.n
    lengths = arm.lengths_array
    qs, _ = random_states(n, 50, seed=5)
    h = 1e-6
    for q in qs:
        theta = np.cumsum(q)
        x, y = tip_position(q, lengths)
        assert x == pytest.approx(float(np.dot(lengths, np.cos(theta))), abs=1e-14)
        assert y == pytest.approx(float(np.dot(lengths, np.sin(theta))), abs=1e-14)
        jac = tip_jacobian(q, lengths)
        assert jac.shape == (2, n)
        for k in range(n):
            e = np.zeros(n)
            e[k] = h
            hi = np.array(tip_position(q + e, lengths))
            lo = np.array(tip_position(q - e, lengths))
            np.testing.assert_allclose(jac[:, k], (hi - lo) / (2 * h), rtol=0, atol=1e-8)
