"""A curriculum over target distance (the ``curriculum`` aid): training starts on the targets
near the arm's starting tip and widens to the whole workspace.

Far targets, those below the base above all, need a long detour whose first moves take the tip
away from the target (docs/plain_agent.md); near ones are reached by moving straight at them. The
curriculum lets the policy learn reaching on the near ones first: targets are drawn within a
radius of the starting tip that grows linearly from ``start`` metres to the farthest target by the
share ``full_at`` of the budget, then the whole workspace for the rest. It uses the Euclidean
distance only, no planner and no obstacle knowledge (not privileged), and changes nothing but
which training targets are drawn: the held-out checks and `armexp eval` draw from the whole
workspace.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext

#: The radius moves in steps of this much (m): each change is a call into every environment.
GRAIN_M = 0.01


class WideningReach(BaseCallback):
    """Sets the training environments' target reach (`ReachEnv.set_target_reach`) from the share
    of the budget spent, ``used()``; None once it covers the farthest target."""

    def __init__(self, start: float, full_at: float, used: Callable[[], float]) -> None:
        super().__init__()
        self.start, self.full_at, self.used = start, full_at, used
        self.farthest = 0.0
        self.reach: float | None = start

    def _on_training_start(self) -> None:
        far = self.training_env.env_method("start_distances")
        self.farthest = float(max(np.max(d) for d in far))
        self._set(self.radius())

    def radius(self) -> float | None:
        """The reach at the budget spent so far (None: the whole workspace)."""
        share = min(1.0, self.used() / self.full_at)
        r = self.start + (self.farthest - self.start) * share
        return None if r >= self.farthest else float(round(r / GRAIN_M) * GRAIN_M)

    def _on_step(self) -> bool:
        r = self.radius()
        if r != self.reach:
            self._set(r)
        return True

    def _set(self, r: float | None) -> None:
        self.reach = r
        self.training_env.env_method("set_target_reach", r)


class TargetCurriculum(TrainingAddOn):
    """Targets within ``start`` metres of the starting tip first, the whole workspace from the
    share ``full_at`` of the budget on (`WideningReach`); ``final/curriculum_reach`` is the
    radius training ended with (0: the whole workspace). A resumed run takes the radius of the
    budget it resumes at."""

    declaration = aids.CURRICULUM

    def __init__(self, start: float, full_at: float) -> None:
        if not float(start) > 0.0:
            raise ValueError(f"start={start} must be a distance > 0 (m)")
        if not 0.0 < float(full_at) <= 1.0:
            raise ValueError(f"full_at={full_at} must be in (0, 1]")
        self.start, self.full_at = float(start), float(full_at)
        self.callback: WideningReach | None = None

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        self.callback = WideningReach(self.start, self.full_at, ctx.budget_used)
        return [self.callback]

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        assert self.callback is not None
        return {"final/curriculum_reach": float(self.callback.reach or 0.0)}
