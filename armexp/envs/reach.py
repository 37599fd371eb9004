"""``armexp/Reach-v0``: velocity-planned reaching around tip obstacles, with the controller inside.

The environment is the closed loop of the paper's §V: the agent's action is a bounded joint
velocity reference (eq. 7a); the tuned low-level controller (Algorithm 3, or the PID baseline)
tracks it at 1 kHz on the uncertain plant (eqs. 2, 40) for one action period (30 ms, 33.33 Hz), in
one compiled call (`armexp.envs.kernel.env_step`, which runs `armexp.sim.simulator.advance`).
"""

from __future__ import annotations

import collections
import itertools
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from armexp.envs.geometry import Array, joint_positions, tips
from armexp.envs.kernel import env_step, goal_rewards, observe
from armexp.envs.observation import ObservationLayout
from armexp.envs.render import Canvas
from armexp.envs.workspace import (
    JointGrid,
    Workspace,
    build_workspace,
    joint_grid,
    shortest_path,
)
from armexp.sim.model import Plant
from armexp.sim.simulator import Simulator
from armexp.sim.trajectory import log_width, trajectory_columns

#: Why an episode ended (``info["reason"]``), in `armexp.envs.kernel` status order; "" while it
#: runs.
REASONS = ("reached", "collision", "joint_limit", "diverged", "time_limit")


@dataclass(frozen=True)
class ReachSettings:
    """Everything that defines one reaching environment (Table I plus the arm and controller).

    Built from a composed config by `armexp.envs.factory.settings_from_config`; the defaults
    of the numbers are Table I's.
    """

    plant: Plant
    controller: str
    gains: Array
    q0: Array
    joint_lower: Array
    joint_upper: Array
    velocity_bound: Array
    obstacles: Array = field(default_factory=lambda: np.zeros((0, 3)))
    tasks: dict[str, tuple[float, float]] = field(default_factory=dict)
    action_period: float = 0.03
    max_steps: int = 1000
    reach_threshold: float = 0.04
    reach_reward: float = 200.0
    boundary_penalty: float = 50.0
    collision_penalty: float = 100.0
    growth_penalty: float = 1.0
    path_margin: float = 0.02
    target_margin: float = 0.05
    min_target_distance: float = 0.2
    max_target_time: float = 12.0
    workspace_cells: int = 40_000
    #: The reference generator between actions (`armexp.sim.step.REFERENCES`).
    reference: str = "ramp"
    #: Actions are cut to keep q_d this far (rad) inside the joint limits
    #: (`armexp.envs.limit_guard`, the agent's ``limit_guard`` aid); None: they are not.
    limit_guard: float | None = None

    @property
    def hold_steps(self) -> int:
        steps = self.action_period / self.plant.dt
        if abs(steps - round(steps)) > 1e-9 or round(steps) < 1:
            raise ValueError(
                f"env.action_period={self.action_period} is not allowed: it must be a whole "
                f"number of controller periods ({self.plant.dt} s)."
            )
        return round(steps)

    def workspace(self, max_time: float | None = None) -> Workspace:
        return build_workspace(
            self.plant.arm.lengths_array,
            self.joint_lower,
            self.joint_upper,
            self.q0,
            self.velocity_bound,
            self.obstacles,
            path_margin=self.path_margin,
            target_margin=self.target_margin,
            min_distance=self.min_target_distance,
            max_time=self.max_target_time if max_time is None else max_time,
            cells=self.workspace_cells,
        )

    def joint_grid(self) -> JointGrid:
        """`armexp.envs.workspace.joint_grid` of `workspace`'s search (path margin included)."""
        return joint_grid(
            self.plant.arm.lengths_array, self.joint_lower, self.joint_upper,
            self.velocity_bound, self.obstacles, self.path_margin, self.workspace_cells,
        )  # fmt: skip

    def shortest_path(self, config: Array, path_margin: float | None = None) -> tuple[Array, float]:
        """`armexp.envs.workspace.shortest_path` from ``q0`` to the grid cell ``config`` on the
        grid of `workspace`, keeping the tip ``path_margin`` (default: the environment's) from
        every obstacle."""
        margin = self.path_margin if path_margin is None else path_margin
        return shortest_path(
            self.plant.arm.lengths_array, self.joint_lower, self.joint_upper, self.q0,
            self.velocity_bound, self.obstacles, config, path_margin=margin,
            max_time=self.max_target_time, cells=self.workspace_cells,
        )  # fmt: skip


def reward_params(s: ReachSettings) -> np.ndarray:
    """Table I's reward terms in `armexp.envs.kernel`'s parameter order (``P_*``)."""
    return np.array(
        [s.reach_threshold, s.reach_reward, s.boundary_penalty, s.collision_penalty,
         s.growth_penalty]
    )  # fmt: skip


class ReachEnv(gym.Env[np.ndarray, np.ndarray]):
    """Reach a target with the arm's tip while the tip avoids circular obstacles.

    ## Action Space
    ``Box(-1, 1, (n,), float32)``: the joint velocity reference q̇_d (eq. 7a) as a fraction of
    the velocity bounds of Table II (q̇1 ∈ [−0.1, 0.1], q̇2 ∈ [−0.4, 0.4] rad/s for the paper
    arm). Across the action period (30 ms) the reference q̇_d ramps linearly from the previous
    action to this one (``reference="hold"``: it jumps to it), while the controller tracks
    q_d = ∫q̇_d at 1 kHz. With ``settings.limit_guard`` (the agent's ``limit_guard`` aid) an action
    that would carry q_d closer than that margin to a joint limit is cut first
    (`armexp.envs.limit_guard`).

    ## Observation Space
    ``Box((6 + n + m,), float32)`` as eq. 5a (eq. 4a when m = 0):
    target position (x, y), tip − target (x, y), tip position (x, y), joint angles q (n), and
    the distance from the tip to the surface of each of the m obstacles (negative inside);
    ``env.layout`` (`armexp.envs.observation.ObservationLayout`) says where each part sits.

    ## Rewards (Table I)
    * ``+reach_reward`` (200) when the tip error falls below ``reach_threshold`` (0.04 m);
    * ``−collision_penalty`` (100) when the tip's path enters an obstacle;
    * ``−boundary_penalty`` (50) when a joint leaves its limits (or the simulation diverges);
    * otherwise ``−log10(1 + error − threshold)``, and ``growth_penalty`` (1) less when the
      error grew during the step.
    A step that both collides and leaves the limits counts as a collision.

    ## Starting State
    The same every episode: the arm at rest at ``q0`` (upper arm horizontal, forearm up). The
    target is drawn uniformly from the precomputed collision-free reachable workspace
    (`armexp.envs.workspace`), or fixed with ``reset(options={"target": (x, y)})`` or
    ``reset(options={"task": "a"})`` for the tasks of ``tasks=paper_four``. Training may start
    a share of the drawn-target episodes at another workspace configuration (`set_start_share`).
    ``reset(options={"reference_offset": [δ1, …, δn]})`` starts the reference at q_d(0) = q0 + δ
    instead of q0 (a defined perturbation for measuring convergence, docs/design.md §8).

    ## Episode End
    Terminated on reach, collision, joint limit or divergence; truncated after ``max_steps``
    (1000) actions. ``info["reason"]`` says which; ``info["is_success"]`` is True on reach.

    ## Arguments
    ``gymnasium.make("armexp/Reach-v0", overrides=["obstacles=none", "robot=three_link"])``
    composes the packaged config with Hydra overrides (`armexp.envs.factory.make_reach`);
    ``ReachEnv(settings)`` takes a `ReachSettings` directly. ``record=True`` keeps every 1 kHz
    row of the episode for `trajectory` (evaluation), ``render_mode="rgb_array"`` draws the arm,
    obstacles and target.
    """

    metadata = {"render_modes": ["rgb_array"], "render_fps": 33}  # noqa: RUF012

    def __init__(
        self, settings: ReachSettings, render_mode: str | None = None, record: bool = False
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode={render_mode!r} is not allowed; choose one of "
                f"{self.metadata['render_modes']} or None."
            )
        self.settings = s = settings
        self.render_mode = render_mode
        self.record = record
        self.n = n = s.plant.arm.n
        self.m = m = s.obstacles.shape[0]
        self._lengths = s.plant.arm.lengths_array
        self._hold = s.hold_steps
        self._bound = np.asarray(s.velocity_bound, dtype=np.float64)
        self._lower = np.asarray(s.joint_lower, dtype=np.float64)
        self._upper = np.asarray(s.joint_upper, dtype=np.float64)
        # The joint-limit guard's margin for the compiled step; negative: none.
        self._guard = -1.0 if s.limit_guard is None else float(s.limit_guard)
        self._obstacles = np.asarray(s.obstacles, dtype=np.float64).reshape(-1, 3)
        self.workspace = s.workspace()
        self.sim = Simulator(s.plant, s.controller, s.gains, q0=s.q0, reference=s.reference)

        self.layout = ObservationLayout(n, m)
        low, high = self.layout.bounds(self._lengths, self._lower, self._upper, self._obstacles)
        self.observation_space = spaces.Box(low.astype(np.float32), high.astype(np.float32))
        self._obs_low, self._obs_high = low, high
        self._params = reward_params(s)
        self._log_width = log_width(n)
        columns = trajectory_columns(n)
        self._tip_columns = [columns.index("tip_x"), columns.index("tip_y")]
        self._no_log = np.zeros((0, self._log_width))
        self.action_space = spaces.Box(-1.0, 1.0, (n,), dtype=np.float32)

        self.target = self.workspace.points[0].copy()
        #: Targets are drawn from these workspace points only (`set_target_reach`; None: all).
        self._near: np.ndarray | None = None
        #: Recently missed training targets, re-drawn at the share `_retry_share` of resets
        #: (`set_target_retry`; None: off). `_index`: the workspace point of this episode's
        #: target (None when a task or an explicit target set it). `retried`: the episodes whose
        #: target was such a re-draw.
        self._missed: collections.deque[int] | None = None
        self._retry_share = 0.0
        self._index: int | None = None
        self.retried = 0
        #: Training episodes start at a drawn workspace configuration at this share of the resets
        #: that draw their target (`set_start_share`); `moved_starts` counts them.
        self._start_share = 0.0
        self.moved_starts = 0
        #: Steps whose action the joint-limit guard cut (`ReachSettings.limit_guard`).
        self.guarded = 0
        self.tip = np.zeros(2)
        self.error = 0.0
        self.steps = 0
        self.reason = ""
        self._rows: list[Array] = []
        self._canvas: Canvas | None = None

    # ----------------------------------------------------------------------------- gym API
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        options = options or {}
        if "task" in options:
            name = str(options["task"])
            if name not in self.settings.tasks:
                raise ValueError(
                    f"task={name!r} is not allowed; this environment's tasks are "
                    f"{sorted(self.settings.tasks) or 'none (tasks.targets is empty)'}."
                )
            self.target = np.asarray(self.settings.tasks[name], dtype=np.float64)
            self._index = None
        elif options.get("target") is not None:
            self.target = np.asarray(options["target"], dtype=np.float64).reshape(2)
            self._index = None
        else:
            self._index = self._draw_index()
            self.target = self.workspace.points[self._index].copy()
        # The τ_d draws of the episode follow the env's seeded generator.
        q0 = self.settings.q0
        if self._index is not None and self._start_share > 0.0:
            q0 = self._draw_start(q0)
        offset = options.get("reference_offset")
        qd0 = None if offset is None else q0 + np.broadcast_to(np.asarray(offset, float), q0.shape)
        self.sim.reset(q0, seed=int(self.np_random.integers(2**31)), qd0=qd0)
        self.steps = 0
        self.reason = ""
        self.tip = np.array(self.sim.tip())
        self.error = float(np.hypot(*(self.tip - self.target)))
        self._rows = []
        return self._observation(), self._info()

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        sim = self.sim
        if sim.diverged:  # stepping on after a divergence changes nothing
            self.steps += 1
            return self._observation(), -self.settings.boundary_penalty, True, False, self._info()
        log = np.zeros((self._hold, self._log_width)) if self.record else self._no_log
        obs = np.empty(self._obs_low.shape[0], dtype=np.float32)
        reward, status, done, self.error, cut = env_step(
            *sim.kernel_args(), self._hold, np.asarray(action, dtype=np.float64), self._guard,
            self._bound, self._lower, self._upper, self._obstacles, self.target, self.tip,
            self._params, self._obs_low, self._obs_high, obs, log,
        )  # fmt: skip
        self.guarded += cut
        sim.record_steps(done, self._hold)
        if self.record:
            self._rows.append(log[: done + 1] if done < self._hold else log)
        self.steps += 1
        self.reason = REASONS[status - 1] if status else ""
        terminated = status != 0
        truncated = not terminated and self.steps >= self.settings.max_steps
        if truncated:
            self.reason = "time_limit"
        return obs, float(reward), terminated, truncated, self._info()

    def goal_rewards(
        self, prev_tips: np.ndarray, tips: np.ndarray, goals: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """The rewards `step` gives, and whether it would end on reach, for steps that took the
        tip from ``prev_tips`` to ``tips`` (k, 2) without a collision or a joint limit, had the
        targets been ``goals`` (k, 2): goal relabelling (`armexp.agents.relabel`) with the
        environment's own reward (`armexp.envs.kernel.task_reward`)."""
        return goal_rewards(
            np.asarray(prev_tips, np.float64), np.asarray(tips, np.float64),
            np.asarray(goals, np.float64), self._params,
        )  # fmt: skip

    def _draw_index(self) -> int:
        """The workspace point of a training target: a recently missed one at the share asked
        (`set_target_retry`), else one within the reach (`set_target_reach`) or anywhere."""
        rng = self.np_random
        missed = self._missed
        if missed is not None:
            if self._index is not None and self.steps > 0:  # the episode that just ended
                if self.reason == "reached":
                    if self._index in missed:
                        missed.remove(self._index)
                elif self._index not in missed:
                    missed.append(self._index)
            if missed and rng.random() < self._retry_share:
                self.retried += 1
                return int(missed[int(rng.integers(len(missed)))])
        if self._near is None:
            return self.workspace.sample_index(rng)
        return int(self._near[int(rng.integers(len(self._near)))])

    def set_target_retry(self, share: float, memory: int) -> None:
        """From the next reset on, remember the last ``memory`` training targets whose episode
        ended without reaching them, forget one once reached, and draw the next target among them
        at the share ``share`` of resets (`armexp.agents.curriculum.MissedTargets`): a curriculum
        over the policy's own outcomes, no obstacle knowledge. ``share`` 0 turns it off."""
        self._retry_share = float(share)
        self._missed = collections.deque(maxlen=int(memory)) if share > 0 else None

    def set_start_share(self, share: float) -> None:
        """From the next reset on, start the share ``share`` of the episodes whose target is drawn
        at rest at the configuration of another workspace point, drawn uniformly
        (`armexp.agents.curriculum.RandomStarts`); the others, and every episode given a task
        or a target, start at ``q0``. ``share`` 0 turns it off."""
        self._start_share = float(share)

    def _draw_start(self, q0: Array) -> Array:
        """A drawn workspace configuration at the share asked, else ``q0``; a draw whose tip
        lies within twice the reach threshold of the target is drawn again (``q0`` after ten),
        so that no episode starts reached."""
        rng, ws = self.np_random, self.workspace
        if rng.random() >= self._start_share:
            return q0
        for _ in range(10):
            i = ws.sample_index(rng)
            if np.hypot(*(ws.points[i] - self.target)) > 2 * self.settings.reach_threshold:
                self.moved_starts += 1
                return np.asarray(ws.configs[i], dtype=np.float64)
        return q0

    def start_distances(self) -> np.ndarray:
        """Each workspace target's distance from the tip at the starting configuration (m)."""
        start = np.asarray(tips(np.asarray(self.settings.q0, float), self._lengths))
        return np.asarray(np.linalg.norm(self.workspace.points - start, axis=1))

    def set_target_reach(self, reach: float | None) -> None:
        """From the next reset on, draw targets within ``reach`` metres of the starting tip only
        (the nearest target when none is that close); None: the whole workspace again. A
        curriculum over target distance (`armexp.agents.curriculum`) widens it over training:
        a Euclidean distance, no obstacle knowledge."""
        if reach is None:
            self._near = None
            return
        d = self.start_distances()
        near = np.flatnonzero(d <= float(reach))
        self._near = near if near.size else np.array([int(np.argmin(d))])

    def render(self) -> np.ndarray | None:
        if self.render_mode != "rgb_array":
            return None
        if self._canvas is None:
            self._canvas = Canvas(extent=float(self._lengths.sum()) + 0.15)
        c = self._canvas
        c.clear()
        for x, y, r in self._obstacles:
            c.disc((x, y), r, (220, 80, 70))
        c.ring(tuple(self.target), self.settings.reach_threshold, (40, 170, 60))
        c.disc(tuple(self.target), 0.015, (40, 170, 60))
        pts = joint_positions(self.sim.q.copy(), self._lengths)
        for p0, p1 in itertools.pairwise(pts):
            c.segment(tuple(p0), tuple(p1), 0.025, (50, 60, 80))
        for p in pts[:-1]:
            c.disc(tuple(p), 0.035, (120, 130, 150))
        c.disc(tuple(pts[-1]), 0.02, (30, 110, 200))
        return c.image()

    # ------------------------------------------------------------------------------ helpers
    def _observation(self) -> np.ndarray:
        obs = np.empty(self._obs_low.shape[0], dtype=np.float32)
        observe(
            self.sim.q, self.tip, self.target, self._obstacles, self._obs_low, self._obs_high, obs
        )
        return obs

    def _info(self) -> dict[str, Any]:
        return {
            "tip_error": self.error,
            "reason": self.reason,
            "is_success": self.reason == "reached",
            "collision": self.reason == "collision",
            "target": self.target.copy(),
            "steps": self.steps,
        }

    def trajectory(self) -> Array:
        """The episode's 1 kHz rows (`armexp.sim.trajectory.trajectory_columns` plus the tip's
        target error in m); needs ``record=True``."""
        if not self.record:
            raise RuntimeError("trajectory() needs ReachEnv(record=True).")
        if not self._rows:
            return np.zeros((0, self._log_width + 1))
        rows = np.concatenate(self._rows)
        tip = rows[:, self._tip_columns]
        err = np.hypot(tip[:, 0] - self.target[0], tip[:, 1] - self.target[1])
        return np.column_stack([rows, err])
