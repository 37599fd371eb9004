"""Animations of evaluated episodes as artifacts of the running stage's MLflow run
(``animations/<controller>/<name>.gif|mp4``), shared by `armexp eval` and `armexp play`."""

from __future__ import annotations

import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import mlflow
import numpy as np
import pandas as pd

from armexp.baselines import title
from armexp.envs.reach import ReachEnv
from armexp.render.animation import Scene, write
from armexp.tracking import store

ANIMATIONS_DIR = "animations"
#: A target as an episode stores it (an array) or as written in a config.
Point = Sequence[float] | np.ndarray


def describe(task: str | None, target: Point) -> str:
    """An episode as its title names it: ``task (a)``, or the target's coordinates."""
    return f"task ({task})" if task else f"target ({target[0]:.2f}, {target[1]:.2f}) m"


def scene(env: ReachEnv, label: str, what: str, target: Point, reason: str) -> Scene:
    """The still parts of an episode of ``env`` towards ``target``: the arm's links, the
    obstacles, the target and threshold, and a title naming the controller's label
    (`armexp.baselines.title`), the episode (``what``) and how it ended."""
    x, y = float(target[0]), float(target[1])
    return Scene(
        lengths=tuple(float(v) for v in env.settings.plant.arm.lengths_array),
        circles=tuple((float(c[0]), float(c[1]), float(c[2])) for c in env.settings.obstacles),
        target=(x, y),
        threshold=float(env.settings.reach_threshold),
        title=f"{title(label)} · {what} · {reason.replace('_', ' ')}",
    )


def log_animation(
    frame: pd.DataFrame, still: Scene, label: str, name: str, formats: Sequence[str]
) -> float:
    """Render ``frame`` (one episode's 1 kHz trajectory) in ``still`` and log it to the active
    run as ``animations/<label>/<name>.<format>``; returns the seconds it took."""
    start = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        paths = write(frame, still, Path(tmp) / name, formats)
        folder = f"{ANIMATIONS_DIR}/{label}"
        for path in paths.values():
            store.retry(lambda p=path: mlflow.log_artifact(str(p), folder))  # type: ignore[misc]
    return time.perf_counter() - start
