"""Potential-based reward shaping with the planner's time to go (``agent.shaping``).

Table I pays the reach reward only at the end of a motion that can last hundreds of 30 ms steps,
and it charges every step on which the tip moves away from the target. Where the only clear path
first leads away (targets close below the base, behind an obstacle), a critic has to carry the
reach reward back over that whole detour before the actor takes it. Shaping the *training*
reward with a potential (Ng, Harada & Russell, 1999),

    r' = r + γ Φ(s') − Φ(s),   Φ(s) = −k · T(q, target),   Φ(terminal) = 0,

where T is the least time in which a velocity-bounded, obstacle-clear motion brings the tip
within the reach threshold (a breadth-first search over the workspace grid,
`armexp.envs.workspace.time_to_go`), pays ``k`` per second of progress along such a path at once.
The shaped discounted return of any trajectory is the Table I return minus Φ(s₀), the same
constant for every policy, so the optimal policy is unchanged. The environment, its logged
episode rewards and every evaluation keep Table I's reward; only what SAC learns from changes.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import replace
from typing import Any

import numpy as np
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper
from stable_baselines3.common.vec_env.base_vec_env import VecEnvStepReturn

from armexp.agents.demonstrations import Demonstration
from armexp.envs.reach import ReachSettings
from armexp.envs.workspace import JointGrid, fill_unreached, time_to_go
from armexp.sim.model import Array

#: Observation layout of `armexp.envs.kernel.observe` (eq. 5a): target, then q from index 6.
TARGET, JOINTS_FROM = slice(0, 2), 6


class TimeToGoPotential:
    """Φ(s) = −``scale`` · T(q, target) from an observation, with T bilinear between grid cells.

    A cell with no finite time (its tip within the path margin of an obstacle, or cut off from
    the target) gets the least time over paths through such cells to a finite cell, at
    ``inside_cost`` time cells per grid move, so that the potential stays continuous where the
    arm skirts an obstacle (finite times are never shortened through them).
    Time-to-go maps are kept for the ``cache`` most recent targets (one search is ~15 ms).
    """

    def __init__(
        self, settings: ReachSettings, scale: float, cache: int = 64, inside_cost: float = 1.0
    ) -> None:
        """``inside_cost``: the time of one grid move among cells with no finite time, in
        free moves (1: such cells cost what free ones do)."""
        self.scale = float(scale)
        self.inside_cost = float(inside_cost)
        self.threshold = settings.reach_threshold
        self.n = int(settings.q0.shape[0])
        self.grid: JointGrid = settings.joint_grid()
        self._maps: OrderedDict[tuple[float, ...], Array] = OrderedDict()
        self._cache = int(cache)

    def times(self, target: Array) -> Array:
        key = tuple(float(v) for v in target)
        if key in self._maps:
            self._maps.move_to_end(key)
            return self._maps[key]
        t = time_to_go(self.grid, np.asarray(target, dtype=np.float64), self.threshold)
        t = fill_unreached(t, self.grid.dt * self.inside_cost)
        self._maps[key] = t
        if len(self._maps) > self._cache:
            self._maps.popitem(last=False)
        return t

    def time(self, obs: Array) -> float:
        """T (s) at the joint angles and target of one observation."""
        q = np.asarray(obs[JOINTS_FROM : JOINTS_FROM + self.n], dtype=np.float64)
        return float(self.times_at(obs[TARGET], q[None, :])[0])

    def times_at(self, target: Array, q: Array) -> Array:
        """T (s) to ``target`` at each row of joint angles ``q`` (k, n), bilinear between cells."""
        t = self.times(target)
        lo, frac = [], []
        for j, axis in enumerate(self.grid.axes):
            x = np.clip((q[:, j] - axis[0]) / (axis[1] - axis[0]), 0.0, len(axis) - 1.0)
            i = np.minimum(np.floor(x).astype(np.int64), len(axis) - 2)
            lo.append(i)
            frac.append(x - i)
        value = np.zeros(q.shape[0])
        for corner in range(2**self.n):
            bits = [(corner >> j) & 1 for j in range(self.n)]
            w = np.prod([f if b else 1.0 - f for f, b in zip(frac, bits, strict=True)], axis=0)
            value += w * t[tuple(i + b for i, b in zip(lo, bits, strict=True))]
        return value

    def __call__(self, obs: Array) -> float:
        return -self.scale * self.time(obs)

    def shape(self, demo: Demonstration, gamma: float) -> Demonstration:
        """``demo`` with shaped rewards (a terminated last step has Φ(s') = 0)."""
        phi = np.array([self(o) for o in demo.obs])
        phi_next = np.where(demo.terminated, 0.0, [self(o) for o in demo.next_obs])
        rewards = (demo.rewards + gamma * phi_next - phi).astype(demo.rewards.dtype)
        return replace(demo, rewards=rewards)


class ShapedRewards(VecEnvWrapper):
    """Training environments whose step rewards are shaped by ``potential`` (see module doc).

    Wrap it around `VecMonitor` so that episode returns and success stay Table I's. A time-limit
    end is bootstrapped (Φ(s') of its last observation); a terminal one has Φ(s') = 0. The
    unshaped reward is in ``info["table_i_reward"]``.
    """

    def __init__(self, venv: VecEnv, potential: TimeToGoPotential, gamma: float) -> None:
        super().__init__(venv)
        self.potential = potential
        self.gamma = float(gamma)
        self._phi = np.zeros(self.num_envs)

    def _potentials(self, obs: Any) -> Array:
        return np.array([self.potential(o) for o in np.asarray(obs)])

    def reset(self) -> Any:
        obs = self.venv.reset()
        self._phi = self._potentials(obs)
        return obs

    def step_wait(self) -> VecEnvStepReturn:
        obs, rewards, dones, infos = self.venv.step_wait()
        assert isinstance(obs, np.ndarray)  # Reach-v0's Box observation
        shaped = np.asarray(rewards, dtype=np.float64).copy()
        now = self._potentials(obs)  # after an auto-reset: the next episode's first state
        for i, info in enumerate(infos):
            info["table_i_reward"] = float(rewards[i])
            if not dones[i]:
                after = now[i]
            elif info.get("TimeLimit.truncated", False):
                after = self.potential(info["terminal_observation"])
            else:
                after = 0.0
            shaped[i] += self.gamma * after - self._phi[i]
        self._phi = now
        return obs, shaped.astype(np.float32), dones, infos
