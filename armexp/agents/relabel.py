"""Hindsight goal relabelling for `armexp/Reach-v0` in SB3's flat replay buffer.

Hindsight experience replay (Andrychowicz et al., 2017, "future" strategy): a share of every
sampled batch has its target replaced by a tip position the arm actually reached later in the same
episode, and its reward and termination recomputed with Table I's rules. A failed episode then
still teaches how to reach the places it passed through, which is what the agent lacks on targets
whose path first leads away from them (below the shoulder, behind an obstacle).

Relabelling is exact for this environment because everything that depends on the target is in
the observation (eq. 5a: target, tip − target, tip, ...) and the reward of a non-failing step is a
function of the tip before and after it and the target (Table I). Collision, joint-limit and
divergence endings do not depend on the target and keep their reward and termination.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.type_aliases import ReplayBufferSamples
from stable_baselines3.common.vec_env import VecNormalize

# Observation layout of `armexp.envs.kernel.observe` (eq. 5a).
TARGET, OFFSET, TIP = slice(0, 2), slice(2, 4), slice(4, 6)


class GoalRelabelBuffer(ReplayBuffer):
    """SB3 ``ReplayBuffer`` that relabels ``ratio`` of each batch with a future achieved tip.

    Samples carry ``n_steps``-step returns (as SB3's ``NStepReplayBuffer``), computed after
    relabelling, so that a relabelled reach inside the n steps ends the return there.

    ``threshold``, ``reach_reward`` and ``growth_penalty`` are the environment's Table I values
    (`armexp.envs.reach.ReachSettings`); a relabelled step whose tip ends within ``threshold`` of
    the new target earns ``reach_reward`` and terminates, any other non-failing step earns
    ``−log10(1 + error − threshold)``, ``growth_penalty`` less if the error grew.
    """

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        n_envs: int = 1,
        optimize_memory_usage: bool = False,
        handle_timeout_termination: bool = True,
        *,
        ratio: float = 0.5,
        n_steps: int = 1,
        gamma: float = 0.99,
        threshold: float = 0.04,
        reach_reward: float = 200.0,
        growth_penalty: float = 1.0,
    ) -> None:
        if optimize_memory_usage:
            raise ValueError("GoalRelabelBuffer needs optimize_memory_usage=False.")
        super().__init__(
            buffer_size, observation_space, action_space, device, n_envs,
            optimize_memory_usage=False, handle_timeout_termination=handle_timeout_termination,
        )  # fmt: skip
        self.ratio = float(ratio)
        self.n_steps = int(n_steps)
        self.gamma = float(gamma)
        self.threshold = float(threshold)
        self.reach_reward = float(reach_reward)
        self.growth_penalty = float(growth_penalty)
        # Last position of each stored step's episode, -1 while the episode still runs.
        self.episode_end = np.full((self.buffer_size, n_envs), -1, dtype=np.int64)
        self._episode_start = np.zeros(n_envs, dtype=np.int64)

    def add(
        self,
        obs: np.ndarray,
        next_obs: np.ndarray,
        action: np.ndarray,
        reward: np.ndarray,
        done: np.ndarray,
        infos: list[dict[str, Any]],
    ) -> None:
        pos = self.pos
        self.episode_end[pos] = -1
        super().add(obs, next_obs, action, reward, done, infos)
        for env in np.flatnonzero(done):
            span = (pos - self._episode_start[env]) % self.buffer_size
            rows = (self._episode_start[env] + np.arange(span + 1)) % self.buffer_size
            self.episode_end[rows, env] = pos
            self._episode_start[env] = self.pos

    def _get_samples(
        self, batch_inds: np.ndarray, env: VecNormalize | None = None
    ) -> ReplayBufferSamples:
        size, n = self.buffer_size, self.n_steps
        envs = np.random.randint(0, high=self.n_envs, size=(len(batch_inds),))
        rows = (batch_inds[:, None] + np.arange(n)) % size  # the n steps of each sample
        cols = envs[:, None]
        rewards = self.rewards[rows, cols].copy()
        truncated = self.timeouts[rows, cols] > 0
        ended = (self.dones[rows, cols] > 0) | truncated  # the stored episode stops here
        # The newest step may be followed by a different episode's slot; never read past it.
        truncated |= (rows == (self.pos - 1) % size) & ~ended
        ended |= truncated
        terminal = ended & ~truncated  # no bootstrap from the next observation
        # Collision, joint-limit and divergence endings are the same for any target.
        failed = terminal & (rewards < 0)

        obs = self.observations[batch_inds, envs].copy()
        pick = np.flatnonzero((np.random.random(len(batch_inds)) < self.ratio) & ~failed[:, 0])
        goal = None
        if pick.size:
            i, e = batch_inds[pick], envs[pick]
            end = self.episode_end[i, e]
            end = np.where(end >= 0, end, (self.pos - 1) % size)
            span = (end - i) % size
            future = (i + (np.random.random(pick.size) * (span + 1)).astype(np.int64)) % size
            goal = self.next_observations[future, e][:, TIP]
            r, c = rows[pick], cols[pick]
            before = np.linalg.norm(self.observations[r, c][..., TIP] - goal[:, None], axis=2)
            after = np.linalg.norm(self.next_observations[r, c][..., TIP] - goal[:, None], axis=2)
            reached = after < self.threshold
            shaped = -np.log10(1.0 + after - self.threshold) - self.growth_penalty * (
                after > before
            )
            rewards[pick] = np.where(
                failed[pick], rewards[pick], np.where(reached, self.reach_reward, shaped)
            )
            terminal[pick] = failed[pick] | reached

        stop = ended | terminal
        last = np.where(stop.any(axis=1), stop.argmax(axis=1), n - 1)
        mask = np.arange(n)[None, :] <= last[:, None]
        returns = (rewards * self.gamma ** np.arange(n)[None, :] * mask).sum(axis=1)
        discounts = self.gamma ** mask.sum(axis=1)
        final = rows[np.arange(len(batch_inds)), last]
        next_obs = self.next_observations[final, envs].copy()
        dones = terminal[np.arange(len(batch_inds)), last]
        if goal is not None:
            for o in (obs, next_obs):
                o[pick, TARGET] = goal
                o[pick, OFFSET] = o[pick, TIP] - goal

        data = (
            self._normalize_obs(obs, env),
            self.actions[batch_inds, envs],
            self._normalize_obs(next_obs, env),
            dones.astype(np.float32).reshape(-1, 1),
            self._normalize_reward(returns.astype(np.float32).reshape(-1, 1), env),
            discounts.astype(np.float32).reshape(-1, 1),
        )
        return ReplayBufferSamples(*tuple(map(self.to_torch, data)))
