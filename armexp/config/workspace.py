"""Where the arm can reach: task targets, `armexp play`'s extra targets and the start pose,
checked against the robot's links and the obstacle circles.

A check of a stage's own section runs only for the stages that read it (``stage`` None: every
check, as for a config composed outside a command): `armexp eval` does not read ``play``, so an
eval is never refused over play's settings.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

from armexp.config.checks import ConfigError, fail

#: The stages that run the paper tasks of ``tasks.targets`` (``eval.paper_tasks``): eval and the
#: pipeline (and a study, a pipeline per seed).
EVAL_STAGES = ("eval", "pipeline")
#: The stages that read the ``play`` section.
PLAY_STAGES = ("play",)


def _runs(stage: str | None, stages: tuple[str, ...]) -> bool:
    return stage is None or stage in stages


def _segment_distance(
    p: tuple[float, float], a: tuple[float, float], b: tuple[float, float]
) -> float:
    """Distance from point ``p`` to the segment ``a``–``b``."""
    ax, ay = a
    dx, dy = b[0] - ax, b[1] - ay
    length2 = dx * dx + dy * dy
    t = 0.0 if length2 == 0 else max(0.0, min(1.0, ((p[0] - ax) * dx + (p[1] - ay) * dy) / length2))
    return math.hypot(p[0] - ax - t * dx, p[1] - ay - t * dy)


def target_problem(
    point: tuple[float, float],
    lengths: Sequence[float],
    circles: Sequence[tuple[float, float, float]],
) -> str | None:
    """Why the arm (base at the origin) cannot have its tip at ``point``: outside its reach, or
    inside an obstacle circle; None when neither."""
    reach, inner = sum(lengths), max(0.0, 2 * max(lengths) - sum(lengths))
    distance = math.hypot(*point)
    if not inner <= distance <= reach:
        return (
            f"it is {distance:.3g} m from the base, outside the arm's reach "
            f"[{inner:.3g}, {reach:.3g}] m"
        )
    for k, (x, y, r) in enumerate(circles):
        if math.hypot(point[0] - x, point[1] - y) < r:
            return f"it lies inside obstacles.circles[{k}] (x={x:g}, y={y:g}, r={r:g})"
    return None


def workspace_checks(cfg: DictConfig, stage: str | None = None) -> None:
    """Targets the arm can reach outside every obstacle, as many as the stage needs, and no
    obstacle over the arm at its start pose (base at the origin, angles summed along the
    chain)."""
    robot, obstacles, tasks = cfg.get("robot"), cfg.get("obstacles"), cfg.get("tasks")
    if robot is None or obstacles is None or tasks is None:
        return
    lengths = [float(v) for v in robot.lengths]
    circles = [(float(c.x), float(c.y), float(c.r)) for c in obstacles.circles]
    for i, target in enumerate(tasks.targets):
        point = (float(target.x), float(target.y))
        problem = target_problem(point, lengths, circles)
        if problem:
            raise ConfigError(
                f"tasks.targets[{i}] ({target.name} at x={point[0]:g}, y={point[1]:g}) is not "
                f"allowed: {problem}."
            )
    evaluation = cfg.get("eval")
    paper_tasks = evaluation is not None and evaluation.paper_tasks
    if _runs(stage, EVAL_STAGES) and paper_tasks and not tasks.targets:
        raise ConfigError(
            "tasks.targets=[] is not allowed: eval.paper_tasks=true evaluates the tasks it "
            "lists, so give at least one ({name, x, y}; tasks=paper_four has the paper's "
            "four), or set eval.paper_tasks=false for the random targets alone."
        )
    if _runs(stage, PLAY_STAGES):
        _play_checks(cfg, lengths, circles)
    joints, angle = [(0.0, 0.0)], 0.0
    for length, q in zip(lengths, robot.q0, strict=True):
        angle += float(q)
        last = joints[-1]
        joints.append((last[0] + length * math.cos(angle), last[1] + length * math.sin(angle)))
    for k, (x, y, r) in enumerate(circles):
        for j in range(len(lengths)):
            if _segment_distance((x, y), joints[j], joints[j + 1]) < r:
                raise ConfigError(
                    f"obstacles.circles[{k}] (x={x:g}, y={y:g}, r={r:g}) is not allowed: it covers "
                    f"link {j + 1} of the arm at its start pose robot.q0="
                    f"{[float(q) for q in robot.q0]}."
                )


def _play_checks(
    cfg: DictConfig, lengths: list[float], circles: list[tuple[float, float, float]]
) -> None:
    """`armexp play`'s tasks name ``tasks.targets``; its extra targets are points [x, y] the arm
    can reach outside every obstacle."""
    play = cfg.get("play")
    if play is None:
        return
    if not play.tasks and not play.targets:
        raise ConfigError(
            "play.tasks=[] with play.targets=[] is not allowed: give at least one task or target."
        )
    names = [str(t.name) for t in cfg.tasks.targets]
    if play.tasks and not names:
        raise ConfigError(
            f"tasks.targets=[] is not allowed: play.tasks=[{', '.join(map(str, play.tasks))}] "
            "names tasks of it; give those targets ({name, x, y}; tasks=paper_four has the "
            "paper's four), or play.tasks=[] with extra targets play.targets=[[x, y], ...]."
        )
    for task in play.tasks:
        if str(task) not in names:
            raise ConfigError(
                f"play.tasks contains {task}, which is not allowed: the tasks of "
                f"tasks={cfg.tasks.name} are {', '.join(names)}."
            )
    for i, target in enumerate(play.targets):
        value: Any = OmegaConf.to_container(target) if _is_container(target) else target
        numbers = isinstance(value, list) and all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v)
            for v in value
        )
        if not numbers or len(value) != 2:
            raise fail(f"play.targets[{i}]", value, "give a point as [x, y] in metres")
        point = (float(value[0]), float(value[1]))
        problem = target_problem(point, lengths, circles)
        if problem:
            raise fail(f"play.targets[{i}]", list(point), problem)


def _is_container(x: Any) -> bool:
    return isinstance(x, DictConfig | ListConfig)
