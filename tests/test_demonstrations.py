"""Planner demonstrations (armexp.agents.demonstrations, armexp.envs.workspace.shortest_path)."""

from __future__ import annotations

import numpy as np
import pytest

from armexp.agents.demonstrations import (
    demonstrate,
    demonstrations,
    fill_replay,
    planned_actions,
)
from armexp.agents.sac import build_sac
from armexp.agents.vec import make_vec_env
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.geometry import clearance, tips
from armexp.envs.reach import ReachEnv, ReachSettings


@pytest.fixture(scope="module")
def settings() -> ReachSettings:
    return settings_from_config(compose_config(["controller.gains=paper"]))


@pytest.fixture(scope="module")
def env(settings: ReachSettings) -> ReachEnv:
    return ReachEnv(settings)


def test_shortest_path_is_a_clear_velocity_bounded_least_time_path(
    settings: ReachSettings, env: ReachEnv
) -> None:
    ws = env.workspace
    rng = np.random.default_rng(0)
    for index in rng.integers(len(ws), size=25):
        cells, cell_time = settings.shortest_path(ws.configs[index])
        moves = np.abs(np.diff(cells, axis=0)) / (settings.velocity_bound * cell_time)
        assert np.all(moves <= 1 + 1e-9)  # one cell per joint per time cell at most
        assert np.allclose(cells[0], settings.q0, atol=settings.velocity_bound * cell_time)
        assert np.allclose(cells[-1], ws.configs[index])
        assert (len(cells) - 1) * cell_time == pytest.approx(ws.times[index])
        clear = clearance(tips(cells, settings.plant.arm.lengths_array), settings.obstacles)
        assert np.all(clear[1:] > settings.path_margin)


def test_planned_actions_are_bounded_and_bring_the_reference_to_the_target(
    settings: ReachSettings, env: ReachEnv
) -> None:
    config = env.workspace.configs[7]
    actions = planned_actions(env, config)
    assert np.all(np.abs(actions) <= 1.0)
    qd = settings.q0 + (actions * settings.velocity_bound * settings.action_period).sum(axis=0)
    assert np.allclose(qd, config, atol=1e-9)


def test_planner_demonstrations_reach_their_targets(env: ReachEnv) -> None:
    rng = np.random.default_rng(1)
    demos = [demonstrate(env, int(rng.integers(len(env.workspace))), i) for i in range(30)]
    assert sum(d.reason == "reached" for d in demos) >= 27
    reached = next(d for d in demos if d.reason == "reached")
    assert reached.rewards[-1] == env.settings.reach_reward and reached.terminated[-1]
    assert not reached.terminated[:-1].any()


def test_fill_replay_stores_whole_episodes_column_by_column(
    settings: ReachSettings, env: ReachEnv
) -> None:
    agent = compose_config(["agent=sac_quick", "agent.n_envs=3", "agent.buffer_size=20000"]).agent
    venv = make_vec_env(settings, 3, "dummy", 0)
    model = build_sac(agent, venv, 0)
    demos = demonstrations(env, 9, seed=4)
    fill_replay(model, demos)
    buffer = model.replay_buffer
    assert buffer is not None
    length = buffer.pos
    assert 0 < length <= sum(map(len, demos)) // 3 + 1
    dones, timeouts = buffer.dones[:length], buffer.timeouts[:length]
    assert np.all(dones[-1] == 1.0)  # every column ends on an episode boundary
    # Terminal steps are the demonstrations' own endings; cuts are time-limit ends.
    terminal = (dones == 1) & (timeouts == 0)
    assert np.all(np.isin(buffer.rewards[:length][terminal], [200.0, -50.0, -100.0]))
    assert np.all(buffer.rewards[:length][(dones == 1) & (timeouts == 1)] > -50.0)
    # The stored observations follow one another inside an episode.
    inside = dones[:-1] == 0
    after, before = buffer.next_observations[: length - 1], buffer.observations[1:length]
    assert np.allclose(after[inside], before[inside])
    venv.close()
