"""A count-based exploration bonus over the arm's observed posture (the ``count_bonus`` aid).

The non-privileged agents miss the targets below the base whose only posture within the joint
limits has the elbow folded the other way from the start, within about 0.42 rad of its lower
limit (docs/plain_agent.md, "Which postures the misses need"): a swing of the forearm through
3.8–4.2 rad that neither white nor coloured noise around the policy carries through, so that the
final policies' own sampling almost never reaches them. A bonus for postures the agent has
rarely been in (Strehl & Littman, 2008; the pseudo-counts of Bellemare et al., 2016, and the
hashed counts of Tang et al., 2017, in their simplest form: a grid) pays it to go where it has
not been:

    r⁺(s') = β(t) / √N(φ(q'))

with q' the joint angles of the observation reached, φ its cell on a grid of ``cell`` rad, N the
visits to that cell so far (this one included) and β(t) falling linearly from ``beta`` at the
first step to 0 at the share ``until`` of the training budget, so that the critic learns the
environment's own reward alone over the rest of training. The bonus is added to the reward the
replay buffer stores; episode returns, success rates, checks and evaluations are the
environment's own. It reads the joint angles of the observation only: no planner, no obstacle
knowledge (not privileged). The counts are not part of a checkpoint: a resumed run counts
afresh. At three seeds it left the misses where they were (docs/plain_agent.md).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext
from armexp.envs.observation import ObservationLayout


class PostureCounts(BaseCallback):
    """Counts the cells of the postures the training environments reach and adds the bonus to
    the rewards of the step before the replay buffer stores them (SB3 stores the same array
    after its callbacks run)."""

    def __init__(
        self, layout: ObservationLayout, beta: float, cell: float, until: float,
        used: Callable[[], float],
    ) -> None:  # fmt: skip
        super().__init__()
        self.layout, self.beta, self.cell, self.until, self.used = layout, beta, cell, until, used
        self.counts: Counter[tuple[int, ...]] = Counter()
        self.paid = 0.0

    def scale(self) -> float:
        """β(t): ``beta`` falling linearly to 0 at the share ``until`` of the budget."""
        return self.beta * max(0.0, 1.0 - self.used() / self.until)

    def bonus(self, observations: np.ndarray) -> np.ndarray:
        """Count each row's posture cell and return its bonus at the current scale."""
        scale = self.scale()
        cells = np.floor(self.layout.q(observations) / self.cell).astype(np.int64)
        out = np.empty(len(cells))
        for i, key in enumerate(map(tuple, cells)):
            self.counts[key] += 1
            out[i] = scale / np.sqrt(self.counts[key])
        return out

    def _on_step(self) -> bool:
        reached = np.array(self.locals["new_obs"], copy=True)
        infos = self.locals["infos"]
        for i, (done, info) in enumerate(zip(self.locals["dones"], infos, strict=True)):
            if done and "terminal_observation" in info:  # new_obs holds the next episode's start
                reached[i] = info["terminal_observation"]
        extra = self.bonus(reached)
        rewards = self.locals["rewards"]
        rewards += extra.astype(rewards.dtype)  # in place: the array SB3 then stores
        self.paid += float(extra.sum())
        self.logger.record_mean("train/count_bonus", float(extra.mean()))
        return True


class CountBonus(TrainingAddOn):
    """The bonus above (``beta``, ``cell`` rad, falling to 0 at the share ``until`` of the
    budget). Not privileged. Off-policy algorithms: the bonus enters the stored rewards."""

    declaration = aids.COUNT_BONUS

    def __init__(self, beta: float = 0.5, cell: float = 0.1, until: float = 0.75) -> None:
        if not (float(beta) > 0 and float(cell) > 0 and 0 < float(until) <= 1):
            raise ValueError(
                f"beta={beta} and cell={cell} must be greater than 0, until={until} in (0, 1]"
            )
        self.beta, self.cell, self.until = float(beta), float(cell), float(until)
        self.callback: PostureCounts | None = None

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        n = len(ctx.settings.plant.arm.lengths_array)
        layout = ObservationLayout(n, int(np.asarray(ctx.settings.obstacles).size // 3))
        self.callback = PostureCounts(layout, self.beta, self.cell, self.until, ctx.budget_used)
        return [self.callback]

    def finish(self, ctx: TrainingContext) -> dict[str, float]:
        if self.callback is None:
            return {}
        return {
            "final/count_bonus_cells": float(len(self.callback.counts)),
            "final/count_bonus_paid": self.callback.paid,
        }
