"""Vectorised reaching environments for training."""

from __future__ import annotations

from collections.abc import Callable

import gymnasium as gym
from stable_baselines3.common.vec_env import DummyVecEnv, SubprocVecEnv, VecEnv, VecMonitor

from armexp.envs.reach import ReachEnv, ReachSettings


def make_vec_env(settings: ReachSettings, n_envs: int, kind: str, seed: int) -> VecEnv:
    """``n_envs`` copies of the environment, each seeded ``seed + i``, with episode statistics.

    ``kind="dummy"`` steps them in this process (right when, as here, one step costs ~10 µs and
    the network update dominates); ``"subproc"`` gives each its own process.
    """

    def factory() -> Callable[[], gym.Env]:
        return lambda: ReachEnv(settings)

    fns = [factory() for _ in range(n_envs)]
    venv: VecEnv = SubprocVecEnv(fns) if kind == "subproc" else DummyVecEnv(fns)
    venv.seed(seed)
    return VecMonitor(venv, info_keywords=("is_success", "collision", "reason"))
