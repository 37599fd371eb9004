"""A new SQLite store starts as a copy of an empty one (`armexp.tracking.new_store`), the same
store MLflow would have made."""

from __future__ import annotations

import contextlib
import sqlite3
from pathlib import Path

import mlflow
import pytest
from mlflow.tracking import MlflowClient

from armexp.config import compose_config
from armexp.tracking import new_store, stage_runs


def _schema(db: Path) -> tuple[list[tuple[str, str]], list[tuple[str]], list[tuple[int, str, str]]]:
    with contextlib.closing(sqlite3.connect(db)) as con:
        tables = con.execute("SELECT type, name FROM sqlite_master ORDER BY name").fetchall()
        version = con.execute("SELECT version_num FROM alembic_version").fetchall()
        experiments = con.execute(
            "SELECT experiment_id, name, artifact_location FROM experiments"
        ).fetchall()
    return tables, version, experiments


@pytest.mark.long
def test_a_copied_store_is_the_store_mlflow_makes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(new_store.CACHE_ENV, str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    by_mlflow = tmp_path / "a" / "mlflow.db"
    by_mlflow.parent.mkdir()
    MlflowClient(f"sqlite:///{by_mlflow}").search_experiments()
    copied = tmp_path / "b" / "mlflow.db"
    copied.parent.mkdir()
    assert new_store.make(copied)
    assert new_store.template_path().is_file()
    assert _schema(copied) == _schema(by_mlflow)
    # MLflow reads and writes the copy.
    client = MlflowClient(f"sqlite:///{copied}")
    run = client.create_run("0")
    client.log_metric(run.info.run_id, "x", 1.0)
    assert client.get_run(run.info.run_id).data.metrics == {"x": 1.0}


@pytest.mark.long
def test_the_template_is_made_once_and_copied_after(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv(new_store.CACHE_ENV, str(tmp_path / "cache"))
    assert new_store.make(tmp_path / "one.db")
    made = new_store.template_path().stat().st_mtime_ns
    assert new_store.make(tmp_path / "two.db")
    assert new_store.template_path().stat().st_mtime_ns == made
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache", "one.db", "two.db"]


@pytest.mark.long
def test_a_cache_that_cannot_be_written_leaves_the_store_to_mlflow_made_beside_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """MLflow makes the store under another name and it is renamed into place whole: a client
    that opens it meanwhile (a test polling a starting run) never migrates it a second time."""
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("")
    monkeypatch.setenv(new_store.CACHE_ENV, str(blocker / "cache"))
    made = tmp_path / "made" / "mlflow.db"
    made.parent.mkdir()
    made.with_name("mlflow.db.new").write_text("left by a process that died")
    assert new_store.make(made)
    assert sorted(p.name for p in made.parent.iterdir()) == ["mlflow.db"]
    reference = tmp_path / "reference" / "mlflow.db"
    MlflowClient(f"sqlite:///{reference}").search_experiments(max_results=1)
    assert _schema(made) == _schema(reference)
    runs = tmp_path / "runs"
    cfg = compose_config([f"tracking.runs_dir={runs}"])
    stage_runs.setup(cfg)
    assert (runs / "mlflow.db").is_file()
    assert mlflow.get_tracking_uri() == f"sqlite:///{runs.resolve() / 'mlflow.db'}"
