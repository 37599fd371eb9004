"""The contract of a loss term that SAC's actor update adds to its own (`ActorTerm`), shared by
the update paths (`armexp.agents.sac`, `armexp.agents.compiled`) and the aids that add terms
(`armexp.agents.cloning`)."""

from __future__ import annotations

from typing import Protocol

import torch


class ActorTerm(Protocol):
    """A loss that SAC's actor update adds to its own (Algorithm 1, line 14), on states of the
    term's choosing (the cloning aid, `armexp.agents.cloning`)."""

    def batch(self) -> tuple[torch.Tensor, torch.Tensor]:
        """States (k, d) and actions (k, n) for this update."""
        ...

    def value(self, mode: torch.Tensor, actions: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """The term from the actor's deterministic action ``mode`` (k, n) at the states, the
        batch's ``actions`` and the critics' (smaller) value of them ``q`` (k,), no gradient;
        without side effects (a compiled update traces it)."""
        ...

    def record(self, loss: float) -> None:
        """Log one update's `value`."""
        ...

    def loss(self, mode: torch.Tensor, actions: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """`value`, recorded (the eager updates)."""
        ...
