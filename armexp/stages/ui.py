"""`armexp ui`: serve the MLflow UI for the configured store (default runs/mlflow.db) on
``ui.host``:``ui.port``, until Ctrl-C."""

from __future__ import annotations

import os
import shlex
import signal
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
    # In its own session: Ctrl-C reaches armexp alone, which stops the server with SIGTERM, its
    # quiet shutdown (on SIGINT the server re-raises it after shutting down, with a traceback).
    server = subprocess.Popen(cmd, env=env, start_new_session=True)
    try:
        server.wait()
    except KeyboardInterrupt:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=60)
        print("armexp ui: stopped")
