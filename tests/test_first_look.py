"""What a user meets first: the experiment opens on its runs table in the MLflow UI, runs are named
by what they are, and a pipeline's terminal output fits on one screen without warnings."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from armexp.cli import main
from armexp.tracking.stage_runs import setup
from armexp.tracking.tags import KIND, KIND_TAG
from tests.helpers import SMALL_TRAIN, SMALL_TUNE, stage_runs

ROOT = Path(__file__).resolve().parents[1]
KIND_TAGS = {KIND_TAG: KIND}


def _names(runs: Path, stage: str) -> list[str]:
    return [r.info.run_name for r in stage_runs(runs, stage, newest_first=False)]


def _armexp(args: list[str], cwd: Path, **env: str) -> subprocess.CompletedProcess[str]:
    """``python -m armexp`` as a user runs it: its own process, this checkout's code."""
    path = os.pathsep.join([str(ROOT), *filter(None, [os.environ.get("PYTHONPATH")])])
    environ = {**os.environ, "PYTHONPATH": path, **env}
    environ.pop("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", None)  # armexp's own default applies
    return subprocess.run([sys.executable, "-m", "armexp", *args], cwd=cwd, env=environ,
                          capture_output=True, text=True, timeout=900)  # fmt: skip


@pytest.mark.slow
def test_a_pipeline_fits_on_one_screen_with_one_line_per_stage(tmp_path: Path) -> None:
    """From a fresh runs/ folder, with warnings shown as a developer's Python shows them: every
    stage prints one summary line naming its run, the pipeline names its report, and nothing
    else reaches the terminal (no warnings, download bars or log records)."""
    small = [*SMALL_TUNE, *SMALL_TRAIN, "tasks.n_random=1", "seed=2", "tuner.seed=1"]
    done = _armexp(["pipeline", "experiment=smoke", *small], tmp_path, PYTHONWARNINGS="default")
    out = done.stdout + done.stderr
    assert done.returncode == 0, out[-3000:]
    lines = out.splitlines()
    assert len(lines) <= 40, out
    for noise in ("Warning", "warning", "Traceback", "Downloading artifacts", "INFO"):
        assert noise not in out, out
    runs = tmp_path / "runs"
    (parent,) = stage_runs(runs, "pipeline")
    for stage in ("tune", "train", "eval", "report"):
        ids = [r.info.run_id for r in stage_runs(runs, stage, newest_first=False)]
        summaries = [line for line in lines if line.startswith(f"{stage}: run ")]
        assert [line.split()[2] for line in summaries] == ids, out
    assert lines[-1].startswith(f"pipeline: run {parent.info.run_id} |"), out
    assert lines[-1].endswith(str(runs.resolve() / "report" / "index.html")), out
    # Each stage's run is named by what it is (simulate runs: the next test).
    assert _names(runs, "pipeline") == ["pipeline-s2"]
    assert _names(runs, "tune") == [
        "tune-subsystem_adaptive-itae-s1", "tune-pid-gaing-s1", "tune-pid-itae-s1",
        "tune-computed_torque-itae-s1", "tune-subsystem_adaptive-gaing-s1",
    ]  # fmt: skip
    assert _names(runs, "train") == ["train-sac_smoke-s2"]
    assert _names(runs, "eval") == ["eval-sac_smoke-s2"]
    assert _names(runs, "report") == ["report"]


@pytest.mark.long
def test_the_experiment_is_marked_classic_ml_and_runs_are_named_by_what_they_are(
    tmp_path: Path,
) -> None:
    """The experiment's kind in a real store, and simulate runs named by controller, scenario
    and seed unless the user names them (the pipeline's stages: the test above)."""
    runs = tmp_path / "runs"
    assert main(["simulate", "scenario.duration=0.05", f"tracking.runs_dir={runs}"]) == 0
    assert main(["simulate", "scenario.duration=0.05", "controller=pid", "scenario=hold",
                 "seed=3", "simulate.run_name=mine", f"tracking.runs_dir={runs}"]) == 0  # fmt: skip
    assert _names(runs, "simulate") == ["simulate-subsystem_adaptive-switching-s0", "mine"]
    experiment = MlflowClient(f"sqlite:///{runs}/mlflow.db").get_experiment_by_name("armexp")
    assert experiment is not None and experiment.tags.items() >= KIND_TAGS.items()


@pytest.mark.long
def test_a_sweep_names_its_jobs_by_the_values_it_varies(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    where = f"tracking.runs_dir={runs}"
    assert main(["tune", "-m", "controller=pid", "tuner.seed=0,1", "tuner.pa=0.1,0.3",
                 *SMALL_TUNE, "tune.progress=false", where]) == 0  # fmt: skip
    assert _names(runs, "sweep") == ["sweep-tune"]
    # tuner.seed shows as s<seed> already; the other swept key is added.
    assert _names(runs, "tune") == [
        "tune-pid-itae-s0-tuner.pa=0.1",
        "tune-pid-itae-s0-tuner.pa=0.3",
        "tune-pid-itae-s1-tuner.pa=0.1",
        "tune-pid-itae-s1-tuner.pa=0.3",
    ]


@pytest.mark.long
def test_the_kind_is_added_to_an_older_experiment_and_a_users_kind_stays(
    tmp_path: Path,
) -> None:
    from armexp.config import compose_config

    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(uri)
    older = client.create_experiment("older", artifact_location=str(tmp_path / "a"))
    theirs = client.create_experiment("theirs", artifact_location=str(tmp_path / "b"))
    client.set_experiment_tag(theirs, KIND_TAG, "genai_development")
    for name in ("older", "theirs"):
        setup(compose_config([f"tracking.uri={uri}", f"tracking.experiment={name}"]))
    assert client.get_experiment(older).tags[KIND_TAG] == KIND
    assert client.get_experiment(theirs).tags[KIND_TAG] == "genai_development"


DOWNLOAD = """
import mlflow, subprocess, sys
mlflow.set_tracking_uri(sys.argv[1])
mlflow.artifacts.download_artifacts(run_id=sys.argv[2], artifact_path="a.txt", dst_path=sys.argv[3])
"""


@pytest.mark.long
@pytest.mark.parametrize("how", ["without armexp", "armexp", "a process armexp started"])
def test_artifact_downloads_show_no_progress_bar_once_armexp_is_imported(
    tmp_path: Path, how: str
) -> None:
    """MLflow draws a bar for every download (on stderr, terminal or not) unless told otherwise;
    importing armexp tells it, for that process and for those it starts. Without armexp the bar
    shows, so the check can see it."""
    uri = f"sqlite:///{tmp_path}/mlflow.db"
    client = MlflowClient(uri)
    experiment = client.create_experiment("e", artifact_location=(tmp_path / "art").as_uri())
    run_id = client.create_run(experiment).info.run_id
    (tmp_path / "a.txt").write_text("a")
    client.log_artifact(run_id, str(tmp_path / "a.txt"))
    code = {
        "without armexp": DOWNLOAD,
        "armexp": "import armexp\n" + DOWNLOAD,
        "a process armexp started": "import armexp, subprocess, sys\n"
        f"subprocess.run([sys.executable, '-c', {DOWNLOAD!r}, *sys.argv[1:]], check=True)",
    }[how]
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    env.pop("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", None)
    done = subprocess.run([sys.executable, "-c", code, uri, run_id, str(tmp_path / "dst")],
                          env=env, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert ("Downloading artifacts" in done.stderr) == (how == "without armexp"), done.stderr
