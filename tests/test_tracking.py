"""Run status, params and look-up of the MLflow backbone."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import mlflow
import pytest
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig

from armexp.tracking import stage_runs, store


def _only_run(cfg: DictConfig) -> mlflow.entities.Run:
    client = MlflowClient(store.store_uri(cfg))
    exp = client.get_experiment_by_name("armexp")
    assert exp is not None
    (run,) = client.search_runs([exp.experiment_id])
    return run


def test_store_defaults_to_sqlite_under_runs_dir(compose: Callable[..., DictConfig]) -> None:
    cfg = compose()
    assert store.store_uri(cfg).startswith("sqlite:///")
    assert store.store_uri(cfg).endswith("/runs/mlflow.db")
    assert store.artifact_root(cfg).endswith("/runs/artifacts")  # type: ignore[union-attr]


def test_flatten_keeps_lists_as_one_param(compose: Callable[..., DictConfig]) -> None:
    flat = stage_runs.flatten(compose())
    assert flat["robot.lengths"] == "[1.0, 0.8]"
    assert flat["controller.gains.r1"] == "0.69"
    assert flat["robot.uncertainty.f_terms"].startswith('[{"joint": 1')


def test_failed_stage_is_failed_and_keeps_what_was_logged(
    compose: Callable[..., DictConfig],
) -> None:
    cfg = compose()
    with pytest.raises(RuntimeError), stage_runs.stage_run(cfg, "simulate"):
        mlflow.log_metric("partial", 1.5)
        raise RuntimeError("boom")
    run = _only_run(cfg)
    assert run.info.status == "FAILED"
    assert run.data.metrics["partial"] == 1.5
    assert run.data.tags["armexp.error"] == "RuntimeError: boom"
    assert run.data.tags["armexp.stage"] == "simulate"
    assert run.data.params["robot.name"] == "two_link_paper"


def test_interrupted_stage_is_killed(compose: Callable[..., DictConfig]) -> None:
    cfg = compose()
    with pytest.raises(KeyboardInterrupt), stage_runs.stage_run(cfg, "tune"):
        mlflow.log_metric("partial", 2.0)
        raise KeyboardInterrupt
    run = _only_run(cfg)
    assert run.info.status == "KILLED" and run.data.metrics["partial"] == 2.0


@pytest.mark.parametrize("outcome", ["FINISHED", "KILLED"])
def test_a_locked_store_does_not_lose_the_final_status(
    compose: Callable[..., DictConfig], monkeypatch: pytest.MonkeyPatch, outcome: str
) -> None:
    # A reader (the MLflow UI, a poll) holding the SQLite store when the run ends: the first
    # status write fails with a lock, as it did for an interrupted train run in a fresh clone.
    cfg = compose()
    real = MlflowClient.set_terminated
    calls: list[str] = []

    def locked_once(self: MlflowClient, run_id: str, status: str | None = None) -> None:
        calls.append(str(status))
        if len(calls) == 1:
            raise mlflow.exceptions.MlflowException("(sqlite3.OperationalError) database is locked")
        real(self, run_id, status)

    monkeypatch.setattr(MlflowClient, "set_terminated", locked_once)
    if outcome == "KILLED":
        with pytest.raises(KeyboardInterrupt), stage_runs.stage_run(cfg, "tune"):
            raise KeyboardInterrupt
    else:
        with stage_runs.stage_run(cfg, "simulate"):
            mlflow.log_metric("partial", 3.0)
    assert calls == [outcome, outcome]
    assert _only_run(cfg).info.status == outcome
    assert mlflow.active_run() is None


@pytest.mark.slow
def test_four_processes_racing_on_a_fresh_store_all_finish(tmp_path: Path) -> None:
    """MLflow creates a new SQLite store's schema on first open; processes doing it at once
    must not fail inside the migration nor leave the store half-migrated."""
    import subprocess
    import sys

    from mlflow.tracking import MlflowClient

    runs = tmp_path / "runs"
    command = [sys.executable, "-m", "armexp", "simulate", "scenario=hold",
               "scenario.duration=0.05", f"tracking.runs_dir={runs}"]  # fmt: skip
    procs = [
        subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for _ in range(4)
    ]
    outputs = [p.communicate(timeout=300)[0] for p in procs]
    assert [p.returncode for p in procs] == [0] * 4, outputs
    client = MlflowClient(f"sqlite:///{runs / 'mlflow.db'}")
    exp = client.get_experiment_by_name("armexp")
    assert exp is not None
    runs_found = client.search_runs([exp.experiment_id])
    assert len(runs_found) == 4 and {r.info.status for r in runs_found} == {"FINISHED"}


def test_a_corrupt_store_is_one_sentence(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from armexp.cli import main

    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / "mlflow.db").write_text("not a database")
    assert main(["simulate", f"tracking.runs_dir={runs}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert f"tracking.runs_dir={runs} is not allowed: its MLflow store mlflow.db cannot" in err[0]
    assert (runs / "mlflow.db").read_text() == "not a database"  # left for the user to inspect


@pytest.mark.long
def test_a_moved_store_finds_its_artifacts_and_writes_new_ones_beside_them(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from mlflow.tracking import MlflowClient

    from armexp.cli import main

    first, moved = tmp_path / "proj", tmp_path / "proj2"
    sim = ["simulate", "scenario=hold", "scenario.duration=0.05"]
    assert main([*sim, f"tracking.runs_dir={first / 'runs'}"]) == 0
    first.rename(moved)  # mv proj proj2
    runs = moved / "runs"
    assert main([*sim, "seed=1", f"tracking.runs_dir={runs}"]) == 0
    assert f"was copied or moved from {first / 'runs'}" in capsys.readouterr().err
    client = MlflowClient(f"sqlite:///{runs / 'mlflow.db'}")
    exp = client.get_experiment_by_name("armexp")
    assert exp is not None
    for run in client.search_runs([exp.experiment_id]):
        assert run.info.artifact_uri.startswith(f"file://{runs / 'artifacts'}")
        assert Path(client.download_artifacts(run.info.run_id, "config.yaml", str(tmp_path)))
    assert not first.exists()  # nothing written to the old place


def test_a_runs_dir_that_cannot_be_written_is_one_sentence(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from armexp.cli import main

    blocker = tmp_path / "a_file"
    blocker.write_text("x")  # a folder cannot be made inside a file (root or not)
    assert main(["simulate", f"tracking.runs_dir={blocker / 'runs'}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not allowed: armexp cannot write there" in err[0]


@pytest.mark.long
def test_a_read_only_runs_dir_is_one_sentence_and_nothing_is_written(tmp_path: Path) -> None:
    """Permission bits bind root only without CAP_DAC_OVERRIDE: as root, the command runs with
    that capability dropped (``setpriv``); as another user, the bits bind anyway."""
    import os
    import shutil
    import subprocess
    import sys

    from armexp.cli import main

    runs = tmp_path / "runs"
    assert main(["simulate", "scenario=hold", "scenario.duration=0.05",
                 f"tracking.runs_dir={runs}"]) == 0  # fmt: skip
    before = sorted(str(p.relative_to(runs)) for p in runs.rglob("*"))
    prefix: list[str] = []
    if os.geteuid() == 0:
        if shutil.which("setpriv") is None:
            pytest.skip("running as root without setpriv (util-linux) to drop CAP_DAC_OVERRIDE")
        prefix = ["setpriv", "--bounding-set=-dac_override,-dac_read_search"]
    runs.chmod(0o555)
    try:
        command = [*prefix, sys.executable, "-m", "armexp", "simulate", "scenario=hold",
                   f"tracking.runs_dir={runs}"]  # fmt: skip
        done = subprocess.run(command, capture_output=True, text=True, timeout=120)
    finally:
        runs.chmod(0o755)
    err = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(err) == 1, done.stderr[-2000:]
    assert f"tracking.runs_dir={runs} is not allowed: armexp cannot write there" in err[0]
    assert "Permission denied" in err[0]
    assert sorted(str(p.relative_to(runs)) for p in runs.rglob("*")) == before


@pytest.mark.slow  # a whole pipeline: about 25 s
def test_no_download_folder_is_left_in_the_temp_directory(tmp_path: Path) -> None:
    """Stages download configs, gains and models; the folders go when the process ends."""
    import os
    import subprocess
    import sys

    from armexp.cli import main

    runs = tmp_path / "runs"
    from tests.helpers import SMALL_TRAIN

    train = ["train", "controller.gains=paper", *SMALL_TRAIN, f"tracking.runs_dir={runs}"]
    assert main(train) == 0
    temp = tmp_path / "tmp"
    temp.mkdir()
    command = [sys.executable, "-m", "armexp", "eval", "eval.baselines=[pid_gaing]",
               "eval.baseline_gains=config", "tasks.n_random=1",
               f"tracking.runs_dir={runs}"]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "TMPDIR": str(temp)})  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    assert [p.name for p in temp.iterdir() if p.name.startswith("armexp-")] == []
