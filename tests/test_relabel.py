"""Goal relabelling (the ``her`` aid): relabelled transitions carry the reward, the end and the
observation `ReachEnv.step` gives toward the new target; the buffer relabels toward tips reached
later in the same episode; the aid is refused where it cannot work."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import DummyVecEnv

from armexp import aids
from armexp.agents.addons import TrainingContext
from armexp.agents.relabel import GoalRelabelling, RelabellingReplayBuffer
from armexp.cli import main
from armexp.config import ConfigError, compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.observation import TARGET, TIP
from armexp.envs.reach import ReachEnv, ReachSettings, reward_params
from tests.helpers import plain_train, stage_runs

HER = "+agent.aids.her={_target_:armexp.agents.relabel.GoalRelabelling,ratio:0.8}"


@pytest.fixture(scope="module")
def settings() -> ReachSettings:
    return settings_from_config(compose_config(["controller.gains=paper"]))


def _buffer(env: ReachEnv | Any, settings: ReachSettings, ratio: float = 0.8,
            n_envs: int = 1, size: int = 1000) -> RelabellingReplayBuffer:  # fmt: skip
    return RelabellingReplayBuffer(size, env.observation_space, env.action_space,
                                   reward_params(settings), ratio, "cpu", n_envs)  # fmt: skip


def _episode(env: ReachEnv, actions: np.ndarray, **reset: Any) -> dict[str, np.ndarray]:
    obs, _ = env.reset(seed=11, **reset)
    rows: dict[str, list[Any]] = {"obs": [], "next": [], "reward": [], "terminated": []}
    for action in actions:
        nxt, reward, terminated, _, _ = env.step(action)
        for key, value in zip(rows, (obs, nxt, reward, terminated), strict=True):
            rows[key].append(value)
        obs = nxt
        if terminated:
            break
    return {k: np.array(v) for k, v in rows.items()}


def test_a_relabelled_step_is_what_the_environment_gives_toward_that_target(
    settings: ReachSettings,
) -> None:
    """The same seed and actions toward a tip the first episode reached: the environment's own
    rewards, ends and observations are the relabelled ones, step for step."""
    env = ReachEnv(settings)
    actions = np.random.default_rng(5).uniform(-0.2, 1, (80, 2))  # away from the start
    first = _episode(env, actions)
    assert len(first["reward"]) == 80 and not first["terminated"].any()
    goal = first["next"][60, TIP].astype(np.float64)
    again = _episode(env, actions, options={"target": goal})
    k = len(again["reward"])
    assert again["terminated"][-1] and k <= 61  # it reaches the tip of step 60, or near it
    buffer = _buffer(env, settings)
    obs, nxt, rewards, ended = buffer.relabel(
        first["obs"][:k], first["next"][:k], first["reward"][:k].astype(np.float32),
        first["terminated"][:k].astype(np.float32), np.tile(goal, (k, 1)),
    )  # fmt: skip
    assert np.allclose(rewards, again["reward"], rtol=1e-5, atol=1e-5)
    assert ended.tolist() == again["terminated"].astype(float).tolist()
    assert np.allclose(obs, again["obs"], atol=1e-6)
    assert np.allclose(nxt, again["next"], atol=1e-6)
    assert rewards[-1] == settings.reach_reward
    assert (rewards[:-1] < 0).all() and len(set(np.round(rewards, 4))) > 5


def test_a_step_that_collided_keeps_its_penalty_and_its_end(settings: ReachSettings) -> None:
    env = ReachEnv(settings)
    obs, _ = env.reset(seed=1)
    two = np.stack([obs, obs])
    rewards = np.array([-settings.collision_penalty, -0.3], np.float32)
    goals = np.stack([two[0, TIP], two[0, TIP]])  # reached at once, had nothing gone wrong
    _, _, out, ended = _buffer(env, settings).relabel(
        two, two, rewards, np.array([1.0, 0.0], np.float32), goals
    )
    assert out.tolist() == [-settings.collision_penalty, settings.reach_reward]
    assert ended.tolist() == [1.0, 1.0]


def test_the_buffer_relabels_toward_tips_reached_later_in_the_same_episode(
    settings: ReachSettings,
) -> None:
    """Two environments, episodes of 3–7 steps; each observation's tip encodes (episode, step),
    so a relabelled target says which transition it came from."""
    env = ReachEnv(settings)
    buffer = _buffer(env, settings, ratio=1.0, n_envs=2, size=400)
    rng = np.random.default_rng(0)
    lengths = [list(rng.integers(3, 8, 60)) for _ in range(2)]
    step, episode = [0, 0], [0, 100]
    dim = env.layout.size
    while buffer.pos < 150:
        obs, nxt, done = np.zeros((2, dim), np.float32), np.zeros((2, dim), np.float32), []
        for e in range(2):
            obs[e, TIP] = (episode[e], step[e])
            nxt[e, TIP] = (episode[e], step[e] + 1)
            step[e] += 1
            done.append(step[e] == lengths[e][0])
            if done[-1]:
                lengths[e].pop(0)
                step[e], episode[e] = 0, episode[e] + 1
        buffer.add(obs, nxt, np.zeros((2, 2)), np.zeros(2), np.array(done), [{}, {}])
    np.random.seed(3)
    batch = buffer.sample(512)
    tips, goals = batch.observations[:, TIP].numpy(), batch.observations[:, TARGET].numpy()
    assert (goals[:, 0] == tips[:, 0]).all()  # the same episode
    assert (goals[:, 1] >= tips[:, 1] + 1).all()  # a tip reached at this step or later
    assert len(np.unique(goals[:, 1] - tips[:, 1])) >= 4  # spread over the future, not the next
    half = _buffer(env, settings, ratio=0.5, n_envs=2, size=400)
    half.__dict__.update({k: v for k, v in buffer.__dict__.items() if k != "ratio"})
    mixed = half.sample(2000).observations.numpy()
    relabelled = np.mean(np.any(mixed[:, TARGET] != 0, axis=1))
    assert 0.45 < relabelled < 0.55


@pytest.mark.long
def test_her_trains_a_non_privileged_preset_and_is_refused_where_it_cannot_work(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert aids.HER.privileged is False
    base = plain_train(runs_dir, HER)
    assert main([*base, "agent.n_steps=1"]) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.data.metrics["final/her_ratio"] == 0.8
    assert main([*base, "agent.n_steps=3"]) == 2
    err = capsys.readouterr().err
    assert "agent.aids.her is not allowed with agent.n_steps=3" in err
    assert "set agent.n_steps=1" in err
    assert main([*base, "agent=ppo_quick", "agent.max_env_steps=2048"]) == 2
    assert "agent.aids.her is not allowed with agent.algo=ppo" in capsys.readouterr().err
    assert len(stage_runs(runs_dir, "train")) == 1  # nothing started for the refused ones


def test_her_on_an_environment_without_a_goal_is_one_sentence(settings: ReachSettings) -> None:
    venv = DummyVecEnv([lambda: gym.make("Pendulum-v1")])
    model = SAC("MlpPolicy", venv, buffer_size=1000, device="cpu")
    ctx = TrainingContext(model, settings, 0, False, lambda: 0.0, lambda: 0.0)
    with pytest.raises(ConfigError, match=r"agent.aids.her is not allowed with Pendulum-v1: it "
                       r"has no goal to relabel"):  # fmt: skip
        GoalRelabelling(0.8).setup(ctx)
