"""The best return Table I's reward allows from the start posture of the 2-link paper arm, and
whether the policy that earns it reaches the target: value iteration over the joint grid that one
30 ms action at the velocity bounds moves across.

    python scripts/reach_values.py --target -0.02 -0.60 --gamma 0.995
    python scripts/reach_values.py --eval-run <id> --below -2.0     # every such held-out target
    python scripts/reach_values.py --target -0.02 -0.60 --guard     # with the joint-limit guard
    python scripts/reach_values.py --target -0.02 -0.60 --guard --obstacles  # and the obstacles

The model is kinematic (the joints follow the commanded velocities at once). Without obstacles
it is an upper bound for reaching: where its optimal policy does not reach a target, no policy
of the real environment that maximises Table I's return at that γ reaches it. With
``--obstacles`` a move whose tip path enters one of the default environment's obstacles ends the
episode with the collision penalty (−100), as the environment's step does; the grid's moves are
the velocity bounds' only, so it then shows which ending the return prefers, not a bound.
Per step, the environment's own reward (`armexp.envs.kernel.goal_rewards`): −log10(1 + e − 0.04)
at the tip error e after it, −1 more if e grew; +200 on reaching (e < 0.04 m), and −50 on leaving
a joint limit, both terminal; no time limit (docs/plain_agent.md,
"Which postures the misses need").
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from numba import njit

from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.geometry import tips
from armexp.envs.kernel import goal_rewards, segment_enters
from armexp.envs.reach import ReachSettings, reward_params

MOVES = [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)]


class JointGrid:
    """The joint angles one action at the velocity bounds apart, within the limits, the tip at
    each, and the reward's terms, all from ``settings`` (the default environment's)."""

    def __init__(self, settings: ReachSettings | None = None) -> None:
        s = settings_from_config(compose_config([])) if settings is None else settings
        self.settings = s
        lower, step = s.joint_lower, s.velocity_bound * s.action_period
        n = ((s.joint_upper - lower) / step).astype(int) + 1
        axes = [lower[k] + step[k] * np.arange(n[k]) for k in range(2)]
        q = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1)
        self.x, self.y = np.moveaxis(tips(q, s.plant.arm.lengths_array), -1, 0)
        i, j = np.rint((s.q0 - lower) / step).astype(int)
        self.start = (int(i), int(j))


def _shifted(n: int, d: int) -> tuple[slice, slice]:
    """Source and destination slices of a move by ``d`` cells along an axis of ``n``."""
    return slice(max(0, -d), n - max(0, d)), slice(max(0, d), n - max(0, -d))


@njit
def _enters(before: np.ndarray, after: np.ndarray, obstacles: np.ndarray) -> np.ndarray:
    """Whether each tip segment before→after (k, 2) enters any circle (x, y, r): the
    environment's own test, `armexp.envs.kernel.segment_enters`, over arrays."""
    hit = np.zeros(before.shape[0], dtype=np.bool_)
    for i in range(before.shape[0]):
        hit[i] = segment_enters(before[i, 0], before[i, 1], after[i, 0], after[i, 1], obstacles)
    return hit


def optimal(grid: JointGrid, target: tuple[float, float], gamma: float, tol: float = 1e-2,
            guard: bool = False, obstacles: bool = False) -> tuple[float, str, int]:  # fmt: skip
    """V*(start), how the greedy policy's episode ends (``reached``, ``joint_limit``,
    ``collision`` or ``stays``, holding still for ever) and after how many steps. ``guard``: a
    move past a limit is not made (the joint-limit guard, `armexp.envs.limit_guard`; the joint
    stops at the limit, which is the move without that joint) instead of ending the episode.
    ``obstacles``: a move whose tip path enters an obstacle ends the episode with −100."""
    s = grid.settings
    error = np.hypot(grid.x - target[0], grid.y - target[1])
    reach = error < s.reach_threshold
    value = np.zeros_like(error)
    n1, n2 = error.shape
    tip = np.stack([grid.x, grid.y], axis=-1)
    params = reward_params(s)
    # Each move's reward from every cell, the environment's own function (`goal_rewards`: the
    # reach reward where the cell moved to reaches), once: it does not change with the values.
    moves = []
    for a, b in MOVES:
        (s1, d1), (s2, d2) = _shifted(n1, a), _shifted(n2, b)
        before, after = tip[s1, s2].reshape(-1, 2), tip[d1, d2].reshape(-1, 2)
        goals = np.broadcast_to(np.asarray(target, dtype=float), before.shape).copy()
        rewards, reached = goal_rewards(before, after, goals, params)
        shape = error[s1, s2].shape
        hits = _enters(before, after, s.obstacles) if obstacles else np.zeros(len(before), bool)
        moves.append((s1, s2, d1, d2, rewards.reshape(shape), reached.reshape(shape),
                      hits.reshape(shape)))  # fmt: skip
    while True:
        best = np.full_like(error, -np.inf)
        choice = np.zeros(error.shape, dtype=np.int8)
        for k, (s1, s2, d1, d2, reward, reached, hits) in enumerate(moves):
            # Off the grid: a limit left, or under the guard a move it does not let through.
            q = np.full_like(error, -np.inf if guard else -s.boundary_penalty)
            q[s1, s2] = np.where(reached, reward, reward + gamma * value[d1, d2])
            q[s1, s2] = np.where(hits, -s.collision_penalty, q[s1, s2])
            better = q > best
            best, choice = np.where(better, q, best), np.where(better, k, choice)
        best[reach] = 0.0
        change = float(np.max(np.abs(best - value)))
        value = best
        if change < tol:
            break
    i, j = grid.start
    for steps in range(1, 5000):
        a, b = MOVES[choice[i, j]]
        if (a, b) == (0, 0):
            return float(value[grid.start]), "stays", steps
        if not (0 <= i + a < n1 and 0 <= j + b < n2):
            return float(value[grid.start]), "joint_limit", steps
        s1, s2, _, _, _, _, hits = moves[choice[i, j]]
        if hits[i - s1.start, j - s2.start]:
            return float(value[grid.start]), "collision", steps
        i, j = i + a, j + b
        if reach[i, j]:
            return float(value[grid.start]), "reached", steps
    return float(value[grid.start]), "stays", 5000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--target", nargs=2, type=float, action="append", default=[])
    parser.add_argument("--eval-run", help="every random target of this eval run (--below)")
    parser.add_argument(
        "--below", type=float, default=-2.0,
        help="with --eval-run: targets whose posture needs q2 below this (rad)",
    )  # fmt: skip
    parser.add_argument("--store", default="sqlite:///runs/mlflow.db")
    parser.add_argument("--gamma", type=float, default=0.995)
    parser.add_argument(
        "--guard", action="store_true", help="the joint-limit guard: no episode ends at a limit"
    )
    parser.add_argument(
        "--obstacles", action="store_true", help="the default obstacles: a collision ends with -100"
    )
    args = parser.parse_args()
    targets = [tuple(t) for t in args.target]
    if args.eval_run:
        import mlflow
        from mlflow.tracking import MlflowClient

        sys.path.insert(0, str(Path(__file__).parent))
        from misses_by_posture import elbow_needed, episodes, full_id

        mlflow.set_tracking_uri(args.store)
        frame = episodes(MlflowClient(), full_id(args.eval_run))
        for x, y in zip(frame.target_x, frame.target_y, strict=True):
            start_side, q2 = elbow_needed(x, y)
            if not start_side and q2 < args.below:
                targets.append((x, y))
    grid = JointGrid()
    print("x, y, V*(start), greedy episode, steps")
    for x, y in targets:
        value, end, steps = optimal(
            grid, (x, y), args.gamma, guard=args.guard, obstacles=args.obstacles
        )
        print(f"{x:+.3f}, {y:+.3f}, {value:.1f}, {end}, {steps}", flush=True)


if __name__ == "__main__":
    main()
