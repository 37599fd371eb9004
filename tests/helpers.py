"""Shared budgets for tests that run real stages (seconds, not minutes)."""

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
