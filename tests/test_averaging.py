"""The actor's weights averaged over the end of the budget (armexp.agents.averaging)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from armexp.agents.averaging import ActorAverage
from armexp.agents.sac import ResumableSAC
from armexp.cli import main
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from tests.helpers import SMALL_TRAIN, small_sac, stage_runs


def _fill(module: torch.nn.Module, value: float) -> None:
    with torch.no_grad():
        for p in module.parameters():
            p.fill_(value)


def test_the_average_is_the_mean_of_the_weights_taken_in_the_tail_only() -> None:
    model = small_sac(settings_from_config(compose_config(["controller.gains=paper"])))
    share = [0.0]
    average = ActorAverage(0.25, lambda: share[0])
    average.init_callback(model)
    # Weights 0..9 at budget shares 0.0..0.9: the tail (share ≥ 0.75) holds 8 and 9.
    for k in range(10):
        share[0] = k / 10
        _fill(model.actor, float(k))
        average.on_step()
    critic = {k: v.clone() for k, v in model.critic.state_dict().items()}
    assert average.apply() == 2
    for p in model.actor.parameters():
        torch.testing.assert_close(p, torch.full_like(p, 8.5))
    for k, v in model.critic.state_dict().items():
        torch.testing.assert_close(v, critic[k])  # only the actor is averaged


def test_without_a_weight_set_in_the_tail_the_actor_is_left_as_trained() -> None:
    model = small_sac(settings_from_config(compose_config(["controller.gains=paper"])))
    average = ActorAverage(0.1, lambda: 0.5)
    average.init_callback(model)
    _fill(model.actor, 3.0)
    average.on_step()
    assert average.apply() == 0
    assert all(torch.all(p == 3.0) for p in model.actor.parameters())


AVERAGE_HALF = "+agent.aids.averaging={_target_:armexp.agents.averaging.WeightAveraging,tail:0.5}"


@pytest.mark.long
def test_a_train_run_saves_the_averaged_actor_and_checkpoints_the_last_one(
    runs_dir: Path, tmp_path: Path
) -> None:
    import mlflow

    rc = main(
        ["train", "controller.gains=paper", *SMALL_TRAIN, AVERAGE_HALF,
         f"tracking.runs_dir={runs_dir}"]
    )  # fmt: skip
    assert rc == 0
    (run,) = stage_runs(runs_dir, "train")
    # One weight set per vector step over the last half of 600 environment steps.
    n_envs = int(run.data.params["agent.n_envs"])
    assert run.data.metrics["final/averaged_actors"] == pytest.approx(300 / n_envs, abs=1)
    mlflow.set_tracking_uri(f"sqlite:///{runs_dir}/mlflow.db")

    def load(folder: str) -> ResumableSAC:
        path = mlflow.artifacts.download_artifacts(
            run_id=run.info.run_id,
            artifact_path=f"{folder}/model.zip",
            dst_path=str(tmp_path / folder),
        )
        return ResumableSAC.load(path)

    final, last = load("model"), load("checkpoint")
    assert final.num_timesteps == last.num_timesteps == 600
    moved = [
        float((a - b).detach().abs().max())
        for a, b in zip(final.actor.parameters(), last.actor.parameters(), strict=True)
    ]
    assert max(moved) > 1e-4  # the actor trained over the tail, so its mean is elsewhere
    for a, b in zip(final.critic.parameters(), last.critic.parameters(), strict=True):
        np.testing.assert_array_equal(a.detach().numpy(), b.detach().numpy())
