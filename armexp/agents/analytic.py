"""SAC's update (Algorithm 1, lines 11–15) with its gradients written out (``agent.gradients``).

For the small multilayer perceptrons of this task (a 128×128 actor, 64×64 critics, batches of
256) most of an autograd update's time is bookkeeping, not arithmetic: building the graph,
module calls and the distribution objects cost about three times the matrix products. This
update runs the same losses as SB3's `SAC.train`, with the same sampling and Adam (its fused
kernel), but computes each gradient with the chain rule written out below, one matrix product
per layer:

- critics: L_Q = ½ Σᵢ mean (Qᵢ(s, a) − y)², y = r + (1 − d) γⁿ (min_j Q̄_j(s', a') − α log π(a'|s'));
- actor: L_π = mean (α log π(ã|s) − min_j Q_j(s, ã)), ã = tanh(μ + σ ε), with
  log π = Σ_k log N(u_k; μ_k, σ_k) − Σ_k log(1 − ã_k² + 10⁻⁶); along u = μ + σε the Gaussian's
  exponent is −ε²/2 and has no gradient, so ∂ log π/∂μ_k = 2ã_k(1 − ã_k²)/(1 − ã_k² + 10⁻⁶) and
  ∂ log π/∂ log σ_k = −1 + σ_k ε_k ∂ log π/∂μ_k (the clamp of log σ to [−20, 2] passes its
  gradient inside the range only);
- entropy coefficient: ∂L_α/∂ log α = −mean(log π + H̄);
- actor terms (`armexp.agents.sac.ActorTerm`, the cloning aid): their states share the actor's
  hidden-layer pass with SAC's batch and their critic values the actor loss's critic pass; the
  term's gradient with respect to the actor's mode tanh(μ) comes from its own (small) loss.

`tests/test_analytic.py` checks every parameter's update against autograd's on the same batch.
`AnalyticUpdate.supports` names what it covers: SB3's default MLP policy with ReLU hidden
layers, separate actor and critic features, no gSDE, target updates every step.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import torch
from torch import nn

if TYPE_CHECKING:
    from armexp.agents.sac import ResumableSAC

Layers = list[tuple[torch.Tensor, torch.Tensor]]  # (weight, bias) per linear layer

LOG_STD_MIN, LOG_STD_MAX = -20.0, 2.0  # SB3's clamp of the actor's log σ
EPSILON = 1e-6  # SB3's guard in log(1 − tanh² + ε)
HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


def _linear_layers(net: nn.Module) -> Layers | None:
    """(weight, bias) of ``net``'s layers if it is Linear, ReLU, …, Linear; else None."""
    modules = list(net) if isinstance(net, nn.Sequential) else [net]
    kinds = [nn.Linear if k % 2 == 0 else nn.ReLU for k in range(len(modules))]
    if not all(isinstance(m, kind) for m, kind in zip(modules, kinds, strict=True)):
        return None  # not Linear and ReLU strictly alternating
    linears: list[nn.Linear] = modules[0::2]  # type: ignore[assignment]
    if any(m.bias is None for m in linears):
        return None
    return [(m.weight, m.bias) for m in linears]


def _layers(net: nn.Module) -> Layers:
    layers = _linear_layers(net)
    assert layers is not None, "AnalyticUpdate.supports checks the model first"
    return layers


def _forward(x: torch.Tensor, layers: Layers, last_relu: bool) -> list[torch.Tensor]:
    """Every layer's input and the output: [x, h₁, …, out] (ReLU after all but the last layer
    unless ``last_relu``)."""
    out = [x]
    for k, (weight, bias) in enumerate(layers):
        h = torch.addmm(bias, out[-1], weight.t())
        out.append(h.relu_() if last_relu or k < len(layers) - 1 else h)
    return out


def _backward(
    grad: torch.Tensor, acts: list[torch.Tensor], layers: Layers, rows: int | None = None,
    weights: bool = True, inputs: bool = False,
) -> tuple[Layers, torch.Tensor | None]:  # fmt: skip
    """Back through ``_forward``'s layers from the output gradient ``grad``: the parameter
    gradients (if ``weights``) and the input's (if ``inputs``); ``rows`` limits the pass to
    the first rows of ``acts``."""
    grads: Layers = []
    for k in range(len(layers) - 1, -1, -1):
        weight, _ = layers[k]
        below = acts[k] if rows is None else acts[k][:rows]
        if weights:
            grads.append((grad.t() @ below, grad.sum(0)))
        if k > 0 or inputs:
            grad = grad @ weight
            if k > 0:  # ReLU's own backward kernel: zero where its output was zero
                grad = torch.ops.aten.threshold_backward(grad, below, 0)
    grads.reverse()
    return grads, (grad if inputs else None)


def _set(layers: Layers, grads: Layers) -> None:
    for (weight, bias), (gw, gb) in zip(layers, grads, strict=True):
        weight.grad, bias.grad = gw, gb


class AnalyticUpdate:
    """The update above for ``model``; `train` replaces SB3's `SAC.train` loop body."""

    def __init__(self, model: ResumableSAC) -> None:
        self.model = model
        actor, critic = model.actor, model.critic
        self.hidden = _layers(actor.latent_pi)
        log_std: nn.Module = actor.log_std  # type: ignore[assignment]  # a Linear without gSDE
        self.heads = [*_layers(actor.mu), *_layers(log_std)]  # μ, then log σ
        self.critics = [_layers(q) for q in critic.q_networks]
        self.targets = [_layers(q) for q in model.critic_target.q_networks]
        self.critic_params: list[torch.Tensor] = list(critic.parameters())
        self.target_params: list[torch.Tensor] = list(model.critic_target.parameters())

    @staticmethod
    def supports(model: ResumableSAC) -> str | None:
        """None if this update covers ``model``, else why not (one phrase)."""
        from stable_baselines3.common.torch_layers import FlattenExtractor

        actor, critic = model.actor, model.critic
        if not model.plain_update:
            return "gSDE, delayed target updates and batch norm are not covered"
        if (
            not isinstance(actor.features_extractor, FlattenExtractor)
            or critic.share_features_extractor
        ):
            return "it needs flat observations and the critics' own features"
        nets = [actor.latent_pi, *critic.q_networks, *model.critic_target.q_networks]
        heads = (actor.mu, actor.log_std)
        if any(_linear_layers(n) is None for n in nets) or not all(
            isinstance(h, nn.Linear) for h in heads
        ):
            return "it needs Linear and ReLU layers (SB3's MlpPolicy with activation_fn=ReLU)"
        return None

    def _actor(self, states: torch.Tensor) -> tuple[list[torch.Tensor], torch.Tensor, torch.Tensor]:
        acts = _forward(states, self.hidden, last_relu=True)
        (mw, mb), (sw, sb) = self.heads
        return acts, torch.addmm(mb, acts[-1], mw.t()), torch.addmm(sb, acts[-1], sw.t())

    @staticmethod
    def _squash(
        mean: torch.Tensor, raw_log_std: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """ã, log π(ã) (k, 1), ε and σ: SB3's squashed Gaussian sample."""
        log_std = raw_log_std.clamp(LOG_STD_MIN, LOG_STD_MAX)
        std = log_std.exp()
        noise = torch.empty_like(mean).normal_()  # as Normal.rsample draws it
        action = torch.tanh(mean + std * noise)
        gaussian = (-0.5 * noise.square() - log_std - HALF_LOG_2PI).sum(1, keepdim=True)
        log_prob = gaussian - torch.log(1 - action.square() + EPSILON).sum(1, keepdim=True)
        return action, log_prob, noise, std

    def train(self, gradient_steps: int, batch_size: int) -> dict[str, list[float]]:
        """``gradient_steps`` updates on batches of ``batch_size``; the losses of each."""
        logs: dict[str, list[float]] = {k: [] for k in ("ent_coef", "ent_coef_loss",
                                                         "actor_loss", "critic_loss")}  # fmt: skip
        with torch.no_grad():
            for _ in range(gradient_steps):
                self._step(batch_size, logs)
        return logs

    def _step(self, n: int, logs: dict[str, list[float]]) -> None:
        model = self.model
        data = model.replay_buffer.sample(n, env=model._vec_normalize_env)  # type: ignore[union-attr]
        discounts = data.discounts if data.discounts is not None else model.gamma
        batches = [term.batch() for term in model.actor_terms]
        states = torch.cat([data.observations, *(b[0] for b in batches)])
        acts, mean, raw_log_std = self._actor(states)
        action, log_prob, noise, std = self._squash(mean[:n], raw_log_std[:n])

        if model.ent_coef_optimizer is not None and model.log_ent_coef is not None:
            log_alpha = model.log_ent_coef
            alpha = torch.exp(log_alpha)
            gap = log_prob + float(model.target_entropy)
            logs["ent_coef_loss"].append(float(-(log_alpha * gap).mean()))
            log_alpha.grad = -gap.mean().reshape(1)
            model.ent_coef_optimizer.step()
        else:
            alpha = model.ent_coef_tensor
        logs["ent_coef"].append(float(alpha))

        # Critics (line 12), towards the n-step target of the target critics.
        _, next_mean, next_raw = self._actor(data.next_observations)
        next_action, next_log_prob, _, _ = self._squash(next_mean, next_raw)
        after = torch.cat([data.next_observations, next_action], dim=1)
        next_q = torch.cat([_forward(after, net, False)[-1] for net in self.targets], dim=1)
        next_q = next_q.min(dim=1, keepdim=True).values - alpha * next_log_prob
        target_q = data.rewards + (1 - data.dones) * discounts * next_q
        taken = torch.cat([data.observations, data.actions], dim=1)
        critic_loss = 0.0
        for net in self.critics:
            net_acts = _forward(taken, net, False)
            error = net_acts[-1] - target_q
            critic_loss += 0.5 * float(error.square().mean())
            _set(net, _backward(error / n, net_acts, net)[0])  # ∂(½ mean e²)/∂Q = e/n
        logs["critic_loss"].append(critic_loss)
        model.critic.optimizer.step()

        # Actor (line 13) on the updated critics; the terms' states ride along.
        chosen = torch.cat([action, *(b[1] for b in batches)])
        q_acts = [_forward(torch.cat([states, chosen], dim=1), net, False) for net in self.critics]
        q_all = torch.cat([a[-1] for a in q_acts], dim=1)
        min_q, which = q_all.min(dim=1, keepdim=True)
        logs["actor_loss"].append(float((alpha * log_prob - min_q[:n]).mean()))
        grad_action = torch.zeros_like(action)
        obs_dim = states.shape[1]
        for i, (net, net_acts) in enumerate(zip(self.critics, q_acts, strict=True)):
            grad_q = (which[:n] == i).to(action.dtype) * (-1.0 / n)
            _, grad_in = _backward(grad_q, net_acts, net, rows=n, weights=False, inputs=True)
            assert grad_in is not None
            grad_action += grad_in[:, obs_dim:]
        grad_log_prob = alpha / n
        slack = 1 - action.square()
        grad_u = grad_action * slack + grad_log_prob * (2 * action * slack / (slack + EPSILON))
        grad_mean = torch.zeros_like(mean)
        grad_raw = torch.zeros_like(raw_log_std)
        grad_mean[:n] = grad_u
        inside = (raw_log_std[:n] >= LOG_STD_MIN) & (raw_log_std[:n] <= LOG_STD_MAX)
        grad_raw[:n] = (grad_u * noise * std - grad_log_prob) * inside
        start = n
        for term, (term_states, term_actions) in zip(model.actor_terms, batches, strict=True):
            rows = slice(start, start + len(term_states))
            with torch.enable_grad():
                mode = torch.tanh(mean[rows]).requires_grad_(True)
                (grad_mode,) = torch.autograd.grad(
                    term.loss(mode, term_actions, min_q[rows, 0]), mode
                )
            grad_mean[rows] = grad_mode * (1 - mode.detach().square())
            start += len(term_states)
        top = acts[-1]
        (mean_w, _), (std_w, _) = self.heads
        _set(self.heads, [(grad_mean.t() @ top, grad_mean.sum(0)),
                          (grad_raw.t() @ top, grad_raw.sum(0))])  # fmt: skip
        grad_top = torch.ops.aten.threshold_backward(grad_mean @ mean_w + grad_raw @ std_w, top, 0)
        _set(self.hidden, _backward(grad_top, acts, self.hidden)[0])
        model.actor.optimizer.step()

        torch._foreach_mul_(self.target_params, 1 - model.tau)
        torch._foreach_add_(self.target_params, self.critic_params, alpha=model.tau)
