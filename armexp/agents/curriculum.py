"""Curricula over the training targets. The ``curriculum`` aid: training starts on the targets
near the arm's starting tip and widens to the whole workspace.

Far targets, those below the base above all, need a long detour whose first moves take the tip
away from the target (docs/plain_agent.md); near ones are reached by moving straight at them. The
curriculum lets the policy learn reaching on the near ones first: targets are drawn within a
radius of the starting tip that grows linearly from ``start`` metres to the farthest target by the
share ``full_at`` of the budget, then the whole workspace for the rest. It uses the Euclidean
distance only, no planner and no obstacle knowledge (not privileged), and changes nothing but
which training targets are drawn: the held-out checks and `armexp eval` draw from the whole
workspace. The ``missed_targets`` aid (`MissedTargets`) draws again the targets the policy has
missed, while it still misses them; the ``random_starts`` aid (`RandomStarts`) starts some
training episodes away from the fixed starting posture.
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


class SwitchOnAtStart(BaseCallback):
    """Calls ``method(*args)`` on every training environment when training starts (the
    environment's own switch for an aid, `ReachEnv.set_target_retry` or `ReachEnv.set_start_share`),
    and sums the environments' ``counter`` attribute for the run's final metric."""

    def __init__(self, method: str, args: tuple[float, ...], counter: str) -> None:
        super().__init__()
        self.method, self.args, self.counter = method, args, counter

    def _on_training_start(self) -> None:
        self.training_env.env_method(self.method, *self.args)

    def _on_step(self) -> bool:
        return True

    def total(self) -> int:
        """The environments' ``counter``, summed over every environment."""
        return int(sum(self.training_env.get_attr(self.counter)))


class MissedTargets(TrainingAddOn):
    """A curriculum over the policy's own misses: each training environment remembers the last
    ``memory`` targets whose episode ended without reaching them (a collision, a joint limit, the
    time limit), forgets one once it is reached, and draws the next target among them at the
    share ``share`` of resets; the others are drawn as without the aid. The targets the policy
    has not learned come back while it still fails them (below the base, near it: the detour
    docs/plain_agent.md describes), where a uniform draw shows each only as often as any other.
    It reads the episode's outcome only, no planner and no obstacle knowledge (not privileged);
    the held-out checks and `armexp eval` draw as always. ``final/retried_episodes`` counts the
    re-drawn episodes. A resumed run starts with empty memories."""

    declaration = aids.MISSED_TARGETS

    def __init__(self, share: float, memory: int) -> None:
        if not 0.0 < float(share) < 1.0:
            raise ValueError(f"share={share} must be in (0, 1)")
        if not int(memory) >= 1 or int(memory) != memory:
            raise ValueError(f"memory={memory} must be a whole number of targets >= 1")
        self.share, self.memory = float(share), int(memory)
        self.callback: SwitchOnAtStart | None = None

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        # `retried`: training episodes whose target was a re-drawn miss.
        self.callback = SwitchOnAtStart(
            "set_target_retry", (self.share, self.memory), counter="retried"
        )
        return [self.callback]

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        assert self.callback is not None
        return {"final/retried_episodes": float(self.callback.total())}


class RandomStarts(TrainingAddOn):
    """Exploring starts: the share ``share`` of training episodes starts at rest at the posture of
    a workspace point drawn uniformly (`armexp.envs.workspace.Workspace.configs`, the postures the
    targets are drawn from) instead of the paper's fixed starting posture; the target is drawn as
    always. Postures the fixed start reaches only after a long detour (the forearm swung below
    the base) are then visited from their first step, so their values are learned from episodes
    that start there (docs/plain_agent.md has what it measured). The agent is given nothing
    beyond its observation and reward, and the environment's reset alone changes (not
    privileged); the held-out checks and `armexp eval` start at the fixed posture as always.
    ``final/moved_starts`` counts the episodes started elsewhere; a resumed run counts from its
    resumption."""

    declaration = aids.RANDOM_STARTS

    def __init__(self, share: float) -> None:
        if not 0.0 < float(share) < 1.0:
            raise ValueError(f"share={share} must be in (0, 1)")
        self.share = float(share)
        self.callback: SwitchOnAtStart | None = None

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        # `moved_starts`: training episodes that started at a drawn posture.
        self.callback = SwitchOnAtStart("set_start_share", (self.share,), counter="moved_starts")
        return [self.callback]

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        assert self.callback is not None
        return {"final/moved_starts": float(self.callback.total())}
