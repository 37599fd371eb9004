"""Coloured-noise exploration: rollout actions keep a direction over many steps, the update and
the deterministic actions stay SAC's own, and a non-privileged preset takes the aid."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.distributions import SquashedDiagGaussianDistribution
from stable_baselines3.common.vec_env import DummyVecEnv

from armexp import aids
from armexp.agents.addons import TrainingContext
from armexp.agents.exploration import ColouredGaussian, ColouredNoise
from armexp.cli import main
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv, ReachSettings
from tests.helpers import plain_train, stage_runs

COLOURED = "+agent.aids.coloured_noise={_target_:armexp.agents.exploration.ColouredNoise,beta:1}"
N_ENVS = 4


@pytest.fixture(scope="module")
def settings() -> ReachSettings:
    return settings_from_config(compose_config(["controller.gains=paper"]))


def _rollout_actions(settings: ReachSettings, beta: float) -> tuple[np.ndarray, list[type]]:
    """300 steps of 4 environments with the aid at ``beta`` (SAC, updates from the first step):
    the stored actions (steps, envs, joints) and the actor's distribution class at each update."""
    venv = DummyVecEnv([lambda: ReachEnv(settings)] * N_ENVS)
    model = SAC("MlpPolicy", venv, learning_starts=0, buffer_size=2000, batch_size=32,
                policy_kwargs={"net_arch": [16, 16]}, seed=3, device="cpu")  # fmt: skip
    at_update: list[type] = []
    train = model.train

    def spy(*args: Any, **kwargs: Any) -> None:
        at_update.append(type(model.actor.action_dist))
        train(*args, **kwargs)

    model.train = spy  # type: ignore[method-assign]
    ctx = TrainingContext(model, settings, 3, False, lambda: 0.0, lambda: 0.0)
    model.learn(300, callback=ColouredNoise(beta).setup(ctx))
    assert type(model.actor.action_dist) is SquashedDiagGaussianDistribution
    return model.replay_buffer.actions[: 300 // N_ENVS].copy(), at_update


def test_coloured_rollouts_keep_a_direction_and_the_update_samples_white_noise(
    settings: ReachSettings,
) -> None:
    white, white_updates = _rollout_actions(settings, 0.0)
    red, red_updates = _rollout_actions(settings, 2.0)
    # Same policy scale early on; red noise moves each action a little from the last.
    step_white = np.abs(np.diff(white, axis=0)).mean()
    step_red = np.abs(np.diff(red, axis=0)).mean()
    assert step_red < 0.3 * step_white
    assert np.abs(red).mean() > 0.3  # the noise still spans the action range, not ~0
    # Each environment has a process of its own.
    assert np.abs(red[:, 0] - red[:, 1]).mean() > 0.1
    assert len(red_updates) > 50
    assert set(white_updates) == set(red_updates) == {SquashedDiagGaussianDistribution}


def test_the_coloured_distribution_samples_white_noise_for_a_batch_it_was_not_built_for() -> None:
    import torch
    from pink import ColoredNoiseProcess

    dist = ColouredGaussian(2, ColoredNoiseProcess(2.0, (N_ENVS, 2, 100)), N_ENVS)
    mean, log_std = torch.zeros(256, 2), torch.zeros(256, 2)
    a = dist.actions_from_params(mean, log_std)
    assert a.shape == (256, 2)
    assert float(a.std(dim=0).min()) > 0.4  # independent draws, not one noise vector repeated


@pytest.mark.long
def test_a_non_privileged_preset_trains_with_coloured_noise_and_others_are_refused(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert aids.COLOURED_NOISE.privileged is False
    base = plain_train(runs_dir)
    assert main([*base, COLOURED]) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.data.params["agent.aids.coloured_noise.beta"] == "1"
    assert main([*base, COLOURED, "agent=td3_quick", "agent.max_env_steps=600"]) == 2
    assert "agent.aids.coloured_noise is not allowed with agent.algo=td3" in capsys.readouterr().err
    assert main([*base, COLOURED.replace("beta:1", "beta:7")]) == 2
    err = capsys.readouterr().err
    assert "agent.aids.coloured_noise is not allowed" in err and "beta=7" in err
    assert len(stage_runs(runs_dir, "train")) == 1  # nothing started for the refused ones
