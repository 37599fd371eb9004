"""Behaviour cloning of planner demonstrations inside SAC's actor update (the ``cloning`` aid).

Demonstrations in the replay buffer alone (`armexp.agents.demonstrations`) show SAC where the
detours are, but the critic must still carry the reach reward back over hundreds of 30 ms steps
before the actor follows them, and under a short discount the return can even prefer ending on
a joint limit. A behaviour-cloning term pulls the actor towards the planner's actions on the
demonstrated states directly, as in DDPGfD/TD3+BC (Nair et al., 2018; Fujimoto & Gu, 2021):

    L_actor = E_B[α log π(a|s) − Q(s, a)] + w · mean|Q(s_d, a_d)| · E_D[‖μ(s_d) − a_d‖²]

with B SAC's replayed batch, D a batch of demonstrated states s_d and planner actions a_d, and μ
the actor's deterministic (squashed mean) action. Scaling by mean |Q| makes ``w`` independent of
the reward's scale, as TD3+BC's normalisation does. The term is one of the model's
`~armexp.agents.terms.ActorTerm`s: each update adds its gradient to that of SAC's actor loss
before the actor's optimiser step.

With ``capacity`` > 0, D also holds up to that many further labelled steps (`add`, the newest
replacing the oldest), such as the learner's own states labelled by the planner
(`armexp.agents.expert`); the demonstrations stay. Like the replay buffer, added steps are not
part of a checkpoint: a resumed run labels afresh.
"""

from __future__ import annotations

import numpy as np
import torch
from stable_baselines3.common.callbacks import BaseCallback

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext
from armexp.agents.demonstrations import Demonstration, PlannerDemonstrations, planned
from armexp.agents.sac import ResumableSAC
from armexp.agents.terms import TermBatch, weighted_cloning


class DemonstrationCloning:
    """Adds the behaviour-cloning loss of the reached ``demos`` to every actor update of
    ``model`` (a batch of ``model.batch_size`` demonstrated steps each): an
    `~armexp.agents.terms.ActorTerm`."""

    def __init__(
        self,
        model: ResumableSAC,
        demos: list[Demonstration],
        weight: float,
        seed: int,
        capacity: int = 0,
    ) -> None:
        reached = [d for d in demos if d.reason == "reached"]
        if not reached:
            raise ValueError("behaviour cloning needs at least one demonstration that reaches.")
        device = model.device
        self.model = model
        self.weight = float(weight)
        obs = np.concatenate([d.obs for d in reached])
        actions = np.concatenate([d.actions for d in reached])
        self._fixed = len(actions)
        self._capacity = int(capacity)
        self._added = 0
        self.obs = torch.zeros((self._fixed + self._capacity, obs.shape[1]), device=device)
        self.actions = torch.zeros((self._fixed + self._capacity, actions.shape[1]), device=device)
        self.obs[: self._fixed] = torch.as_tensor(obs)
        self.actions[: self._fixed] = torch.as_tensor(actions)
        self.generator = torch.Generator(device=device).manual_seed(seed)
        self.last_loss = float("nan")
        model.actor_terms.append(self)

    def reserve(self, capacity: int) -> None:
        """Room for ``capacity`` added steps (`add`); steps added before are dropped."""
        fixed, device = self._fixed, self.obs.device
        obs = torch.zeros((fixed + capacity, self.obs.shape[1]), device=device)
        actions = torch.zeros((fixed + capacity, self.actions.shape[1]), device=device)
        obs[:fixed], actions[:fixed] = self.obs[:fixed], self.actions[:fixed]
        self.obs, self.actions = obs, actions
        self._capacity, self._added = int(capacity), 0

    def __len__(self) -> int:
        """Steps to clone from: the demonstrated ones and those `add`ed (at most ``capacity``)."""
        return self._fixed + min(self._added, self._capacity)

    def add(self, obs: np.ndarray, actions: np.ndarray) -> None:
        """Clone ``actions`` (k, n) at ``obs`` (k, d) too, in place of the oldest added steps
        once ``capacity`` is full."""
        if self._capacity == 0:
            raise ValueError("this cloning term was built without room for added steps.")
        rows = (self._added + np.arange(len(actions))) % self._capacity + self._fixed
        index = torch.as_tensor(rows, device=self.obs.device)
        self.obs[index] = torch.as_tensor(obs, dtype=self.obs.dtype, device=self.obs.device)
        self.actions[index] = torch.as_tensor(
            actions, dtype=self.actions.dtype, device=self.actions.device
        )
        self._added += len(actions)

    def batch(self) -> TermBatch:
        """A batch of ``model.batch_size`` demonstrated or added states and their actions (no
        returns: the term clones every one)."""
        index = torch.randint(
            len(self), (self.model.batch_size,), generator=self.generator, device=self.obs.device
        )
        return self.obs[index], self.actions[index], None

    def value(
        self, mode: torch.Tensor, actions: torch.Tensor, q: torch.Tensor,
        returns: torch.Tensor | None = None,
    ) -> torch.Tensor:  # fmt: skip
        """The weighted cloning loss of the actor's deterministic actions ``mode`` at a `batch`
        whose actions are ``actions`` and whose critic value is ``q`` (no gradient); no side
        effects, so that a compiled update can trace it."""
        return weighted_cloning(self.weight, mode, actions, q)

    def record(self, loss: float) -> None:
        """Log an update's cloning loss (``train/bc_loss``, the mean over a call's steps)."""
        self.last_loss = float(loss)
        self.model.logger.record_mean("train/bc_loss", self.last_loss)

    def loss(
        self, mode: torch.Tensor, actions: torch.Tensor, q: torch.Tensor,
        returns: torch.Tensor | None = None,
    ) -> torch.Tensor:  # fmt: skip
        """`value`, recorded."""
        loss = self.value(mode, actions, q, returns)
        self.record(float(loss.detach()))
        return loss

    def detach(self) -> None:
        """Stop adding the term to the model's actor updates."""
        self.model.actor_terms.remove(self)


class BehaviourCloning(TrainingAddOn):
    """The cloning term above, with weight ``weight``, on the planner's demonstrations (listed
    before it in ``agent.aids``). Privileged: it imitates the planner. SAC only: the term
    joins SAC's actor update (`armexp.agents.sac.ResumableSAC`), which the other algorithms'
    library updates have no place for."""

    declaration = aids.CLONING
    needs = (PlannerDemonstrations,)

    def __init__(self, weight: float) -> None:
        if not float(weight) > 0:
            raise ValueError(f"weight={weight} must be greater than 0")
        self.weight = float(weight)

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        model = ctx.model
        assert isinstance(model, ResumableSAC)  # its declaration says so
        ctx.shared["cloning"] = DemonstrationCloning(model, planned(ctx), self.weight, ctx.seed)
        return []
