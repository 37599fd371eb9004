"""The contract of a loss term that SAC's actor update adds to its own (`ActorTerm`), shared by
the update paths (`armexp.agents.sac`, `armexp.agents.compiled`) and the aids that add terms
(`armexp.agents.cloning`, `armexp.agents.self_imitation`)."""

from __future__ import annotations

from typing import Protocol

import torch

#: A term's batch: states (k, d), actions (k, n) and, for a term that weighs its states by what
#: followed them, the discounted returns observed from each (k,); None where unused.
TermBatch = tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]


class ActorTerm(Protocol):
    """A loss that SAC's actor update adds to its own (Algorithm 1, line 14), on states of the
    term's choosing (the cloning and self-imitation aids)."""

    def batch(self) -> TermBatch:
        """States, actions and returns (or None) for this update."""
        ...

    def value(
        self, mode: torch.Tensor, actions: torch.Tensor, q: torch.Tensor,
        returns: torch.Tensor | None,
    ) -> torch.Tensor:  # fmt: skip
        """The term from the actor's deterministic action ``mode`` (k, n) at the states, the
        batch's ``actions``, the critics' (smaller) value of them ``q`` (k,), no gradient, and
        the batch's ``returns``; without side effects (a compiled update traces it)."""
        ...

    def record(self, loss: float) -> None:
        """Log one update's `value`."""
        ...

    def loss(
        self, mode: torch.Tensor, actions: torch.Tensor, q: torch.Tensor,
        returns: torch.Tensor | None,
    ) -> torch.Tensor:  # fmt: skip
        """`value`, recorded (the eager updates)."""
        ...


def weighted_cloning(
    weight: float, mode: torch.Tensor, actions: torch.Tensor, q: torch.Tensor,
    keep: torch.Tensor | None = None,
) -> torch.Tensor:  # fmt: skip
    """w · mean|Q| · E[k · ‖μ(s) − a‖²] (the squared error averaged over the action's entries):
    behaviour cloning scaled by the critics' magnitude, as TD3+BC normalises it, with ``keep``
    (k,) the 0/1 weight of each state (None: every one)."""
    error = ((mode - actions) ** 2).mean(dim=1)
    if keep is not None:
        error = keep * error
    return weight * q.abs().mean() * error.mean()
