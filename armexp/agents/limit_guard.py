"""The ``limit_guard`` aid: the joint-limit guard (`armexp.envs.limit_guard`) on the agent's
actions, in training and wherever the policy runs.

The guard lives in the environment, whose settings take its margin from the policy's own config
(`armexp.aids.limit_guard_margin`, read by `armexp.envs.factory.settings_from_config`): the
training environments, the held-out checks, `armexp eval` and `armexp play` all cut the same
actions. This add-on checks that the training environment has it and counts the steps it cut.
"""

from __future__ import annotations

from stable_baselines3.common.callbacks import BaseCallback

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext


class GuardCount(BaseCallback):
    """Sums the training environments' `armexp.envs.reach.ReachEnv.guarded` at the end."""

    def __init__(self) -> None:
        super().__init__()
        self.cut = 0

    def _on_step(self) -> bool:
        return True

    def _on_training_end(self) -> None:
        self.cut = int(sum(self.training_env.get_attr("guarded")))


class LimitGuard(TrainingAddOn):
    """Actions are cut so that the joint reference q_d stays ``margin`` rad inside the joint
    limits and can always stop there (`armexp.envs.limit_guard`): an episode no longer ends at a
    joint limit because the agent drove a joint into it, and a posture beside a limit is reached
    by driving towards it. It uses the arm's joint limits (the bounds of the observed angles) and
    the integral of the agent's own commands; no planner, no obstacle knowledge (not privileged).
    Table I's reward is unchanged. ``final/guarded_steps`` counts the training steps it cut."""

    declaration = aids.LIMIT_GUARD

    def __init__(self, margin: float = aids.DEFAULT_GUARD_MARGIN) -> None:
        if not 0.0 <= float(margin) <= 0.2:
            raise ValueError(f"margin={margin} must be in [0, 0.2] rad")
        self.margin = float(margin)
        self.counter: GuardCount | None = None

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        if ctx.settings.limit_guard != self.margin:
            raise RuntimeError(
                f"the training environment guards at {ctx.settings.limit_guard}, not {self.margin}"
                " rad: build its settings with armexp.envs.factory.settings_from_config"
            )
        self.counter = GuardCount()
        return [self.counter]

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        assert self.counter is not None
        return {"final/guarded_steps": float(self.counter.cut)}
