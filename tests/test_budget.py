"""Training against a budget: a learning rate that decays over whichever budget runs out
first (``agent.lr_final``), and the best held-out check kept as the final model
(``train.keep_best``)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from mlflow.tracking import MlflowClient
from stable_baselines3.common.logger import Logger

import armexp.agents.rollout
from armexp.agents.callbacks import Budget, EpisodeStats, HeldOutEval
from armexp.agents.sac import ResumableSAC, build_sac
from armexp.agents.vec import make_vec_env
from armexp.cli import main
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachSettings
from tests.helpers import SMALL_TRAIN, stage_runs


@pytest.fixture(autouse=True)
def _private_default_store(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # The callbacks open MLflow's default store; keep it out of the working tree.
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path}/default.db")


@pytest.fixture(scope="module")
def settings() -> ReachSettings:
    return settings_from_config(compose_config(["controller.gains=paper"]))


def _model(settings: ReachSettings, *overrides: str) -> ResumableSAC:
    agent = compose_config(["agent=sac_smoke", "agent.n_envs=1", *overrides]).agent
    model = build_sac(agent, make_vec_env(settings, 1, "dummy", 0), 0, settings)
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


def _lr(model: ResumableSAC) -> float:
    model._update_learning_rate(model.actor.optimizer)
    return float(model.actor.optimizer.param_groups[0]["lr"])


def test_the_learning_rate_follows_the_budget_that_is_furthest_along(
    settings: ReachSettings, tmp_path: Path
) -> None:
    model = _model(settings, "agent.learning_rate=0.001", "agent.lr_final=0.0001")
    used = {"share": 0.5}
    model.budget_used = lambda: used["share"]
    # Half the wall time gone, a tiny share of the step bound: the time decides.
    model._update_current_progress_remaining(10, 1_000_000)
    assert _lr(model) == pytest.approx(0.00055)
    # Steps further along than the time: the steps decide.
    used["share"] = 0.1
    model._update_current_progress_remaining(900_000, 1_000_000)
    assert _lr(model) == pytest.approx(0.00019)
    used["share"] = 1.7  # past the budget: held at the final rate
    model._update_current_progress_remaining(0, 1_000_000)
    assert _lr(model) == pytest.approx(0.0001)
    # The budget is the run's, not the model's: saving leaves it out, the schedule stays.
    model.save(tmp_path / "m.zip")
    loaded = ResumableSAC.load(tmp_path / "m.zip")
    assert loaded.budget_used is None
    assert loaded.lr_schedule(0.5) == pytest.approx(0.00055)
    constant = _model(settings, "agent.learning_rate=0.0003")
    constant.budget_used = lambda: 0.9
    constant._update_current_progress_remaining(0, 100)
    assert _lr(constant) == pytest.approx(0.0003)


def test_budget_share_is_the_furthest_of_episodes_steps_and_time() -> None:
    stats = EpisodeStats("run", 1000, start_episode=10)
    stats.wall = lambda: 30.0  # type: ignore[method-assign]
    assert Budget(stats, 100, 1000, 60.0).used(200) == pytest.approx(0.5)
    assert Budget(stats, 100, 1000, None).used(200) == pytest.approx(0.2)
    assert Budget(stats, 20, None, None).used(200) == pytest.approx(0.5)
    assert Budget(stats, 20, 100, None).used(200) == 1.0


def test_keep_best_restores_the_policy_of_the_best_check(
    settings: ReachSettings, monkeypatch: pytest.MonkeyPatch
) -> None:
    model = _model(settings)
    # Each check's outcome is scripted; the weights at each check are marked by one bias.
    script = iter(
        [
            ["reached", "collision"],  # 0.5
            ["reached", "reached"],  # 1.0, return -10
            ["reached", "reached"],  # 1.0, return -5: best (same success, higher return)
            ["reached", "time_limit"],  # 0.5
        ]
    )
    returns = iter([-50.0, -10.0, -5.0, -20.0])

    class Episode:
        def __init__(self, reason: str, episode_return: float) -> None:
            self.reason, self.episode_return = reason, episode_return

    outcome: list[Episode] = []

    def scripted(env: Any, policy: Any, options: Any, seed: int) -> Episode:
        if not outcome:
            ret = next(returns)
            outcome.extend(Episode(r, ret) for r in next(script))
        return outcome.pop(0)

    monkeypatch.setattr(armexp.agents.rollout, "rollout", scripted)
    stats = EpisodeStats("run", 1000)
    check = HeldOutEval("run", 1, None, [np.zeros(2)] * 2, stats, keep_best=True)
    check.model, check.num_timesteps = model, 0
    check.client = type("Quiet", (), {"log_batch": lambda *a, **k: None})()
    bias = model.actor.mu.bias
    for mark in range(4):
        with torch.no_grad():
            bias.fill_(float(mark))
        check.num_timesteps = 100 * (mark + 1)
        check.evaluate()
    best = check.restore_best()
    assert best["step"] == 300 and best["eval/mean_return"] == -5.0
    assert torch.all(model.actor.mu.bias == 2.0)
    # The checks chose the model, so their time stays on the training clock.
    assert stats.wall_offset == 0.0
    plain = HeldOutEval("run", 1, None, [], stats)
    with pytest.raises(RuntimeError, match="no held-out check has run"):
        plain.restore_best()


def test_a_train_run_with_keep_best_logs_the_model_it_kept(runs_dir: Path) -> None:
    rc = main(
        ["train", "controller.gains=paper", *SMALL_TRAIN, "agent.max_env_steps=150",
         "agent.lr_final=0.0001", "train.eval_every=60", "train.eval_targets=2",
         "train.keep_best=true", f"tracking.runs_dir={runs_dir}"]
    )  # fmt: skip
    assert rc == 0
    (run,) = stage_runs(runs_dir, "train")
    history = MlflowClient(f"sqlite:///{runs_dir}/mlflow.db").get_metric_history
    success = {m.step: m.value for m in history(run.info.run_id, "eval/success_rate")}
    mean_return = {m.step: m.value for m in history(run.info.run_id, "eval/mean_return")}
    # Checks at 60 and 120, and the policy as trained at the end (150).
    assert sorted(success) == [60, 120, 150]
    # The best check; on a full tie, the later one.
    best = max(sorted(success, reverse=True), key=lambda s: (success[s], mean_return[s]))
    m = run.data.metrics
    assert m["final/kept_step"] == best and m["final/kept_success"] == success[best]
