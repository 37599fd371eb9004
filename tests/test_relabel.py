"""Hindsight relabelling (armexp.agents.relabel): exact Table I rewards for the new target, SB3's
n-step returns when it is off, and failures that stay failures."""

from __future__ import annotations

import numpy as np
import pytest
from stable_baselines3.common.buffers import NStepReplayBuffer, ReplayBuffer

from armexp.agents.relabel import TARGET, GoalRelabelBuffer
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv

GAMMA = 0.99
SEED = 3


@pytest.fixture(scope="module")
def env() -> ReachEnv:
    return ReachEnv(settings_from_config(compose_config(["controller.gains=paper"])))


def _actions(steps: int, seed: int) -> np.ndarray:
    """Smooth random velocity commands, so the tip keeps moving."""
    rng = np.random.default_rng(seed)
    return np.clip(np.cumsum(rng.normal(0, 0.3, (steps, 2)), axis=0), -1, 1).astype(np.float32)


def _record(
    env: ReachEnv,
    buffers: list[ReplayBuffer],
    actions: np.ndarray,
    target: tuple[float, float],
    seed: int,
    cut: int | None = None,
) -> list[float]:
    """One episode into every buffer (a time-limit cut after ``cut`` steps); its rewards."""
    obs, _ = env.reset(seed=seed, options={"target": target})
    rewards = []
    for t, action in enumerate(actions):
        nxt, reward, terminated, truncated, _ = env.step(action)
        truncated = truncated or (cut is not None and t + 1 >= cut)
        infos = [{"TimeLimit.truncated": truncated and not terminated}]
        for b in buffers:
            b.add(obs[None], nxt[None], action[None], np.array([reward]),
                  np.array([terminated or truncated]), infos)  # fmt: skip
        rewards.append(reward)
        obs = nxt
        if terminated or truncated:
            break
    return rewards


def _buffer(env: ReachEnv, ratio: float, n_steps: int) -> GoalRelabelBuffer:
    s = env.settings
    return GoalRelabelBuffer(
        4000, env.observation_space, env.action_space, "cpu", 1, ratio=ratio, n_steps=n_steps,
        gamma=GAMMA, threshold=s.reach_threshold, reach_reward=s.reach_reward,
        growth_penalty=s.growth_penalty,
    )  # fmt: skip


def _mixed_episodes(env: ReachEnv, buffers: list[ReplayBuffer]) -> None:
    """A time-limit cut, a joint-limit ending (q2 folded past 5π/6), and an unfinished one."""
    far = (-0.3, 1.25)
    _record(env, buffers, _actions(60, 1), far, seed=1, cut=60)
    fold = np.tile(np.array([0.0, 1.0], dtype=np.float32), (200, 1))
    assert _record(env, buffers, fold, far, seed=2)[-1] == -env.settings.boundary_penalty
    _record(env, buffers, _actions(40, 3), far, seed=3, cut=None)


@pytest.mark.parametrize("n_steps", [1, 5])
def test_without_relabelling_it_is_sb3s_n_step_buffer(env: ReachEnv, n_steps: int) -> None:
    ours = _buffer(env, ratio=0.0, n_steps=n_steps)
    sb3 = NStepReplayBuffer(
        4000, env.observation_space, env.action_space, "cpu", 1, n_steps=n_steps, gamma=GAMMA
    )
    _mixed_episodes(env, [ours, sb3])
    for seed in range(3):
        np.random.seed(seed)
        a = ours.sample(256)
        np.random.seed(seed)
        b = sb3.sample(256)
        for name in a._fields:
            assert np.allclose(getattr(a, name), getattr(b, name), atol=1e-5), name


@pytest.mark.parametrize("n_steps", [1, 5])
def test_relabelled_samples_are_what_the_environment_gives_for_that_target(
    env: ReachEnv, n_steps: int
) -> None:
    """Replaying the same actions with the hindsight target as the episode's target gives the
    relabelled reward, n-step return, termination and observations."""
    actions = _actions(150, SEED)
    buffer = _buffer(env, ratio=1.0, n_steps=n_steps)
    _record(env, [buffer], actions, (-0.3, 1.25), seed=SEED, cut=150)
    np.random.seed(0)
    inds = np.random.choice(buffer.pos, 40, replace=False)
    data = buffer._get_samples(inds)
    reaches = 0
    for k, i in enumerate(inds):
        goal = data.observations[k, TARGET].numpy().astype(np.float64)
        obs, _ = env.reset(seed=SEED, options={"target": goal})
        rewards, ended, observed = [], False, []
        for t, action in enumerate(actions[: i + n_steps]):
            nxt, reward, terminated, _, _ = env.step(action)
            if t == i:
                assert np.allclose(obs, data.observations[k].numpy(), atol=1e-5)
            if t >= i:
                rewards.append(reward)
                observed.append(nxt)
                if terminated or t + 1 >= 150:
                    ended = terminated
                    break
            obs = nxt
        expected = sum(r * GAMMA**j for j, r in enumerate(rewards))
        assert data.rewards[k, 0].item() == pytest.approx(expected, abs=1e-3)
        assert data.discounts[k, 0].item() == pytest.approx(GAMMA ** len(rewards), rel=1e-5)
        assert bool(data.dones[k, 0]) == ended
        assert np.allclose(observed[-1], data.next_observations[k].numpy(), atol=1e-5)
        reaches += ended
    # The hindsight targets make reaches common: that is the point of relabelling.
    assert reaches >= 5


def test_failures_keep_their_penalty_and_ending_for_any_target(env: ReachEnv) -> None:
    buffer = _buffer(env, ratio=1.0, n_steps=1)
    _mixed_episodes(env, [buffer])
    failed = np.flatnonzero(buffer.rewards[: buffer.pos, 0] == -env.settings.boundary_penalty)
    assert failed.size == 1
    data = buffer._get_samples(np.repeat(failed, 16))
    assert np.all(data.rewards.numpy() == -env.settings.boundary_penalty)
    assert np.all(data.dones.numpy() == 1.0)


def test_hindsight_targets_come_from_later_in_the_same_episode(env: ReachEnv) -> None:
    buffer = _buffer(env, ratio=1.0, n_steps=1)
    _mixed_episodes(env, [buffer])
    ends = np.flatnonzero(buffer.dones[: buffer.pos, 0])
    starts = np.concatenate([[0], ends + 1])
    tips = buffer.next_observations[: buffer.pos, 0, 4:6]
    np.random.seed(1)
    inds = np.random.randint(0, buffer.pos, 500)
    goals = buffer._get_samples(inds).observations[:, TARGET].numpy()
    for i, goal in zip(inds, goals, strict=True):
        if buffer.rewards[i, 0] == -env.settings.boundary_penalty:  # failures keep theirs
            assert np.allclose(goal, buffer.observations[i, 0, TARGET])
            continue
        episode = np.searchsorted(starts, i, side="right") - 1
        last = ends[episode] if episode < ends.size else buffer.pos - 1
        later = tips[i : last + 1]
        assert np.any(np.all(np.isclose(later, goal), axis=1))
