"""Config → `ReachSettings`, and the ``gymnasium.make("armexp/Reach-v0", …)`` entry point."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from omegaconf import DictConfig, OmegaConf

from armexp.aids import limit_guard_margin
from armexp.builders import build_plant, controller_gains
from armexp.envs.reach import ReachEnv, ReachSettings
from armexp.sim.controllers import KINDS, gain_vector
from armexp.sim.model import Array


def obstacle_array(cfg: DictConfig) -> Array:
    return np.array([[c.x, c.y, c.r] for c in cfg.obstacles.circles], dtype=np.float64).reshape(
        -1, 3
    )


def task_targets(cfg: DictConfig) -> dict[str, tuple[float, float]]:
    return {str(t.name): (float(t.x), float(t.y)) for t in cfg.tasks.targets}


def settings_from_config(
    cfg: DictConfig,
    controller: str | None = None,
    gains: Array | dict[str, Any] | None = None,
    with_tasks: bool = True,
) -> ReachSettings:
    """The environment of a composed config; ``controller``/``gains`` replace the configured
    controller (evaluation runs the same plant under PID too). Gains may be a vector or the
    config form (``{"a0": …}`` / ``{"kp": [...], …}``). ``with_tasks=False``: no named tasks
    (``tasks.targets`` is not read; training draws its targets)."""
    robot = cfg.robot
    n = len(robot.lengths)
    name = str(cfg.controller.name) if controller is None else controller
    if gains is None:
        vector = controller_gains(cfg)
    elif isinstance(gains, dict):
        vector = gain_vector(KINDS[name], gains, n)
    else:
        vector = np.asarray(gains, dtype=np.float64)
    e = cfg.env

    def vec(values: Any) -> Array:
        return np.asarray(list(values), dtype=np.float64)

    return ReachSettings(
        plant=build_plant(cfg),
        controller=name,
        gains=vector,
        q0=vec(robot.q0),
        joint_lower=vec(robot.joint_lower),
        joint_upper=vec(robot.joint_upper),
        velocity_bound=vec(robot.velocity_bound),
        obstacles=obstacle_array(cfg),
        tasks=task_targets(cfg) if with_tasks else {},
        action_period=float(e.action_period),
        max_steps=int(e.max_steps),
        reach_threshold=float(e.reach_threshold),
        reach_reward=float(e.reach_reward),
        boundary_penalty=float(e.boundary_penalty),
        collision_penalty=float(e.collision_penalty),
        growth_penalty=float(e.growth_penalty),
        limit_guard=limit_guard_margin(OmegaConf.select(cfg, "agent", default=None)),
        path_margin=float(e.path_margin),
        target_margin=float(e.target_margin),
        min_target_distance=float(e.min_target_distance),
        max_target_time=float(e.max_target_time),
        workspace_cells=int(e.workspace_cells),
        reference=str(e.reference),
    )


def make_reach(
    overrides: Sequence[str] = (),
    gains: Array | dict[str, Any] | None = None,
    render_mode: str | None = None,
    record: bool = False,
) -> ReachEnv:
    """``gymnasium.make("armexp/Reach-v0", overrides=[...])``: the packaged config (paper arm,
    ``paper_five`` obstacles, the paper's gains) with Hydra overrides such as
    ``"obstacles=none"``, ``"robot=three_link"`` or ``"controller=pid"``."""
    from armexp.config import compose_config

    cfg = compose_config(list(overrides))
    return ReachEnv(settings_from_config(cfg, gains=gains), render_mode=render_mode, record=record)
