"""The compiled body of one `ReachEnv.step`: 30 controller steps plus the task logic in one call.

Keeping the reward, termination and observation next to the closed loop in one numba function
means an environment step costs one dispatch instead of a dozen small numpy calls (52 → ~9 µs).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from armexp.envs.limit_guard import guarded_action
from armexp.sim.dynamics import tip_position
from armexp.sim.simulator import advance
from armexp.sim.work import work_offsets

# Status codes of `env_step`, in `armexp.envs.reach.REASONS` order (0 = still running).
RUNNING, REACHED, COLLISION, JOINT_LIMIT, DIVERGED = 0, 1, 2, 3, 4
# Layout of the float parameter vector.
P_THRESHOLD, P_REACH, P_BOUNDARY, P_COLLISION, P_GROWTH = 0, 1, 2, 3, 4


@njit(cache=True)
def segment_enters(x0: float, y0: float, x1: float, y1: float, obstacles: np.ndarray) -> bool:
    """Whether the segment (x0, y0)→(x1, y1) enters any circle (x, y, r) of ``obstacles``."""
    vx = x1 - x0
    vy = y1 - y0
    length2 = vx * vx + vy * vy
    for i in range(obstacles.shape[0]):
        cx = obstacles[i, 0] - x0
        cy = obstacles[i, 1] - y0
        s = 0.0
        if length2 > 0.0:
            s = min(max((cx * vx + cy * vy) / length2, 0.0), 1.0)
        dx = cx - s * vx
        dy = cy - s * vy
        if dx * dx + dy * dy < obstacles[i, 2] * obstacles[i, 2]:
            return True
    return False


@njit(cache=True)
def task_reward(
    prev_error: float, error: float, collided: bool, outside: bool, params: np.ndarray
) -> tuple[float, int]:
    """Table I's reward and the step's status, from the tip's target error before and after the
    step and whether its path entered an obstacle or a joint left its limits. The checks run in
    the order collision, joint limit, reach, so a step that collides while reaching is a
    collision."""
    if collided:
        return -params[P_COLLISION], COLLISION
    if outside:
        return -params[P_BOUNDARY], JOINT_LIMIT
    if error < params[P_THRESHOLD]:
        return params[P_REACH], REACHED
    reward = -math.log10(1.0 + error - params[P_THRESHOLD])
    if error > prev_error:
        reward -= params[P_GROWTH]
    return reward, RUNNING


@njit(cache=True)
def goal_rewards(
    prev_tips: np.ndarray, tips: np.ndarray, goals: np.ndarray, params: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """`task_reward` of steps that neither collided nor left the limits, for other targets: the
    tip at each step's start and end (k, 2) and a target each (k, 2); (rewards, reached)."""
    k = goals.shape[0]
    rewards = np.empty(k)
    reached = np.zeros(k, dtype=np.bool_)
    for i in range(k):
        gx, gy = goals[i, 0], goals[i, 1]
        before = math.hypot(prev_tips[i, 0] - gx, prev_tips[i, 1] - gy)
        after = math.hypot(tips[i, 0] - gx, tips[i, 1] - gy)
        rewards[i], status = task_reward(before, after, False, False, params)
        reached[i] = status == REACHED
    return rewards, reached


@njit(cache=True)
def observe(
    q: np.ndarray,
    tip: np.ndarray,
    target: np.ndarray,
    obstacles: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    out: np.ndarray,
) -> None:
    """Eq. 5a into ``out``: target, tip − target, tip, q, tip-to-surface distance per obstacle;
    non-finite entries become 0 and everything is clipped to the observation box."""
    n = q.shape[0]
    out[0] = target[0]
    out[1] = target[1]
    out[2] = tip[0] - target[0]
    out[3] = tip[1] - target[1]
    out[4] = tip[0]
    out[5] = tip[1]
    for j in range(n):
        out[6 + j] = q[j]
    for i in range(obstacles.shape[0]):
        dx = tip[0] - obstacles[i, 0]
        dy = tip[1] - obstacles[i, 1]
        out[6 + n + i] = math.sqrt(dx * dx + dy * dy) - obstacles[i, 2]
    for i in range(out.shape[0]):
        v = out[i]
        if not math.isfinite(v):
            v = 0.0
        out[i] = min(max(v, low[i]), high[i])


@njit(cache=True)
def env_step(
    state: np.ndarray,
    work: np.ndarray,
    model: tuple,
    gains: np.ndarray,
    kind: int,
    dt: float,
    key: np.uint64,
    k0: int,
    ramp: bool,
    hold: int,
    action: np.ndarray,
    guard: float,
    bound: np.ndarray,
    lower: np.ndarray,
    upper: np.ndarray,
    obstacles: np.ndarray,
    target: np.ndarray,
    tip: np.ndarray,
    params: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    obs: np.ndarray,
    log: np.ndarray,
) -> tuple[float, int, int, float, bool]:
    """One environment step. Updates ``tip`` (x, y) in place and fills ``obs``.

    The arguments up to ``ramp`` are the closed loop's
    (`armexp.sim.simulator.Simulator.kernel_args`); ``hold`` controller steps run towards the
    clipped ``action`` scaled by ``bound``, first cut by the joint-limit guard at the margin
    ``guard`` (rad; negative: no guard; `armexp.envs.limit_guard`).

    Returns (reward, status, controller steps completed, tip error, whether the guard cut the
    action); `task_reward` gives the reward and status of a step that did not diverge.
    """
    n = state.shape[0] // 4
    dqd = np.empty(n)
    for j in range(n):
        dqd[j] = min(max(float(action[j]), -1.0), 1.0)
    cut = False
    if guard >= 0.0:
        ref = work_offsets(n, int(work[1]))[1]  # the last command, where the ramp starts
        allowed = guarded_action(
            dqd, state[2 * n : 3 * n], work[ref : ref + n], bound, lower, upper, guard,
            hold * dt, ramp,
        )  # fmt: skip
        for j in range(n):
            cut = cut or abs(allowed[j] - dqd[j]) > 1e-12
            dqd[j] = allowed[j]
    for j in range(n):
        dqd[j] *= bound[j]
    prev_error = math.hypot(tip[0] - target[0], tip[1] - target[1])
    done = advance(state, dqd, k0, hold, kind, gains, model, dt, key, work, log, ramp)
    q = state[:n]
    status = RUNNING
    reward = 0.0
    diverged = done < hold
    if diverged:
        status = DIVERGED
        reward = -params[P_BOUNDARY]
        error = prev_error
    else:
        x0 = tip[0]
        y0 = tip[1]
        tip[0], tip[1] = tip_position(q, model[2])
        error = math.hypot(tip[0] - target[0], tip[1] - target[1])
        outside = False
        for j in range(n):
            if q[j] < lower[j] or q[j] > upper[j]:
                outside = True
        collided = segment_enters(x0, y0, tip[0], tip[1], obstacles)
        reward, status = task_reward(prev_error, error, collided, outside, params)
    observe(q, tip, target, obstacles, low, high, obs)
    return reward, status, done, error, cut
