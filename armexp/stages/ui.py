"""`armexp ui`: serve the MLflow UI for the configured store (default runs/mlflow.db) on
``ui.host``:``ui.port``, until Ctrl-C."""

from __future__ import annotations

import os
import shlex
import signal
import subprocess
import sys

from omegaconf import DictConfig

from armexp import console, tracking

#: MLflow's UI keeps a "GenAI" or "Machine learning" view; the link names the second, where an
#: experiment opens on its runs table (a run's params, metrics, artifacts) rather than on traces.
VIEW = "workflowType=machine_learning"


def ui_command(cfg: DictConfig) -> list[str]:
    """The `mlflow ui` command line that shows this store."""
    uri = tracking.store_uri(cfg)
    # The model registry in the same store, as MLflow would pick, without its line saying so.
    cmd = ["mlflow", "ui", "--backend-store-uri", uri, "--registry-store-uri", uri]
    # One worker: one person browsing one store, and Ctrl-C never lands in a worker mid-import.
    cmd += ["--host", str(cfg.ui.host), "--port", str(cfg.ui.port), "--workers", "1"]
    root = tracking.artifact_root(cfg)
    if root:
        cmd += ["--default-artifact-root", root]
    return cmd


def run(cfg: DictConfig) -> None:
    # The experiment exists, with its kind tag, before the UI first shows it.
    experiment_id = tracking.setup(cfg)
    # The interpreter running armexp has MLflow, whether or not its scripts are on PATH.
    cmd = [sys.executable, "-m", *ui_command(cfg)]
    print("running:", shlex.join(cmd[2:]))
    link = f"http://{cfg.ui.host}:{cfg.ui.port}/#/experiments/{experiment_id}/runs?{VIEW}"
    print(f"open {link} (Ctrl-C stops it)", flush=True)
    # MLflow's GenAI job runner (a process and two queue consumers) has nothing to do for armexp's
    # runs; without it the UI starts sooner and Ctrl-C stops one process. A user's setting wins.
    env = console.quiet_environment({"MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false", **os.environ})
    # In its own session: Ctrl-C reaches armexp alone, which stops the server with SIGTERM, its
    # quiet shutdown (on SIGINT the server re-raises it after shutting down, with a traceback).
    server = subprocess.Popen(cmd, env=env, start_new_session=True)
    try:
        server.wait()
    except KeyboardInterrupt:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=60)
        print("armexp ui: stopped")
