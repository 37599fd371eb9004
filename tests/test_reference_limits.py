"""The reference generator (ramp | hold), actuator limits and the PID's anti-windup
(docs/design.md §4)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from armexp.sim.controllers import ADAPTIVE, PAPER_GAINS, PID, gain_vector
from armexp.sim.model import THREE_LINK, TWO_LINK_PAPER, ArmModel, Plant, Uncertainty
from armexp.sim.simulator import Simulator
from armexp.sim.trajectory import trajectory_columns

DATA = Path(__file__).parent / "data"
HOLD = 30
DT = 1e-3
PID_GAINS = gain_vector(PID, {"kp": [1e5, 1e4], "ki": [1e5, 1e4], "kd": [4e3, 4e2]}, 2)


def _columns(rows: np.ndarray, n: int, name: str) -> np.ndarray:
    cols = trajectory_columns(n)
    return rows[:, [cols.index(f"{name}_{j}") for j in range(1, n + 1)]]


def _golden_cases() -> dict[str, tuple[Plant, str, np.ndarray]]:
    return {
        "two_link_adaptive": (
            Plant.build(TWO_LINK_PAPER, Uncertainty.paper()),
            "subsystem_adaptive",
            gain_vector(ADAPTIVE, PAPER_GAINS, 2),
        ),
        "two_link_pid": (Plant.build(TWO_LINK_PAPER, Uncertainty.paper()), "pid", PID_GAINS),
        "three_link_adaptive": (
            Plant.build(THREE_LINK),
            "subsystem_adaptive",
            gain_vector(ADAPTIVE, PAPER_GAINS, 3),
        ),
    }


@pytest.mark.parametrize("case", ["two_link_adaptive", "two_link_pid", "three_link_adaptive"])
def test_hold_reproduces_the_zero_order_hold_core_bit_for_bit(case: str) -> None:
    """``reference=hold`` gives exactly the trajectories of the core before the ramp existed
    (recorded from commit 8ee7c28 with the same plant, gains, commands and seed): the state,
    the reference and the torque bit for bit."""
    golden = np.load(DATA / "hold_reference_8ee7c28.npz")
    plant, controller, gains = _golden_cases()[case]
    n = plant.arm.n
    cmds = np.random.default_rng(11).uniform(-0.3, 0.3, (20, n))
    q0 = np.linspace(0.3, -0.2, n)
    sim = Simulator(plant, controller, gains, q0=q0 + 0.05, qd0=q0, seed=3, reference="hold")
    rows = np.concatenate([sim.advance(c, HOLD, log=True) for c in cmds])
    columns = trajectory_columns(n)[: 4 + 5 * n]
    tip = [columns.index("tip_x"), columns.index("tip_y")]
    state = [i for i in range(len(columns)) if i not in tip]
    assert np.array_equal(rows[:, state], golden[case][:, state])
    assert np.array_equal(sim.state, golden[case + "_state"])
    # The logged tip is computed from q after the step, outside the loop's state; how numba
    # inlines that helper can move it by an ulp from one compilation to the next.
    np.testing.assert_allclose(rows[:, tip], golden[case][:, tip], rtol=0, atol=1e-15)


def _ramp_run(n_cmd: int = 20) -> tuple[np.ndarray, np.ndarray, Simulator]:
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    cmds = np.random.default_rng(4).uniform(-1, 1, (n_cmd, 2)) * [0.1, 0.4]
    sim = Simulator(plant, "subsystem_adaptive", gain_vector(ADAPTIVE, PAPER_GAINS, 2), [0.2, 1.0])
    rows = np.concatenate([sim.advance(c, HOLD, log=True) for c in cmds])
    return rows, cmds, sim


def test_ramp_bounds_the_reference_acceleration() -> None:
    """q̈_d never exceeds Δcommand / action period, and q̇_d has no jumps."""
    rows, cmds, _ = _ramp_run()
    dqd = _columns(rows, 2, "dq_d")
    prev = np.vstack([np.zeros((1, 2)), cmds[:-1]])
    slope = np.repeat(np.abs(cmds - prev) / (HOLD * DT), HOLD, axis=0)  # per step
    accel = np.abs(np.diff(dqd, axis=0)) / DT
    assert np.all(accel <= slope[:-1] * (1 + 1e-9) + 1e-12)
    # Each period starts at the previous command and ends one step short of the new one.
    np.testing.assert_allclose(dqd[::HOLD], prev, atol=1e-15)
    np.testing.assert_allclose(dqd[HOLD - 1 :: HOLD], prev + (cmds - prev) * (HOLD - 1) / HOLD)
    # The hold reference jumps by the full command change in one step.
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    held = Simulator(plant, "pid", PID_GAINS, [0.2, 1.0], reference="hold")
    jumps = np.concatenate([held.advance(c, HOLD, log=True) for c in cmds])
    assert np.abs(np.diff(_columns(jumps, 2, "dq_d"), axis=0)).max() / DT > 10 * accel.max()


def test_ramp_reference_is_the_exact_integral() -> None:
    """q_d integrates the piecewise-linear q̇_d exactly: per step the trapezoid, per period
    q_d advances by period · (previous + new command) / 2."""
    rows, cmds, sim = _ramp_run()
    qd = _columns(rows, 2, "q_d")
    dqd = _columns(rows, 2, "dq_d")
    step_end = np.vstack([dqd[1:], cmds[-1:]])
    np.testing.assert_allclose(
        np.diff(qd, axis=0), DT * 0.5 * (dqd[:-1] + step_end[:-1]), atol=1e-15
    )
    prev = np.vstack([np.zeros((1, 2)), cmds[:-1]])
    closed_form = qd[0] + np.cumsum(HOLD * DT * 0.5 * (prev + cmds), axis=0)
    np.testing.assert_allclose(qd[HOLD::HOLD], closed_form[:-1], atol=1e-13)
    np.testing.assert_allclose(sim.q_d, closed_form[-1], atol=1e-13)


@pytest.mark.parametrize("arm", [TWO_LINK_PAPER, THREE_LINK], ids=["two_link", "three_link"])
@pytest.mark.parametrize("controller", ["subsystem_adaptive", "pid"])
def test_plant_never_receives_more_than_the_limit(arm: ArmModel, controller: str) -> None:
    n = arm.n
    limit = np.array([650.0, 150.0] if n == 2 else [500.0, 150.0, 50.0])
    plant = Plant.build(arm, torque_limit=limit)
    kind = ADAPTIVE if controller == "subsystem_adaptive" else PID
    gains = gain_vector(
        kind, PAPER_GAINS if kind == ADAPTIVE else {"kp": 1e4, "ki": 1e3, "kd": 50}, n
    )
    q = np.full(n, 0.3)
    sim = Simulator(plant, controller, gains, q0=q + 0.1, qd0=q, seed=1)
    rows = np.concatenate([sim.advance(c, HOLD, log=True) for c in np.full((30, n), 0.2)])
    tau = _columns(rows, n, "tau")
    sat = _columns(rows, n, "sat")
    assert np.all(np.abs(tau) <= limit)
    assert np.all((sat == 1.0) == (np.abs(tau) == limit))
    assert sat[:5].all()  # a 0.1 rad error at these gains asks for far more than the limit


def _pid_hold(limit: np.ndarray | None, offset: float) -> tuple[np.ndarray, np.ndarray]:
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper(), torque_limit=limit)
    gains = gain_vector(PID, {"kp": [2e4, 4e3], "ki": [2e5, 4e4], "kd": [2e3, 200.0]}, 2)
    q_d = np.array([0.5, 0.8])
    sim = Simulator(plant, "pid", gains, q0=q_d + offset, qd0=q_d, seed=0)
    rows = sim.advance([0.0, 0.0], 3000, log=True)
    assert rows is not None and not sim.diverged
    e = _columns(rows, 2, "q") - _columns(rows, 2, "q_d")
    return e, _columns(rows, 2, "sat")


def test_saturated_pid_hold_does_not_wind_up() -> None:
    """A PID held at the torque limit by a 0.2 rad offset overshoots no more than the same loop
    without a limit (its integrator would otherwise collect the whole saturated error: without
    anti-windup these gains overshoot by 9× and 17× the offset)."""
    offset = 0.2
    e, sat = _pid_hold(np.array([650.0, 150.0]), offset)
    assert sat[:50].all(axis=0).all()  # both joints start saturated
    linear, linear_sat = _pid_hold(None, offset)
    assert not linear_sat.any()
    overshoot = np.maximum(0.0, -e / offset).max(axis=0)
    linear_overshoot = np.maximum(0.0, -linear / offset).max(axis=0)
    assert np.all(overshoot <= linear_overshoot + 0.05)
    assert np.abs(e[-1]).max() < 1e-3
