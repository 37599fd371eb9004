"""The sampled-loop stability constraint of the tuner (docs/design.md §5) against the compiled
loop."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from omegaconf import DictConfig

from armexp.builders import build_plant
from armexp.cli import main
from armexp.sim.controllers import ADAPTIVE, COMPUTED_TORQUE, PAPER_GAINS, PID, gain_vector
from armexp.sim.model import TWO_LINK_PAPER, Plant, Uncertainty
from armexp.sim.simulator import Simulator
from armexp.sim.trajectory import trajectory_columns
from armexp.stages.tune import build_objective
from armexp.tune import stability
from tests.helpers import SMALL_TUNE, stage_runs

#: Gains the paper-budget CSO found before the constraint existed (Kp, Ki, Kd per joint).
OLD_PID = np.array([5.2e5, 2.0e5, 0.0, 0.0, 8415.0, 1247.0])
LOWER = np.array([-np.pi / 4, -5 * np.pi / 6])
UPPER = np.array([3 * np.pi / 4, 5 * np.pi / 6])


def _plant(limit: np.ndarray | None = None) -> Plant:
    return Plant.build(TWO_LINK_PAPER, Uncertainty.paper(), torque_limit=limit)


def _hold(
    plant: Plant, controller: str, gains: np.ndarray, pose: np.ndarray, rho0: float = 0.0
) -> np.ndarray:
    """0.5 s regulating a 5 mrad offset at ``pose`` (ρ̂ starting at ``rho0``); the logged rows."""
    sim = Simulator(plant, controller, gains, q0=pose + 0.005, qd0=pose, seed=0)
    sim.state[4 * sim.n] = rho0
    rows = sim.advance(np.zeros(2), 500, log=True)
    assert rows is not None
    return rows


def _tau(rows: np.ndarray) -> np.ndarray:
    cols = trajectory_columns(2)
    return rows[:, [cols.index("tau_1"), cols.index("tau_2")]]


def _chatters(tau: np.ndarray) -> bool:
    """τ alternates in sign from step to step over most of the last 100 ms."""
    late = tau[-100:]
    flips = (np.sign(late[1:]) * np.sign(late[:-1]) < 0).mean(axis=0)
    return bool(flips.max() > 0.5)


def test_pose_grid_spans_the_ranges_and_includes_the_straight_arm() -> None:
    grid = stability.pose_grid(LOWER, UPPER, 9)
    assert grid.shape == (9, 2)
    assert np.allclose(grid[:, 0], (LOWER[0] + UPPER[0]) / 2)
    assert grid[:, 1].min() == LOWER[1] and grid[:, 1].max() == UPPER[1]
    assert (grid[:, 1] == 0.0).any()
    # An even number of points would miss 0; it is added.
    assert (stability.pose_grid(LOWER, UPPER, 4)[:, 1] == 0.0).any()


def test_prediction_agrees_with_the_compiled_loop() -> None:
    """Where the linearised sampled loop has spectral radius > 1 the compiled loop chatters and
    grows; where it is < 1 a small offset settles."""
    plant = _plant()
    poses = np.array([[0.5, q2] for q2 in (0.0, 0.05, 0.3, 1.0, 2.0)])
    lin = stability.linearise(plant, poses)
    radius = stability.spectral_radius(PID, OLD_PID, lin)[0]
    assert (radius > 1).any() and (radius < 1).any()  # both verdicts are exercised
    for pose, r in zip(poses, radius, strict=True):
        tau = _tau(_hold(plant, "pid", OLD_PID, pose))
        if r > 1.0:
            assert _chatters(tau), pose
            assert np.abs(tau[-50:]).max() > 10 * np.abs(tau[50:100]).max(), pose
        else:
            assert not _chatters(tau), pose
            assert np.abs(tau[-50:]).max() < 2 * 9.81 * 35, pose  # about the gravity load
    # The paper's adaptive gains: stable everywhere, and the compiled loop settles everywhere.
    adaptive = gain_vector(ADAPTIVE, PAPER_GAINS, 2)
    assert (stability.spectral_radius(ADAPTIVE, adaptive, lin) < 1).all()
    for pose in poses:
        assert not _chatters(_tau(_hold(plant, "subsystem_adaptive", adaptive, pose)))


def _agrees(plant: Plant, controller: str, gains: np.ndarray, pose: np.ndarray, r: float,
            rho0: float = 0.0) -> None:  # fmt: skip
    rows = _hold(plant, controller, gains, pose, rho0)
    tau = _tau(rows)
    if r > 1.0:  # diverged within the 0.5 s, or chatters and grows
        grows = len(rows) < 500 or (
            _chatters(tau) and np.abs(tau[-50:]).max() > 10 * np.abs(tau[50:100]).max()
        )
        assert grows, (gains, pose)
    else:
        assert len(rows) == 500 and not _chatters(tau), (gains, pose)


def test_computed_torque_prediction_agrees_with_the_compiled_loop() -> None:
    """The computed-torque law acts through M(q), so its sampled loop is nearly the same at every
    pose: a derivative gain past the 1 kHz limit chatters everywhere, one below settles."""
    plant = _plant()
    poses = np.array([[0.5, q2] for q2 in (0.0, 0.3, 2.0)])
    lin = stability.linearise(plant, poses)
    soft = np.array([1e4, 1e4, 1e5, 1e5, 1500.0, 1500.0])
    hard = np.array([1e4, 1e4, 1e5, 1e5, 2500.0, 2500.0])
    radius = stability.spectral_radius(COMPUTED_TORQUE, np.stack([soft, hard]), lin)
    assert (radius[0] < 1).all() and (radius[1] > 1).all()
    for gains, radii in ((soft, radius[0]), (hard, radius[1])):
        for pose, r in zip(poses, radii, strict=True):
            _agrees(plant, "computed_torque", gains, pose, float(r))


def test_adaptive_term_prediction_agrees_with_the_compiled_loop() -> None:
    """The adaptive law frozen at σ = b1 ρ̂ > 0: gains stable at ρ̂ = 0 become unstable once
    a1 + σ passes the sampling limit, and the compiled loop started at that ρ̂ (with λ and γ so
    small that ρ̂ stays put) chatters and grows; at a smaller σ it settles."""
    plant = _plant()
    poses = np.array([[0.5, 0.0], [0.5, 1.0]])
    lin = stability.linearise(plant, poses)
    gains = np.array([50.0, 2000.0, 1.0, 1e-9, 1.0])  # λ = γ = 1e-9
    assert (stability.spectral_radius(ADAPTIVE, gains, lin) < 1).all()
    for sigma in (1000.0, 3000.0):
        radius = stability.spectral_radius(ADAPTIVE, gains, lin, sigma=np.array([sigma]))[0]
        assert (radius > 1).all() if sigma == 3000.0 else (radius < 1).all()
        for pose, r in zip(poses, radius, strict=True):
            _agrees(plant, "subsystem_adaptive", gains, pose, float(r), rho0=sigma / gains[2])
    # The margin shrinks with σ, and b1 = 0 (no adaptation) has the loop of σ = 0.
    assert stability.gain_margin(ADAPTIVE, gains, lin, sigma=1000.0) < stability.gain_margin(
        ADAPTIVE, gains, lin
    )


def test_gain_margin_and_integrators_without_gain() -> None:
    plant = _plant()
    lin = stability.linearise(plant, stability.pose_grid(LOWER, UPPER, 9))
    assert stability.gain_margin(PID, OLD_PID, lin) == 0.0  # unstable at the straight arm
    soft = np.array([1e5, 1e4, 0.0, 0.0, 2000.0, 200.0])
    margin = stability.gain_margin(PID, soft, lin)
    assert 2.0 < margin < 10.0
    assert stability.stable_with_margin(PID, soft, lin, 0.99 * margin)[0]
    assert not stability.stable_with_margin(PID, soft, lin, 1.01 * margin)[0]
    # ki = 0 leaves the integrator out (it would add an eigenvalue of exactly 1)...
    assert stability.spectral_radius(PID, soft, lin).max() < 1.0
    # ...and a small integral gain keeps the loop stable.
    with_i = soft.copy()
    with_i[2:4] = [1e3, 1e2]
    assert stability.spectral_radius(PID, with_i, lin).max() < 1.0


@pytest.mark.long
def test_objective_rejects_gains_the_scenarios_alone_accept(
    compose: Callable[..., DictConfig],
) -> None:
    small = ["tuner.objective.n_scenarios=2", "tuner.objective.horizon=0.2", "controller=pid"]
    blind = build_objective(compose(*small, "tuner.objective.gain_margin=null"))
    assert np.isfinite(blind(OLD_PID[None])[0])
    constrained = build_objective(compose(*small))
    assert constrained.settings.gain_margin == 1.25
    assert not constrained.stable(OLD_PID[None])[0]
    assert constrained(OLD_PID[None])[0] == np.inf


@pytest.mark.long
def test_tuned_pid_holds_every_grid_pose_and_the_near_straight_arm(
    runs_dir: Path, compose: Callable[..., DictConfig]
) -> None:
    """A small-budget PID tune finds feasible gains (the box fits the constraint), and they hold
    q0 = [0.5, 0.05] and every pose of the grid without chatter, within the torque limit."""
    where = f"tracking.runs_dir={runs_dir}"
    assert main(["tune", "controller=pid", *SMALL_TUNE, where]) == 0
    run = stage_runs(runs_dir, "tune")[0]
    assert run.data.metrics["best_gain_margin"] >= 1.25
    assert run.data.metrics["best_peak_torque"] <= 800.0  # the joint-1 limit
    assert "armexp.gains_on_bound" in run.data.tags
    names = [f"{g}_{j}" for g in ("kp", "ki", "kd") for j in (1, 2)]
    gains = np.array([float(run.data.params[f"tuned.{k}"]) for k in names])
    cfg = compose("controller=pid")
    plant = build_plant(cfg)
    limit = plant.torque_limit
    poses = [np.array([0.5, 0.05]), *stability.pose_grid(LOWER, UPPER, 9)]
    for pose in poses:
        tau = _tau(_hold(plant, "pid", gains, pose))
        assert not _chatters(tau), pose
        assert np.all(np.abs(tau) <= limit)


def test_no_feasible_candidate_is_one_sentence(runs_dir: Path) -> None:
    code = main(
        ["tune", "controller=pid", *SMALL_TUNE, f"tracking.runs_dir={runs_dir}",
         "controller.bounds.kd_1=[20000.0,50000.0]"]
    )  # fmt: skip
    assert code == 2
    run = stage_runs(runs_dir, "tune")[0]
    assert run.info.status == "FAILED"


@pytest.mark.parametrize(
    ("override", "words"),
    [
        ("tuner.objective.gain_margin=0.9", ["tuner.objective.gain_margin=0.9", "≥ 1"]),
        ("robot.torque_limit=[0.0,150.0]", ["robot.torque_limit[0]=0.0", "> 0"]),
        ("env.reference=smooth", ["env.reference='smooth'", "ramp, hold"]),
        ("eval.initial_offset=3.5", ["eval.initial_offset=3.5", "joint range"]),
    ],
)
def test_bad_constraint_values_are_one_sentence(
    override: str, words: list[str], capsys: pytest.CaptureFixture[str], runs_dir: Path
) -> None:
    assert main(["tune", override, f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    for w in words:
        assert w in err, (w, err)
