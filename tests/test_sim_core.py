"""The compiled closed loop (`armexp.sim.simulator` and the modules it runs): against the numpy
reference, and its contracts."""

from __future__ import annotations

import math

import numpy as np
import pytest

from armexp.sim import reference
from armexp.sim.angle_cache import ROTATE_MAX, series, turn
from armexp.sim.controllers import ADAPTIVE, KINDS, PAPER_GAINS, PID, gain_vector
from armexp.sim.dynamics import tip_position
from armexp.sim.generic_path import run_generic
from armexp.sim.model import THREE_LINK, TWO_LINK_PAPER, ArmModel, Plant, Uncertainty
from armexp.sim.noise import stream_key, uniform, uniform_numpy
from armexp.sim.simulator import Simulator, advance, simulate_batch
from armexp.sim.trajectory import trajectory_columns
from armexp.sim.two_link_path import run_two_link
from armexp.sim.work import make_work

HOLD = 30


def small_uncertainty() -> Uncertainty:
    """A three-link set of unknown terms touching every code path (q and q̇ sources, τ_d)."""
    f_terms = np.array(
        [
            [0, 0.3, 0.5, 1, 2],  # joint 1 += 0.3 cos(0.5 q̇3)
            [2, -0.4, 1.3, 0, 1],  # joint 3 += −0.4 cos(1.3 q2)
            [1, 0.2, 0.9, 0, 0],  # joint 2 += 0.2 cos(0.9 q1)
        ]
    )
    return Uncertainty(
        f_terms, np.array([1.0, 0.0, 0.5]), np.array([2.0, 0.0, 3.0]), np.array([0.0, -0.1, 0.2])
    )


def switching_commands(n: int, steps: int, seed: int, scale: float = 0.4) -> np.ndarray:
    rng = np.random.default_rng(seed)
    n_cmd = -(-steps // HOLD)
    return np.repeat(rng.uniform(-scale, scale, (n_cmd, n)), HOLD, axis=0)[:steps]


def compiled_states(sim: Simulator, commands: np.ndarray) -> np.ndarray:
    """State after every step, advancing one command block (30 steps) per call."""
    out = []
    for start in range(0, len(commands), HOLD):
        block = commands[start : start + HOLD]
        for cmd in block:
            sim.advance(cmd, 1)
            out.append(sim.state.copy())
    return np.array(out)


CASES = [
    pytest.param(
        TWO_LINK_PAPER, Uncertainty.paper(), "subsystem_adaptive", id="two_link-adaptive-paper"
    ),
    pytest.param(TWO_LINK_PAPER, Uncertainty.paper(), "pid", id="two_link-pid-paper"),
    pytest.param(
        THREE_LINK, Uncertainty.off(3), "subsystem_adaptive", id="three_link-adaptive-off"
    ),
    pytest.param(
        THREE_LINK, small_uncertainty(), "subsystem_adaptive", id="three_link-adaptive-custom"
    ),
    pytest.param(THREE_LINK, small_uncertainty(), "pid", id="three_link-pid-custom"),
    pytest.param(
        TWO_LINK_PAPER, Uncertainty.paper(), "computed_torque", id="two_link-computed_torque-paper"
    ),
    pytest.param(
        THREE_LINK, small_uncertainty(), "computed_torque", id="three_link-computed_torque-custom"
    ),
]


def controller_gains(controller: str, n: int) -> np.ndarray:
    if controller == "subsystem_adaptive":
        return gain_vector(ADAPTIVE, PAPER_GAINS, n)
    if controller == "computed_torque":  # M(q)-scaled: ω ≈ 40 rad/s
        return gain_vector(KINDS[controller], {"kp": 1600.0, "ki": 4000.0, "kd": 80.0}, n)
    return gain_vector(PID, {"kp": [900.0, 700.0, 400.0][:n], "ki": 60.0, "kd": 80.0}, n)


@pytest.mark.parametrize(("arm", "unc", "controller"), CASES)
def test_compiled_matches_reference(arm: ArmModel, unc: Uncertainty, controller: str) -> None:
    n = arm.n
    plant = Plant.build(arm, unc)
    gains = controller_gains(controller, n)
    qd0 = np.linspace(0.4, -0.3, n)
    q0 = qd0 + np.linspace(0.05, -0.04, n)
    commands = switching_commands(n, 1000, seed=n)
    sim = Simulator(plant, controller, gains, q0=q0, qd0=qd0, seed=5, reference="hold")
    got = compiled_states(sim, commands)
    want = reference.simulate(plant, KINDS[controller], gains, q0, qd0, commands, 5)
    assert np.isfinite(want).all()
    assert np.abs(got - want).max() < 1e-9
    assert sim.step_index == 1000 and sim.time == pytest.approx(1.0)


@pytest.mark.parametrize(("arm", "unc", "controller"), CASES)
def test_compiled_ramp_matches_reference(arm: ArmModel, unc: Uncertainty, controller: str) -> None:
    """The ramped reference (one command per 30-step call) against the numpy reference."""
    n = arm.n
    plant = Plant.build(arm, unc, torque_limit=np.full(n, 60.0))
    gains = controller_gains(controller, n)
    qd0 = np.linspace(0.4, -0.3, n)
    q0 = qd0 + np.linspace(0.05, -0.04, n)
    blocks = switching_commands(n, 1200, seed=n)[::HOLD]
    sim = Simulator(plant, controller, gains, q0=q0, qd0=qd0, seed=5)
    got = []
    for cmd in blocks:
        sim.advance(cmd, HOLD)
        got.append(sim.state.copy())
    want = reference.simulate(
        plant, KINDS[controller], gains, q0, qd0, blocks, 5, hold=HOLD, ramp=True
    )
    assert np.isfinite(want).all()
    assert np.abs(np.array(got) - want[HOLD - 1 :: HOLD]).max() < 1e-9


def test_two_link_fast_path_matches_generic_path() -> None:
    """The unrolled n = 2 loop and the generic n-link loop agree to rounding."""
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    model = plant.packed()
    key = np.uint64(stream_key(9))
    commands = np.random.default_rng(0).uniform(-0.4, 0.4, (40, 2))
    traces = []
    gains = controller_gains("subsystem_adaptive", 2)
    for run in (run_two_link, run_generic):
        state = np.zeros(9)
        state[:2] = [0.35, -0.25]
        state[4:6] = [0.3, -0.2]
        trace = np.empty((40 * HOLD, 4))
        done, diverged = run(
            state,
            commands,
            HOLD,
            0,
            ADAPTIVE,
            gains,
            model,
            plant.dt,
            key,
            make_work(2),
            np.zeros((0, 16)),
            trace,
            True,
        )
        assert (done, diverged) == (40 * HOLD, False)
        traces.append(trace)
    assert np.abs(traces[0][:, :2] - traces[1][:, :2]).max() < 1e-12  # e1
    tau = np.abs(traces[0][:, 2:]).max()
    assert np.abs(traces[0][:, 2:] - traces[1][:, 2:]).max() < 1e-12 * tau  # applied τ


def test_rows_beyond_the_cache_use_libm() -> None:
    """F rows past the work buffer's capacity are evaluated directly, with the same result."""
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    gains = controller_gains("subsystem_adaptive", 2)
    key = np.uint64(stream_key(3))
    finals = []
    for cap in (8, 1, 0):
        state = np.zeros(9)
        state[:2] = [0.05, 0.05]
        advance(
            state,
            np.array([0.1, -0.3]),
            0,
            500,
            ADAPTIVE,
            gains,
            plant.packed(),
            plant.dt,
            key,
            make_work(2, cap),
            np.zeros((0, 16)),
            True,
        )
        finals.append(state)
    assert np.abs(finals[0] - finals[1]).max() < 1e-12
    assert np.abs(finals[0] - finals[2]).max() < 1e-12


def test_angle_series_matches_libm() -> None:
    """The Taylor step from a cached angle is good to about two ulp (checked in long double)."""
    rng = np.random.default_rng(0)
    worst = 0.0
    for phi0, d in zip(
        rng.uniform(-10, 10, 4000), rng.uniform(-ROTATE_MAX, ROTATE_MAX, 4000), strict=True
    ):
        d = d * 10.0 ** rng.uniform(-4, 0)
        c, s = series(math.cos(phi0), math.sin(phi0), d)
        p0, dd = np.longdouble(phi0), np.longdouble(d)
        want_c = np.cos(p0) * np.cos(dd) - np.sin(p0) * np.sin(dd)
        want_s = np.sin(p0) * np.cos(dd) + np.cos(p0) * np.sin(dd)
        worst = max(worst, abs(float(c - want_c)), abs(float(s - want_s)))
    assert worst < 4.5e-16
    # Far from the cached angle (or with nothing cached) libm answers.
    assert turn(1.0, 0.5, math.cos(0.5), math.sin(0.5)) == (math.cos(1.0), math.sin(1.0))
    assert turn(1.0, math.nan, 0.0, 0.0) == (math.cos(1.0), math.sin(1.0))


def test_uniform_exponential_convergence() -> None:
    """Definition 1 with the paper's gains, F and τ_d on, q(0) = q_d(0) + 0.05 rad, q̇_d = 0.

    Measured: ‖e1‖ falls from 0.0707 to 2.3e-4 rad (≈300×) by 0.1 s and stays below 2.7e-4 rad
    through 2 s (the band set by F and τ_d); the envelope ‖e1(t)‖ ≤ 2 e^{−αt}‖e1(0)‖ + α* holds
    with α* = that band and α ≈ 159 s⁻¹.
    """
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    sim = Simulator(
        plant,
        "subsystem_adaptive",
        controller_gains("subsystem_adaptive", 2),
        q0=[0.05, 0.05],
        qd0=[0.0, 0.0],
        seed=0,
    )
    rows = sim.advance([0.0, 0.0], 2001, log=True)
    assert rows is not None and not sim.diverged
    t = rows[:, 0]
    e = np.linalg.norm(rows[:, 1:3] - rows[:, 3:5], axis=1)
    assert e[0] == pytest.approx(0.05 * math.sqrt(2))
    assert e[0] / e[100] >= 100.0  # 0.1 s
    band = e[t >= 0.1].max()
    assert band < 5e-4
    # Exponential envelope on the transient: the largest α for which ᾱ = 2 bounds every sample.
    bar = 2.0
    above = (e > band) & (t > 0)
    alpha = float(np.min(-np.log((e[above] - band) / (bar * e[0])) / t[above]))
    assert alpha > 100.0
    envelope = bar * np.exp(-alpha * t) * e[0] + band
    assert np.all(e <= envelope * (1 + 1e-12))


def test_seeds_chunking_and_reset() -> None:
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    gains = controller_gains("subsystem_adaptive", 2)
    cmds = np.random.default_rng(1).uniform(-0.4, 0.4, (100, 2))

    def run(seed: int, sim: Simulator | None = None) -> np.ndarray:
        if sim is None:
            sim = Simulator(
                plant, "subsystem_adaptive", gains, q0=[0.3, 0.1], qd0=[0.25, 0.0], seed=seed
            )
        else:
            sim.reset([0.3, 0.1], seed=seed, qd0=[0.25, 0.0])
        return np.concatenate([sim.advance(c, HOLD, log=True) for c in cmds])

    a = run(4)
    assert np.array_equal(a, run(4))  # same seed ⇒ bit-identical
    b = run(5)
    assert not np.array_equal(a, b)  # another seed ⇒ another trajectory
    steps = np.arange(3000)
    u4, u5 = uniform_numpy(4, steps, 2), uniform_numpy(5, steps, 2)
    assert np.abs(u4 - u5).max() > 0.5 and (u4 != u5).all()
    assert uniform(np.uint64(stream_key(4)), 1234, 1, 2) == u4[1234, 1]
    # A reused Simulator after reset equals a fresh one, bit for bit.
    sim = Simulator(plant, "subsystem_adaptive", gains, q0=[0.0, 0.0], seed=9)
    sim.advance([0.2, -0.1], 777)
    assert np.array_equal(run(4, sim=sim), a)

    # 30-step calls and one long call give bit-identical trajectories (anchoring crosses chunks).
    start = {"q0": [0.3, 0.1], "qd0": [0.25, 0.0], "seed": 4, "reference": "hold"}
    one = Simulator(plant, "subsystem_adaptive", gains, **start)  # type: ignore[arg-type]
    many = Simulator(plant, "subsystem_adaptive", gains, **start)  # type: ignore[arg-type]
    long_rows = one.advance([0.07, -0.3], 3000, log=True)
    short_rows = np.concatenate([many.advance([0.07, -0.3], HOLD, log=True) for _ in range(100)])
    assert np.array_equal(long_rows, short_rows)
    assert np.array_equal(one.state, many.state)
    assert one.step_index == many.step_index == 3000


def test_kernel_args_and_record_steps_drive_the_loop_like_advance() -> None:
    """A compiled kernel run on `Simulator.kernel_args` and accounted by `record_steps` leaves the
    simulator as `Simulator.advance` does, bit for bit, a divergence included."""
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    cmds = np.random.default_rng(3).uniform(-0.4, 0.4, (20, 2))
    no_log = np.zeros((0, len(trajectory_columns(2))))
    outcomes = []
    for gains in (controller_gains("subsystem_adaptive", 2), np.array([1e7, 1e7, 1.8, 1e-3, 0.69])):
        by_method, by_kernel = (
            Simulator(plant, "subsystem_adaptive", gains, q0=[0.3, 0.1], qd0=[0.25, 0.0], seed=2)
            for _ in range(2)
        )
        for cmd in cmds:
            by_method.advance(cmd, HOLD)
            if by_kernel.diverged:
                continue
            state, work, model, g, kind, dt, key, k0, ramp = by_kernel.kernel_args()
            done = advance(state, cmd, k0, HOLD, kind, g, model, dt, key, work, no_log, ramp)
            by_kernel.record_steps(done, HOLD)
        assert np.array_equal(by_method.state, by_kernel.state, equal_nan=True)
        assert np.array_equal(by_method.tau, by_kernel.tau, equal_nan=True)
        assert by_method.step_index == by_kernel.step_index
        assert by_method.diverged == by_kernel.diverged
        outcomes.append((by_kernel.diverged, by_kernel.step_index))
    assert outcomes[0] == (False, 20 * HOLD)
    assert outcomes[1][0] and outcomes[1][1] < 20 * HOLD


def test_simulate_batch_equals_sequential_runs() -> None:
    n = 2
    plant = Plant.build(TWO_LINK_PAPER, Uncertainty.paper())
    base = controller_gains("subsystem_adaptive", n)
    gains = np.stack(
        [base, base * [1.2, 0.8, 1.0, 2.0, 1.0], np.array([1e7, 1e7, 1.8, 1e-3, 0.69])]
    )
    rng = np.random.default_rng(2)
    n_scen, n_cmd = 3, 6
    q0 = rng.uniform(-0.5, 0.5, (n_scen, n))
    offset = rng.uniform(-0.05, 0.05, (n_scen, n))
    commands = rng.uniform(-0.4, 0.4, (n_scen, n_cmd, n))
    seeds = np.array([3, 1, 4])
    trace = np.zeros((3, n_scen, n_cmd * HOLD, 2 * n + 1))
    done = simulate_batch(
        ADAPTIVE, gains, q0, offset, commands, HOLD, plant.packed(), plant.dt, seeds, trace, True
    )
    err = trace[..., :n]
    total = n_cmd * HOLD
    assert (done[:2] == total).all()
    for c in range(2):
        for s in range(n_scen):
            sim = Simulator(
                plant,
                "subsystem_adaptive",
                gains[c],
                q0=q0[s] + offset[s],
                qd0=q0[s],
                seed=int(seeds[s]),
            )
            parts = []
            for cmd in commands[s]:
                rows = sim.advance(cmd, HOLD, log=True)
                parts.append(
                    np.hstack(
                        [rows[:, 1 : 1 + n] - rows[:, 1 + n : 1 + 2 * n],
                         rows[:, 1 + 4 * n : 1 + 5 * n], rows[:, 1 + 5 * n : 2 + 5 * n]]
                    )
                )  # fmt: skip
            assert np.abs(np.concatenate(parts) - trace[c, s]).max() <= 1e-12
    # The absurd candidate diverges: a NaN tail, fewer steps completed, no exception.
    assert (done[2] < total).all()
    for s in range(n_scen):
        assert np.isnan(err[2, s, done[2, s] :]).all()
        assert np.isfinite(err[2, s, : done[2, s]]).all()


def test_logged_rows_layout() -> None:
    for arm, unc in ((TWO_LINK_PAPER, Uncertainty.paper()), (THREE_LINK, small_uncertainty())):
        n = arm.n
        plant = Plant.build(arm, unc)
        sim = Simulator(
            plant,
            "subsystem_adaptive",
            controller_gains("subsystem_adaptive", n),
            q0=np.full(n, 0.2),
            qd0=np.full(n, 0.1),
            seed=2,
            reference="hold",
        )
        cmd = np.linspace(0.1, -0.2, n)
        q_before, qd_before, dq_before = sim.q.copy(), sim.q_d.copy(), sim.dq.copy()
        rows = sim.advance(cmd, 1, log=True)
        columns = trajectory_columns(n)
        assert rows is not None and rows.shape == (1, len(columns)) == (1, 4 + 6 * n)
        row = dict(zip(columns, rows[0], strict=True))
        assert row["t"] == 0.0
        for i in range(n):
            assert row[f"q_{i + 1}"] == q_before[i]
            assert row[f"q_d_{i + 1}"] == qd_before[i]
            assert row[f"dq_{i + 1}"] == dq_before[i]
            assert row[f"dq_d_{i + 1}"] == cmd[i]
            assert row[f"tau_{i + 1}"] == sim.tau[i]
            assert row[f"sat_{i + 1}"] == 0.0  # no torque limit
        assert np.any(sim.tau != 0.0)
        assert row["rho_hat"] == 0.0
        tip = tip_position(q_before, arm.lengths_array)
        assert abs(row["tip_x"] - tip[0]) <= 1e-15 and abs(row["tip_y"] - tip[1]) <= 1e-15
        more = sim.advance(cmd, 5, log=True)
        assert more is not None
        np.testing.assert_array_equal(more[:, 0], np.arange(1, 6) * plant.dt)
        assert more[-1, 1 + 4 * n] == sim.tau[0]
        x, y = tip_position(more[-1, 1 : 1 + n], arm.lengths_array)
        tip_x, tip_y = columns.index("tip_x"), columns.index("tip_y")
        assert abs(more[-1, tip_x] - x) <= 1e-15 and abs(more[-1, tip_y] - y) <= 1e-15
