"""Behaviour cloning of planner demonstrations in SAC's actor update (armexp.agents.cloning)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

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


def _actor_grads(model: ResumableSAC) -> list[torch.Tensor]:
    return [
        torch.zeros_like(p) if p.grad is None else p.grad.clone() for p in model.actor.parameters()
    ]


def _grads(loss: torch.Tensor, params: list[torch.Tensor]) -> list[torch.Tensor]:
    got = torch.autograd.grad(loss, params, allow_unused=True)  # log_std: not in μ
    return [torch.zeros_like(p) if g is None else g for p, g in zip(params, got, strict=True)]


def test_only_reaching_demonstrations_are_cloned(env: ReachEnv, demos: list[Demonstration]) -> None:
    model = _model(env)
    failed = Demonstration(**{**vars(demos[0]), "reason": "joint_limit"})
    cloning = DemonstrationCloning(model, [*demos, failed], 1.0, seed=0)
    assert len(cloning) == sum(len(d) for d in demos if d.reason == "reached")
    with pytest.raises(ValueError, match="at least one demonstration that reaches"):
        DemonstrationCloning(model, [failed], 1.0, seed=0)


def test_each_actor_step_gets_sacs_gradient_plus_the_cloning_gradient(
    env: ReachEnv, demos: list[Demonstration]
) -> None:
    model = _model(env)
    cloning = DemonstrationCloning(model, demos, 0.7, seed=3)
    seen: list[list[torch.Tensor]] = []
    model.actor.optimizer.register_step_pre_hook(lambda *_: seen.append(_actor_grads(model)))
    params = list(model.actor.parameters())

    # Any actor loss stands in for SAC's; the optimiser step must see the sum of both gradients.
    obs = torch.as_tensor(np.stack([d.obs[0] for d in demos]))
    own = model.actor(obs, deterministic=True).sum()
    own_grads = _grads(own, params)
    state = cloning.generator.get_state()
    bc_grads = _grads(cloning.loss(), params)
    cloning.generator.set_state(state)  # the hook draws the same demonstrated batch

    model.actor.optimizer.zero_grad()
    model.actor(obs, deterministic=True).sum().backward()
    model.actor.optimizer.step()
    assert len(seen) == 1
    for got, a, b in zip(seen[0], own_grads, bc_grads, strict=True):
        assert torch.allclose(got, a + b, atol=1e-6)
    assert cloning.last_loss > 0
    assert model.logger.name_to_value["train/bc_loss"] == pytest.approx(cloning.last_loss)


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
    for _ in range(400):
        model.actor.optimizer.zero_grad()
        model.actor.optimizer.step()  # no SAC gradient: only the cloning term moves the actor
    after = error()
    assert after < before / 5
    with torch.no_grad():
        signs = torch.sign(model.actor(obs, deterministic=True)) == torch.sign(planned)
    assert float(signs[planned.abs() > 0.5].float().mean()) > 0.9
    cloning.detach()
    weights = [p.clone() for p in model.actor.parameters()]
    model.actor.optimizer.zero_grad()
    model.actor.optimizer.step()
    assert all(torch.equal(w, p) for w, p in zip(weights, model.actor.parameters(), strict=True))
