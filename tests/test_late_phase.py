"""The late phase: from a share of the budget on, the model's discount (and an n-step buffer's,
which discounts its own samples) and its updates per call change; before it they are the
preset's; a run resumed past the switch starts switched and keeps the step its switch came at; a
non-privileged preset takes it and bad values are one sentence."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.buffers import NStepReplayBuffer
from stable_baselines3.common.callbacks import BaseCallback

from armexp import aids
from armexp.agents.late_phase import LatePhase, SwitchAt
from armexp.cli import main
from armexp.config import compose_config
from tests.helpers import (
    plain_train,
    refused_in_one_sentence,
    stage_runs,
    stop_and_resume,
)

LATE = (
    "+agent.aids.late_phase={_target_:armexp.agents.late_phase.LatePhase,"
    "at:0.5,gamma:0.999,gradient_steps:2}"
)
BUDGET = 400


class Watch(BaseCallback):
    """Keeps, after each step, the step count, the model's and its buffer's discount and its
    updates per call."""

    def __init__(self) -> None:
        super().__init__()
        self.seen: list[tuple[int, float, float, int]] = []

    def _on_step(self) -> bool:
        model = self.model
        buffer = model.replay_buffer  # type: ignore[attr-defined]
        assert isinstance(buffer, NStepReplayBuffer)
        steps = model.gradient_steps  # type: ignore[attr-defined]
        gamma = model.gamma  # type: ignore[attr-defined]
        self.seen.append((model.num_timesteps, gamma, buffer.gamma, steps))
        return True


def _model(n_steps: int = 3) -> SAC:
    return SAC(
        "MlpPolicy", "Pendulum-v1", gamma=0.95, n_steps=n_steps, learning_starts=50,
        gradient_steps=1, batch_size=16, policy_kwargs={"net_arch": [8]}, seed=0,
    )  # fmt: skip


def test_the_switch_comes_at_the_share_and_every_later_sample_and_update_takes_it() -> None:
    model = _model()
    switch = SwitchAt(0.5, 0.99, 3, used=lambda: model.num_timesteps / BUDGET)
    watch = Watch()
    model.learn(BUDGET, callback=[switch, watch])
    assert switch.switched_at == BUDGET // 2
    for step, gamma, buffer_gamma, gradient_steps in watch.seen:
        expected = (0.99, 0.99, 3) if step >= BUDGET // 2 else (0.95, 0.95, 1)
        assert (gamma, buffer_gamma, gradient_steps) == expected
    # One update after each step past learning_starts (51 to 199), three from the step that
    # switched (200 to 400: the switch comes in the step's callback, before its update).
    assert model._n_updates == (BUDGET // 2 - 51) * 1 + (BUDGET // 2 + 1) * 3
    # An n-step sample's bootstrap discount is the new gamma to the steps it sums.
    buffer = model.replay_buffer
    assert isinstance(buffer, NStepReplayBuffer)
    discounts = buffer.sample(256).discounts
    assert discounts is not None
    allowed = {round(0.99**k, 5) for k in (1, 2, 3)}
    assert {round(float(d), 5) for d in discounts.flatten()} <= allowed
    assert round(0.99**3, 5) in {round(float(d), 5) for d in discounts.flatten()}


def constant(share: float) -> Callable[[], float]:
    return lambda: share


def test_a_run_resumed_past_the_switch_starts_switched_and_one_before_it_does_not() -> None:
    for used, switched in ((0.7, True), (0.2, False)):
        model = _model(n_steps=1)
        switch = SwitchAt(0.5, 0.98, None, used=constant(used))
        model.learn(60, callback=switch)
        assert (switch.switched_at is not None) is switched
        assert model.gamma == (0.98 if switched else 0.95)
        assert model.gradient_steps == 1  # not asked to change


@pytest.mark.parametrize(
    ("args", "words"),
    [
        ({"at": 1.0, "gamma": 0.99}, "at=1.0"),
        ({"at": 0.5}, "give gamma, gradient_steps or both"),
        ({"at": 0.5, "gamma": 1.0}, "gamma=1.0"),
        ({"at": 0.5, "gradient_steps": 0}, "gradient_steps=0"),
    ],
)
def test_bad_values_are_refused_when_built(args: dict, words: str) -> None:
    with pytest.raises(ValueError, match=words):
        LatePhase(**args)


def test_the_preset_is_the_missed_targets_preset_with_the_late_phase_and_not_privileged() -> None:
    assert aids.LATE_PHASE.privileged is False
    late = compose_config(["agent=crossq_plain_guard_late"]).agent
    missed = compose_config(["agent=crossq_plain_guard_g996_missed"]).agent
    assert late.privileged is False
    assert {k for k in missed if k not in ("name", "aids") and late[k] != missed[k]} == set()
    assert list(late.aids) == [*missed.aids, "late_phase"]
    phase = late.aids.late_phase
    assert (phase.at, phase.gamma, phase.gradient_steps) == (0.4, 0.998, 8)
    assert (late.gamma, late.gradient_steps, late.n_envs) == (0.996, 4, 8)
    assert aids.LATE_PHASE.describe(phase) == (
        "from 40 % of the budget on, γ 0.998 and 8 gradient steps per call"
    )


@pytest.mark.long
def test_a_non_privileged_run_switches_through_the_train_stage_and_bad_input_is_one_sentence(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(plain_train(runs_dir, LATE)) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.info.status == "FINISHED"
    # 600 steps of two environments: the switch at the first vector step from 300.
    assert run.data.metrics["final/late_phase_step"] in (300.0, 302.0)
    bad = plain_train(runs_dir, LATE.replace("at:0.5", "at:1.5"))
    refused_in_one_sentence(runs_dir, capsys, bad, "agent.aids.late_phase", "at=1.5")
    ppo = plain_train(runs_dir, LATE, "agent.algo=ppo")
    refused_in_one_sentence(
        runs_dir, capsys, ppo, "agent.aids.late_phase is not allowed with agent.algo=ppo"
    )
    sil = (
        "+agent.aids.self_imitation="
        "{_target_:armexp.agents.self_imitation.SelfImitation,weight:0.5,capacity:2000}"
    )
    both = plain_train(runs_dir, sil, LATE)
    with_sil = "agent.aids.late_phase is not allowed with agent.aids.self_imitation"
    refused_in_one_sentence(runs_dir, capsys, both, with_sil)


@pytest.mark.long
def test_a_run_stopped_after_its_switch_and_resumed_reports_the_step_the_switch_came_at(
    runs_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    stopped, resumed = stop_and_resume(
        runs_dir, monkeypatch, capsys, plain_train(runs_dir, LATE), at=450
    )
    # Logged when it happened, not only at the end the stopped run never reached.
    assert stopped.data.metrics["final/late_phase_step"] in (300.0, 302.0)
    assert resumed.data.metrics["final/env_steps"] == 600
    assert (
        resumed.data.metrics["final/late_phase_step"]
        == stopped.data.metrics["final/late_phase_step"]
    )
