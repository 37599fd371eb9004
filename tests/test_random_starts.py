"""Exploring starts: the environment starts a share of its drawn-target training episodes at the
posture of a drawn workspace point, never an episode given a task or a target, and a
non-privileged preset takes the aid that turns it on."""

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

STARTS = "+agent.aids.random_starts={_target_:armexp.agents.curriculum.RandomStarts,share:0.5}"


@pytest.fixture(scope="module")
def settings() -> ReachSettings:
    return settings_from_config(compose_config(["controller.gains=paper"]))


def test_share_zero_draws_as_an_environment_never_asked(settings: ReachSettings) -> None:
    env, plain = ReachEnv(settings), ReachEnv(settings)
    env.set_start_share(0.0)
    env.reset(seed=5)
    plain.reset(seed=5)
    for _ in range(20):
        a, b = env.reset()[0], plain.reset()[0]
        assert np.array_equal(a, b)
    assert env.moved_starts == 0


def test_moved_starts_are_workspace_postures_at_rest_away_from_the_target(
    settings: ReachSettings,
) -> None:
    env = ReachEnv(settings)
    env.set_start_share(0.5)
    env.reset(seed=3)
    configs = env.workspace.configs
    moved, before = 0, env.moved_starts
    for _ in range(200):
        env.reset()
        q = env.sim.q.copy()
        if np.allclose(q, settings.q0):
            continue
        moved += 1
        assert np.min(np.abs(configs - q).sum(axis=1)) < 1e-12  # one of the workspace postures
        assert np.allclose(env.sim.dq, 0.0)  # at rest
        assert env.error > 2 * settings.reach_threshold  # not reached before the first step
        # The tip, the error and the observation describe the moved arm.
        assert np.allclose(env.tip, env.sim.tip())
    assert moved == env.moved_starts - before
    assert 60 < moved < 140  # about half of 200 draws (binomial, 0.5)
    # A task's or an explicit target's episode starts at the fixed posture, whatever the share.
    env.set_start_share(0.99)
    for options in ({"task": "a"}, {"target": (0.5, -0.7)}):
        env.reset(options=options)
        assert np.allclose(env.sim.q, settings.q0)


def test_a_moved_start_steps_like_the_arm_there(settings: ReachSettings) -> None:
    """The episode from a moved start is the simulation from that posture: the same steps as an
    environment whose fixed posture is that one."""
    env = ReachEnv(settings)
    env.set_start_share(0.99)
    env.reset(seed=8)
    while np.allclose(env.sim.q, settings.q0):
        env.reset()
    q, target = env.sim.q.copy(), env.target.copy()
    there = ReachEnv(dataclasses.replace(settings, q0=q))
    there.reset(seed=0, options={"target": target})
    # Both simulators from the same state with the same disturbance draws.
    env.sim.reset(q, seed=1)
    there.sim.reset(q, seed=1)
    for k in range(30):
        action = np.array([np.sin(0.1 * k), -1.0])
        a, b = env.step(action), there.step(action)
        assert np.array_equal(a[0], b[0]) and a[1:4] == b[1:4]
        if a[2] or a[3]:
            break


@pytest.mark.long
def test_a_non_privileged_preset_trains_with_the_aid_and_bad_values_are_one_sentence(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert aids.RANDOM_STARTS.privileged is False
    assert main(plain_train(runs_dir, STARTS, "env.max_steps=20")) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.info.status == "FINISHED"
    # About 30 episodes of 20 steps in 600 steps of the smoke preset; half start elsewhere.
    assert run.data.metrics["final/moved_starts"] >= 5
    bad = plain_train(runs_dir, STARTS.replace("share:0.5", "share:0"))
    refused_in_one_sentence(runs_dir, capsys, bad, "agent.aids.random_starts", "share=0")
