"""The ``late_phase`` aid: from a share of the budget on, a longer discount and more updates per
environment step.

Table I's return ranks the swing to the targets beside the elbow's lower limit (task (b)) above
parking or a collision only at a long discount, and one learner found that swing, when aimed at
it, only at γ 0.998 with one update per environment step (docs/plain_agent.md, "CrossQ at one
update per step and γ 0.998"). From the first step, that discount also makes a collision worth
more than staying far from a target, and the learners that start there learn to end their
episodes on an obstacle; γ 0.996 at half an update per step learns the rest of the workspace
without it. This aid runs the preset's own discount and updates until the share ``at`` of the
budget and the longer discount and the extra updates after it, once the policy reaches most
targets. It changes the learner's settings only: no planner, no obstacle knowledge (not
privileged).

The discount is the model's ``gamma`` and, with n-step returns, its replay buffer's (SB3's
`NStepReplayBuffer` discounts the n rewards and the bootstrap when it samples), so every sample
drawn after the switch is discounted at the new γ; the updates per call are the model's
``gradient_steps``.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import cast

from mlflow.tracking import MlflowClient
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext

#: The environment step of the switch (−1: it never came).
SWITCH_METRIC = "final/late_phase_step"


def set_discount(model: OffPolicyAlgorithm, gamma: float) -> None:
    """Sets the discount that the update reads: the model's, and an n-step buffer's, which
    discounts its samples itself."""
    model.gamma = gamma
    buffer = getattr(model, "replay_buffer", None)
    if buffer is not None and hasattr(buffer, "gamma"):
        buffer.gamma = gamma


class SwitchAt(BaseCallback):
    """Sets ``gamma`` and ``gradient_steps`` (None: left as they are) on the model once
    ``used()``, the share of the budget spent, reaches ``at``; `switched_at` is the step it did
    (None before), handed to ``on_switch`` too. A run resumed past ``at`` switches when training
    starts."""

    def __init__(
        self,
        at: float,
        gamma: float | None,
        gradient_steps: int | None,
        used: Callable[[], float],
        on_switch: Callable[[int], None] | None = None,
    ) -> None:
        super().__init__()
        self.at, self.gamma, self.gradient_steps, self.used = at, gamma, gradient_steps, used
        self.on_switch = on_switch
        self.switched_at: int | None = None

    def _on_training_start(self) -> None:
        self._on_step()

    def _on_step(self) -> bool:
        if self.switched_at is None and self.used() >= self.at:
            model = cast(OffPolicyAlgorithm, self.model)  # the aid's algorithms are off-policy
            if self.gamma is not None:
                set_discount(model, self.gamma)
            if self.gradient_steps is not None:
                model.gradient_steps = self.gradient_steps
            self.switched_at = int(model.num_timesteps)
            if self.on_switch is not None:
                self.on_switch(self.switched_at)
        return True


class LatePhase(TrainingAddOn):
    """From the share ``at`` of the budget on, discount ``gamma`` and ``gradient_steps`` updates
    per call (either None: the preset's own); before it, the preset's (module doc).
    ``final/late_phase_step`` is the environment step the switch came at (−1: never). It is
    logged when the switch happens, so that a run stopped after it and resumed keeps that step
    rather than the one it resumed at (a run stopped before this was logged, and resumed past
    ``at``, reports the step it resumed at)."""

    declaration = aids.LATE_PHASE

    def __init__(
        self, at: float, gamma: float | None = None, gradient_steps: int | None = None
    ) -> None:
        if not 0.0 <= float(at) < 1.0:
            raise ValueError(f"at={at} must be a share of the budget in [0, 1)")
        if gamma is None and gradient_steps is None:
            raise ValueError("give gamma, gradient_steps or both: without them it changes nothing")
        if gamma is not None and not 0.0 < float(gamma) < 1.0:
            raise ValueError(f"gamma={gamma} must be in (0, 1)")
        if gradient_steps is not None and (
            int(gradient_steps) != gradient_steps or int(gradient_steps) < 1
        ):
            raise ValueError(f"gradient_steps={gradient_steps} must be a whole number >= 1")
        self.at = float(at)
        self.gamma = None if gamma is None else float(gamma)
        self.gradient_steps = None if gradient_steps is None else int(gradient_steps)
        self.callback: SwitchAt | None = None
        #: The switch step a resumed run logged before it stopped (None: none logged).
        self.logged_before: int | None = None

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        client = MlflowClient() if ctx.run_id else None
        if client is not None and ctx.resumed:
            earlier = client.get_run(ctx.run_id).data.metrics.get(SWITCH_METRIC)
            self.logged_before = None if earlier is None or earlier < 0 else int(earlier)

        def record(step: int) -> None:
            if client is not None and self.logged_before is None:
                client.log_metric(ctx.run_id, SWITCH_METRIC, float(step), step=step)

        self.callback = SwitchAt(self.at, self.gamma, self.gradient_steps, ctx.budget_used, record)
        return [self.callback]

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        assert self.callback is not None
        step = self.logged_before if self.logged_before is not None else self.callback.switched_at
        return {SWITCH_METRIC: float(-1 if step is None else step)}
