"""Core simulation checks: physics identities, reference equality, convergence, determinism."""

from __future__ import annotations

import numpy as np
import pytest

from armexp.sim import reference as ref
from armexp.sim.controllers import ADAPTIVE, PAPER_GAINS, PID, gain_vector
from armexp.sim.dynamics import energy
from armexp.sim.model import THREE_LINK, TWO_LINK_PAPER, Plant, Uncertainty
from armexp.sim.simulator import Simulator

PAPER = gain_vector(ADAPTIVE, PAPER_GAINS, 2)


def test_mass_matrix_symmetric_positive_definite_and_skew_property() -> None:
    rng = np.random.default_rng(0)
    for arm in (TWO_LINK_PAPER, THREE_LINK):
        plant = Plant.build(arm)
        for _ in range(200):
            q = rng.uniform(-np.pi, np.pi, arm.n)
            dq = rng.uniform(-2, 2, arm.n)
            m = ref.mass_matrix(plant, q)
            assert np.allclose(m, m.T, atol=1e-12)
            assert np.linalg.eigvalsh(m).min() > 0
            # Ṁ by central differences along q̇; C from Christoffel symbols of ∂M/∂q.
            h = 1e-6
            dm = np.stack(
                [
                    (ref.mass_matrix(plant, q + h * e) - ref.mass_matrix(plant, q - h * e))
                    / (2 * h)
                    for e in np.eye(arm.n)
                ]
            )  # dm[l] = ∂M/∂q_l
            c = 0.5 * (
                np.einsum("ljk,l->jk", dm, dq)
                + np.einsum("kjl,l->jk", dm, dq)
                - np.einsum("jkl,l->jk", dm, dq)
            )
            mdot = np.einsum("ljk,l->jk", dm, dq)
            s = mdot - 2 * c
            assert np.allclose(s, -s.T, atol=1e-6 * np.abs(m).max())
            g = ref.bias(plant, q, np.zeros(arm.n))
            assert np.allclose(c @ dq + g, ref.bias(plant, q, dq), atol=1e-5 * np.abs(m).max())


def test_energy_is_conserved_without_torque_and_uncertainty() -> None:
    for arm, q0 in ((TWO_LINK_PAPER, [0.3, -0.5]), (THREE_LINK, [0.3, -0.5, 0.8])):
        plant = Plant.build(arm, Uncertainty.off(arm.n))
        sim = Simulator(plant, "pid", np.zeros(3 * arm.n), q0=q0, seed=0)  # τ ≡ 0
        e = [energy(sim.q, sim.dq, arm.weights, arm.gravity_coef)]
        kinetic = []
        for _ in range(1000):  # 10 s
            sim.advance(np.zeros(arm.n), 10)
            e.append(energy(sim.q, sim.dq, arm.weights, arm.gravity_coef))
            kinetic.append(e[-1] - energy(sim.q, np.zeros(arm.n), arm.weights, arm.gravity_coef))
        drift = np.abs(np.array(e) - e[0]).max() / max(kinetic)
        assert drift < 1e-6, drift
        assert max(kinetic) > 10.0  # the arm really swung


def _commands(rng: np.random.Generator, bound: np.ndarray, steps: int) -> np.ndarray:
    return np.repeat(rng.uniform(-1, 1, (steps // 30 + 1, bound.size)) * bound, 30, axis=0)[:steps]


@pytest.mark.long
def test_compiled_core_equals_numpy_reference() -> None:
    rng = np.random.default_rng(1)
    cases = [
        (Plant.build(TWO_LINK_PAPER, Uncertainty.paper()), ADAPTIVE, PAPER),
        (
            Plant.build(TWO_LINK_PAPER, Uncertainty.paper()),
            PID,
            gain_vector(PID, {"kp": [1e5, 1e4], "ki": [1e5, 1e4], "kd": [4e3, 4e2]}, 2),
        ),
        (Plant.build(THREE_LINK), ADAPTIVE, PAPER),
    ]
    for plant, kind, gains in cases:
        n = plant.arm.n
        cmds = _commands(rng, np.full(n, 0.3), 1000)
        q0 = rng.uniform(-0.5, 0.5, n)
        sim = Simulator(
            plant,
            "pid" if kind == PID else "subsystem_adaptive",
            gains,
            q0=q0 + 0.05,
            qd0=q0,
            seed=5,
            reference="hold",
        )
        states = []
        for k in range(1000):
            sim.advance(cmds[k], 1)
            states.append(sim.state.copy())
        expected = ref.simulate(plant, kind, gains, q0 + 0.05, q0, cmds, 5)
        assert np.abs(np.array(states) - expected).max() < 1e-9


def test_uniform_exponential_convergence_with_paper_gains() -> None:
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    sim = Simulator(plant, "subsystem_adaptive", PAPER, q0=[0.05, 1.62], qd0=[0.0, 1.57], seed=0)
    rows = sim.advance([0.0, 0.0], 2000, log=True)
    assert rows is not None
    err = np.linalg.norm(rows[:, 1:3] - rows[:, 3:5], axis=1)
    t = rows[:, 0]
    assert err[t <= 0.1].min() < err[0] / 100
    assert err[t >= 0.1].max() < 1e-3  # stays in a small band through 2 s
    # envelope ‖e(t)‖ ≤ ᾱ e^{−α t} ‖e(0)‖ + α* with α = 40 /s, ᾱ = 1.5, α* = 1e-3
    assert np.all(err <= 1.5 * np.exp(-40 * t) * err[0] + 1e-3)


def test_seed_determinism_and_chunking() -> None:
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    cmds = _commands(np.random.default_rng(2), np.array([0.1, 0.4]), 600)

    def run(seed: int, chunk: int) -> np.ndarray:
        sim = Simulator(
            plant, "subsystem_adaptive", PAPER, q0=[0.1, 1.0], seed=seed, reference="hold"
        )
        out = []
        for k in range(0, 600, chunk):
            rows = sim.advance(cmds[k], chunk, log=True)
            assert rows is not None
            out.append(rows)
        return np.concatenate(out)

    a, b = run(3, 30), run(3, 30)
    assert np.array_equal(a, b)
    c = run(4, 30)
    assert not np.array_equal(a, c)
    one = Simulator(plant, "subsystem_adaptive", PAPER, q0=[0.1, 1.0], seed=3, reference="hold")
    for k in range(600):  # the same commands, one controller step per call
        one.advance(cmds[k - k % 30], 1)
    last = a[-1]
    stepped = np.concatenate([one.q, one.q_d, one.dq])
    chunked = Simulator(plant, "subsystem_adaptive", PAPER, q0=[0.1, 1.0], seed=3, reference="hold")
    for k in range(0, 600, 30):
        chunked.advance(cmds[k], 30)
    assert np.array_equal(np.concatenate([chunked.q, chunked.q_d, chunked.dq]), stepped)
    assert last[0] == 0.599
