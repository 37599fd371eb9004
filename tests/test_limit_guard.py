"""The joint-limit guard: actions cut so that the joint reference stays a margin inside the limits
and can always stop there, in every environment built for a policy that has the aid."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from omegaconf import DictConfig, OmegaConf

from armexp import aids
from armexp.cli import main
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.limit_guard import guarded_action
from armexp.envs.reach import ReachEnv
from tests.helpers import plain_train, refused_in_one_sentence, stage_runs

GUARD = "+agent.aids.limit_guard={_target_:armexp.agents.limit_guard.LimitGuard,margin:0.02}"
LOWER, UPPER = np.array([-0.8, -2.6]), np.array([2.4, 2.6])
BOUND = np.array([0.1, 0.4])
PERIOD = 0.03


def _drive(q_d: np.ndarray, actions: list[np.ndarray], ramp: bool) -> list[np.ndarray]:
    """The reference q_d after each guarded action, integrated as the simulator does (the ramp:
    the mean of the last command and this one over the period)."""
    command = np.zeros(2)
    out = []
    for action in actions:
        cut = guarded_action(action, q_d, command, BOUND, LOWER, UPPER, 0.02, PERIOD, ramp)
        v = cut * BOUND
        q_d = q_d + PERIOD * (0.5 * (command + v) if ramp else v)
        command = v
        out.append(q_d)
    return out


@pytest.mark.parametrize("ramp", [True, False], ids=["ramp", "hold"])
def test_full_speed_into_a_limit_stops_the_reference_at_the_margin_and_rests_there(
    ramp: bool,
) -> None:
    pushes = [np.array([-1.0, 1.0])] * 400  # 12 s: both joints reach their guarded limit
    path = np.array(_drive(np.array([0.0, 1.57]), pushes, ramp))
    assert np.all(path[:, 0] >= LOWER[0] + 0.02 - 1e-12)
    assert np.all(path[:, 1] <= UPPER[1] - 0.02 + 1e-12)
    # It gets there (within one action's travel) and stays, without chatter.
    assert path[-1] == pytest.approx([LOWER[0] + 0.02, UPPER[1] - 0.02], abs=PERIOD * 0.4)
    assert np.ptp(path[-50:], axis=0) == pytest.approx([0.0, 0.0], abs=1e-12)


def test_away_from_the_limits_the_action_is_untouched_and_at_a_limit_only_its_way_out() -> None:
    command = np.array([0.05, -0.2])
    free = guarded_action(
        np.array([0.7, -1.3]), np.array([0.5, 0.0]), command, BOUND, LOWER, UPPER, 0.02,
        PERIOD, True,
    )  # fmt: skip
    assert free == pytest.approx([0.7, -1.0])  # clipped to the action box only
    at_limit = np.array([LOWER[0] + 0.02, UPPER[1] - 0.02])
    into = guarded_action(
        np.array([-1.0, 1.0]), at_limit, np.zeros(2), BOUND, LOWER, UPPER, 0.02, PERIOD, True
    )
    out = guarded_action(
        np.array([1.0, -1.0]), at_limit, np.zeros(2), BOUND, LOWER, UPPER, 0.02, PERIOD, True
    )
    assert into == pytest.approx([0.0, 0.0]) and out == pytest.approx([1.0, -1.0])


@pytest.mark.parametrize("controller", ["subsystem_adaptive", "pid"])
def test_an_episode_pushing_into_a_limit_ends_there_without_the_guard_and_not_with_it(
    controller: str,
) -> None:
    for guarded in (False, True):
        overrides = [f"controller={controller}", "controller.gains=paper"] if (
            controller == "subsystem_adaptive") else [f"controller={controller}"]  # fmt: skip
        env = ReachEnv(settings_from_config(compose_config(overrides + [GUARD] * guarded)))
        env.reset(seed=3, options={"target": (-0.5, 1.5)})
        lowest = np.inf
        for _ in range(1000):
            _, _, terminated, truncated, info = env.step(np.array([-1.0, -1.0], np.float32))
            lowest = min(lowest, float(env.sim.q[1]))
            if terminated or truncated:
                break
        if not guarded:
            assert info["reason"] == "joint_limit" and env.guarded == 0
        else:
            # Rests beside the elbow's lower limit; the tracking stays within the margin.
            assert info["reason"] == "time_limit" and env.guarded > 100
            limit = env.settings.joint_lower[1]
            assert limit < lowest < limit + 0.03
            assert env.sim.q[0] > env.settings.joint_lower[0]


def test_the_margin_is_read_from_the_policys_config_under_any_key() -> None:
    assert settings_from_config(compose_config([])).limit_guard is None
    preset = compose_config(["agent=sac_plain_guard"])
    assert settings_from_config(preset).limit_guard == 0.02
    # As evaluation reads it: the train run's stored config, under another name.
    stored = OmegaConf.create(OmegaConf.to_container(preset, resolve=True))
    assert isinstance(stored, DictConfig)
    stored.agent.aids = {"guard": {"_target_": aids.LIMIT_GUARD.target, "margin": 0.05}}
    assert settings_from_config(stored).limit_guard == 0.05
    assert aids.limit_guard_margin({"aids": {"g": {"_target_": aids.LIMIT_GUARD.target}}}) == (
        aids.DEFAULT_GUARD_MARGIN
    )
    assert aids.LIMIT_GUARD.privileged is False


@pytest.mark.long
def test_a_non_privileged_run_trains_with_the_guard_and_a_bad_margin_is_refused(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    base = plain_train(runs_dir)
    assert main([*base, GUARD]) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.data.params["agent.aids.limit_guard.margin"] == "0.02"
    assert run.data.metrics["final/guarded_steps"] >= 0
    refused_in_one_sentence(
        runs_dir, capsys, [*base, GUARD.replace("margin:0.02", "margin:-1")],
        "agent.aids.limit_guard is not allowed", "margin=-1",
    )  # fmt: skip
