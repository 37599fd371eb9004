"""Temporally correlated exploration (the ``coloured_noise`` aid): the stochastic actor samples
its training actions with coloured noise instead of white.

An action is a joint velocity held for one 30 ms step, within Table II's small bounds, so the
white noise of a Gaussian policy averages out: over 100 steps, noise of scale σ moves the elbow
(0.4 rad/s) a random walk of 0.12σ rad, against 1.2σ rad for noise that keeps its direction, while
a target below the base needs the forearm swung through more than three radians
(docs/plain_agent.md). Noise whose power grows toward
low frequencies (``beta`` 1: pink, 2: red) keeps a direction for many steps, so exploration can
follow such a detour to its end. Eberhard et al., "Pink Noise Is All You Need: Colored Noise
Exploration in Deep Reinforcement Learning", ICLR 2023; the noise process is theirs
(``pink-noise-rl``, `pink.ColoredNoiseProcess`).

Only the sampled rollout actions change: ``a = tanh(μ + σ ε)`` with ``ε`` from one unit-variance
coloured process per environment and joint instead of ``ε ~ N(0, 1)`` each step. The update, its
log-probabilities and the deterministic actions of checks and evaluation are SAC's own: the
coloured distribution is in place only while the algorithm collects a rollout. No planner, no
obstacle knowledge (not privileged).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch
from pink import ColoredNoiseProcess
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.distributions import SquashedDiagGaussianDistribution

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext


class ColouredGaussian(SquashedDiagGaussianDistribution):
    """SAC's squashed Gaussian whose ``sample`` draws ``ε`` from ``process`` (n_envs, action
    dimensions) when asked for exactly that many actions, and white noise otherwise."""

    def __init__(self, action_dim: int, process: ColoredNoiseProcess, n_envs: int) -> None:
        super().__init__(action_dim)
        self.process, self.n_envs = process, n_envs

    def sample(self) -> torch.Tensor:
        assert self.distribution is not None
        mean, std = self.distribution.mean, self.distribution.stddev
        if mean.shape[0] != self.n_envs:
            return super().sample()
        eps = torch.as_tensor(self.process.sample(), dtype=mean.dtype, device=mean.device)
        self.gaussian_actions = mean + std * eps
        return torch.tanh(self.gaussian_actions)


class ColouredRollouts(BaseCallback):
    """Puts ``coloured`` in the actor while a rollout is collected, the actor's own distribution
    back before the update."""

    def __init__(self, coloured: ColouredGaussian) -> None:
        super().__init__()
        self.coloured = coloured
        self.white: Any = None

    def _on_training_start(self) -> None:
        self.white = self.model.actor.action_dist  # type: ignore[attr-defined]

    def _on_rollout_start(self) -> None:
        self.model.actor.action_dist = self.coloured  # type: ignore[attr-defined]

    def _on_rollout_end(self) -> None:
        self.model.actor.action_dist = self.white  # type: ignore[attr-defined]

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self._on_rollout_end()


class ColouredNoise(TrainingAddOn):
    """Rollout actions with coloured noise of exponent ``beta`` (`ColouredGaussian`), one
    process per environment and joint over sequences of ``seq_len`` steps (the episode length by
    default), seeded by the run's seed."""

    declaration = aids.COLOURED_NOISE

    def __init__(self, beta: float = 1.0, seq_len: int | None = None) -> None:
        if not 0.0 <= float(beta) <= 4.0:
            raise ValueError(f"beta={beta} must be in [0, 4] (0 white, 1 pink, 2 red)")
        if seq_len is not None and int(seq_len) < 2:
            raise ValueError(f"seq_len={seq_len} must be at least 2 steps, or null")
        self.beta = float(beta)
        self.seq_len = None if seq_len is None else int(seq_len)

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        model = ctx.model
        n_envs = int(model.n_envs)
        dim = int(np.prod(model.action_space.shape or (1,)))
        seq_len = self.seq_len or int(ctx.settings.max_steps)
        process = ColoredNoiseProcess(
            beta=self.beta, size=(n_envs, dim, seq_len), rng=np.random.default_rng(ctx.seed)
        )
        return [ColouredRollouts(ColouredGaussian(dim, process, n_envs))]
