"""SAC's update with its gradients written out (armexp.agents.analytic) against autograd's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from armexp.agents.analytic import AnalyticUpdate
from armexp.agents.cloning import DemonstrationCloning
from armexp.agents.demonstrations import demonstrations
from armexp.agents.sac import ResumableSAC, _with_gradients, build_sac, load_sac
from armexp.agents.vec import make_vec_env
from armexp.config import ConfigError, compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv


def _filled(gradients: str, *overrides: str) -> ResumableSAC:
    """`sac_demo`'s model after 300 steps of collection, untrained, with ``gradients``."""
    cfg = compose_config(
        ["controller.gains=paper", "experiment=demo", "agent.learning_starts=300",
         f"agent.gradients={gradients}", *overrides]
    )  # fmt: skip
    model = build_sac(cfg.agent, make_vec_env(settings_from_config(cfg), 2, "dummy", 0), 0)
    model.learn(total_timesteps=300)  # collection only: learning_starts is not reached
    return model


def _state(model: ResumableSAC) -> list[torch.Tensor]:
    assert model.log_ent_coef is not None  # ent_coef "auto"
    return [p.detach().clone() for p in model.policy.parameters()] + [model.log_ent_coef.clone()]


@pytest.mark.parametrize("cloning", [False, True])
def test_the_written_out_gradients_make_autograds_update(cloning: bool) -> None:
    models = {g: _filled(g) for g in ("autograd", "analytic")}
    before = _state(models["autograd"])
    assert all(torch.equal(a, b) for a, b in zip(before, _state(models["analytic"]), strict=True))
    terms = {}
    if cloning:
        settings = settings_from_config(compose_config(["controller.gains=paper"]))
        demos = demonstrations(ReachEnv(settings), 4, seed=1)
        terms = {g: DemonstrationCloning(m, demos, 3.0, seed=7) for g, m in models.items()}
    logged = {}
    for gradients, model in models.items():
        torch.manual_seed(11)
        np.random.seed(11)  # the replay buffer samples with NumPy's global generator
        model.train(gradient_steps=3, batch_size=256)
        logged[gradients] = dict(model.logger.name_to_value)
    ours, theirs = _state(models["analytic"]), _state(models["autograd"])
    for got, want, was in zip(ours, theirs, before, strict=True):
        assert not torch.equal(want, was)  # every parameter moved
        assert torch.allclose(got, want, rtol=1e-4, atol=1e-6), float((got - want).abs().max())
    for key in ("train/actor_loss", "train/critic_loss", "train/ent_coef", "train/ent_coef_loss"):
        assert logged["analytic"][key] == pytest.approx(logged["autograd"][key], rel=1e-5)
    if cloning:
        assert terms["analytic"].last_loss == pytest.approx(terms["autograd"].last_loss, rel=1e-5)


def test_analytic_gradients_refuse_what_they_do_not_cover() -> None:
    assert AnalyticUpdate.supports(_filled("autograd")) is None
    with pytest.raises(ConfigError, match=r"agent\.gradients=analytic is not allowed"):
        cfg = compose_config(
            ["controller.gains=paper", "agent=sac_quick", "agent.gradients=analytic"]
        )
        env = make_vec_env(settings_from_config(cfg), 1, "dummy", 0)
        model = ResumableSAC("MlpPolicy", env, policy_kwargs={"activation_fn": torch.nn.Tanh})
        _with_gradients(model, cfg.agent)


def test_a_saved_analytic_model_loads_with_its_gradients_and_trains_on(tmp_path: Path) -> None:
    model = _filled("analytic")
    model.train(gradient_steps=1, batch_size=64)
    model.save(tmp_path / "m.zip")
    agent = compose_config(["experiment=demo"]).agent
    loaded = load_sac(str(tmp_path / "m.zip"), model.get_env(), agent)
    assert loaded.gradients == "analytic" and loaded.actor_terms == [] and loaded._analytic is None
    assert loaded.actor.optimizer.defaults["fused"] is True
    for a, b in zip(loaded.policy.parameters(), model.policy.parameters(), strict=True):
        assert torch.equal(a, b)
    loaded.replay_buffer = model.replay_buffer
    loaded.set_logger(model.logger)
    loaded.train(gradient_steps=1, batch_size=64)
    assert any(
        not torch.equal(a, b)
        for a, b in zip(loaded.policy.parameters(), model.policy.parameters(), strict=True)
    )
