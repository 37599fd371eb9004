"""SB3 SAC (Algorithm 1) from the ``agent`` config group (Table II for ``agent=sac_paper``)."""

from __future__ import annotations

import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
from omegaconf import DictConfig
from stable_baselines3 import SAC
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.common.vec_env import VecEnv

from armexp.agents.relabel import GoalRelabelBuffer
from armexp.envs.reach import ReachSettings


class ResumableSAC(SAC):
    """SAC that, once resumed from a checkpoint, refills its (empty) replay buffer with its own
    policy instead of the uniform random actions SB3 uses before ``learning_starts``, and whose
    schedules (the learning rate's) can follow a budget other than SB3's step count.

    SB3 measures progress as ``num_timesteps / total_timesteps``; with a wall-time budget the
    step total is only an upper bound, so a decaying learning rate would barely move.
    ``budget_used`` (a callable giving the share of the budget spent, 0 to 1) replaces that when
    it is further along.
    """

    resumed = False
    budget_used: Callable[[], float] | None = None

    def _update_current_progress_remaining(self, num_timesteps: int, total_timesteps: int) -> None:
        super()._update_current_progress_remaining(num_timesteps, total_timesteps)
        if self.budget_used is not None:
            remaining = 1.0 - min(max(self.budget_used(), 0.0), 1.0)
            self._current_progress_remaining = min(self._current_progress_remaining, remaining)

    def _excluded_save_params(self) -> list[str]:
        # The budget belongs to the run that trains, not to the saved model.
        return [*super()._excluded_save_params(), "budget_used"]

    def _sample_action(
        self, learning_starts: int, action_noise: Any = None, n_envs: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        if self.resumed:
            learning_starts = 0
        return super()._sample_action(learning_starts, action_noise, n_envs)


def sac_kwargs(agent: DictConfig, settings: ReachSettings | None = None) -> dict[str, Any]:
    """SB3 keyword arguments of an ``agent`` config (the keys are Table II's).

    ``agent.relabel`` > 0 replays that share of each batch with hindsight targets
    (`armexp.agents.relabel`), which needs the environment's reward ``settings``.
    """
    extra: dict[str, Any] = {}
    if float(agent.relabel) > 0:
        if settings is None:
            raise ValueError("agent.relabel > 0 needs the environment's settings for its rewards.")
        extra["replay_buffer_class"] = GoalRelabelBuffer
        extra["replay_buffer_kwargs"] = {
            "ratio": float(agent.relabel),
            "n_steps": int(agent.n_steps),
            "gamma": float(agent.gamma),
            "threshold": settings.reach_threshold,
            "reach_reward": settings.reach_reward,
            "growth_penalty": settings.growth_penalty,
        }
    return {
        "batch_size": int(agent.batch_size),
        "tau": float(agent.tau),
        "buffer_size": int(agent.buffer_size),
        "learning_starts": int(agent.learning_starts),
        "gamma": float(agent.gamma),
        "learning_rate": learning_rate(agent),
        "train_freq": int(agent.train_freq),
        "gradient_steps": int(agent.gradient_steps),
        "ent_coef": agent.ent_coef,
        # With relabelling the buffer forms the n-step returns itself.
        "n_steps": 1 if extra else int(agent.n_steps),
        "policy_kwargs": {"net_arch": list(agent.net_arch)},
        "device": str(agent.device),
        **extra,
    }


def learning_rate(agent: DictConfig) -> float | LinearSchedule:
    """``agent.learning_rate``, or a linear decay from it to ``agent.lr_final`` over the budget."""
    start = float(agent.learning_rate)
    if agent.get("lr_final") is None:
        return start
    return LinearSchedule(start, float(agent.lr_final), end_fraction=1.0)


def build_sac(
    agent: DictConfig, env: VecEnv, seed: int, settings: ReachSettings | None = None
) -> ResumableSAC:
    kwargs = sac_kwargs(agent, settings)
    return ResumableSAC("MlpPolicy", env, seed=seed, verbose=0, **kwargs)


def load_sac(path: str, env: VecEnv | None, agent: DictConfig) -> ResumableSAC:
    """A saved model (checkpoint or final); ``env`` None for inference only."""
    with warnings.catch_warnings():
        # A model saved with n-step returns carries its NStepReplayBuffer class and kwargs; SB3
        # warns on load that it will not set them up again, which is what we want.
        warnings.filterwarnings("ignore", message=".*n_steps=.* is ignored because a custom")
        return ResumableSAC.load(path, env=env, device=str(agent.device))
