"""The planner as a feedback policy, and cloning it on the states SAC visits (``agent.bc_expert``).

Cloning the planner's demonstrated episodes (`armexp.agents.cloning`) teaches the actor on the
planner's own states only. Once the actor strays from them (a slightly different detour, a lag
behind the path), nothing says how to get back, and small errors compound into the collisions
and joint-limit folds that remain after 20 minutes. DAgger (Ross, Gordon & Bagnell, 2011) closes
that gap by asking the expert what it would do on the learner's states. The expert here is the
least-time map of `armexp.agents.shaping.TimeToGoPotential`, which knows the time to go T(q) from
every joint configuration to the target: its action at an observation is the bounded velocity
command c ∈ {−1, 0, 1}ⁿ whose motion held for ``lookahead`` environment steps lowers T
most (ties go to the command that moves fewer joints); where that is to hold still, the one
that brings the tip closest to the target.

The map keeps the tip ``margin`` from every obstacle. Measured on held-out targets with
``paper_five`` (two-link arm, the paper's gains): at the environment's 2 cm path margin and a
one-step look-ahead this greedy expert reaches 77 of 100 (23 collide: descending T hugs the
margin, and the tracking lag carries the tip over it); at 8 cm and three steps 290 of 300 (10
collide); at 10 cm and five steps (the defaults of ``agent.expert_margin`` and
``agent.expert_lookahead``) 296 of 300 (3 collide, 1 times out); at 12 cm 291. Without the
hold rule, 1-3 % stalled a millimetre outside the reach threshold. On the three-link
arm's coarser grid (34 cells per joint): 19 of 20.
"""

from __future__ import annotations

import itertools
from dataclasses import replace
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from armexp.agents.cloning import DemonstrationCloning
from armexp.agents.shaping import JOINTS_FROM, TARGET, TimeToGoPotential
from armexp.envs.geometry import tips
from armexp.envs.reach import ReachSettings
from armexp.sim.model import Array


class TimeToGoExpert:
    """The greedy least-time action at an observation (see module doc); ``predict`` as SB3's,
    so that `armexp.agents.rollout.rollout` can run it."""

    def __init__(
        self, settings: ReachSettings, margin: float, lookahead: int = 5, cache: int = 64
    ) -> None:
        self.potential = TimeToGoPotential(replace(settings, path_margin=margin), 1.0, cache)
        n = self.potential.n
        commands = np.array(list(itertools.product((-1.0, 0.0, 1.0), repeat=n)))
        self.commands = commands[np.argsort(np.abs(commands).sum(axis=1), kind="stable")]
        bound = np.asarray(settings.velocity_bound, dtype=np.float64)
        self._moves = self.commands * bound * settings.action_period * lookahead
        self._lengths = np.asarray(settings.plant.arm.lengths_array, dtype=np.float64)

    def __call__(self, obs: Array) -> np.ndarray:
        """Actions (k, n) for the observations ``obs`` (k, d)."""
        obs = np.atleast_2d(np.asarray(obs, dtype=np.float64))
        n = self.potential.n
        out = np.empty((obs.shape[0], n), dtype=np.float32)
        for row, o in enumerate(obs):
            q = o[JOINTS_FROM : JOINTS_FROM + n] + self._moves
            best = int(np.argmin(self.potential.times_at(o[TARGET], q)))
            # To hold (commands[0], the only one of |c|₁ = 0) is right on the target, but T is
            # also flat or at a local minimum of the interpolation a millimetre outside the
            # reach threshold: the tip's distance to the target decides there.
            if best == 0:
                error = np.linalg.norm(tips(q, self._lengths) - o[TARGET], axis=1)
                best = int(np.argmin(error))
            out[row] = self.commands[best]
        return out

    def predict(self, obs: Array, *args: Any, **kwargs: Any) -> tuple[np.ndarray, None]:
        return self(obs)[0], None


class ExpertLabels(BaseCallback):
    """Adds every observation the training environments return, labelled with ``expert``'s
    action, to the states ``cloning`` clones."""

    def __init__(self, expert: TimeToGoExpert, cloning: DemonstrationCloning) -> None:
        super().__init__()
        self.expert = expert
        self.cloning = cloning

    def _on_step(self) -> bool:
        obs = np.asarray(self.locals["new_obs"])
        self.cloning.add(obs, self.expert(obs))
        return True
