"""armexp pipeline: one parent run, a FINISHED child per stage with lineage, reuse, failure."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from armexp.cli import main
from armexp.config import compose_config, group_options
from tests.helpers import SMALL_TRAIN, interrupt_training_at, stage_runs

SMALL = [
    "experiment=smoke",
    "tuner.n_iterations=2",
    "tuner.objective.n_scenarios=2",
    "tuner.objective.horizon=0.2",
    *SMALL_TRAIN,
    "eval.animations=false",  # the renderer has its own tests
    "tasks.n_random=1",
]


def _runs(runs: Path, stage: str) -> list[Any]:
    return stage_runs(runs, stage, newest_first=False)


@pytest.fixture(scope="module")
def pipeline_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    runs = tmp_path_factory.mktemp("pipe") / "runs"
    assert main(["pipeline", *SMALL, f"tracking.runs_dir={runs}"]) == 0
    return runs


def test_pipeline_makes_one_parent_and_a_finished_child_per_stage(pipeline_store: Path) -> None:
    (parent,) = _runs(pipeline_store, "pipeline")
    assert parent.info.status == "FINISHED"
    pid = parent.info.run_id
    children = {s: _runs(pipeline_store, s) for s in ("tune", "train", "eval", "report")}
    assert [len(children[s]) for s in ("tune", "train", "eval", "report")] == [2, 1, 1, 1]
    for group in children.values():
        for run in group:
            assert run.info.status == "FINISHED"
            assert run.data.tags["mlflow.parentRunId"] == pid
    tunes = {r.data.params["controller.name"]: r.info.run_id for r in children["tune"]}
    (train,), (ev,), (report,) = children["train"], children["eval"], children["report"]
    # Lineage: every child names its upstream runs, all inside this pipeline.
    assert train.data.tags["armexp.tune_run"] == tunes["subsystem_adaptive"]
    assert ev.data.tags["armexp.train_run"] == train.info.run_id
    assert ev.data.tags["armexp.pid_tune_run"] == tunes["pid"]
    assert report.data.tags["armexp.report_runs"] == ev.info.run_id
    assert parent.data.tags["armexp.run.train"] == train.info.run_id
    index = pipeline_store / "report" / "index.html"
    assert index.exists() and ev.info.run_id in index.read_text()


def test_pipeline_reuse_skips_stages_whose_inputs_match(pipeline_store: Path) -> None:
    before = {s: len(_runs(pipeline_store, s)) for s in ("tune", "train", "eval")}
    assert (
        main(["pipeline", *SMALL, "pipeline.reuse=true", f"tracking.runs_dir={pipeline_store}"])
        == 0
    )
    after = {s: len(_runs(pipeline_store, s)) for s in ("tune", "train", "eval")}
    assert after == before
    second = _runs(pipeline_store, "pipeline")[-1]
    first_train = _runs(pipeline_store, "train")[0]
    assert second.data.tags["armexp.reused.train"] == first_train.info.run_id
    assert {"armexp.reused.tune", "armexp.reused.tune_pid", "armexp.reused.eval"} <= set(
        second.data.tags
    )
    # A changed input runs that stage (and everything downstream of it) again.
    assert (
        main(
            [
                "pipeline",
                *SMALL,
                "pipeline.reuse=true",
                "seed=5",
                f"tracking.runs_dir={pipeline_store}",
            ]
        )
        == 0
    )
    assert len(_runs(pipeline_store, "train")) == before["train"] + 1


def test_failing_stage_fails_the_parent_and_names_itself(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from armexp.stages import train

    def bogus(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("bogus value met while training (injected)")

    monkeypatch.setattr(train, "_learn", bogus)
    runs = tmp_path / "runs"
    assert main(["pipeline", *SMALL, f"tracking.runs_dir={runs}"]) == 1
    assert "pipeline: train failed" in capsys.readouterr().out
    (parent,) = _runs(runs, "pipeline")
    assert parent.info.status == "FAILED"
    assert parent.data.tags["armexp.failed_stage"] == "train"
    assert "bogus" in parent.data.tags["armexp.error"]
    (train,) = _runs(runs, "train")
    assert train.info.status == "FAILED"
    assert all(r.info.status == "FINISHED" for r in _runs(runs, "tune"))


@pytest.mark.parametrize("robot", group_options("robot"))
def test_smoke_pipeline_runs_on_every_shipped_robot(tmp_path: Path, robot: str) -> None:
    """Choosing a robot is enough: both controllers get that arm's gains, search box and torque
    limits in every stage, and the eval torques stay within its limits."""
    runs = tmp_path / "runs"
    assert main(["pipeline", *SMALL, f"robot={robot}", f"tracking.runs_dir={runs}"]) == 0
    (parent,) = _runs(runs, "pipeline")
    assert parent.info.status == "FINISHED"
    n = len(compose_config([f"robot={robot}"]).robot.lengths)
    limit = list(compose_config([f"robot={robot}"]).robot.torque_limit)
    tunes = _runs(runs, "tune")
    assert sorted(r.data.params["controller.name"] for r in tunes) == ["pid", "subsystem_adaptive"]
    for run in tunes:
        assert run.data.params["robot.name"] == robot
        assert run.data.metrics["best_gain_margin"] >= 1.25
    (ev,) = _runs(runs, "eval")
    for label in ("adaptive", "pid"):
        for j in range(1, n + 1):
            assert ev.data.metrics[f"{label}.a.max_abs_tau_{j}"] <= limit[j - 1]


def test_reuse_resumes_an_interrupted_train_run_instead_of_starting_over(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    runs = tmp_path / "runs"
    interrupt_training_at(monkeypatch, 450)
    command = ["pipeline", *SMALL, "pipeline.reuse=true", f"tracking.runs_dir={runs}"]
    assert main(command) == 130
    (stopped,) = _runs(runs, "train")
    assert stopped.info.status == "KILLED"
    monkeypatch.undo()  # training runs to its end again
    assert main(command) == 0
    (train,) = _runs(runs, "train")  # the same run, continued, not a second one
    assert train.info.run_id == stopped.info.run_id and train.info.status == "FINISHED"
    assert int(train.data.tags["armexp.resumed_from_step"]) >= 400
    assert train.data.metrics["final/env_steps"] == 600
    second = _runs(runs, "pipeline")[-1]
    assert second.data.tags["armexp.resumed.train"] == train.info.run_id
    (ev,) = _runs(runs, "eval")
    assert ev.data.tags["armexp.train_run"] == train.info.run_id
