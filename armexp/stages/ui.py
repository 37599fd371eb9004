"""`armexp ui`: serve the MLflow UI for the configured store (default runs/mlflow.db) on
``ui.host``:``ui.port``, until Ctrl-C."""

from __future__ import annotations

import errno
import os
import shlex
import signal
import socket
import subprocess
import sys

from omegaconf import DictConfig

from armexp import console
from armexp.config import ConfigError
from armexp.tracking import stage_runs, store

#: MLflow's UI keeps a "GenAI" or "Machine learning" view; the link names the second, where an
#: experiment opens on its runs table (a run's params, metrics, artifacts) rather than on traces.
VIEW = "workflowType=machine_learning"


def ui_command(cfg: DictConfig) -> list[str]:
    """The `mlflow ui` command line that shows this store."""
    uri = store.store_uri(cfg)
    # The model registry in the same store, as MLflow would pick, without its line saying so.
    cmd = ["mlflow", "ui", "--backend-store-uri", uri, "--registry-store-uri", uri]
    # One worker: one person browsing one store, and Ctrl-C never lands in a worker mid-import.
    cmd += ["--host", str(cfg.ui.host), "--port", str(cfg.ui.port), "--workers", "1"]
    root = store.artifact_root(cfg)
    if root:
        cmd += ["--default-artifact-root", root]
    return cmd


def check_address(host: str, port: int) -> None:
    """The UI can listen on ``host``:``port``: one sentence (`ConfigError`) when another
    program listens there (the link printed would open that one), when the port is one only
    root may take, or when ``host`` is not an address of this machine."""
    try:
        family, kind, proto, _, address = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0]
        with socket.socket(family, kind, proto) as s:
            # As uvicorn does: a port left in TIME_WAIT by a server just stopped is free.
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(address)
    except socket.gaierror as exc:
        raise ConfigError(
            f"ui.host={host} is not allowed: it is not a host name this machine can resolve "
            f"({exc.strerror}); give an address of this machine, such as 127.0.0.1."
        ) from None
    except OSError as exc:
        if exc.errno == errno.EADDRINUSE:
            raise ConfigError(
                f"ui.port={port} is not allowed now: another program already listens on "
                f"{host}:{port}; stop it, or choose a free port (ui.port={_free_port(host)})."
            ) from None
        if exc.errno == errno.EACCES:
            raise ConfigError(
                f"ui.port={port} is not allowed: only root may listen on a port below 1024; "
                f"choose a port from 1024 up (ui.port={_free_port(host)})."
            ) from None
        raise ConfigError(
            f"ui.host={host} is not allowed: the UI cannot listen there ({exc.strerror}); give "
            "an address of this machine, such as 127.0.0.1."
        ) from None


def _free_port(host: str) -> int:
    """A port nothing listens on now, to suggest."""
    with socket.socket(socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM)[0][0]) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def run(cfg: DictConfig) -> None:
    check_address(str(cfg.ui.host), int(cfg.ui.port))
    # The experiment exists, with its kind tag, before the UI first shows it.
    experiment_id = stage_runs.setup(cfg)
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
        code = server.wait()
    except KeyboardInterrupt:
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=60)
        print("armexp ui: stopped")
        return
    if code != 0:  # it could not start (its own message is above), or it was killed
        print(f"armexp ui: the MLflow UI stopped with exit code {code}", file=sys.stderr)
        raise SystemExit(1)
