"""`armexp eval` and `armexp play` of a given train run: the run's id as armexp prints it (8
characters), the robot and environment the policy ran on recorded as they were, and a train run
whose model is gone refused in one sentence, before any run."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from armexp.cli import main
from tests.helpers import stage_runs
from tests.test_store import fresh

#: A short eval: the paper tasks with the policy's own controller only.
QUICK_EVAL = ["eval", "tasks.n_random=0", "eval.baselines=[]", "eval.ablation=false",
              "eval.animations=false", "eval.large_offset=null", "eval.progress=false"]  # fmt: skip
QUICK_PLAY = ["play", "play.tasks=[d]", "play.formats=[gif]"]


@pytest.mark.long
def test_eval_of_an_8_character_id_records_the_full_id_and_the_policys_robot(
    three_link_train: tuple[Path, str], capsys: pytest.CaptureFixture[str]
) -> None:
    runs, train_id = three_link_train
    fresh()
    assert main([*QUICK_EVAL, f"eval.train_run={train_id[:8]}", f"tracking.runs_dir={runs}"]) == 0
    ev = stage_runs(runs, "eval")[0]
    (train,) = stage_runs(runs, "train")
    assert ev.info.status == "FINISHED"
    assert ev.data.params["eval.train_run"] == train_id
    assert ev.data.tags["armexp.train_run"] == train_id
    # The policy ran on its train run's arm and environment, and the run says so.
    for key in ("robot.name", "robot.lengths", "robot.masses", "env.max_steps", "obstacles.name"):
        assert ev.data.params[key] == train.data.params[key], key
    assert ev.data.params["robot.name"] == "three_link"
    assert "robot=three_link" in capsys.readouterr().out


@pytest.mark.long
def test_play_records_the_policys_robot(three_link_train: tuple[Path, str]) -> None:
    runs, train_id = three_link_train
    fresh()
    assert main([*QUICK_PLAY, f"play.train_run={train_id[:8]}", f"tracking.runs_dir={runs}"]) == 0
    play = stage_runs(runs, "play")[0]
    assert play.data.params["play.train_run"] == train_id
    assert play.data.params["robot.name"] == "three_link"
    assert play.data.params["robot.lengths"] == "[0.8, 0.6, 0.4]"


@pytest.mark.long
@pytest.mark.parametrize("stage", ["eval", "play"])
def test_a_train_run_without_its_model_is_one_sentence_and_no_run(
    stage: str,
    three_link_train: tuple[Path, str],
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
) -> None:
    source, train_id = three_link_train
    runs = tmp_path / "runs"
    shutil.copytree(source, runs)  # a store is a folder: the copy is its own
    shutil.rmtree(runs / "artifacts" / train_id / "artifacts" / "model")
    before = len(stage_runs(runs, stage))
    fresh()
    args = QUICK_EVAL if stage == "eval" else QUICK_PLAY
    assert main([*args, f"{stage}.train_run={train_id}", f"tracking.runs_dir={runs}"]) == 2
    # The copied store says once that it was moved, then the one sentence.
    *moved, said = capsys.readouterr().err.strip().splitlines()
    assert all(line.startswith("armexp: the store ") for line in moved)
    assert said == (
        f"armexp {stage}: {stage}.train_run={train_id} is not allowed: that train run has no "
        "artifact model/model.zip (its final model; it was deleted or never written); train "
        "again, or give another train run."
    )
    assert len(stage_runs(runs, stage)) == before
