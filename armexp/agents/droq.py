"""DroQ-style critics for SAC (``agent.critic_dropout``): dropout and layer normalisation in
each Q-network (Hiraoka et al., "Dropout Q-functions for doubly efficient reinforcement
learning", ICLR 2022).

Each hidden layer of a critic becomes Linear → Dropout(p) → LayerNorm → ReLU, the paper's
order; the actor is SB3's. Dropout acts whenever the critics are evaluated for the
update (the current Q, the target Q and the actor's loss), as Stable Baselines Jax's DroQ
does, so the target critics are kept in training mode as well; SB3 keeps them in evaluation
mode, which would turn their dropout off. DroQ pairs these critics with many
updates per environment step; here that is ``agent.gradient_steps`` as for any SAC preset.

SB3 has no such critic; it is SB3's `ContinuousCritic` with its Q-networks built again, so
SB3's SAC update, save, load and resume run on it unchanged. The compiled update does not
cover it (`armexp.agents.compiled.CompiledUpdate.supports`): dropout draws inside the graph
would break the promise that a seed gives the eager update's batches and noise.
"""

from __future__ import annotations

from typing import Any

from gymnasium import spaces
from stable_baselines3.common.policies import ContinuousCritic
from stable_baselines3.common.preprocessing import get_action_dim
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor
from stable_baselines3.sac.policies import SACPolicy
from torch import nn


def droq_mlp(
    inputs: int, hidden: list[int], dropout: float, activation: type[nn.Module]
) -> nn.Sequential:
    """One Q-network: per hidden layer Linear, Dropout(``dropout``), LayerNorm, activation;
    then the linear output."""
    layers: list[nn.Module] = []
    width = inputs
    for units in hidden:
        layers += [nn.Linear(width, units), nn.Dropout(dropout), nn.LayerNorm(units), activation()]
        width = units
    layers.append(nn.Linear(width, 1))
    return nn.Sequential(*layers)


class DropoutCritic(ContinuousCritic):
    """SB3's twin critics with DroQ's Q-networks (`droq_mlp`)."""

    def __init__(self, *args: Any, dropout: float, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        inputs = int(kwargs["features_dim"]) + get_action_dim(self.action_space)
        hidden = list(kwargs["net_arch"])
        activation = kwargs.get("activation_fn", nn.ReLU)
        self.q_networks = []
        for idx in range(self.n_critics):
            q_net = droq_mlp(inputs, hidden, dropout, activation)
            self.add_module(f"qf{idx}", q_net)  # replaces SB3's plain network of that name
            self.q_networks.append(q_net)


class DroQPolicy(SACPolicy):
    """SB3's SAC policy with `DropoutCritic` critics of dropout rate ``critic_dropout``."""

    def __init__(self, *args: Any, critic_dropout: float = 0.01, **kwargs: Any) -> None:
        self.critic_dropout = float(critic_dropout)
        super().__init__(*args, **kwargs)
        self.critic_target.set_training_mode(True)  # dropout in the target Q as well

    def make_critic(
        self, features_extractor: BaseFeaturesExtractor | None = None
    ) -> ContinuousCritic:
        kwargs = self._update_features_extractor(self.critic_kwargs, features_extractor)
        assert isinstance(self.action_space, spaces.Box)
        return DropoutCritic(dropout=self.critic_dropout, **kwargs).to(self.device)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        return {**super()._get_constructor_parameters(), "critic_dropout": self.critic_dropout}
