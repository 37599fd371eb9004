"""The observation of ``armexp/Reach-v0`` (eq. 5a; eq. 4a without obstacles), in one place.

Entries, in order: target (x, y), tip − target (x, y), tip (x, y), the n joint angles q, and
the distance from the tip to the surface of each of the m obstacles (negative inside). The
compiled step (`armexp.envs.kernel.observe`) writes this order; everything that reads an
observation (the planner's expert, cloning, tests) goes through `ObservationLayout`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from armexp.sim.model import Array

#: Fixed positions, before the joint angles (the compiled kernel writes these indices).
TARGET = slice(0, 2)
OFFSET = slice(2, 4)
TIP = slice(4, 6)
JOINTS_FROM = 6


@dataclass(frozen=True)
class ObservationLayout:
    """Where each part of an observation of an n-joint arm among m obstacles sits."""

    n: int
    m: int

    @property
    def size(self) -> int:
        return JOINTS_FROM + self.n + self.m

    @property
    def joints(self) -> slice:
        return slice(JOINTS_FROM, JOINTS_FROM + self.n)

    @property
    def clearances(self) -> slice:
        return slice(JOINTS_FROM + self.n, self.size)

    def target(self, obs: Array) -> Array:
        """The target (x, y) of an observation, or of each row of a batch."""
        return np.asarray(obs[..., TARGET], dtype=np.float64)

    def tip(self, obs: Array) -> Array:
        return np.asarray(obs[..., TIP], dtype=np.float64)

    def q(self, obs: Array) -> Array:
        """The joint angles (rad) of an observation, or of each row of a batch."""
        return np.asarray(obs[..., self.joints], dtype=np.float64)

    def bounds(
        self, lengths: Array, lower: Array, upper: Array, obstacles: Array
    ) -> tuple[Array, Array]:
        """The observation box: positions within the arm's reach, angles within their limits
        widened by π, clearances from minus each radius to the farthest obstacle."""
        reach = float(np.sum(lengths))
        far = reach + (float(np.hypot(*obstacles[:, :2].T).max()) if self.m else 0.0)
        low = np.concatenate(
            [[-reach] * 2, [-2 * reach] * 2, [-reach] * 2, lower - math.pi, -obstacles[:, 2]]
        )
        high = np.concatenate(
            [[reach] * 2, [2 * reach] * 2, [reach] * 2, upper + math.pi, [far] * self.m]
        )
        return low, high
