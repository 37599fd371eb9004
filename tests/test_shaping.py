"""Potential-based shaping with the planner's time to go (armexp.agents.shaping, time_to_go)."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3.common.vec_env import DummyVecEnv, VecMonitor

from armexp.agents.demonstrations import demonstrate, planned_actions
from armexp.agents.shaping import ShapedRewards, TimeToGoPotential
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv, ReachSettings
from armexp.envs.workspace import breadth_first_times, fill_unreached, time_to_go

GAMMA = 0.995


@pytest.fixture(scope="module")
def settings() -> ReachSettings:
    return settings_from_config(compose_config(["controller.gains=paper"]))


@pytest.fixture(scope="module")
def potential(settings: ReachSettings) -> TimeToGoPotential:
    return TimeToGoPotential(settings, 30.0)


def test_time_to_go_is_the_least_time_from_the_start_to_any_goal_cell(
    settings: ReachSettings, potential: TimeToGoPotential
) -> None:
    grid, ws = potential.grid, ReachEnv(settings).workspace
    start = np.zeros(grid.free.shape, dtype=bool)
    start[grid.cell(settings.q0)] = True
    from_start = breadth_first_times(grid.free | start, start, grid.dt, grid.free.size)
    for index in np.random.default_rng(0).integers(len(ws), size=8):
        target = ws.points[index]
        to_go = time_to_go(grid, target, settings.reach_threshold)
        goal = np.linalg.norm(grid.tip - target, axis=-1) < settings.reach_threshold
        assert np.all(to_go[goal & grid.free] == 0.0)
        # Moves are symmetric: searching from the goal equals searching from the start.
        assert to_go[grid.cell(settings.q0)] == pytest.approx(from_start[goal].min())
        assert to_go[grid.cell(settings.q0)] <= ws.times[index] + 1e-9


def test_filled_times_are_finite_and_grow_one_cell_at_a_time() -> None:
    times = np.full((6, 5), np.inf)
    times[0, 0] = 0.0
    times[5, 4] = 1.0
    filled = fill_unreached(times, 0.5)
    assert np.isfinite(filled).all() and filled[0, 0] == 0.0 and filled[5, 4] == 1.0
    assert filled[2, 1] == 1.0  # two Chebyshev moves from (0, 0)
    assert filled[4, 4] == 1.5  # one move from (5, 4) beats four from (0, 0)
    # A finite time is never shortened by a path through filled cells, and a filled cell gets
    # its least time even where a dearer finite cell is nearer.
    line = fill_unreached(np.array([[0.0, np.inf, np.inf, np.inf, np.inf, np.inf, 9.0]]), 0.5)
    np.testing.assert_array_equal(line, [[0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 9.0]])


def test_a_dearer_inside_makes_the_time_grow_faster_with_depth_into_the_margin(
    settings: ReachSettings,
) -> None:
    cheap_potential = TimeToGoPotential(settings, 1.0)
    target = ReachEnv(settings).workspace.points[0]
    cheap = cheap_potential.times(target)
    dear = TimeToGoPotential(settings, 1.0, inside_cost=10.0).times(target)
    grid = cheap_potential.grid
    free = np.isfinite(time_to_go(grid, target, settings.reach_threshold))
    assert (~free).any()
    np.testing.assert_array_equal(dear[free], cheap[free])
    # A filled cell d ≥ 1 moves from free cell f: dear = T_f + 10·d·dt ≥ cheap + 9·d·dt.
    assert np.all(dear[~free] - cheap[~free] >= 9 * grid.dt - 1e-9)


def _shaped_episode(
    settings: ReachSettings, potential: TimeToGoPotential, index: int
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray], dict]:
    env = ReachEnv(settings)
    venv = ShapedRewards(VecMonitor(DummyVecEnv([lambda: env])), potential, GAMMA)
    venv.seed(11)
    venv.set_options({"target": env.workspace.points[index]})
    obs = [venv.reset()[0]]
    actions = planned_actions(env, env.workspace.configs[index])
    shaped, table_i = [], []
    for action in actions:
        o, r, done, infos = venv.step(action[None])
        shaped.append(float(r[0]))
        table_i.append(infos[0]["table_i_reward"])
        if done[0]:
            return np.array(shaped), np.array(table_i), obs, infos[0]
        obs.append(o[0])
    raise AssertionError("the planned episode did not end")


def test_shaping_changes_a_return_by_the_start_potential_only(
    settings: ReachSettings, potential: TimeToGoPotential
) -> None:
    index = 123
    shaped, table_i, obs, info = _shaped_episode(settings, potential, index)
    assert info["reason"] == "reached" and table_i[-1] == settings.reach_reward
    discount = GAMMA ** np.arange(len(shaped))
    # Telescoping (Ng et al., 1999): Σ γᵗ r'ₜ = Σ γᵗ rₜ − Φ(s₀), with Φ(terminal) = 0.
    assert discount @ shaped == pytest.approx(discount @ table_i - potential(obs[0]), rel=1e-5)
    # The monitor below the wrapper still reports Table I's return.
    assert info["episode"]["r"] == pytest.approx(table_i.sum(), abs=1e-3)
    # Along the planner's path the time to go falls at about the action period per step.
    times = np.array([potential.time(o) for o in obs])
    assert times[0] == pytest.approx(ReachEnv(settings).workspace.times[index], abs=0.5)
    assert np.mean(np.diff(times[:-30])) == pytest.approx(-settings.action_period, rel=0.25)


def test_shaped_demonstrations_equal_the_wrapper_rewards(
    settings: ReachSettings, potential: TimeToGoPotential
) -> None:
    shaped, _, _, _ = _shaped_episode(settings, potential, 123)
    demo = potential.shape(demonstrate(ReachEnv(settings), 123, seed=11), GAMMA)
    assert np.allclose(demo.rewards, shaped, atol=1e-4)
