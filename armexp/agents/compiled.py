"""SAC's update through ``torch.compile`` (``agent.gradients=compiled``).

For the small networks of this task most of an eager update's time is per-operation overhead
(graph building, module calls, distribution objects, one optimiser kernel per tensor), not
arithmetic (`docs/update_paths.md`). This update runs SB3's own modules and `ResumableSAC`'s
losses as one function of the sampled batches and the policy noise, which ``torch.compile``
turns into one graph of up to two gradient steps (`steps_per_graph`), run as often as a call
needs:

- gradients come from ``torch.func.grad_and_value`` over ``functional_call`` of SB3's actor
  and critics (``Tensor.backward`` does not trace), so no gradient is written by hand;
- Adam's update is written on tensors here (`adam`, torch's own arithmetic for tensor step
  counts) instead of calling ``Optimizer.step``, which torch keeps out of a graph; its moments
  and step counts are the SB3 optimisers' own ``state`` entries, updated in place, so their
  state dicts, SB3's save and load and the checkpoints are unchanged;
- each call's ``gradient_steps`` batches and noise are drawn before the graph runs, in the
  order the eager update draws them (NumPy's generator for the batches, torch's for the noise:
  s, then s′, per step), so a seed gives the eager update's batches and noise.

The function compiles at the first update of a process (inductor keeps the generated code on
disk, `armexp.jit_cache`); `CompiledUpdate.supports` names what it leaves out.
``tests/test_compiled_update.py`` checks losses, gradients and weights against autograd's.
"""

from __future__ import annotations

import math
import types
from collections.abc import Callable, Sequence
from typing import Any, Protocol

import torch
import torch.nn.functional as F
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.common.vec_env import VecNormalize
from stable_baselines3.sac.policies import Actor
from torch import nn
from torch.func import functional_call, grad_and_value

from armexp.agents.terms import ActorTerm, TermBatch


class SACModel(Protocol):
    """What this update reads of the model it updates (`armexp.agents.sac.ResumableSAC`, which
    imports this module: a protocol instead of that class keeps the import one way)."""

    @property
    def actor(self) -> Actor: ...
    @property
    def critic(self) -> ContinuousCritic: ...
    @property
    def critic_target(self) -> ContinuousCritic: ...
    @property
    def plain_update(self) -> bool: ...
    @property
    def observation_space(self) -> spaces.Space[Any]: ...
    @property
    def action_space(self) -> spaces.Space[Any]: ...
    @property
    def ent_coef_optimizer(self) -> torch.optim.Optimizer | None: ...
    @property
    def log_ent_coef(self) -> torch.Tensor | None: ...
    @property
    def ent_coef_tensor(self) -> torch.Tensor: ...
    @property
    def target_entropy(self) -> str | float: ...
    @property
    def tau(self) -> float: ...
    @property
    def gamma(self) -> float: ...
    @property
    def replay_buffer(self) -> ReplayBuffer | None: ...
    @property
    def _vec_normalize_env(self) -> VecNormalize | None: ...
    @property
    def device(self) -> torch.device: ...
    @property
    def actor_terms(self) -> list[ActorTerm]: ...


Tensors = list[torch.Tensor]
EPSILON = 1e-6  # SB3's guard in log(1 − tanh² + ε)
LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))
#: torch.compile's mode: the default. ``max-autotune-no-cudagraphs`` was no faster here and its
#: tuned matmul-plus-matmul kernel fails on ``sac_paper``'s 256-wide layers (torch 2.13, an
#: inductor assertion on the two products' layouts).
MODE: str | None = None
LOGGED = ("ent_coef", "ent_coef_loss", "critic_loss", "actor_loss")
#: At most this many gradient steps in one graph. Two per graph ran 1.1-1.2x one per graph
#: (docs/update_paths.md); an unrolled graph compiles in time roughly proportional to its steps,
#: so a call of more steps runs the graph of two (or of one, for an odd count) several times.
MAX_STEPS_PER_GRAPH = 2


def own_code(method: Callable[..., Any]) -> Callable[..., Any]:
    """``method`` bound to a copy of its function with a code object of its own.

    Dynamo keeps compiled graphs, and counts recompilations against its limit, per code object:
    compiling the one shared ``steps`` of every update would add a graph per model to one cache,
    so a process that trains many models (an HPO's trials, a study) would hit the limit and fail
    (``fullgraph``). A code object per update gives each its own cache, which goes with it.
    """
    fn = method.__func__  # type: ignore[attr-defined]
    copy = types.FunctionType(
        fn.__code__.replace(), fn.__globals__, fn.__name__, fn.__defaults__, fn.__closure__
    )
    return types.MethodType(copy, method.__self__)  # type: ignore[attr-defined]


def steps_per_graph(gradient_steps: int) -> int:
    """The largest divisor of ``gradient_steps`` up to `MAX_STEPS_PER_GRAPH`: every call of a
    run then uses one graph, compiled once."""
    return max(k for k in range(1, MAX_STEPS_PER_GRAPH + 1) if gradient_steps % k == 0)


def adam(params: Tensors, grads: Tensors, state: list[Tensors], lr: torch.Tensor,
         betas: tuple[float, float], eps: float) -> None:  # fmt: skip
    """torch's Adam (no weight decay, amsgrad or maximize) in place on ``params`` and their
    ``state`` ([step, exp_avg, exp_avg_sq] each), in torch's arithmetic for tensor steps."""
    beta1, beta2 = betas
    for p, g, (step, avg, sq) in zip(params, grads, state, strict=True):
        step.add_(1)
        avg.lerp_(g, 1 - beta1)
        sq.mul_(beta2).addcmul_(g, g, value=1 - beta2)
        step_size_neg = -(lr / (1 - beta1**step))
        bias2_sqrt = (1 - beta2**step).sqrt()
        p.addcdiv_(avg, (sq.sqrt() / (bias2_sqrt * step_size_neg)).add_(eps / step_size_neg))


class _Policy(nn.Module):
    """The actor's Gaussian (μ and clamped log σ, SB3's `get_action_dist_params`) as a
    module's forward, for ``functional_call``."""

    def __init__(self, actor: nn.Module) -> None:
        super().__init__()
        self.actor = actor

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean, log_std, _ = self.actor.get_action_dist_params(obs)  # type: ignore[operator]
        return mean, log_std


class CompiledUpdate:
    """The update above for ``model``; `train` replaces the body of SB3's `SAC.train` loop."""

    #: Also keep the last step's gradients in the parameters' ``.grad`` (for tests).
    keep_grads = False

    def __init__(self, model: SACModel, mode: str | None = MODE, **options: Any) -> None:
        # One graph or an error (no silent graph breaks); shapes fixed per batch size and
        # steps per call, so a call never recompiles after the first.
        options = {"fullgraph": True, "dynamic": False, **options}
        self.model = model
        self.policy = _Policy(model.actor)
        self.actor_names = [k for k, _ in self.policy.named_parameters()]
        self.actor_params = [p for _, p in self.policy.named_parameters()]
        self.critic_names = [k for k, _ in model.critic.named_parameters()]
        self.critic_params = list(model.critic.parameters())
        self.target_names = [k for k, _ in model.critic_target.named_parameters()]
        self.target_params = list(model.critic_target.parameters())
        self.fn: Callable[..., Any] = (
            self.steps
            if mode == "eager"
            else torch.compile(own_code(self.steps), mode=mode, **options)
        )

    @staticmethod
    def supports(model: SACModel) -> str | None:
        """None if this update covers ``model``, else why not (one phrase)."""
        if not model.plain_update:
            return "gSDE, delayed target updates and batch norm are not covered"
        if any(isinstance(m, nn.Dropout) for m in model.critic.modules()):
            return "dropout critics (agent.critic_dropout) are not covered"
        if not isinstance(model.observation_space, spaces.Box):
            return "it needs array (Box) observations"
        optimizers = [model.actor.optimizer, model.critic.optimizer, model.ent_coef_optimizer]
        for opt in filter(None, optimizers):
            group = opt.param_groups[0]
            plain = type(opt) is torch.optim.Adam and len(opt.param_groups) == 1
            if not plain or group["weight_decay"] or group["amsgrad"] or group["maximize"]:
                return "it writes Adam's update without weight decay, amsgrad or maximize"
        return None

    # ------------------------------------------------------------------ inside the graph
    def _sample(self, params: Tensors, obs: torch.Tensor,
                noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
        """SB3's squashed Gaussian sample ã = tanh(μ + σε) and log π(ã|s) (k, 1), from ε."""
        named = dict(zip(self.actor_names, params, strict=True))
        mean, log_std = functional_call(self.policy, named, (obs,))
        std = torch.ones_like(mean) * log_std.exp()
        gaussian = mean + noise * std  # Normal.rsample; its log_prob below, term for term
        log_prob = -((gaussian - mean) ** 2) / (2 * std**2) - std.log() - LOG_SQRT_2PI
        action = torch.tanh(gaussian)
        log_prob = log_prob.sum(1) - torch.log(1 - action**2 + EPSILON).sum(1)
        return action, log_prob.reshape(-1, 1)

    def _q(self, params: Tensors, obs: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        named = dict(zip(self.critic_names, params, strict=True))
        return torch.cat(functional_call(self.model.critic, named, (obs, actions)), dim=1)

    def _critic_loss(self, params: Tensors, obs: torch.Tensor, actions: torch.Tensor,
                     target: torch.Tensor) -> torch.Tensor:  # fmt: skip
        qs = self._q(params, obs, actions).split(1, dim=1)
        return 0.5 * sum(F.mse_loss(q, target) for q in qs)  # type: ignore[return-value]

    def _actor_loss(self, params: Tensors, critic: Tensors, obs: torch.Tensor,
                    noise: torch.Tensor, alpha: torch.Tensor,
                    terms: list[TermBatch]) -> tuple[torch.Tensor, Any]:  # fmt: skip
        action, log_prob = self._sample(params, obs, noise)
        min_q = self._q(critic, obs, action).min(dim=1, keepdim=True).values
        actor_loss = (alpha * log_prob - min_q).mean()
        values = []
        for term, (states, actions, returns) in zip(self.model.actor_terms, terms, strict=True):
            with torch.no_grad():
                q = self._q(critic, states, actions).min(dim=1).values
            named = dict(zip(self.actor_names, params, strict=True))
            mean, _ = functional_call(self.policy, named, (states,))
            values.append(term.value(torch.tanh(mean), actions, q, returns))
        return actor_loss + sum(values), (actor_loss, log_prob, values)

    def steps(self, actor: Tensors, critic: Tensors, target: Tensors, log_alpha: Tensors,
              state: list[list[Tensors]], lr: torch.Tensor, batches: list[Tensors],
              noises: Tensors, terms: list[list[TermBatch]],
              ) -> tuple[torch.Tensor, Tensors]:  # fmt: skip
        """Every gradient step of a call: for each, (ent_coef, its loss, critic loss, actor
        loss, actor terms' losses); the last step's gradients if `keep_grads`."""
        model = self.model
        opts = [model.actor.optimizer, model.critic.optimizer, model.ent_coef_optimizer]
        hyper = [(o.param_groups[0]["betas"], o.param_groups[0]["eps"]) for o in opts if o]
        rows, grads = [], []
        for k, (obs, actions, next_obs, rewards, dones, discounts) in enumerate(batches):
            noise, next_noise = noises[2 * k], noises[2 * k + 1]
            alpha = log_alpha[0].exp() if log_alpha else model.ent_coef_tensor
            with torch.no_grad():
                next_action, next_log_prob = self._sample(actor, next_obs, next_noise)
                next_q = self._q(target, next_obs, next_action).min(dim=1, keepdim=True).values
                target_q = rewards + (1 - dones) * discounts * (next_q - alpha * next_log_prob)
            critic_grads, critic_loss = grad_and_value(self._critic_loss)(
                critic, obs, actions, target_q
            )
            adam(critic, critic_grads, state[1], lr[1], *hyper[1])
            actor_grads, (_, (actor_loss, log_prob, values)) = grad_and_value(
                self._actor_loss, has_aux=True
            )(actor, critic, obs, noise, alpha, terms[k])
            adam(actor, actor_grads, state[0], lr[0], *hyper[0])
            entropy_loss = torch.zeros(())
            grads = [*actor_grads, *critic_grads]
            if log_alpha:
                gap = log_prob + float(model.target_entropy)
                entropy_loss = -(log_alpha[0] * gap).mean()
                alpha_grad = [-gap.mean().reshape(1)]
                adam(log_alpha, alpha_grad, state[2], lr[2], *hyper[2])
                grads += alpha_grad
            torch._foreach_mul_(target, 1 - model.tau)
            torch._foreach_add_(target, critic, alpha=model.tau)
            rows.append(torch.stack([alpha.reshape(()), entropy_loss, critic_loss, actor_loss,
                                     *values]))  # fmt: skip
        return torch.stack(rows), (grads if self.keep_grads else [])

    # --------------------------------------------------------------------- outside it
    def _adam_state(
        self, opt: torch.optim.Optimizer, params: Sequence[torch.Tensor]
    ) -> list[Tensors]:
        """[step, exp_avg, exp_avg_sq] of each of ``params`` in ``opt``'s own state (created
        as Adam creates it at its first step)."""
        out = []
        for p in params:
            s = opt.state[p]
            if not s:
                s["step"] = torch.tensor(0.0, dtype=torch.float32)
                s["exp_avg"] = torch.zeros_like(p, memory_format=torch.preserve_format)
                s["exp_avg_sq"] = torch.zeros_like(p, memory_format=torch.preserve_format)
            out.append([s["step"], s["exp_avg"], s["exp_avg_sq"]])
        return out

    def train(self, gradient_steps: int, batch_size: int) -> dict[str, list[float]]:
        """``gradient_steps`` updates on batches of ``batch_size``; the losses of each."""
        model = self.model
        batches, noises, terms = [], [], []
        shape, device = (batch_size, *model.action_space.shape), model.device  # type: ignore[misc]
        for _ in range(gradient_steps):  # drawn in the eager update's order
            data = model.replay_buffer.sample(batch_size, env=model._vec_normalize_env)  # type: ignore[union-attr]
            discounts = data.discounts if data.discounts is not None else model.gamma
            batches.append((data.observations, data.actions, data.next_observations,
                            data.rewards, data.dones, discounts))  # fmt: skip
            noises += [torch.empty(shape, device=device).normal_() for _ in "s'"]
            terms.append([term.batch() for term in model.actor_terms])
        actor, critic = model.actor.optimizer, model.critic.optimizer
        # Detached aliases: the graph updates the parameters' storage in place, untracked.
        params = [[p.detach() for p in ps] for ps in (self.actor_params, self.critic_params)]
        state = [self._adam_state(actor, self.actor_params),
                 self._adam_state(critic, self.critic_params)]  # fmt: skip
        log_alpha: Tensors = []
        lrs = [actor.param_groups[0]["lr"], critic.param_groups[0]["lr"], 0.0]
        if model.ent_coef_optimizer is not None and model.log_ent_coef is not None:
            log_alpha = [model.log_ent_coef.detach()]
            state.append(self._adam_state(model.ent_coef_optimizer, [model.log_ent_coef]))
            lrs[2] = model.ent_coef_optimizer.param_groups[0]["lr"]
        targets = [p.detach() for p in self.target_params]
        lr = torch.tensor(lrs, device=device)
        chunk = steps_per_graph(gradient_steps)
        parts, grads = [], []
        for k in range(0, gradient_steps, chunk):
            part, grads = self.fn(
                *params, targets, log_alpha, state, lr,
                batches[k : k + chunk], noises[2 * k : 2 * (k + chunk)], terms[k : k + chunk],
            )  # fmt: skip
            parts.append(part)
        rows = torch.cat(parts)
        if grads:
            owners = [*self.actor_params, *self.critic_params]
            owners += [model.log_ent_coef] if log_alpha else []  # type: ignore[list-item]
            for p, g in zip(owners, grads, strict=True):
                p.grad = g
        table = rows.tolist()
        logs = {key: [row[i] for row in table] for i, key in enumerate(LOGGED)}
        if not log_alpha:
            logs["ent_coef_loss"] = []
        for i, term in enumerate(model.actor_terms):
            for row in table:
                term.record(row[len(LOGGED) + i])
        return logs
