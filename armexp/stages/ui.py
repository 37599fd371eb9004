"""`armexp ui`: serve the MLflow UI for the configured store (default runs/mlflow.db) on
``ui.host``:``ui.port``, until Ctrl-C."""

from __future__ import annotations

import os
import shlex
import subprocess
import sys

from omegaconf import DictConfig

from armexp import tracking


def run(cfg: DictConfig) -> None:
    # The interpreter running armexp has MLflow, whether or not its scripts are on PATH.
    cmd = [sys.executable, "-m", *tracking.ui_command(cfg)]
    print("running:", shlex.join(cmd[2:]))
    print(f"open http://{cfg.ui.host}:{cfg.ui.port} (Ctrl-C stops it)", flush=True)
    # MLflow's GenAI job runner (a process and two queue consumers) has nothing to do for armexp's
    # runs; without it the UI starts sooner and Ctrl-C stops one process. A user's setting wins.
    env = {"MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false", **os.environ}
    subprocess.run(cmd, check=False, env=env)
