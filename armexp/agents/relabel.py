"""Goal relabelling (hindsight experience replay, Andrychowicz et al. 2017; the ``her`` aid).

armexp/Reach-v0 puts its target in the observation (eq. 5a: target, tip − target, tip, …), so
a stored transition can be replayed toward another target by rewriting those entries and asking
the environment's own reward function what the step would have returned
(`armexp.envs.reach.ReachEnv.goal_rewards`, `armexp.envs.kernel.task_reward`). With the paper's
``future`` strategy, a share ``ratio`` of every sampled batch takes as its target the tip reached
at the end of the same or a later step of the same episode (ratio 0.8 is the paper's k = 4): a
detour that missed its target reached others, and those transitions say how.

A step that collided or left the joint limits ended its episode whatever the target, so it keeps
its reward and its end; every other step gets the reward of the new target and ends if it reached
it. Nothing here knows the obstacles or the planner (not privileged). The relabelled reward is
exactly the one-step reward: an n-step buffer's sums were taken for the old target, so the aid
needs ``agent.n_steps=1``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext
from armexp.config import ConfigError
from armexp.envs.kernel import P_REACH, goal_rewards
from armexp.envs.observation import OFFSET, TARGET, TIP
from armexp.envs.reach import reward_params

KEY = "agent.aids.her"


class RelabellingReplayBuffer(ReplayBuffer):
    """SB3's replay buffer that remembers where each transition's episode ends and relabels a
    share ``ratio`` of every sample with a future achieved tip (module doc); ``params`` are the
    environment's reward terms (`armexp.envs.reach.reward_params`), which its own reward
    function (`armexp.envs.kernel.goal_rewards`, as `ReachEnv.goal_rewards` calls it) takes."""

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        params: np.ndarray,
        ratio: float = 0.8,
        device: torch.device | str = "auto",
        n_envs: int = 1,
    ) -> None:
        super().__init__(buffer_size, observation_space, action_space, device, n_envs)
        self.params = np.asarray(params, dtype=np.float64)
        self.reach_reward = float(params[P_REACH])
        self.ratio = float(ratio)
        #: The position of each stored transition's episode's last transition (-1 while the
        #: episode runs), and where each environment's running episode started.
        self.last = np.full((self.buffer_size, n_envs), -1, dtype=np.int64)
        self._start = np.zeros(n_envs, dtype=np.int64)

    def add(self, obs: np.ndarray, next_obs: np.ndarray, action: np.ndarray, reward: np.ndarray,
            done: np.ndarray, infos: list[dict[str, Any]]) -> None:  # fmt: skip
        pos = self.pos
        self.last[pos] = -1
        super().add(obs, next_obs, action, reward, done, infos)
        for e in np.flatnonzero(np.asarray(done)):
            length = (pos - self._start[e]) % self.buffer_size + 1
            rows = (self._start[e] + np.arange(length)) % self.buffer_size
            self.last[rows, e] = pos
            self._start[e] = self.pos

    def end_episodes(self) -> None:
        """Each environment's running episode ends with its last stored transition (an
        interrupted run's buffer, kept for the resumed run, which starts new episodes)."""
        newest = (self.pos - 1) % self.buffer_size
        for e in range(self.n_envs):
            if self._start[e] == self.pos:
                continue  # its last episode ended with the last transition
            length = (newest - self._start[e]) % self.buffer_size + 1
            self.last[(self._start[e] + np.arange(length)) % self.buffer_size, e] = newest
            self._start[e] = self.pos

    def _future(self, rows: np.ndarray, envs: np.ndarray) -> np.ndarray:
        """A position of the same episode at or after each (row, env), uniformly."""
        newest = (self.pos - 1) % self.buffer_size
        last = self.last[rows, envs]
        last = np.where(last < 0, newest, last)
        span = (last - rows) % self.buffer_size + 1
        return (rows + (np.random.random(len(rows)) * span).astype(np.int64)) % self.buffer_size

    def _get_samples(
        self, batch_inds: np.ndarray, env: VecNormalize | None = None
    ) -> ReplayBufferSamples:
        envs = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        obs = self.observations[batch_inds, envs].copy()
        next_obs = self.next_observations[batch_inds, envs].copy()
        rewards = self.rewards[batch_inds, envs].copy()
        dones = self.dones[batch_inds, envs] * (1 - self.timeouts[batch_inds, envs])
        chosen = np.flatnonzero(np.random.random(len(batch_inds)) < self.ratio)
        if chosen.size:
            future = self._future(batch_inds[chosen], envs[chosen])
            goals = self.next_observations[future, envs[chosen]][:, TIP]
            obs[chosen], next_obs[chosen], rewards[chosen], dones[chosen] = self.relabel(
                obs[chosen], next_obs[chosen], rewards[chosen], dones[chosen], goals
            )
        data = (
            self._normalize_obs(obs, env),
            self.actions[batch_inds, envs],
            self._normalize_obs(next_obs, env),
            dones.reshape(-1, 1),
            self._normalize_reward(rewards.reshape(-1, 1), env),
        )
        return ReplayBufferSamples(*tuple(map(self.to_torch, data)))

    def relabel(self, obs: np.ndarray, next_obs: np.ndarray, rewards: np.ndarray,
                terminated: np.ndarray, goals: np.ndarray,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # fmt: skip
        """Transitions (observation, next observation, reward, terminated) toward ``goals``
        instead of their own targets."""
        obs, next_obs = obs.copy(), next_obs.copy()
        for o in (obs, next_obs):
            o[:, TARGET] = goals
            o[:, OFFSET] = o[:, TIP] - goals
        failed = (terminated > 0) & (rewards != np.float32(self.reach_reward))
        new, reached = goal_rewards(
            obs[:, TIP].astype(np.float64), next_obs[:, TIP].astype(np.float64),
            np.asarray(goals, np.float64), self.params,
        )  # fmt: skip
        rewards = np.where(failed, rewards, new).astype(np.float32)
        ended = np.where(failed, 1.0, reached).astype(np.float32)
        return obs, next_obs, rewards, ended


class GoalRelabelling(TrainingAddOn):
    """Replace the model's replay buffer with a `RelabellingReplayBuffer` (``ratio`` of each
    sample relabelled); ``final/her_ratio`` is logged."""

    declaration = aids.HER

    def __init__(self, ratio: float = 0.8) -> None:
        if not 0.0 < float(ratio) <= 1.0:
            raise ValueError(f"ratio={ratio} must be in (0, 1]")
        self.ratio = float(ratio)

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        model: Any = ctx.model
        venv = model.get_env()
        if not venv.has_attr("goal_rewards"):
            spec = venv.get_attr("spec", [0])[0]
            raise ConfigError(
                f"{KEY} is not allowed with {spec.id if spec else 'this environment'}: it has "
                "no goal to relabel (HER needs an environment that observes its target and gives "
                "its reward for another, as armexp/Reach-v0 does); remove it (~agent.aids.her)."
            )
        old = model.replay_buffer
        if ctx.resumed and isinstance(old, RelabellingReplayBuffer):
            return []  # the interrupted run's buffer, kept (`armexp.agents.kept_buffer`)
        if type(old) is not ReplayBuffer or old.optimize_memory_usage or old.size():
            raise ConfigError(
                f"{KEY} is not allowed here: it needs SB3's plain replay buffer, empty "
                f"(this model has {type(old).__name__} with {old.size()} transitions); list "
                "it before aids that fill the buffer and use agent.n_steps=1."
            )
        model.replay_buffer = RelabellingReplayBuffer(
            old.buffer_size * old.n_envs, model.observation_space, model.action_space,
            reward_params(ctx.settings), self.ratio, old.device, old.n_envs,
        )  # fmt: skip
        return []

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        return {"final/her_ratio": self.ratio}
