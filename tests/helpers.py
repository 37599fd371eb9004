"""Shared budgets and look-ups for tests that run real stages (seconds, not minutes)."""

from __future__ import annotations

from typing import Any

SMALL_TUNE = [
    "tuner=cso_fast",
    "tuner.n_iterations=2",
    "tuner.objective.n_scenarios=2",
    "tuner.objective.horizon=0.2",
]
# 600 steps of a small SAC with 100-step episodes: it learns nothing, it exercises everything.
SMALL_TRAIN = [
    "agent=sac_smoke",
    "agent.max_env_steps=600",
    "agent.learning_starts=100",
    "agent.net_arch=[32,32]",
    "train.checkpoint_every=200",
    "train.progress=false",
    "env.max_steps=100",
]


def stage_runs(store: Any, stage: str, newest_first: bool = True) -> list[Any]:
    """The runs of one stage in experiment 'armexp' of a store: a runs folder (SQLite) or a URI."""
    from mlflow.tracking import MlflowClient

    uri = store if isinstance(store, str) else f"sqlite:///{store}/mlflow.db"
    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("armexp")
    assert exp is not None, f"no experiment 'armexp' in {uri}"
    order = "DESC" if newest_first else "ASC"
    return client.search_runs(
        [exp.experiment_id],
        f"tags.`armexp.stage` = '{stage}'",
        order_by=[f"attributes.start_time {order}"],
    )
