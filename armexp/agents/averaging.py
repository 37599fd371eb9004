"""The actor's weights averaged over the end of training (the ``averaging`` aid).

At a constant learning rate SAC's actor never settles: late in a run the held-out success of
successive checks swings by several points, and the model that is saved is whichever point of
that swing the budget ends on. Averaging the
weights the actor passes through over the last part of the budget (stochastic weight averaging,
Izmailov et al., 2018; for policies, Nikishin et al., 2018) gives a model at the centre of the
region it moves about in instead. Only the actor is averaged: it alone acts in `armexp eval`;
the critics, optimisers and entropy coefficient stay as trained.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import cast

import torch
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext


class ActorAverage(BaseCallback):
    """Sums the actor's weights after every vector step once ``used()`` (the share of the
    budget spent, 0 to 1) reaches ``1 − tail``; `apply` loads their mean into the actor."""

    def __init__(self, tail: float, used: Callable[[], float]) -> None:
        super().__init__()
        self.tail = tail
        self.used = used
        self.count = 0
        self._sum: dict[str, torch.Tensor] = {}

    def _on_step(self) -> bool:
        if self.used() >= 1.0 - self.tail:
            self.add()
        return True

    @property
    def actor(self) -> torch.nn.Module:
        return cast(SAC, self.model).actor  # SAC, TD3, TQC and CrossQ all have one

    def add(self) -> None:
        """Adds the actor's current weights to the average."""
        with torch.no_grad():
            for name, value in self.actor.state_dict().items():
                if name in self._sum:
                    self._sum[name] += value.double()
                else:
                    self._sum[name] = value.detach().double().clone()
        self.count += 1

    def apply(self) -> int:
        """Loads the average into the actor; returns how many weight sets it averages (0:
        none were taken, and the actor is left as trained)."""
        if self.count:
            actor = self.actor
            current = actor.state_dict()
            actor.load_state_dict(
                {k: (v / self.count).to(current[k].dtype) for k, v in self._sum.items()}
            )
        return self.count


class WeightAveraging(TrainingAddOn):
    """The final actor is the mean of its weights over the last ``tail`` share of the budget
    (`ActorAverage`; ``final/averaged_actors`` says how many). The checkpoint keeps the last
    weights; a resumed run averages from where it resumes. Uses no privileged knowledge.
    The off-policy algorithms only, whose policies have a separate ``actor`` (PPO's actor and
    value network share one policy module)."""

    declaration = aids.AVERAGING

    def __init__(self, tail: float) -> None:
        if not 0.0 < float(tail) <= 1.0:
            raise ValueError(f"tail={tail} must be in (0, 1]")
        self.tail = float(tail)
        self.callback: ActorAverage | None = None

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        self.callback = ActorAverage(self.tail, ctx.budget_used)
        return [self.callback]

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        assert self.callback is not None
        return {"final/averaged_actors": float(self.callback.apply())}
