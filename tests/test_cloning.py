"""Behaviour cloning of planner demonstrations in SAC's actor update (armexp.agents.cloning)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from stable_baselines3 import SAC

from armexp.agents.cloning import DemonstrationCloning
from armexp.agents.demonstrations import Demonstration, demonstrations
from armexp.agents.sac import ResumableSAC
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv
from tests.helpers import small_sac


@pytest.fixture(scope="module")
def env() -> ReachEnv:
    return ReachEnv(settings_from_config(compose_config(["controller.gains=paper"])))


@pytest.fixture(scope="module")
def demos(env: ReachEnv) -> list[Demonstration]:
    return demonstrations(env, 6, seed=2)


def _model(env: ReachEnv) -> ResumableSAC:
    model: ResumableSAC = small_sac(env.settings)
    return model


def test_only_reaching_demonstrations_are_cloned(env: ReachEnv, demos: list[Demonstration]) -> None:
    model = _model(env)
    failed = Demonstration(**{**vars(demos[0]), "reason": "joint_limit"})
    cloning = DemonstrationCloning(model, [*demos, failed], 1.0, seed=0)
    assert len(cloning) == sum(len(d) for d in demos if d.reason == "reached")
    with pytest.raises(ValueError, match="at least one demonstration that reaches"):
        DemonstrationCloning(model, [failed], 1.0, seed=0)


def _filled(env: ReachEnv) -> ResumableSAC:
    """A model whose replay buffer holds 200 random steps and that has not trained yet."""
    model = _model(env)
    model.learn(total_timesteps=200)  # learning_starts (1000) not reached: collection only
    return model


def _term_loss(model: ResumableSAC, term: DemonstrationCloning) -> torch.Tensor:
    """The term's loss on its next batch, from actor and critic passes of their own."""
    obs, actions, returns = term.batch()
    with torch.no_grad():
        q = torch.cat(model.critic(obs, actions), dim=1).min(dim=1).values
    return term.loss(model.actor(obs, deterministic=True), actions, q, returns)


@pytest.mark.long
def test_an_update_with_the_cloning_term_is_sacs_update_plus_the_cloning_gradient(
    env: ReachEnv, demos: list[Demonstration]
) -> None:
    # The reference: SB3's own update, with the term's gradient added just before the actor's
    # optimiser step from separate actor and critic passes on the term's batch.
    class Reference(ResumableSAC):
        train = SAC.train

    ours, reference = _filled(env), _filled(env)
    reference.__class__ = Reference
    term = DemonstrationCloning(ours, demos, 0.7, seed=3)
    reference_term = DemonstrationCloning(reference, demos, 0.7, seed=3)

    def add_gradient(*_: object) -> None:
        with torch.enable_grad():
            _term_loss(reference, reference_term).backward()

    reference.actor.optimizer.register_step_pre_hook(add_gradient)
    for model in (ours, reference):
        torch.manual_seed(5)
        np.random.seed(5)
        model.train(gradient_steps=3, batch_size=64)
    for a, b in zip(ours.policy.parameters(), reference.policy.parameters(), strict=True):
        assert torch.allclose(a, b, atol=1e-5), float((a - b).abs().max())
    untrained = _model(env).actor.parameters()
    assert all(
        not torch.equal(a, b) for a, b in zip(ours.actor.parameters(), untrained, strict=True)
    )
    assert term.last_loss > 0 and term.last_loss == pytest.approx(reference_term.last_loss, 1e-4)
    logged = [m.logger.name_to_value["train/bc_loss"] for m in (ours, reference)]  # 3 steps' mean
    assert logged[0] == pytest.approx(logged[1], 1e-4)


def test_the_cloning_term_alone_makes_the_actor_imitate_the_planner(
    env: ReachEnv, demos: list[Demonstration]
) -> None:
    model = _model(env)
    cloning = DemonstrationCloning(model, demos, 1.0, seed=0)
    obs, planned = cloning.obs, cloning.actions

    def error() -> float:
        with torch.no_grad():
            return float(((model.actor(obs, deterministic=True) - planned) ** 2).mean())

    before = error()
    for _ in range(400):  # no SAC loss: only the cloning term moves the actor
        model.actor.optimizer.zero_grad()
        _term_loss(model, cloning).backward()
        model.actor.optimizer.step()
    after = error()
    assert after < before / 5
    with torch.no_grad():
        signs = torch.sign(model.actor(obs, deterministic=True)) == torch.sign(planned)
    assert float(signs[planned.abs() > 0.5].float().mean()) > 0.9
    assert model.actor_terms == [cloning]
    cloning.detach()
    assert model.actor_terms == []
