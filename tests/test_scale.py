"""Sweeps against one SQLite store, a real `mlflow server`, launcher configs, signals."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import mlflow
import pytest
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from mlflow.tracking import MlflowClient

from armexp.cli import main
from armexp.config import config_dir, register_schemas
from tests.helpers import SMALL_TRAIN, stage_runs


def _search(uri: str, stage: str) -> list[Any]:
    return stage_runs(uri, stage)


@pytest.mark.long
def test_joblib_sweep_of_4_jobs_on_2_workers_loses_nothing(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    rc = main(
        [
            "simulate",
            "-m",
            "seed=0,1,2,3",
            "scenario.duration=0.5",
            "robot.torque_limit=null",
            "hydra/launcher=joblib",
            "hydra.launcher.n_jobs=2",
            f"tracking.runs_dir={runs}",
        ]
    )
    assert rc == 0
    uri = f"sqlite:///{runs}/mlflow.db"
    jobs = _search(uri, "simulate")
    (sweep,) = _search(uri, "sweep")
    assert len(jobs) == 4 and sweep.info.status == "FINISHED"
    assert sorted(r.data.params["seed"] for r in jobs) == ["0", "1", "2", "3"]
    keys = {frozenset(r.data.metrics) for r in jobs}
    assert len(keys) == 1 and {"rms_e1", "convergence_time"} <= next(iter(keys))
    for r in jobs:
        assert r.info.status == "FINISHED"
        assert r.data.tags["armexp.sweep"] == sweep.info.run_id
        assert r.data.tags["mlflow.parentRunId"] == sweep.info.run_id
        assert "database is locked" not in r.data.tags.get("armexp.error", "")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def mlflow_server(tmp_path: Path) -> Iterator[str]:
    port = _free_port()
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "mlflow",
            "server",
            "--host",
            "127.0.0.1",
            "--port",
            str(port),
            "--backend-store-uri",
            f"sqlite:///{tmp_path}/server.db",
            "--artifacts-destination",
            str(tmp_path / "server-artifacts"),
            "--workers",
            "1",
        ],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        for _ in range(120):
            try:
                with urllib.request.urlopen(f"{url}/health", timeout=1) as res:
                    if res.status == 200:
                        break
            except OSError:
                time.sleep(0.5)
        else:
            pytest.fail("mlflow server did not start within 60 s")
        yield url
    finally:
        proc.terminate()
        proc.wait(timeout=30)


@pytest.mark.slow
def test_stages_log_through_a_real_mlflow_server(mlflow_server: str, tmp_path: Path) -> None:
    where = ["tracking=server", f"tracking.uri={mlflow_server}", f"tracking.runs_dir={tmp_path}"]
    assert main(["simulate", "scenario.duration=0.3", *where]) == 0
    assert (
        main(
            [
                "tune",
                "tuner=cso_fast",
                "tuner.n_iterations=2",
                "tuner.objective.n_scenarios=2",
                "tuner.objective.horizon=0.2",
                *where,
            ]
        )
        == 0
    )
    (sim,) = _search(mlflow_server, "simulate")
    (tune,) = _search(mlflow_server, "tune")
    assert sim.info.status == tune.info.status == "FINISHED"
    client = MlflowClient(mlflow_server)
    assert {f.path for f in client.list_artifacts(sim.info.run_id)} >= {
        "config.yaml",
        "trajectory.parquet",
    }
    assert client.get_metric_history(tune.info.run_id, "best_objective")
    assert not (tmp_path / "mlflow.db").exists()  # nothing went to the local store


def test_cluster_launcher_configs_compose() -> None:
    register_schemas()
    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(config_dir()), version_base="1.3"):
            slurm = compose(
                "config",
                ["hydra/launcher=slurm", "hydra.launcher.partition=gpu"],
                return_hydra_config=True,
            ).hydra.launcher
            ray = compose("config", ["hydra/launcher=ray"], return_hydra_config=True).hydra.launcher
            par = compose("config", ["hydra/launcher=parallel"], return_hydra_config=True)
    finally:
        GlobalHydra.instance().clear()
    assert slurm._target_.endswith("submitit_launcher.SlurmLauncher")
    assert (slurm.partition, slurm.cpus_per_task, slurm.timeout_min) == ("gpu", 4, 240)
    assert ray._target_ == "hydra_plugins.armexp_launcher.ray_launcher.RayLauncher"
    assert ray.ray.init.address == "auto" and ray.ray.remote.num_cpus == 2
    # Present and null: Ray 2.x refuses a size when it joins a running cluster.
    assert "object_store_memory" in ray.ray.init and ray.ray.init.object_store_memory is None
    assert ray.ray.remote.max_retries == 0
    assert par.hydra.launcher._target_.endswith("JoblibLauncher")


# A shell without job control starts background jobs with SIGINT ignored, and Python keeps an
# inherited SIG_IGN instead of installing its KeyboardInterrupt handler: under a pytest run in
# the background the child slept through the signal and finished (rc 0). The child stands for a
# run at a terminal, so it installs Python's handler before armexp starts. Both signals stay
# slow: in a fresh clone the 3000-step child can still finish before the poll sees its episodes
# (seen on 2026-11-26); the default run covers resume in-process (test_train_eval).
AT_A_TERMINAL = (
    "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
    "from armexp.cli import main; sys.exit(main())"
)


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_during_train_leaves_killed_run_with_checkpoint_and_resume_finishes(
    tmp_path: Path, sig: signal.Signals
) -> None:
    runs = tmp_path / "runs"
    uri = f"sqlite:///{runs}/mlflow.db"
    args = [
        "train",
        "controller.gains=paper",
        *SMALL_TRAIN,
        "agent.max_env_steps=3000",
        "env.max_steps=50",
        "train.log_every=100",
        f"tracking.runs_dir={runs}",
    ]
    proc = subprocess.Popen(
        [sys.executable, "-c", AT_A_TERMINAL, *args],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ},
    )
    polled: Exception | None = None
    try:
        deadline = time.time() + 120
        while time.time() < deadline:  # wait until training has logged some episodes
            time.sleep(0.5)
            try:
                (run,) = _search(uri, "train")
                if MlflowClient(uri).get_metric_history(run.info.run_id, "episode/reward"):
                    break
            except Exception as exc:  # the store may not exist yet, or be locked
                polled = exc
                continue
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    # A shell's codes: 128 + the signal's number (130 for Ctrl-C, 143 for SIGTERM).
    assert proc.returncode == 128 + sig, f"last poll error: {polled!r}; stderr: {err[-2000:]}"
    (run,) = _search(uri, "train")
    assert run.info.status == "KILLED"
    client = MlflowClient(uri)
    names = {f.path for f in client.list_artifacts(run.info.run_id, "checkpoint")}
    assert names == {"checkpoint/model.zip", "checkpoint/state.json"}
    mlflow.set_tracking_uri(uri)
    state = mlflow.artifacts.download_artifacts(
        run_id=run.info.run_id, artifact_path="checkpoint/state.json", dst_path=str(tmp_path)
    )
    saved = json.loads(Path(state).read_text())["num_timesteps"]
    assert 0 < saved < 3000

    assert main(["train", f"train.resume={run.info.run_id}", f"tracking.runs_dir={runs}"]) == 0
    (done,) = _search(uri, "train")
    assert done.info.run_id == run.info.run_id and done.info.status == "FINISHED"
    assert done.data.tags["armexp.resumed_from_step"] == str(saved)
    assert done.data.metrics["final/env_steps"] == 3000


@pytest.mark.slow
def test_a_password_in_the_tracking_uri_is_nowhere_in_the_runs(
    mlflow_server: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Not in params, artifacts, printed lines or Hydra's folders; MLflow still gets it."""
    for name in ("MLFLOW_TRACKING_USERNAME", "MLFLOW_TRACKING_PASSWORD", "ARMEXP_TRACKING_URI"):
        monkeypatch.setenv(name, "")  # restored after the test
    secret = "s3cr3t-pw"
    uri = mlflow_server.replace("http://", f"http://alice:{secret}@")
    runs = tmp_path / "runs"
    where = ["tracking=server", f"tracking.uri={uri}", f"tracking.runs_dir={runs}"]
    assert main(["simulate", "scenario=hold", "scenario.duration=0.05", *where]) == 0
    printed = capsys.readouterr()
    assert secret not in printed.out + printed.err
    (run,) = _search(mlflow_server, "simulate")
    assert run.info.status == "FINISHED"
    assert run.data.params["tracking.uri"] == mlflow_server
    assert all(secret not in v for v in [*run.data.params.values(), *run.data.tags.values()])
    config = MlflowClient(mlflow_server).download_artifacts(
        run.info.run_id, "config.yaml", str(tmp_path)
    )
    assert secret not in Path(config).read_text()
    written = [p for p in runs.rglob("*") if p.is_file()]
    assert written and all(secret not in p.read_text(errors="ignore") for p in written)
    import os

    assert os.environ["MLFLOW_TRACKING_PASSWORD"] == secret  # MLflow's own way to send it


def test_a_database_uri_keeps_its_password_out_of_the_logs(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from armexp.tracking import store

    monkeypatch.setenv("ARMEXP_TRACKING_URI", "")
    # No database behind the address: the connection check is not what this test is about.
    monkeypatch.setattr("armexp.tracking.remote.probe_database", lambda uri, timeout: None)
    shown = store.keep_credentials_out("postgresql://bob:pa55@db.example:5432/mlflow")
    assert shown == "postgresql://bob:***@db.example:5432/mlflow"
    from armexp.config import ConfigError, compose_config

    cfg = compose_config(["tracking=server", f"tracking.uri={shown}"])
    assert store.store_uri(cfg) == "postgresql://bob:pa55@db.example:5432/mlflow"
    monkeypatch.setenv("ARMEXP_TRACKING_URI", "")
    with pytest.raises(ConfigError, match="its password is hidden"):
        store.store_uri(cfg)


@pytest.mark.slow
def test_sigint_to_a_joblib_sweep_leaves_no_running_job(tmp_path: Path) -> None:
    from armexp.config import compose_config
    from armexp.tracking import store

    runs = tmp_path / "runs"
    # The store made first, so this test's look-ups do not race the sweep's creation of it.
    uri = store.store_uri(compose_config([f"tracking.runs_dir={runs}"]))
    command = [sys.executable, "-m", "armexp", "train", "-m", "seed=0,1", "controller.gains=paper",
               *SMALL_TRAIN, "agent.max_env_steps=100000", "hydra/launcher=joblib",
               "hydra.launcher.n_jobs=2", f"tracking.runs_dir={runs}"]  # fmt: skip
    proc = subprocess.Popen(
        command,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        # Its own process group (to clean up workers), with Ctrl-C's default action even when
        # this test runs where SIGINT is ignored (a background job), as a terminal would give.
        start_new_session=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL),
    )
    try:
        for _ in range(360):
            try:
                if len(_search(uri, "train")) == 2:
                    break
            except AssertionError:  # no experiment yet
                pass
            assert proc.poll() is None
            time.sleep(0.5)
        else:
            pytest.fail("the sweep's two train runs did not start within 180 s")
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=120)
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
    jobs = _search(uri, "train")
    (sweep,) = _search(uri, "sweep")
    assert sweep.info.status == "KILLED"
    assert [r.info.status for r in jobs] == ["KILLED", "KILLED"]


def test_an_unreachable_tracking_server_is_one_sentence(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    url = f"http://127.0.0.1:{_free_port()}"  # nothing listens there
    where = [f"tracking.uri={url}", f"tracking.runs_dir={tmp_path}"]
    rc = main(["simulate", "tracking=server", *where])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert f"tracking.uri={url} is not allowed: no MLflow server answers there" in err[0]


@pytest.mark.long
def test_the_ray_launcher_without_its_plugin_is_one_sentence(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from armexp import launchers

    monkeypatch.setattr(launchers, "_importable", lambda module: False)
    rc = main(["simulate", "-m", "seed=0,1", "hydra/launcher=ray", f"tracking.runs_dir={tmp_path}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1
    assert "hydra/launcher=ray is not allowed here" in err[0]
    assert 'pip install "armexp[cluster]"' in err[0]
    assert not (tmp_path / "mlflow.db").exists()  # stopped before any run


def test_an_unreachable_ray_cluster_is_one_sentence_within_seconds(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    pytest.importorskip("hydra_plugins.hydra_ray_launcher")
    from armexp import launchers

    where = f"127.0.0.1:{_free_port()}"  # nothing listens there
    sweep = ["simulate", "-m", "seed=0,1", "hydra/launcher=ray", f"tracking.runs_dir={tmp_path}"]
    start = time.time()
    rc = main([*sweep, f"hydra.launcher.ray.init.address={where}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and time.time() - start < 30
    assert f"no Ray cluster answers at {where}" in err[0] and "ray start --head" in err[0]
    # `address: auto` with no cluster started on this machine and no RAY_ADDRESS
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(launchers, "RAY_CURRENT_CLUSTER", tmp_path / "none")
    assert main(sweep) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "no Ray cluster is running on this machine and RAY_ADDRESS is not set" in line


@pytest.mark.long
def test_an_inherited_mlflow_run_id_does_not_capture_a_stage_run(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """mlflow #15713: MLflow continues the run named by MLFLOW_RUN_ID instead of starting one."""
    runs = tmp_path / "runs"
    where = f"tracking.runs_dir={runs}"
    assert main(["simulate", "scenario.duration=0.05", where]) == 0
    (first,) = _search(f"sqlite:///{runs}/mlflow.db", "simulate")
    monkeypatch.setenv("MLFLOW_RUN_ID", first.info.run_id)
    assert main(["simulate", "scenario.duration=0.05", "seed=1", where]) == 0
    second, again = _search(f"sqlite:///{runs}/mlflow.db", "simulate")
    assert again.info.run_id == first.info.run_id and again.data.params["seed"] == "0"
    assert second.info.run_id != first.info.run_id and second.data.params["seed"] == "1"
