"""armexp/Reach-v0: gymnasium's contract, Table I's rewards and terminations, the workspace."""

from __future__ import annotations

import dataclasses
import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import armexp  # noqa: F401  (registers the environment)
from armexp.config import compose_config
from armexp.envs import ENV_ID
from armexp.envs.factory import settings_from_config
from armexp.envs.geometry import clearance, segment_hits, tips
from armexp.envs.observation import OFFSET
from armexp.envs.reach import ReachEnv, ReachSettings
from armexp.envs.workspace import build_workspace
from armexp.sim.trajectory import trajectory_columns


@pytest.fixture(scope="module")
def paper_settings() -> ReachSettings:
    return settings_from_config(compose_config([]))


def _with(settings: ReachSettings, **changes: Any) -> ReachEnv:
    return ReachEnv(dataclasses.replace(settings, **changes))


# ------------------------------------------------------------------------------ gym contract
@pytest.mark.long
@pytest.mark.parametrize("robot", ["two_link_paper", "three_link"])
@pytest.mark.parametrize("obstacles", ["paper_five", "none"])
def test_check_env_passes(robot: str, obstacles: str) -> None:
    env = gym.make(ENV_ID, overrides=[f"robot={robot}", f"obstacles={obstacles}"])
    check_env(env.unwrapped, skip_render_check=False)
    n = 2 if robot == "two_link_paper" else 3
    m = 5 if obstacles == "paper_five" else 0
    assert env.observation_space.shape == (6 + n + m,)
    assert env.action_space.shape == (n,)


def test_reset_with_seed_is_deterministic(paper_settings: ReachSettings) -> None:
    def episode(seed: int) -> tuple[np.ndarray, list[np.ndarray], list[float]]:
        env = ReachEnv(paper_settings)
        obs, _ = env.reset(seed=seed)
        env.action_space.seed(seed)
        seen, rewards = [obs], []
        for _ in range(40):
            obs, r, *_ = env.step(env.action_space.sample())
            seen.append(obs)
            rewards.append(r)
        return env.target, seen, rewards

    t1, o1, r1 = episode(3)
    t2, o2, r2 = episode(3)
    t3, _, _ = episode(4)
    np.testing.assert_array_equal(t1, t2)
    np.testing.assert_array_equal(np.array(o1), np.array(o2))
    assert r1 == r2
    assert not np.array_equal(t1, t3)


def test_same_initial_state_every_episode(paper_settings: ReachSettings) -> None:
    env = ReachEnv(paper_settings)
    first, _ = env.reset(seed=0)
    for seed in (1, 2):
        obs, _ = env.reset(seed=seed)
        np.testing.assert_allclose(env.layout.q(obs), env.layout.q(first))
        np.testing.assert_allclose(env.layout.tip(obs), env.layout.tip(first))
    np.testing.assert_allclose(env.layout.tip(first), [1.0, 0.8], atol=1e-12)


def test_observation_is_eq_5a(paper_settings: ReachSettings) -> None:
    env = ReachEnv(paper_settings)
    obs, _ = env.reset(seed=0, options={"target": (0.5, -0.5)})
    obs, *_ = env.step(np.array([0.5, -0.5], dtype=np.float32))
    tip = tips(env.sim.q.copy(), env.settings.plant.arm.lengths_array)
    layout = env.layout
    assert (layout.joints, layout.clearances, layout.size) == (slice(6, 8), slice(8, 13), 13)
    np.testing.assert_allclose(layout.target(obs), [0.5, -0.5], atol=1e-6)
    np.testing.assert_allclose(obs[OFFSET], tip - [0.5, -0.5], atol=1e-6)
    np.testing.assert_allclose(layout.tip(obs), tip, atol=1e-6)
    np.testing.assert_allclose(layout.q(obs), env.sim.q, atol=1e-6)
    np.testing.assert_allclose(
        obs[layout.clearances], clearance(tip, env.settings.obstacles), atol=1e-6
    )


def test_action_is_scaled_to_the_velocity_bounds(paper_settings: ReachSettings) -> None:
    held = _with(paper_settings, reference="hold")
    held.reset(seed=0)
    q_d0 = held.sim.q_d.copy()
    held.step(np.array([1.0, -1.0], dtype=np.float32))
    np.testing.assert_allclose(held.sim.q_d - q_d0, [0.1 * 0.03, -0.4 * 0.03], rtol=1e-9)
    held.step(np.array([5.0, 5.0], dtype=np.float32))  # clipped to the bounds
    np.testing.assert_allclose(held.sim.q_d - q_d0, [0.2 * 0.03, 0.0], atol=1e-12)
    # The default ramp reaches each command at the period's end: q_d gains the mean of the
    # previous and the new command over the period (from rest at the start).
    env = ReachEnv(paper_settings)
    env.reset(seed=0)
    env.step(np.array([1.0, -1.0], dtype=np.float32))
    np.testing.assert_allclose(env.sim.q_d - q_d0, [0.05 * 0.03, -0.2 * 0.03], rtol=1e-9)
    env.step(np.array([5.0, 5.0], dtype=np.float32))
    np.testing.assert_allclose(env.sim.q_d - q_d0, [0.15 * 0.03, -0.2 * 0.03], rtol=1e-9)
    rows = ReachEnv(paper_settings, record=True)
    rows.reset(seed=0)
    rows.step(np.array([1.0, -1.0], dtype=np.float32))
    dqd = rows.trajectory()[:, 7:9]  # dq_d_1, dq_d_2
    np.testing.assert_allclose(dqd[:, 0], 0.1 * np.arange(30) / 30, atol=1e-15)


# -------------------------------------------------------------------- rewards and endings
def test_reach_pays_the_reach_reward(paper_settings: ReachSettings) -> None:
    env = ReachEnv(paper_settings)
    env.reset(seed=0, options={"target": (1.0, 0.83)})  # 3 cm from the initial tip
    _, reward, terminated, truncated, info = env.step(np.zeros(2, dtype=np.float32))
    assert (reward, terminated, truncated, info["reason"]) == (200.0, True, False, "reached")
    assert info["is_success"]


def test_distance_reward_and_growth_penalty(paper_settings: ReachSettings) -> None:
    env = ReachEnv(paper_settings)
    env.reset(seed=0, options={"target": (1.6, 0.8)})  # to the right of the tip at (1.0, 0.8)
    # q̇2 < 0 swings the forearm clockwise and the tip right, towards the target; then reverse.
    actions = [np.array([0.0, -1.0], dtype=np.float32)] * 5 + [
        np.array([0.0, 1.0], dtype=np.float32)
    ] * 10
    grew_seen = shrank_seen = False
    for a in actions:
        previous = env.error
        _, reward, terminated, _, info = env.step(a)
        assert not terminated
        grew = info["tip_error"] > previous
        expected = -math.log10(1 + info["tip_error"] - 0.04) - (1.0 if grew else 0.0)
        assert reward == pytest.approx(expected, rel=1e-12)
        grew_seen |= grew
        shrank_seen |= not grew
    assert grew_seen and shrank_seen


def test_collision_ends_with_the_collision_penalty(paper_settings: ReachSettings) -> None:
    # A small obstacle just to the right of the initial tip: moving right must hit it.
    env = _with(paper_settings, obstacles=np.array([[1.03, 0.8, 0.02]]), path_margin=0.0)
    env.reset(seed=0, options={"target": (1.6, 0.8)})
    for _ in range(20):
        _, reward, terminated, _, info = env.step(np.array([0.0, -1.0], dtype=np.float32))
        if terminated:
            break
    assert (info["reason"], reward, info["collision"]) == ("collision", -100.0, True)


def test_tip_that_clips_an_obstacle_between_actions_collides() -> None:
    obstacle = np.array([[0.5, 0.0, 0.05]])
    assert segment_hits(np.array([0.4, 0.04]), np.array([0.6, 0.04]), obstacle)
    assert not segment_hits(np.array([0.4, 0.06]), np.array([0.6, 0.06]), obstacle)
    # Neither end point is inside, so an end-point test would have missed it.
    ends = np.array([[0.4, 0.04], [0.6, 0.04]])
    assert (clearance(ends, obstacle) > 0).all()


def test_leaving_the_joint_limits_ends_with_the_boundary_penalty(
    paper_settings: ReachSettings,
) -> None:
    upper = paper_settings.joint_upper.copy()
    upper[1] = paper_settings.q0[1] + 0.01
    env = _with(paper_settings, joint_upper=upper)
    env.reset(seed=0, options={"target": (0.5, 1.2)})
    for _ in range(20):
        _, reward, terminated, _, info = env.step(np.array([0.0, 1.0], dtype=np.float32))
        if terminated:
            break
    assert (info["reason"], reward) == ("joint_limit", -50.0)
    assert env.sim.q[1] > upper[1]


def test_episode_truncates_after_max_steps(paper_settings: ReachSettings) -> None:
    env = _with(paper_settings, max_steps=5)
    env.reset(seed=0, options={"target": (0.5, -0.5)})
    ends = [env.step(np.zeros(2, dtype=np.float32))[2:4] for _ in range(5)]
    assert ends[:4] == [(False, False)] * 4 and ends[4] == (False, True)
    assert env.reason == "time_limit"


def test_divergence_is_an_outcome_not_a_crash(paper_settings: ReachSettings) -> None:
    unstable = np.array([-1e7, -1e7, 0.0, 0.0, 0.0, 0.0])  # negative PID gains
    unlimited = dataclasses.replace(paper_settings.plant, torque_limit=np.full(2, np.inf))
    env = _with(paper_settings, controller="pid", gains=unstable, plant=unlimited)
    env.reset(seed=0)
    for _ in range(100):
        obs, reward, terminated, _, info = env.step(np.zeros(2, dtype=np.float32))
        if terminated:
            break
    assert info["reason"] == "diverged" and reward == -50.0
    assert env.observation_space.contains(obs)


def test_unknown_task_is_one_clear_sentence(paper_settings: ReachSettings) -> None:
    env = ReachEnv(paper_settings)
    with pytest.raises(ValueError, match=r"task='e' is not allowed.*\['a', 'b', 'c', 'd'\]"):
        env.reset(options={"task": "e"})


# ------------------------------------------------------------------------------- workspace
def test_sampled_targets_are_reachable_and_collision_free(paper_settings: ReachSettings) -> None:
    s = paper_settings
    ws = s.workspace()
    lengths = s.plant.arm.lengths_array
    rng = np.random.default_rng(0)
    idx = rng.integers(len(ws), size=500)
    points, configs = ws.points[idx], ws.configs[idx]
    assert (clearance(points, s.obstacles) >= s.target_margin).all()
    assert (configs >= s.joint_lower).all() and (configs <= s.joint_upper).all()
    np.testing.assert_allclose(tips(configs, lengths), points, atol=1e-12)
    assert (ws.times[idx] <= s.max_target_time + 1e-9).all()
    start = tips(s.q0, lengths)
    assert (np.linalg.norm(points - start, axis=1) >= s.min_target_distance).all()
    env = ReachEnv(s)
    for seed in range(50):
        env.reset(seed=seed)
        assert np.linalg.norm(ws.points - env.target, axis=1).min() == 0.0


def test_travel_time_is_the_velocity_bounded_time_without_obstacles() -> None:
    lengths, lower, upper = np.array([1.0, 0.8]), np.array([-1.0, -2.5]), np.array([2.0, 2.5])
    q0, bound = np.array([0.0, 1.5]), np.array([0.1, 0.4])
    ws = build_workspace(
        lengths, lower, upper, q0, bound, np.zeros((0, 3)), max_time=40.0, min_distance=0.0
    )
    # Each joint moves at most at its bound, all at once: the least time is the slowest joint's.
    exact = np.max(np.abs(ws.configs - q0) / bound, axis=1)
    assert np.all(np.abs(ws.times - exact) <= ws.cell_time + 1e-9)


def test_an_obstacle_in_the_way_lengthens_the_travel_time() -> None:
    lengths, lower, upper = np.array([1.0, 0.8]), np.array([-0.8, -2.6]), np.array([2.4, 2.6])
    q0, bound = np.array([0.0, math.pi / 2]), np.array([0.1, 0.4])
    free = build_workspace(lengths, lower, upper, q0, bound, np.zeros((0, 3)), max_time=40.0)
    wall = np.array([[1.25, 0.8, 0.15]])
    blocked = build_workspace(lengths, lower, upper, q0, bound, wall, max_time=40.0)
    target = np.array([1.45, 0.8])  # behind the wall, seen from the initial tip (1.0, 0.8)
    assert segment_hits(np.array([1.0, 0.8]), target, wall)
    assert blocked.travel_time(target) > free.travel_time(target) + 1.0


def test_paper_tasks_are_reachable_at_different_distances_and_need_detours(
    paper_settings: ReachSettings,
) -> None:
    s = paper_settings
    reachable = s.workspace(max_time=s.max_steps * s.action_period)
    start = tips(s.q0, s.plant.arm.lengths_array)
    distances, detours = [], []
    for name, target in s.tasks.items():
        p = np.asarray(target)
        assert np.linalg.norm(reachable.points - p, axis=1).min() < 0.02, name
        assert (clearance(p, s.obstacles) >= s.target_margin).all(), name
        distances.append(float(np.linalg.norm(p - start)))
        detours.append(segment_hits(start, p, s.obstacles))
    assert len({round(d, 1) for d in distances}) == 4
    assert sum(detours) >= 2


def test_render_draws_arm_obstacles_and_target(paper_settings: ReachSettings) -> None:
    env = ReachEnv(paper_settings, render_mode="rgb_array")
    env.reset(seed=0, options={"task": "a"})
    img = env.render()
    assert img is not None and img.shape == (400, 400, 3) and img.dtype == np.uint8
    colours = {tuple(c) for c in img.reshape(-1, 3)[::7]}
    assert (220, 80, 70) in colours  # obstacles
    assert (40, 170, 60) in colours  # target
    assert (50, 60, 80) in colours  # links


def test_record_keeps_the_1khz_rows(paper_settings: ReachSettings) -> None:
    env = ReachEnv(paper_settings, record=True)
    env.reset(seed=0, options={"task": "d"})
    for _ in range(3):
        env.step(np.array([0.3, 0.3], dtype=np.float32))
    rows = env.trajectory()
    columns = trajectory_columns(2)
    assert rows.shape == (90, len(columns) + 1)
    np.testing.assert_allclose(np.diff(rows[:, 0]), 1e-3, rtol=1e-9)
    x, y = env.settings.tasks["d"]
    tip = rows[:, [columns.index("tip_x"), columns.index("tip_y")]]
    err = np.hypot(tip[:, 0] - x, tip[:, 1] - y)
    np.testing.assert_allclose(rows[:, -1], err)
