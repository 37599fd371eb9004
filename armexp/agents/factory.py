"""One factory for the agents of ``agent.algo``: SAC, TD3 and PPO (SB3), TQC and CrossQ
(sb3-contrib), built from an ``agent`` config, loaded from a saved model, and described.

Every preset composes with any ``agent.algo`` (`armexp.config.agent_schema`): the options the
algorithms share are read where they mean the same thing, mapped where the algorithm has them
under another meaning (PPO's ``batch_size`` is its minibatch, ``critic_arch`` its value network)
and left out where it has none (TD3 has no entropy temperature, CrossQ no target networks, PPO
no replay buffer); `usage` says which, and the train run logs and prints it. Each algorithm's own
options are in its section (``agent.td3``, ``agent.tqc``, ``agent.crossq``, ``agent.ppo``).

SAC is `armexp.agents.sac.ResumableSAC` with its own update (``agent.gradients=compiled``
included); the others run their library's update, with `armexp.agents.algorithms`' resume refill
for the off-policy ones.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from gymnasium import spaces
from omegaconf import DictConfig
from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.noise import NormalActionNoise
from stable_baselines3.common.vec_env import VecEnv

from armexp.agents.algorithms import ResumableCrossQ, ResumableTD3, ResumableTQC, ResumeRefill
from armexp.agents.sac import (
    ResumableSAC,
    build_sac,
    load_sac,
    off_policy_kwargs,
    sac_kwargs,
    target_entropy,
)
from armexp.config.agent_schema import ALGORITHMS, TITLES
from armexp.resources import device_here


@dataclass(frozen=True)
class Algorithm:
    """One value of ``agent.algo``: its model class, how its keyword arguments come from the
    config, and which shared options it maps to another meaning or leaves out."""

    name: str
    cls: type[BaseAlgorithm]
    #: Learns from a replay buffer (`armexp.agents.addons.OFF_POLICY` lists these).
    off_policy: bool
    #: (agent config, environment) -> the class's keyword arguments.
    kwargs: Callable[[DictConfig, VecEnv], dict[str, Any]]
    #: Shared options it reads with a meaning of its own: key -> that meaning.
    maps: Mapping[str, str] = field(default_factory=dict)
    #: Shared options it has no use for.
    leaves_out: tuple[str, ...] = ()


@dataclass(frozen=True)
class Usage:
    """How one agent config's shared options apply to its algorithm."""

    algo: str
    mapped: dict[str, str]
    left_out: tuple[str, ...]

    def line(self, preset: str) -> str:
        """One sentence for the run's output; empty when every option applies as it is."""
        title = TITLES[self.algo]
        parts = [f"agent.{k} is {title}'s {v}" for k, v in self.mapped.items()]
        if self.left_out:
            keys = ", ".join(f"agent.{k}" for k in self.left_out)
            parts.append(f"{keys} {'do' if len(self.left_out) > 1 else 'does'} not apply")
        if not parts:
            return ""
        return f"agent.algo={self.algo} on agent={preset}: {'; '.join(parts)}."


def _arch(agent: DictConfig, critic: str) -> list[int] | dict[str, list[int]]:
    """``net_arch``, split by network where ``critic_arch`` sets the critics' (``critic`` is
    the library's key for them: ``qf`` or PPO's ``vf``)."""
    if agent.critic_arch is None:
        return list(agent.net_arch)
    return {"pi": list(agent.net_arch), critic: list(agent.critic_arch)}


def _td3(agent: DictConfig, env: VecEnv) -> dict[str, Any]:
    own = agent.td3
    noise = None
    if float(own.action_noise) > 0:
        assert isinstance(env.action_space, spaces.Box)
        n = int(env.action_space.shape[0])
        noise = NormalActionNoise(np.zeros(n), float(own.action_noise) * np.ones(n))
    return {
        **off_policy_kwargs(agent),
        "policy_delay": int(own.policy_delay),
        "target_policy_noise": float(own.target_policy_noise),
        "target_noise_clip": float(own.target_noise_clip),
        "action_noise": noise,
        "policy_kwargs": {"net_arch": _arch(agent, "qf")},
    }


def _tqc(agent: DictConfig, env: VecEnv) -> dict[str, Any]:
    own = agent.tqc
    return {
        **off_policy_kwargs(agent),
        "ent_coef": agent.ent_coef,
        "target_entropy": target_entropy(agent),
        "top_quantiles_to_drop_per_net": int(own.top_quantiles_to_drop_per_net),
        "policy_kwargs": {
            "net_arch": _arch(agent, "qf"),
            "n_quantiles": int(own.n_quantiles),
            "n_critics": int(own.n_critics),
        },
    }


def _crossq(agent: DictConfig, env: VecEnv) -> dict[str, Any]:
    own = agent.crossq
    return {
        **off_policy_kwargs(agent, tau=False),
        "ent_coef": agent.ent_coef,
        "target_entropy": target_entropy(agent),
        "policy_delay": int(own.policy_delay),
        "policy_kwargs": {
            "net_arch": _arch(agent, "qf"),
            "batch_norm_momentum": float(own.batch_norm_momentum),
            "renorm_warmup_steps": int(own.renorm_warmup_steps),
        },
    }


def _ppo(agent: DictConfig, env: VecEnv) -> dict[str, Any]:
    own = agent.ppo
    return {
        "learning_rate": float(agent.learning_rate),
        "gamma": float(agent.gamma),
        "batch_size": int(agent.batch_size),
        "n_steps": int(own.n_steps),
        "n_epochs": int(own.n_epochs),
        "gae_lambda": float(own.gae_lambda),
        "clip_range": float(own.clip_range),
        "ent_coef": float(own.ent_coef),
        "vf_coef": float(own.vf_coef),
        "max_grad_norm": float(own.max_grad_norm),
        # A list would be the same layers for both: PPO's value network takes critic_arch.
        "policy_kwargs": {"net_arch": _arch(agent, "vf")},
        "device": device_here(str(agent.device)),
    }


def _sac(agent: DictConfig, env: VecEnv) -> dict[str, Any]:
    return sac_kwargs(agent)


#: Every ``agent.algo``, by name.
ALGORITHM: dict[str, Algorithm] = {
    "sac": Algorithm("sac", ResumableSAC, True, _sac),
    "td3": Algorithm(
        "td3", ResumableTD3, True, _td3,
        leaves_out=("ent_coef", "target_entropy", "critic_dropout"),
    ),
    "tqc": Algorithm("tqc", ResumableTQC, True, _tqc, leaves_out=("critic_dropout",)),
    "crossq": Algorithm(
        "crossq", ResumableCrossQ, True, _crossq, leaves_out=("tau", "critic_dropout")
    ),
    "ppo": Algorithm(
        "ppo", PPO, False, _ppo,
        maps={"batch_size": "minibatch size", "critic_arch": "value network"},
        leaves_out=("tau", "buffer_size", "learning_starts", "train_freq", "gradient_steps",
                    "ent_coef", "target_entropy", "n_steps", "critic_dropout"),
    ),
}  # fmt: skip
assert tuple(ALGORITHM) == ALGORITHMS  # the schema's list of choices and this one agree


def algorithm(agent: DictConfig) -> Algorithm:
    """The `Algorithm` of an agent config (a run stored before ``agent.algo`` existed: SAC)."""
    return ALGORITHM[str(agent.get("algo", "sac"))]


def usage(agent: DictConfig) -> Usage:
    """Which of ``agent``'s shared options its algorithm maps or leaves out; an option left
    unset (``critic_arch: null``, ``target_entropy: null``) is neither."""
    algo = algorithm(agent)
    mapped = {k: v for k, v in algo.maps.items() if agent.get(k) is not None}
    left_out = tuple(k for k in algo.leaves_out if agent.get(k) is not None)
    return Usage(algo.name, mapped, left_out)


def _without_argument_checks() -> None:
    # torch.distributions checks every distribution's arguments by default: about a quarter of
    # an actor forward pass. The libraries' Gaussians are built valid (clamped log stds).
    torch.distributions.Distribution.set_default_validate_args(False)


def build_agent(agent: DictConfig, env: VecEnv, seed: int) -> BaseAlgorithm:
    """A new model of ``agent.algo`` on ``env`` from the ``agent`` config."""
    algo = algorithm(agent)
    if algo.name == "sac":
        return build_sac(agent, env, seed)
    _without_argument_checks()
    return algo.cls("MlpPolicy", env, seed=seed, verbose=0, **algo.kwargs(agent, env))


def load_agent(path: str, env: VecEnv | None, agent: DictConfig) -> BaseAlgorithm:
    """A saved model (checkpoint or final) of the run whose agent config is ``agent``;
    ``env`` None for inference only."""
    algo = algorithm(agent)
    if algo.name == "sac":
        return load_sac(path, env, agent)
    _without_argument_checks()
    with warnings.catch_warnings():
        # As for SAC (`armexp.agents.sac.load_sac`): a model saved with n-step returns carries
        # its NStepReplayBuffer class, which SB3 warns it will not set up again.
        warnings.filterwarnings("ignore", message=".*n_steps=.* is ignored because a custom")
        return algo.cls.load(path, env=env, device=str(agent.device))


def mark_resumed(model: BaseAlgorithm, learning_starts: int) -> None:
    """Before a resumed run learns: an off-policy model refills its empty replay buffer with
    its policy for ``learning_starts`` steps before updates resume; PPO collects its next
    rollout as it would have (a checkpoint loses at most the rollout in progress)."""
    if isinstance(model, ResumeRefill):
        model.resumed = True
        model.learning_starts = model.num_timesteps + int(learning_starts)
