"""The missed-target curriculum: the environment remembers the training targets its episodes
missed, draws them again at the share asked until they are reached, and a non-privileged preset
takes the aid that turns it on."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from armexp import aids
from armexp.cli import main
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv, ReachSettings
from tests.helpers import plain_train, refused_in_one_sentence, stage_runs

MISSED = (
    "+agent.aids.missed_targets={_target_:armexp.agents.curriculum.MissedTargets,"
    "share:0.5,memory:8}"
)


@pytest.fixture(scope="module")
def settings() -> ReachSettings:
    # Two-step episodes: every one ends at the time limit, a miss, unless it collides first.
    base = settings_from_config(compose_config(["controller.gains=paper"]))
    return dataclasses.replace(base, max_steps=2)


def _miss(env: ReachEnv) -> np.ndarray:
    """Run the current episode to its end without moving; the target it missed."""
    for _ in range(env.settings.max_steps):
        _, _, terminated, truncated, _ = env.step(np.zeros(len(env.settings.q0)))
        if terminated or truncated:
            break
    assert env.reason != "reached"
    return env.target.copy()


def test_without_retries_the_draws_are_those_of_an_environment_never_asked(
    settings: ReachSettings,
) -> None:
    env, plain = ReachEnv(settings), ReachEnv(settings)
    env.set_target_retry(0.0, 8)
    env.reset(seed=5)
    plain.reset(seed=5)
    for _ in range(20):
        _miss(env), _miss(plain)
        assert np.array_equal(env.reset()[0], plain.reset()[0])
    assert env.retried == 0


def test_a_missed_target_comes_back_until_it_is_reached(settings: ReachSettings) -> None:
    env = ReachEnv(settings)
    env.set_target_retry(1.0, 1)
    env.reset(seed=3)
    missed = _miss(env)
    env.reset()
    assert np.array_equal(env.target, missed) and env.retried == 1
    _miss(env)
    env.reset()
    assert np.array_equal(env.target, missed) and env.retried == 2
    _miss(env)
    # Reached at last (the reason `step` sets on reach): forgotten, the next draw is a new one.
    env.reason = "reached"
    env.reset()
    assert env.retried == 2
    assert not np.array_equal(env.target, missed)


def test_it_remembers_the_last_misses_only_and_never_a_tasks_target(
    settings: ReachSettings,
) -> None:
    env = ReachEnv(dataclasses.replace(settings, tasks={"far": (0.3, 1.2)}))
    env.set_target_retry(0.5, 2)
    env.reset(seed=11)
    targets = []
    for _ in range(200):  # every episode a miss
        targets.append(tuple(_miss(env)))
        env.reset()
    assert env._missed is not None and len(env._missed) == 2  # memory two
    remembered = [tuple(env.workspace.points[i]) for i in env._missed]
    assert targets[-1] in remembered and set(remembered) <= set(targets)
    assert 60 < env.retried < 140  # about half of 200 draws (binomial, 0.5)
    before = list(env._missed)
    env.reset(options={"task": "far"})
    _miss(env)  # a task's episode: not a training target, not remembered
    env.reset()
    assert (0.3, 1.2) not in {tuple(env.workspace.points[i]) for i in env._missed}
    assert list(env._missed) == before


@pytest.mark.long
def test_a_non_privileged_preset_trains_with_the_aid_and_bad_values_are_one_sentence(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert aids.MISSED_TARGETS.privileged is False
    assert main(plain_train(runs_dir, MISSED, "env.max_steps=20")) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.info.status == "FINISHED"
    # 600 steps of 20-step episodes on the smoke preset's environments: about 30 episodes, most
    # of them missed; half of the draws after a miss come back.
    assert run.data.metrics["final/retried_episodes"] >= 3
    bad = plain_train(runs_dir, MISSED.replace("share:0.5", "share:1.5"))
    refused_in_one_sentence(runs_dir, capsys, bad, "agent.aids.missed_targets", "share=1.5")
