"""SB3 SAC (Algorithm 1) from the ``agent`` config group (Table II for ``agent=sac_paper``)."""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from omegaconf import DictConfig
from stable_baselines3 import SAC
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.sac.policies import SACPolicy

from armexp.agents.algorithms import ResumeRefill
from armexp.agents.compiled import CompiledUpdate
from armexp.agents.droq import DroQPolicy
from armexp.agents.terms import ActorTerm
from armexp.config import ConfigError
from armexp.resources import device_here


class ResumableSAC(ResumeRefill, SAC):
    """SB3's SAC with these changes.

    - Once resumed from a checkpoint, it refills its (empty) replay buffer with its own policy
      instead of the uniform random actions SB3 uses before ``learning_starts``
      (`armexp.agents.algorithms.ResumeRefill`, as the other off-policy algorithms).
    - `train` is SB3's update (Algorithm 1, lines 11–15) without the work whose result SB3
      throws away: the critics' parameter gradients of the actor loss (zeroed before the next
      critic step), the recursive train-mode switch when the policy is in train mode already,
      and per-tensor target averaging (one foreach call instead). Without `actor_terms` the
      arithmetic is SB3's operation for operation, so a seed's run gives the same parameters
      as SB3's update (``tests/test_sac.py``), in less time per update.
    - `actor_terms` (the cloning aid's) add their gradients to the actor loss's before the
      actor's optimiser step.
    - With ``gradients = "compiled"`` the same update runs as one ``torch.compile`` graph per
      call (`armexp.agents.compiled`), Adam included: the same update to rounding, in about
      half the time or less.
    """

    #: How `train` computes the gradients: ``autograd`` (SB3's losses through torch's
    #: autograd) or ``compiled`` (`armexp.agents.compiled`); ``agent.gradients``.
    gradients = "autograd"
    #: Further actor loss terms on states of their own (the cloning aid); see `ActorTerm`.
    actor_terms: list[ActorTerm]
    _compiled: CompiledUpdate | None

    def _setup_model(self) -> None:
        super()._setup_model()
        self.actor_terms = []
        self._compiled = None

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "actor_terms", "_compiled"]

    @property
    def plain_update(self) -> bool:
        """Whether `train`'s own update covers this model: no gSDE, target updates every step,
        no batch-norm statistics (otherwise SB3's update runs, without actor terms)."""
        return not (self.use_sde or self.target_update_interval != 1 or self.batch_norm_stats)

    def train(self, gradient_steps: int, batch_size: int = 64) -> None:
        if not self.plain_update:
            if self.actor_terms:
                raise ValueError("actor terms need SAC without gSDE, delayed targets, batch norm")
            return super().train(gradient_steps, batch_size)  # the cases this update leaves out
        if not self.policy.training:
            self.policy.set_training_mode(True)
        optimizers = [self.actor.optimizer, self.critic.optimizer]
        if self.ent_coef_optimizer is not None:
            optimizers.append(self.ent_coef_optimizer)
        self._update_learning_rate(optimizers)
        if self.gradients == "compiled":
            if self._compiled is None:  # compiles at its first call
                self._compiled = CompiledUpdate(self)
            logs = self._compiled.train(gradient_steps, batch_size)
        else:
            logs = self._autograd_train(gradient_steps, batch_size)
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        for key in ("ent_coef", "actor_loss", "critic_loss", "ent_coef_loss"):
            if logs[key]:
                self.logger.record(f"train/{key}", np.mean(logs[key]))

    def _autograd_train(self, gradient_steps: int, batch_size: int) -> dict[str, list[float]]:
        actor, critic, target = self.actor, self.critic, self.critic_target
        critic_params: list[torch.Tensor] = list(critic.parameters())
        target_params: list[torch.Tensor] = list(target.parameters())
        ent_coef_losses, ent_coefs, actor_losses, critic_losses = [], [], [], []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            discounts = data.discounts if data.discounts is not None else self.gamma
            actions_pi, log_prob = actor.action_log_prob(data.observations)
            log_prob = log_prob.reshape(-1, 1)
            if self.ent_coef_optimizer is not None and self.log_ent_coef is not None:
                ent_coef = torch.exp(self.log_ent_coef.detach())
                assert isinstance(self.target_entropy, float)
                entropy_gap = (log_prob + self.target_entropy).detach()
                ent_coef_loss = -(self.log_ent_coef * entropy_gap).mean()
                ent_coef_losses.append(ent_coef_loss.item())
                ent_coefs.append(ent_coef.item())
                self.ent_coef_optimizer.zero_grad()
                ent_coef_loss.backward()
                self.ent_coef_optimizer.step()
            else:
                ent_coef = self.ent_coef_tensor
                ent_coefs.append(ent_coef.item())
            with torch.no_grad():
                next_actions, next_log_prob = actor.action_log_prob(data.next_observations)
                next_q = torch.cat(target(data.next_observations, next_actions), dim=1)
                next_q, _ = torch.min(next_q, dim=1, keepdim=True)
                next_q = next_q - ent_coef * next_log_prob.reshape(-1, 1)
                target_q = data.rewards + (1 - data.dones) * discounts * next_q
            current_q = critic(data.observations, data.actions)
            critic_loss = 0.5 * sum(F.mse_loss(q, target_q) for q in current_q)
            assert isinstance(critic_loss, torch.Tensor)
            critic_losses.append(critic_loss.item())
            critic.optimizer.zero_grad()
            critic_loss.backward()
            critic.optimizer.step()
            # The actor loss needs the critics' gradient with respect to the action only.
            for param in critic_params:
                param.requires_grad_(False)
            try:
                q_pi = torch.cat(critic(data.observations, actions_pi), dim=1)
                min_q_pi, _ = torch.min(q_pi, dim=1, keepdim=True)
                actor_loss = (ent_coef * log_prob - min_q_pi).mean()
                actor_losses.append(actor_loss.item())
                actor.optimizer.zero_grad()
                actor_loss.backward()
                for term in self.actor_terms:  # their gradients add to SAC's
                    states, actions, returns = term.batch()
                    with torch.no_grad():
                        q = torch.cat(critic(states, actions), dim=1).min(dim=1).values
                    term.loss(actor(states, deterministic=True), actions, q, returns).backward()
            finally:
                for param in critic_params:
                    param.requires_grad_(True)
            actor.optimizer.step()
            with torch.no_grad():
                torch._foreach_mul_(target_params, 1 - self.tau)
                torch._foreach_add_(target_params, critic_params, alpha=self.tau)
        return {"ent_coef": ent_coefs, "ent_coef_loss": ent_coef_losses,
                "actor_loss": actor_losses, "critic_loss": critic_losses}  # fmt: skip


def off_policy_kwargs(agent: DictConfig, tau: bool = True) -> dict[str, Any]:
    """The replay-buffer options every off-policy algorithm reads as SAC does (``tau``: whether
    it keeps target networks)."""
    out = {
        "batch_size": int(agent.batch_size),
        "buffer_size": int(agent.buffer_size),
        "learning_starts": int(agent.learning_starts),
        "gamma": float(agent.gamma),
        "learning_rate": float(agent.learning_rate),
        "train_freq": int(agent.train_freq),
        "gradient_steps": int(agent.gradient_steps),
        "n_steps": int(agent.n_steps),
        "device": device_here(str(agent.device)),
    }
    if tau:
        out["tau"] = float(agent.tau)
    return out


def sac_kwargs(agent: DictConfig) -> dict[str, Any]:
    """SB3 keyword arguments of an ``agent`` config (the keys are Table II's)."""
    arch: list[int] | dict[str, list[int]] = list(agent.net_arch)
    if agent.critic_arch is not None:
        arch = {"pi": list(agent.net_arch), "qf": list(agent.critic_arch)}
    policy_kwargs: dict[str, Any] = {"net_arch": arch, "optimizer_kwargs": _adam(agent)}
    if agent.get("critic_dropout") is not None:
        policy_kwargs["critic_dropout"] = float(agent.critic_dropout)
    return {
        **off_policy_kwargs(agent),
        "ent_coef": agent.ent_coef,
        "target_entropy": target_entropy(agent),
        "policy_kwargs": policy_kwargs,
    }


def sac_policy(agent: DictConfig) -> str | type[SACPolicy]:
    """SB3's MLP policy, or DroQ's (`armexp.agents.droq`) where ``agent.critic_dropout`` is set."""
    return "MlpPolicy" if agent.get("critic_dropout") is None else DroQPolicy


def target_entropy(agent: DictConfig) -> str | float:
    """``agent.target_entropy`` as the libraries take it ("auto" when null; a stored run from
    before the key: "auto")."""
    value = agent.get("target_entropy")
    return "auto" if value is None else float(value)


def _without_argument_checks() -> None:
    # torch.distributions checks every Normal's arguments by default: about a quarter of an
    # actor forward pass. SB3's squashed Gaussian builds them valid (a clamped log std).
    torch.distributions.Distribution.set_default_validate_args(False)


def _with_gradients(model: ResumableSAC, agent: DictConfig) -> ResumableSAC:
    model.gradients = str(agent.get("gradients", "autograd"))
    why = CompiledUpdate.supports(model) if model.gradients == "compiled" else None
    if why is not None:
        raise ConfigError(
            f"agent.gradients={model.gradients} is not allowed for this agent: {why}; use "
            "agent.gradients=autograd."
        )
    return model


def _adam(agent: DictConfig) -> dict[str, bool]:
    # Adam's multi-tensor loop keeps autograd's update bit for bit that of SB3's per-tensor
    # default, in fewer calls (the compiled update writes Adam's arithmetic in its graph).
    return {"foreach": True}


def build_sac(agent: DictConfig, env: VecEnv, seed: int) -> ResumableSAC:
    _without_argument_checks()
    model = ResumableSAC(sac_policy(agent), env, seed=seed, verbose=0, **sac_kwargs(agent))
    return _with_gradients(model, agent)


def load_sac(path: str, env: VecEnv | None, agent: DictConfig) -> ResumableSAC:
    """A saved model (checkpoint or final); ``env`` None for inference only."""
    _without_argument_checks()
    with warnings.catch_warnings():
        # A model saved with n-step returns carries its NStepReplayBuffer class and kwargs; SB3
        # warns on load that it will not set them up again, which is what we want.
        warnings.filterwarnings("ignore", message=".*n_steps=.* is ignored because a custom")
        model = ResumableSAC.load(path, env=env, device=str(agent.device))
    return _with_gradients(model, agent)
