"""A run's process reports a heartbeat: a live run cannot be resumed from elsewhere, and a run
whose process died is closed (FAILED, said on stderr) by the next command on the store."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig

from armexp.cli import main
from armexp.tracking import liveness
from armexp.tracking.stage_runs import close_orphans
from armexp.tracking.tags import HEARTBEAT_TAG, PROCESS_TAG, STAGE_TAG
from tests.helpers import SMALL_TRAIN, existing_store_client


def _running_train(runs: Path) -> tuple[subprocess.Popen[str], Any]:
    """A train run in another process, long enough to be caught RUNNING."""
    command = [sys.executable, "-m", "armexp", "train", "controller.gains=paper", *SMALL_TRAIN,
               "agent.max_env_steps=100000", f"tracking.runs_dir={runs}"]  # fmt: skip
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    for _ in range(240):
        found: list[Any] = []
        with contextlib.suppress(FileNotFoundError):  # proc has not made the store yet
            client = existing_store_client(runs)
            exp = client.get_experiment_by_name("armexp")
            found = (
                client.search_runs([exp.experiment_id], "attributes.status = 'RUNNING'")
                if exp
                else []
            )
        if found:
            return proc, found[0]
        assert proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        time.sleep(0.5)
    proc.kill()
    pytest.fail("the train run did not start within 120 s")


@pytest.mark.long
def test_resuming_a_run_that_is_still_training_is_refused(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    proc, run = _running_train(runs)
    try:
        rc = main(["train", f"train.resume={run.info.run_id}", f"tracking.runs_dir={runs}"])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 2 and len(err) == 1
        assert f"train.resume={run.info.run_id} is not allowed" in err[0]
        assert "still training in another process" in err[0]
    finally:
        proc.send_signal(signal.SIGTERM)
        proc.wait(timeout=60)
    client = MlflowClient(f"sqlite:///{runs / 'mlflow.db'}")
    assert client.get_run(run.info.run_id).info.status == "KILLED"


@pytest.mark.long
@pytest.mark.parametrize("same_host", [True, False])
def test_a_run_whose_process_died_is_closed_by_the_next_command(
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    same_host: bool,
) -> None:
    """On the same host the dead process is seen at once; from another host only its silence
    tells, after STALE_S."""
    runs = tmp_path / "runs"
    proc, run = _running_train(runs)
    assert run.data.tags[PROCESS_TAG].split(":")[1] == str(proc.pid)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=60)
    client = MlflowClient(f"sqlite:///{runs / 'mlflow.db'}")
    assert client.get_run(run.info.run_id).info.status == "RUNNING"  # nobody could end it
    if not same_host:
        monkeypatch.setattr(liveness.socket, "gethostname", lambda: "another-host")
        # The heartbeat is fresh: the run is taken for live until it has been silent STALE_S.
        assert liveness.is_alive(client.get_run(run.info.run_id))
        monkeypatch.setattr(liveness, "STALE_S", 0.0)  # the test does not wait that long
    assert main(["simulate", "scenario=hold", "scenario.duration=0.05",
                 f"tracking.runs_dir={runs}"]) == 0  # fmt: skip
    err = capsys.readouterr().err
    assert f"train run {run.info.run_id} was RUNNING but its process stopped" in err
    assert f"train.resume={run.info.run_id}" in err
    closed = client.get_run(run.info.run_id)
    assert closed.info.status == "FAILED"
    reason = closed.data.tags["armexp.error"]
    assert (
        (f":{proc.pid}:" in reason and "is gone" in reason)
        if same_host
        else ("no heartbeat" in reason)
    )
    live = [
        r for r in client.search_runs([closed.info.experiment_id]) if r.info.status == "RUNNING"
    ]
    assert live == []


@pytest.mark.slow
def test_a_live_sweep_and_its_pipeline_parents_are_not_taken_for_dead(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each job's start closes stale RUNNING runs; the sweep's own run, open for the whole
    sweep, keeps its heartbeat and is not among them."""
    from armexp.stages import simulate

    monkeypatch.setattr(liveness, "HEARTBEAT_S", 0.1)
    monkeypatch.setattr(liveness, "STALE_S", 1.0)
    real = simulate.run

    def slow(cfg: Any) -> Any:
        time.sleep(1.5)  # longer than STALE_S: a sweep without a heartbeat would look dead
        return real(cfg)

    monkeypatch.setattr(simulate, "run", slow)
    runs = tmp_path / "runs"
    args = ["simulate", "-m", "seed=0,1,2", "scenario=hold", "scenario.duration=0.05"]
    assert main([*args, f"tracking.runs_dir={runs}"]) == 0
    assert "its process stopped" not in capsys.readouterr().err
    client = MlflowClient(f"sqlite:///{runs / 'mlflow.db'}")
    exp = client.get_experiment_by_name("armexp")
    assert exp is not None
    statuses = [r.info.status for r in client.search_runs([exp.experiment_id])]
    assert statuses == ["FINISHED"] * 4  # three jobs and the sweep


def test_a_stopped_process_on_this_host_keeps_its_run_however_long_it_is_silent(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A process paused with SIGSTOP writes no heartbeat but still runs: on its own host the
    next command leaves its run alone; only from another host does its silence close the run."""
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        os.kill(sleeper.pid, signal.SIGSTOP)
        identity = liveness.process_identity(sleeper.pid)
        runs = tmp_path / "runs"
        assert main(["simulate", "scenario=hold", "scenario.duration=0.05",
                     f"tracking.runs_dir={runs}"]) == 0  # fmt: skip
        client = MlflowClient(f"sqlite:///{runs / 'mlflow.db'}")
        exp = client.get_experiment_by_name("armexp")
        assert exp is not None
        silent = time.time() - 10 * liveness.STALE_S
        paused = client.create_run(exp.experiment_id, tags={
            STAGE_TAG: "train", PROCESS_TAG: identity, HEARTBEAT_TAG: f"{silent:.0f}"})  # fmt: skip
        run_id = paused.info.run_id
        assert liveness.is_alive(client.get_run(run_id))
        assert close_orphans(client, exp.experiment_id) == []
        assert client.get_run(run_id).info.status == "RUNNING"
        monkeypatch.setattr(liveness.socket, "gethostname", lambda: "another-host")
        assert close_orphans(client, exp.experiment_id) == [run_id]
        closed = client.get_run(run_id)
        assert closed.info.status == "FAILED"
        assert "no heartbeat for" in closed.data.tags["armexp.error"]
        capsys.readouterr()
    finally:
        os.kill(sleeper.pid, signal.SIGKILL)
        sleeper.wait(timeout=60)


@pytest.mark.long
def test_a_run_closed_for_dead_that_goes_on_to_finish_keeps_no_error_tag(tmp_path: Path) -> None:
    """Another host took the run's silent process for dead and marked it FAILED; the stage (or
    the HPO trial) then finished: its run ends FINISHED without that error."""
    import mlflow

    from armexp.hpo.record import close_trial
    from armexp.tracking import run_end

    runs = tmp_path / "runs"
    assert main(["simulate", "scenario=hold", "scenario.duration=0.05",
                 f"tracking.runs_dir={runs}"]) == 0  # fmt: skip
    uri = f"sqlite:///{runs / 'mlflow.db'}"
    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("armexp")
    assert exp is not None
    silent = {STAGE_TAG: "train", PROCESS_TAG: "another-host:4242:1",
              HEARTBEAT_TAG: f"{time.time() - 10 * liveness.STALE_S:.0f}"}  # fmt: skip
    mlflow.set_tracking_uri(uri)
    stage = mlflow.start_run(experiment_id=exp.experiment_id, tags=silent).info.run_id
    trial = client.create_run(exp.experiment_id, tags=silent).info.run_id
    assert sorted(close_orphans(client, exp.experiment_id)) == sorted([stage, trial])
    for run_id in (stage, trial):
        closed = client.get_run(run_id)
        assert closed.info.status == "FAILED" and "no heartbeat" in closed.data.tags["armexp.error"]
    run_end.end_run(stage, "FINISHED")
    close_trial(client, trial, "COMPLETE", {0: 0.5, 1: 0.7}, 0.6)
    for run_id in (stage, trial):
        finished = client.get_run(run_id)
        assert finished.info.status == "FINISHED" and "armexp.error" not in finished.data.tags
    # A trial that failed keeps its error.
    failed = client.create_run(exp.experiment_id).info.run_id
    close_trial(client, failed, "FAIL", {}, None, "ValueError: boom")
    assert client.get_run(failed).data.tags["armexp.error"] == "ValueError: boom"


def test_a_resumed_run_is_never_running_under_its_dead_process(
    compose: Callable[..., DictConfig], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Another command that looks for orphans just as a resume reopens its run finds it under the
    resuming process, not the dead one (seen: of two resumes started in the same second, the
    second closed the first's run as FAILED while it trained on)."""
    import mlflow

    from armexp.tracking import stage_runs
    from armexp.tracking.store import store_uri

    cfg = compose()
    with pytest.raises(KeyboardInterrupt), stage_runs.stage_run(cfg, "train") as run:
        raise KeyboardInterrupt
    run_id = run.info.run_id
    client = MlflowClient(store_uri(cfg))
    finished = subprocess.Popen([sys.executable, "-c", "input()"], stdin=subprocess.PIPE)
    dead = liveness.process_identity(finished.pid)
    finished.communicate(b"\n")
    client.set_tag(run_id, PROCESS_TAG, dead)
    assert liveness.process_gone(dead)

    closed: list[str] = []
    start_run = mlflow.start_run

    def start_run_then_look_for_orphans(*args: Any, **kwargs: Any) -> Any:
        active = start_run(*args, **kwargs)
        closed.extend(close_orphans(client, active.info.experiment_id))
        return active

    monkeypatch.setattr(mlflow, "start_run", start_run_then_look_for_orphans)
    with stage_runs.stage_run(cfg, "train", resume_run_id=run_id):
        assert client.get_run(run_id).data.tags[PROCESS_TAG] == liveness.process_identity()
    assert closed == []
    assert client.get_run(run_id).info.status == "FINISHED"
