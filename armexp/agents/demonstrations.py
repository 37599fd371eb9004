"""Planner demonstrations in SAC's replay buffer (the ``demonstrations`` aid).

The environment's workspace search (`armexp.envs.workspace`) already knows a least-time,
obstacle-clear joint path to every target it hands out. Turned into the velocity references the
agent would command and run through the real environment (controller, plant, Table I rewards),
a few hundred such episodes show SAC the detours its own exploration finds slowly: targets below
the shoulder and close to the base are reached only by swinging the forearm down before
lowering the upper arm, while every locally greedy motion ends on a joint limit or an obstacle.
This is learning from demonstrations as in DDPGfD (Večerík et al., 2017): the demonstrations are
ordinary transitions in the replay buffer, and the policy is SAC's own.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from armexp import aids
from armexp.agents.addons import TrainingAddOn, TrainingContext
from armexp.envs.reach import ReachEnv
from armexp.sim.model import Array

#: Actions appended after the planned path, holding still while the tip settles.
SETTLE_STEPS = 30


@dataclass
class Demonstration:
    """One planned episode: stacked transitions as SB3's replay buffer takes them."""

    obs: Array
    next_obs: Array
    actions: Array
    rewards: Array
    terminated: Array
    reason: str

    def __len__(self) -> int:
        return int(self.rewards.shape[0])


def planned_actions(env: ReachEnv, config: Array) -> np.ndarray:
    """Normalised velocity references (K, n) that move q_d from ``q0`` along the least-time grid
    path to ``config`` (keeping the tip the environment's path margin from every obstacle) and
    then hold, never beyond the velocity bounds."""
    s = env.settings
    cells, cell_time = s.shortest_path(config)
    cells[0] = s.q0  # the grid's start cell is q0 rounded to the grid
    period = s.action_period
    bound = np.asarray(s.velocity_bound, dtype=np.float64)
    times = np.arange(len(cells)) * cell_time
    steps = int(np.ceil(times[-1] / period)) + SETTLE_STEPS
    qd = np.asarray(s.q0, dtype=np.float64).copy()
    t = np.minimum((np.arange(steps) + 1) * period, times[-1])
    goals = np.stack([np.interp(t, times, cells[:, j]) for j in range(len(qd))], axis=1)
    out = np.empty((steps, len(qd)), dtype=np.float32)
    for k in range(steps):
        command = np.clip((goals[k] - qd) / (period * bound), -1.0, 1.0)
        qd += command * bound * period
        out[k] = command
    return out


def demonstrate(env: ReachEnv, index: int, seed: int) -> Demonstration:
    """The planned episode to workspace target ``index`` (`planned_actions`); it ends as the
    environment says (or is cut, unended, when the planned actions run out)."""
    actions = planned_actions(env, env.workspace.configs[index])
    obs, _ = env.reset(seed=seed, options={"target": env.workspace.points[index]})
    rows: list[tuple[Array, Array, Array, float, bool]] = []
    info: dict = {"reason": ""}
    for action in actions:
        nxt, reward, terminated, truncated, info = env.step(action)
        rows.append((obs, nxt, action, float(reward), bool(terminated)))
        obs = nxt
        if terminated or truncated:
            break
    o, no, a, r, d = zip(*rows, strict=True)
    return Demonstration(
        np.array(o), np.array(no), np.array(a), np.array(r), np.array(d), info["reason"]
    )


def demonstrations(env: ReachEnv, episodes: int, seed: int) -> list[Demonstration]:
    """``episodes`` planned episodes to random workspace targets (the same ones for a seed)."""
    rng = np.random.default_rng(seed)
    return [
        demonstrate(env, int(rng.integers(len(env.workspace))), seed + i) for i in range(episodes)
    ]


def fill_replay(model: OffPolicyAlgorithm, demos: list[Demonstration]) -> None:
    """Put ``demos`` into ``model``'s replay buffer, one episode after another in each of its
    environment columns.

    The columns are filled to a common length; an episode cut there is stored as a time-limit
    end (SB3 bootstraps through it) and its remainder is dropped.
    """
    columns: list[list[Demonstration]] = [[] for _ in range(model.n_envs)]
    for demo in sorted(demos, key=len, reverse=True):
        min(columns, key=lambda c: sum(map(len, c))).append(demo)
    length = min(sum(map(len, c)) for c in columns)
    if length == 0:
        return

    def stack(field: str) -> Array:
        return np.stack(
            [np.concatenate([getattr(d, field) for d in c])[:length] for c in columns], axis=1
        )

    obs, next_obs, actions, rewards = (stack(f) for f in ("obs", "next_obs", "actions", "rewards"))
    terminated = stack("terminated")
    ends = np.zeros_like(terminated)
    for j, column in enumerate(columns):
        lengths = np.cumsum([len(d) for d in column])
        ends[lengths[lengths <= length] - 1, j] = True
    ends[-1] = True
    buffer = model.replay_buffer
    assert buffer is not None
    for t in range(length):
        # An end that the environment did not terminate is a cut: bootstrapped, like a time limit.
        infos = [
            {"TimeLimit.truncated": bool(ends[t, j] and not terminated[t, j])}
            for j in range(model.n_envs)
        ]
        buffer.add(obs[t], next_obs[t], actions[t], rewards[t], ends[t], infos)


def planned(ctx: TrainingContext) -> list[Demonstration]:
    """The run's planner demonstrations (``ctx.demo_episodes`` of them), planned on first use
    (their time counts in the budget), logged as ``demonstrations/*`` and kept in the context."""
    if "demonstrations" not in ctx.shared:
        import mlflow

        made = demonstrations(ReachEnv(ctx.settings), ctx.demo_episodes, ctx.seed)
        reached = sum(d.reason == "reached" for d in made) / len(made)
        mlflow.log_metrics(
            {"demonstrations/episodes": len(made), "demonstrations/success_rate": reached,
             "demonstrations/steps": sum(map(len, made)), "demonstrations/wall_s": ctx.wall()}
        )  # fmt: skip
        ctx.shared["demonstrations"] = made
    demos: list[Demonstration] = ctx.shared["demonstrations"]
    return demos


class PlannerDemonstrations(TrainingAddOn):
    """``episodes`` planner episodes in the replay buffer before training (module doc); a
    resumed run gets none (its buffer is the interrupted run's, or empty). Privileged: the
    planner knows the obstacles. Off-policy algorithms only: PPO has no replay buffer."""

    declaration = aids.DEMONSTRATIONS

    def __init__(self, episodes: int) -> None:
        if int(episodes) < 1:
            raise ValueError(f"episodes={episodes} must be at least 1")
        self.episodes = int(episodes)

    def setup(self, ctx: TrainingContext) -> list[BaseCallback]:
        ctx.demo_episodes = self.episodes
        if not ctx.resumed:
            assert isinstance(ctx.model, OffPolicyAlgorithm)  # its declaration says so
            fill_replay(ctx.model, planned(ctx))
        return []
