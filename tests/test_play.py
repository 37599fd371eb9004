"""Animations in the stages: `armexp eval` animates the paper tasks, `armexp play` a policy on
chosen tasks and targets; both log GIF and MP4 artifacts to a real MLflow store."""

from __future__ import annotations

from pathlib import Path

import mlflow
import numpy as np
import pandas as pd
import pytest
from mlflow.tracking import MlflowClient
from PIL import GifImagePlugin, Image

from armexp.cli import main
from armexp.render.animation import frame_rows
from tests.helpers import pid_baseline, stage_runs


def _download(store: Path, run_id: str, path: str, dst: Path) -> Path:
    mlflow.set_tracking_uri(f"sqlite:///{store}/mlflow.db")
    return Path(
        mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path=path, dst_path=str(dst))
    )


def _listed(store: Path, run_id: str, folder: str) -> set[str]:
    client = MlflowClient(f"sqlite:///{store}/mlflow.db")
    return {Path(f.path).name for f in client.list_artifacts(run_id, folder)}


def _frames(gif: Path) -> int:
    with Image.open(gif) as image:
        assert isinstance(image, GifImagePlugin.GifImageFile)
        return int(image.n_frames)


@pytest.mark.long
def test_eval_animates_each_paper_task_for_every_label(store: Path, tmp_path: Path) -> None:
    (ev,) = stage_runs(store, "eval")
    for label in ("adaptive", "adaptive_off", pid_baseline()):
        names = _listed(store, ev.info.run_id, f"animations/{label}")
        assert names == {f"{task}.{fmt}" for task in "abcd" for fmt in ("gif", "mp4")}
        gif = _download(store, ev.info.run_id, f"animations/{label}/b.gif", tmp_path / label)
        trajectory = pd.read_parquet(
            _download(store, ev.info.run_id, f"trajectories/{label}/b.parquet", tmp_path / label)
        )
        assert _frames(gif) == len(frame_rows(trajectory.t.to_numpy()))


@pytest.mark.long
def test_play_animates_a_task_and_an_extra_target_in_a_play_run(
    store: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    where = f"tracking.runs_dir={store}"
    assert main(["play", "play.tasks=[c]", "play.targets=[[1.2,0.5]]", where]) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    run = stage_runs(store, "play")[0]
    (train,) = stage_runs(store, "train")
    assert run.info.status == "FINISHED"
    assert run.data.tags["armexp.train_run"] == train.info.run_id
    preset = train.data.tags["armexp.agent_preset"]
    # What it is, at a glance: the policy's own controller when play.controller is not given.
    assert run.info.run_name == f"play-{preset}-adaptive-s0"
    assert run.data.params["play.controller"] == "adaptive"
    assert line.startswith(f"play: run {run.info.run_id} | adaptive")
    folder = Path(line.rsplit(" in ", 1)[1])
    assert sorted(p.name for p in folder.iterdir()) == [
        "c.gif", "c.mp4", "target_0.gif", "target_0.mp4"
    ]  # fmt: skip
    episodes = pd.read_csv(_download(store, run.info.run_id, "episodes.csv", tmp_path))
    assert list(episodes.task) == ["c", "target_0"]
    assert episodes.target_x.tolist()[1] == 1.2 and episodes.target_y.tolist()[1] == 0.5
    # Task (c) is the episode eval measured: same policy, gains, target and seed.
    (ev,) = stage_runs(store, "eval")
    played = pd.read_parquet(
        _download(store, run.info.run_id, "trajectories/adaptive/c.parquet", tmp_path / "p")
    )
    evaluated = pd.read_parquet(
        _download(store, ev.info.run_id, "trajectories/adaptive/c.parquet", tmp_path / "e")
    )
    np.testing.assert_array_equal(played.to_numpy(), evaluated.to_numpy())
    assert _frames(folder / "c.gif") == len(frame_rows(played.t.to_numpy()))


@pytest.mark.long
def test_play_with_a_baseline_writes_only_the_formats_asked_for(store: Path) -> None:
    where = f"tracking.runs_dir={store}"
    pid = pid_baseline()
    command = ["play", f"play.controller={pid}", "play.tasks=[a]", "play.formats=[gif]", where]
    assert main(command) == 0
    run = stage_runs(store, "play")[0]
    assert _listed(store, run.info.run_id, f"animations/{pid}") == {"a.gif"}
    pid_tune = next(
        r for r in stage_runs(store, "tune") if r.data.params["controller.name"] == "pid"
    )
    assert run.data.tags[f"armexp.tune_run.{pid}"] == pid_tune.info.run_id


@pytest.mark.long
def test_play_with_the_ablation_plays_the_episode_eval_measured(
    store: Path, tmp_path: Path
) -> None:
    where = f"tracking.runs_dir={store}"
    command = ["play", "play.controller=adaptive_off", "play.tasks=[d]", "play.formats=[gif]"]
    assert main([*command, where]) == 0
    run = stage_runs(store, "play")[0]
    (ev,) = stage_runs(store, "eval")
    path = "trajectories/adaptive_off/d.parquet"
    played = pd.read_parquet(_download(store, run.info.run_id, path, tmp_path / "p"))
    evaluated = pd.read_parquet(_download(store, ev.info.run_id, path, tmp_path / "e"))
    np.testing.assert_array_equal(played.to_numpy(), evaluated.to_numpy())
    assert (played.rho_hat == 0).all()


@pytest.mark.long
@pytest.mark.parametrize(
    ("override", "says"),
    [
        ("play.tasks=[e]", "play.tasks contains e, which is not allowed"),
        ("play.targets=[[0.5,1.3]]", "inside obstacles.circles[0]"),
        ("play.targets=[[2.5,0]]", "outside the arm's reach"),
        # In reach and clear of the obstacles, but not within the joint limits' workspace.
        ("play.targets=[[-1.2,-0.6]]", "the policy's environment draws no target within"),
        ("play.controller=foo", "play.controller='foo' is not allowed: choose the policy's own"),
        # A label of another policy's own controller: this policy was trained with the adaptive law.
        ("play.controller=pid", "play.controller=pid is not allowed: the policy of train run"),
    ],
)
def test_bad_play_input_is_one_sentence_and_starts_no_run(
    store: Path, override: str, says: str, capsys: pytest.CaptureFixture[str]
) -> None:
    before = len(stage_runs(store, "play"))
    assert main(["play", override, f"tracking.runs_dir={store}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and says in err, err
    assert len(stage_runs(store, "play")) == before
