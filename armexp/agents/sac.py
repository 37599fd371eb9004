"""SB3 SAC (Algorithm 1) from the ``agent`` config group (Table II for ``agent=sac_paper``)."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
from omegaconf import DictConfig
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import VecEnv


class ResumableSAC(SAC):
    """SAC that, once resumed from a checkpoint, refills its (empty) replay buffer with its own
    policy instead of the uniform random actions SB3 uses before ``learning_starts``."""

    resumed = False

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.resumed:
            learning_starts = 0
        return super()._sample_action(learning_starts, action_noise, n_envs)


def sac_kwargs(agent: DictConfig) -> dict[str, Any]:
    """SB3 keyword arguments of an ``agent`` config (the keys are Table II's)."""
    arch: list[int] | dict[str, list[int]] = list(agent.net_arch)
    if agent.critic_arch is not None:
        arch = {"pi": list(agent.net_arch), "qf": list(agent.critic_arch)}
    return {
        "batch_size": int(agent.batch_size),
        "tau": float(agent.tau),
        "buffer_size": int(agent.buffer_size),
        "learning_starts": int(agent.learning_starts),
        "gamma": float(agent.gamma),
        "learning_rate": float(agent.learning_rate),
        "train_freq": int(agent.train_freq),
        "gradient_steps": int(agent.gradient_steps),
        "ent_coef": agent.ent_coef,
        "n_steps": int(agent.n_steps),
        "policy_kwargs": {"net_arch": arch},
        "device": str(agent.device),
    }


def build_sac(agent: DictConfig, env: VecEnv, seed: int) -> ResumableSAC:
    return ResumableSAC("MlpPolicy", env, seed=seed, verbose=0, **sac_kwargs(agent))


def load_sac(path: str, env: VecEnv | None, agent: DictConfig) -> ResumableSAC:
    """A saved model (checkpoint or final); ``env`` None for inference only."""
    with warnings.catch_warnings():
        # A model saved with n-step returns carries its NStepReplayBuffer class and kwargs; SB3
        # warns on load that it will not set them up again, which is what we want.
        warnings.filterwarnings("ignore", message=".*n_steps=.* is ignored because a custom")
        return ResumableSAC.load(path, env=env, device=str(agent.device))
