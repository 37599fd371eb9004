"""Behaviour cloning of planner demonstrations inside SAC's actor update (``agent.bc_weight``).

Demonstrations in the replay buffer alone (`armexp.agents.demonstrations`) show SAC where the
detours are, but the critic must still carry the reach reward back over hundreds of 30 ms steps
before the actor follows them, and under a short discount the return can even prefer ending on
a joint limit. A behaviour-cloning term pulls the actor towards the planner's actions on the
demonstrated states directly, as in DDPGfD/TD3+BC (Nair et al., 2018; Fujimoto & Gu, 2021):

    L_actor = E_B[α log π(a|s) − Q(s, a)] + w · mean|Q(s_d, a_d)| · E_D[‖μ(s_d) − a_d‖²]

with B SAC's replayed batch, D a batch of demonstrated states s_d and planner actions a_d, and μ
the actor's deterministic (squashed mean) action. Scaling by mean |Q| makes ``w`` independent of
the reward's scale, as TD3+BC's normalisation does. The term is added as a gradient just before
each actor optimiser step, so SB3's own SAC update runs unchanged.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from stable_baselines3 import SAC

from armexp.agents.demonstrations import Demonstration


class DemonstrationCloning:
    """Adds the behaviour-cloning gradient of the reached ``demos`` to every actor update of
    ``model`` (a batch of ``model.batch_size`` demonstrated steps each)."""

    def __init__(self, model: SAC, demos: list[Demonstration], weight: float, seed: int) -> None:
        reached = [d for d in demos if d.reason == "reached"]
        if not reached:
            raise ValueError("behaviour cloning needs at least one demonstration that reaches.")
        device = model.device
        self.model = model
        self.weight = float(weight)
        self.obs = torch.as_tensor(np.concatenate([d.obs for d in reached]), device=device)
        self.actions = torch.as_tensor(np.concatenate([d.actions for d in reached]), device=device)
        self.generator = torch.Generator(device=device).manual_seed(seed)
        self.last_loss = float("nan")
        self._handle = model.actor.optimizer.register_step_pre_hook(self._add_gradient)

    def __len__(self) -> int:
        return int(self.actions.shape[0])

    def loss(self) -> torch.Tensor:
        """The weighted cloning loss on one sampled batch of demonstrated steps."""
        index = torch.randint(
            len(self), (self.model.batch_size,), generator=self.generator, device=self.obs.device
        )
        obs, target = self.obs[index], self.actions[index]
        with torch.no_grad():
            q = torch.cat(self.model.critic(obs, target), dim=1).min(dim=1).values
        action = self.model.actor(obs, deterministic=True)
        return self.weight * q.abs().mean() * ((action - target) ** 2).mean()

    def _add_gradient(self, optimizer: Any, args: Any, kwargs: Any) -> None:
        # SAC's actor gradient is already in .grad here; accumulating ours gives the sum's.
        with torch.enable_grad():
            loss = self.loss()
            loss.backward()
        self.last_loss = float(loss.detach())
        self.model.logger.record_mean("train/bc_loss", self.last_loss)

    def detach(self) -> None:
        self._handle.remove()
