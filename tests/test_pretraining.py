"""Pre-training on the demonstrations: SAC's own updates before the first environment step pull
the actor to the planner's actions, cost no environment step, and a resumed run skips them."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
import torch
from stable_baselines3.common.logger import configure

from armexp import aids
from armexp.agents.addons import TrainingContext
from armexp.agents.cloning import BehaviourCloning
from armexp.agents.demonstrations import PlannerDemonstrations
from armexp.agents.pretraining import DemonstrationPretraining
from armexp.agents.sac import ResumableSAC, build_sac
from armexp.agents.vec import make_vec_env
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config

AGENT = ["agent=sac_quick", "agent.gradients=autograd", "agent.net_arch=[32,32]",
         "agent.n_envs=2", "agent.batch_size=64", "agent.n_steps=1"]  # fmt: skip


def _setup(
    monkeypatch: pytest.MonkeyPatch, resumed: bool
) -> tuple[ResumableSAC, TrainingContext, dict[str, float]]:
    """A small SAC with 12 demonstrations in its buffer and the cloning term on them."""
    import mlflow

    logged: dict[str, float] = {}
    monkeypatch.setattr(mlflow, "log_metrics", lambda metrics: logged.update(metrics))
    cfg = compose_config(["controller.gains=paper", *AGENT])
    settings = settings_from_config(cfg, with_tasks=False)
    model = build_sac(cfg.agent, make_vec_env(settings, 2, "dummy", 0), seed=0)
    model.set_logger(configure(None, []))
    ctx = TrainingContext(model, settings, 0, resumed, lambda: 0.0, lambda: 0.0)
    PlannerDemonstrations(12).setup(ctx)
    BehaviourCloning(1.0).setup(ctx)
    return model, ctx, logged


def _cloning_error(model: ResumableSAC, ctx: TrainingContext) -> float:
    """Mean squared distance of the actor's deterministic actions from the planner's on the
    demonstrated states."""
    reached = [d for d in ctx.shared["demonstrations"] if d.reason == "reached"]
    obs = torch.as_tensor(np.concatenate([d.obs for d in reached]))
    actions = np.concatenate([d.actions for d in reached])
    with torch.no_grad():
        mode = model.actor(obs, deterministic=True).numpy()
    return float(((mode - actions) ** 2).mean())


@pytest.mark.long
def test_pretraining_pulls_the_actor_to_the_planner_without_an_environment_step(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    model, ctx, logged = _setup(monkeypatch, resumed=False)
    before = _cloning_error(model, ctx)
    assert DemonstrationPretraining(400).setup(ctx) == []
    after = _cloning_error(model, ctx)
    assert after < 0.5 * before, (before, after)
    assert model._n_updates == 400  # SAC's own updates, in calls of the preset's 2 steps
    assert model.num_timesteps == 0  # and not one environment step
    assert logged["pretraining/gradient_steps"] == 400 and logged["pretraining/wall_s"] > 0


def test_a_resumed_run_does_not_pretrain_again(monkeypatch: pytest.MonkeyPatch) -> None:
    model, ctx, logged = _setup(monkeypatch, resumed=True)
    DemonstrationPretraining(400).setup(ctx)
    assert model._n_updates == 0 and "pretraining/gradient_steps" not in logged


def test_pretraining_is_declared_privileged_and_off_policy() -> None:
    declared: Any = aids.declared("pretraining")
    assert declared is aids.PRETRAINING and declared.privileged
    assert DemonstrationPretraining.algorithms == aids.OFF_POLICY
    assert DemonstrationPretraining.needs == (PlannerDemonstrations,)
    with pytest.raises(ValueError, match="gradient_steps=0 must be at least 1"):
        DemonstrationPretraining(0)
