"""The SAC update as one function of the batch and the policy noise (`TorchUpdate`, the function
``benchmarks.update_paths`` compiles with ``torch.compile``), and the floor of any update: its
matrix-product FLOPs (`update_flops`)."""

from __future__ import annotations

from collections.abc import Callable

import torch
import torch.nn.functional as F
from stable_baselines3.sac.policies import LOG_STD_MAX, LOG_STD_MIN
from torch.func import functional_call, grad_and_value

from armexp.agents.compiled import EPSILON
from armexp.agents.compiled import LOG_SQRT_2PI as HALF_LOG_2PI
from armexp.agents.sac import ResumableSAC

Params = dict[str, torch.Tensor]


def update_flops(obs: int, act: int, pi: list[int], qf: list[int], n: int) -> int:
    """Matrix-product FLOPs of one SAC update at batch ``n`` (2 per multiply-add), the least
    the arithmetic needs: actor forward on s and s', its backward (weights, and inputs above the
    first layer); the two target critics forward on s'; the two critics forward on (s, a) and
    backward (weights, inputs above the first layer); the two critics forward on (s, ã) and
    back to ã only (no weight gradients). Elementwise work is left out."""
    actor = list(zip([obs, *pi[:-1]], pi, strict=True)) + [(pi[-1], act)] * 2
    critic = list(zip([obs + act, *qf], [*qf, 1], strict=True))

    def size(layers: list[tuple[int, int]]) -> int:
        return sum(i * o for i, o in layers)

    a, c = size(actor), size(critic)
    first_c = (obs + act) * qf[0]
    actor_work = 2 * a + a + (a - obs * pi[0])  # two forwards, weight and input gradients
    critic_work = 2 * (c + c + c + (c - first_c))  # target, forward, weight and input grads
    actor_loss = 2 * (c + (c - first_c) + act * qf[0])  # forward, back to the action
    return 2 * n * (actor_work + critic_work + actor_loss)


class TorchUpdate:
    """SAC's update (SB3's losses, `ResumableSAC`'s order of optimiser steps) as one function of
    the batch and the policy's Gaussian noise, for ``torch.compile``. Gradients come from
    ``torch.func`` (``Tensor.backward`` is a graph break and a second backward through one
    compiled graph fails); each optimiser step is two graph breaks that torch puts there."""

    def __init__(self, model: ResumableSAC, mode: str | None) -> None:
        self.model = model
        self.actor_params: Params = dict(model.actor.named_parameters())
        self.critic_params: Params = dict(model.critic.named_parameters())
        self.critic_list: list[torch.Tensor] = list(model.critic.parameters())
        self.target_list: list[torch.Tensor] = list(model.critic_target.parameters())
        self.fn: Callable[..., torch.Tensor] = (
            self.update if mode == "eager" else torch.compile(self.update, mode=mode)
        )

    def _policy(
        self, params: Params, obs: torch.Tensor, noise: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """SB3's squashed Gaussian sample ã = tanh(μ + σε) and log π(ã|s), from ε."""
        actor = self.model.actor

        def sub(prefix: str) -> Params:
            return {k[len(prefix) :]: v for k, v in params.items() if k.startswith(prefix)}

        latent = functional_call(actor.latent_pi, sub("latent_pi."), (obs,))
        mean = functional_call(actor.mu, sub("mu."), (latent,))
        log_std = functional_call(actor.log_std, sub("log_std."), (latent,))  # type: ignore[arg-type]
        log_std = log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)
        action = torch.tanh(mean + log_std.exp() * noise)
        gaussian = (-0.5 * noise.square() - log_std - HALF_LOG_2PI).sum(1, keepdim=True)
        return action, gaussian - torch.log(1 - action.square() + EPSILON).sum(1, keepdim=True)

    def _critic_loss(self, params: Params, obs: torch.Tensor, actions: torch.Tensor,
                     target: torch.Tensor) -> torch.Tensor:  # fmt: skip
        qs = functional_call(self.model.critic, params, (obs, actions))
        return 0.5 * sum(F.mse_loss(q, target) for q in qs)  # type: ignore[return-value]

    def _actor_loss(self, params: Params, critic: Params, obs: torch.Tensor, noise: torch.Tensor,
                    alpha: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
        action, log_prob = self._policy(params, obs, noise)
        q = torch.cat(functional_call(self.model.critic, critic, (obs, action)), dim=1)
        return (alpha * log_prob - q.min(dim=1, keepdim=True).values).mean(), log_prob

    def _entropy_loss(self, log_alpha: torch.Tensor, log_prob: torch.Tensor) -> torch.Tensor:
        return -(log_alpha * (log_prob + float(self.model.target_entropy))).mean()

    def update(self, obs: torch.Tensor, actions: torch.Tensor, next_obs: torch.Tensor,
               rewards: torch.Tensor, dones: torch.Tensor, discounts: torch.Tensor,
               noise: torch.Tensor, next_noise: torch.Tensor) -> torch.Tensor:  # fmt: skip
        """One update; the entropy, critic and actor losses. The entropy step comes last here
        and first in SB3: it changes nothing the other two read (they use α before it)."""
        model = self.model
        log_alpha = model.log_ent_coef
        learned = model.ent_coef_optimizer is not None and log_alpha is not None
        alpha = log_alpha.detach().exp() if learned else model.ent_coef_tensor  # type: ignore[union-attr]
        with torch.no_grad():
            next_action, next_log_prob = self._policy(self.actor_params, next_obs, next_noise)
            next_q = torch.cat(model.critic_target(next_obs, next_action), dim=1)
            next_q = next_q.min(dim=1, keepdim=True).values - alpha * next_log_prob
            target = rewards + (1 - dones) * discounts * next_q
        critic = {k: v.detach() for k, v in self.critic_params.items()}
        grads, critic_loss = grad_and_value(self._critic_loss)(critic, obs, actions, target)
        for k, p in self.critic_params.items():
            p.grad = grads[k]
        model.critic.optimizer.step()
        actor = {k: v.detach() for k, v in self.actor_params.items()}
        grads, (actor_loss, log_prob) = grad_and_value(self._actor_loss, has_aux=True)(
            actor, critic, obs, noise, alpha
        )
        for k, p in self.actor_params.items():
            p.grad = grads[k]
        model.actor.optimizer.step()
        entropy_loss = torch.zeros(())
        if learned:
            grad, entropy_loss = grad_and_value(self._entropy_loss)(log_alpha.detach(), log_prob)  # type: ignore[union-attr]
            log_alpha.grad = grad  # type: ignore[union-attr]
            model.ent_coef_optimizer.step()  # type: ignore[union-attr]
        with torch.no_grad():
            torch._foreach_mul_(self.target_list, 1 - model.tau)
            torch._foreach_add_(self.target_list, self.critic_list, alpha=model.tau)
        return torch.stack([entropy_loss, critic_loss, actor_loss])

    def train(self, batch_size: int) -> list[float]:
        """One update on a sampled batch, the noise drawn as SB3 draws it (s first, then s')."""
        model = self.model
        data = model.replay_buffer.sample(batch_size)  # type: ignore[union-attr]
        shape = (batch_size, data.actions.shape[1])
        noise, next_noise = torch.empty(shape).normal_(), torch.empty(shape).normal_()
        discounts = data.discounts if data.discounts is not None else torch.tensor(model.gamma)
        losses = self.fn(data.observations, data.actions, data.next_observations, data.rewards,
                         data.dones, discounts, noise, next_noise)  # fmt: skip
        return losses.tolist()
