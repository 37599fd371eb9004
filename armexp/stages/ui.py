"""`armexp ui`: serve the MLflow UI for the configured store (default runs/mlflow.db)."""

from __future__ import annotations

import shlex
import subprocess

from omegaconf import DictConfig

from armexp import tracking


def run(cfg: DictConfig) -> None:
    cmd = tracking.ui_command(cfg)
    print("running:", shlex.join(cmd))
    subprocess.run(cmd, check=False)
