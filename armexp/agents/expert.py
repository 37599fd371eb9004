"""The planner as a feedback policy, and cloning it on the states SAC visits (DAgger).

Cloning the planner's demonstrated episodes (`armexp.agents.cloning`) teaches the actor on the
planner's own states only. Once the actor strays from them (a slightly different detour, a lag
behind the path), nothing says how to get back, and small errors compound into collisions and
joint-limit folds. DAgger (Ross, Gordon & Bagnell, 2011) closes that gap by asking the expert
what it would do on the learner's states. The expert here is the least-time map `TimeToGoMap`,
which knows the time to go T(q) from every joint configuration to the target: its action at an
observation is the bounded velocity command c ∈ {−1, 0, 1}ⁿ whose motion held for
``lookahead`` environment steps lowers T most (ties go to the command that moves fewer joints);
where that is to hold still, the one that brings the tip closest to the target. Within
``approach`` of the target, where the straight line to it is clear, the action instead moves the
tip straight at the target at the largest speed the bounds allow (a damped least-squares step
through the arm's Jacobian).

The map keeps the tip ``margin`` from every obstacle, and inside that margin each grid move
costs ``inside_cost`` free ones, so that where the tracking lag has carried the tip in, the
quickest way on leads out first (at one free move per cell the map leads on through the margin
and the obstacle behind it).

Why the straight approach: the actor regresses the labels, and near the target the greedy labels
flip sign over a few hundredths of a radian (a several-step move overshoots the goal from one
side and falls short from the other), which a regression averages to a stop just outside the
reach threshold. The straight approach is continuous in the state and only vanishes on the
target, so the regressed action still points in.
"""

from __future__ import annotations

import itertools
from collections import OrderedDict
from dataclasses import replace
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext
from armexp.agents.cloning import BehaviourCloning, DemonstrationCloning
from armexp.envs.geometry import segment_hits, tips
from armexp.envs.observation import ObservationLayout
from armexp.envs.reach import ReachSettings
from armexp.envs.workspace import JointGrid, fill_unreached, time_to_go
from armexp.sim.dynamics import tip_jacobian
from armexp.sim.model import Array


class TimeToGoMap:
    """T(q, target): the least time (s) in which a velocity-bounded motion that keeps the tip
    ``settings.path_margin`` from every obstacle brings it within the reach threshold (a
    breadth-first search over the joint grid, `armexp.envs.workspace.time_to_go`), bilinear
    between grid cells.

    A cell with no finite time (its tip within the margin of an obstacle, or cut off from the
    target) gets the least time over paths through such cells to a finite cell, at
    ``inside_cost`` time cells per grid move, so that T stays continuous where the arm skirts an
    obstacle (finite times are never shortened through them). Maps are kept for the ``cache``
    most recent targets.
    """

    def __init__(self, settings: ReachSettings, cache: int = 64, inside_cost: float = 1.0) -> None:
        self.inside_cost = float(inside_cost)
        self.threshold = settings.reach_threshold
        self.n = int(settings.q0.shape[0])
        self.grid: JointGrid = settings.joint_grid()
        self._maps: OrderedDict[tuple[float, ...], Array] = OrderedDict()
        self._cache = int(cache)

    def times(self, target: Array) -> Array:
        """T on every grid cell for ``target``."""
        key = tuple(float(v) for v in target)
        if key in self._maps:
            self._maps.move_to_end(key)
            return self._maps[key]
        t = time_to_go(self.grid, np.asarray(target, dtype=np.float64), self.threshold)
        t = fill_unreached(t, self.grid.dt * self.inside_cost)
        self._maps[key] = t
        if len(self._maps) > self._cache:
            self._maps.popitem(last=False)
        return t

    def times_at(self, target: Array, q: Array) -> Array:
        """T (s) to ``target`` at each row of joint angles ``q`` (k, n), bilinear between cells."""
        t = self.times(target)
        lo, frac = [], []
        for j, axis in enumerate(self.grid.axes):
            x = np.clip((q[:, j] - axis[0]) / (axis[1] - axis[0]), 0.0, len(axis) - 1.0)
            i = np.minimum(np.floor(x).astype(np.int64), len(axis) - 2)
            lo.append(i)
            frac.append(x - i)
        value = np.zeros(q.shape[0])
        for corner in range(2**self.n):
            bits = [(corner >> j) & 1 for j in range(self.n)]
            w = np.prod([f if b else 1.0 - f for f, b in zip(frac, bits, strict=True)], axis=0)
            value += w * t[tuple(i + b for i, b in zip(lo, bits, strict=True))]
        return value


class TimeToGoExpert:
    """The greedy least-time action at an observation (see module doc); ``predict`` as SB3's,
    so that `armexp.agents.rollout.rollout` can run it."""

    def __init__(
        self,
        settings: ReachSettings,
        margin: float,
        lookahead: int = 5,
        cache: int = 64,
        approach: float | None = None,
        inside_cost: float = 10.0,
    ) -> None:
        """``approach`` defaults to twice the reach threshold; 0 turns the straight approach
        off. ``inside_cost``: free moves per grid move inside the margin."""
        self.approach = 2 * settings.reach_threshold if approach is None else approach
        self._step = np.asarray(settings.velocity_bound, dtype=np.float64) * settings.action_period
        grown = np.asarray(settings.obstacles, dtype=np.float64).reshape(-1, 3).copy()
        grown[:, 2] += settings.path_margin
        self._grown = grown
        self.map = TimeToGoMap(replace(settings, path_margin=margin), cache, inside_cost)
        n = self.map.n
        self.layout = ObservationLayout(n, int(np.asarray(settings.obstacles).size // 3))
        commands = np.array(list(itertools.product((-1.0, 0.0, 1.0), repeat=n)))
        self.commands = commands[np.argsort(np.abs(commands).sum(axis=1), kind="stable")]
        self._moves = self.commands * self._step * lookahead
        self._lengths = np.asarray(settings.plant.arm.lengths_array, dtype=np.float64)

    def __call__(self, obs: Array) -> np.ndarray:
        """Actions (k, n) for the observations ``obs`` (k, d); rows that share a target are
        looked up in its map together."""
        obs = np.atleast_2d(np.asarray(obs, dtype=np.float64))
        out = np.empty((obs.shape[0], self.map.n), dtype=np.float32)
        here, targets = self.layout.q(obs), self.layout.target(obs)
        near = np.linalg.norm(targets - tips(here, self._lengths), axis=1) < self.approach
        groups: dict[tuple[float, ...], list[int]] = {}
        for row in range(obs.shape[0]):
            straight = self._straight(here[row], targets[row]) if near[row] else None
            if straight is None:
                groups.setdefault(tuple(targets[row]), []).append(row)
            else:
                out[row] = straight
        for key, members in groups.items():
            target, chosen = np.asarray(key), np.asarray(members)
            q = (here[chosen, None, :] + self._moves[None]).reshape(-1, self.map.n)
            times = self.map.times_at(target, q).reshape(len(chosen), len(self._moves))
            best = np.argmin(times, axis=1)
            # To hold (commands[0], the only one of |c|₁ = 0) is right on the target, but T is
            # also flat or at a local minimum of the interpolation a millimetre outside the
            # reach threshold: the tip's distance to the target decides there.
            hold = best == 0
            if hold.any():
                moved = q.reshape(len(chosen), len(self._moves), -1)[hold]
                error = np.linalg.norm(tips(moved, self._lengths) - target, axis=-1)
                best[hold] = np.argmin(error, axis=1)
            out[chosen] = self.commands[best]
        return out

    def _straight(self, q: Array, target: Array) -> Array | None:
        """The command that moves the tip straight at ``target``, scaled so that its fastest
        joint runs at its bound (proportional within a step of the target), or None beyond
        ``approach`` or where the segment to the target enters an obstacle grown by the
        environment's path margin."""
        tip = tips(q, self._lengths)
        error = target - tip
        if not np.linalg.norm(error) < self.approach or segment_hits(tip, target, self._grown):
            return None
        # In command units, so that a redundant arm (three links) moves its faster joints more.
        per_command = tip_jacobian(q, self._lengths) * self._step
        gram = per_command @ per_command.T
        damping = 1e-3 * np.trace(gram) * np.eye(2)  # bounded near the stretched-arm singularity
        command = per_command.T @ np.linalg.solve(gram + damping, error)
        return command / max(1.0, float(np.abs(command).max()))

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


class DaggerExpert(TrainingAddOn):
    """DAgger: every state the training environments visit is cloned with the action of a
    `TimeToGoExpert` kept ``margin`` (m) from obstacles that compares commands held
    ``lookahead`` steps; up to the replay buffer's size of such steps are kept beside the
    demonstrations. Needs the cloning aid before it, so SAC only. Privileged: the planner
    labels."""

    declaration = aids.EXPERT
    needs = (BehaviourCloning,)

    def __init__(self, margin: float = 0.10, lookahead: int = 5) -> None:
        if not float(margin) > 0 or int(lookahead) < 1:
            raise ValueError(f"margin={margin} must be > 0 and lookahead={lookahead} at least 1")
        self.margin, self.lookahead = float(margin), int(lookahead)

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        cloning = ctx.shared.get("cloning")
        assert isinstance(cloning, DemonstrationCloning)  # `needs` put the cloning aid first
        cloning.reserve(int(cloning.model.buffer_size))
        return [ExpertLabels(TimeToGoExpert(ctx.settings, self.margin, self.lookahead), cloning)]
