"""Bad input a user will type is one sentence naming the key, the value and what is allowed, exit
code 2, and no MLflow run: launchers, empty task lists, values that would not fit in memory, and
MLflow filters."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from mlflow.tracking import MlflowClient

from armexp.cli import main
from armexp.tracking import stage_runs

SIM = ["simulate", "-m", "seed=0,1", "scenario=hold", "scenario.duration=0.05"]


def one_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def stub_stage(monkeypatch: pytest.MonkeyPatch, module: str) -> list[Any]:
    """Replace a stage's ``run`` by one that records its config: a check that lets a value
    through shows as a call, without running the stage."""
    import importlib

    calls: list[Any] = []

    def run(cfg: Any) -> stage_runs.StageResult:
        calls.append(cfg)
        return stage_runs.StageResult("stub", {})

    monkeypatch.setattr(importlib.import_module(module), "run", run)
    return calls


# ------------------------------------------------------------------------------- launchers
@pytest.mark.long
@pytest.mark.parametrize(
    ("launcher", "said"),
    [
        (["hydra/launcher=foo"], "hydra/launcher=foo is not a known option; choose one of: "),
        (
            ["hydra.launcher.n_jobs=0"],
            "hydra.launcher.n_jobs=0 is not allowed: the launcher hydra/launcher=basic has no "
            "setting n_jobs",
        ),
        (
            ["hydra/launcher=parallel", "hydra.launcher.n_jobs=0"],
            "hydra.launcher.n_jobs=0 is not allowed: give how many jobs run at once (1 or more), "
            "or -1 for one per core",
        ),
    ],
)
def test_a_bad_launcher_is_one_sentence_and_leaves_no_sweep_run(
    launcher: list[str], said: str, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([*SIM, *launcher, f"tracking.runs_dir={runs_dir}"]) == 2
    assert one_line(capsys).startswith(f"armexp simulate: {said}")
    assert not (runs_dir / "mlflow.db").exists()


def test_launcher_options_are_listed(runs_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main([*SIM, "hydra/launcher=foo", f"tracking.runs_dir={runs_dir}"]) == 2
    line = one_line(capsys)
    assert all(name in line for name in ("basic", "parallel", "ray", "slurm"))


# ------------------------------------------------------------------------- tasks.targets
@pytest.mark.long
def test_eval_without_task_targets_is_answered_about_tasks_targets(
    runs_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = stub_stage(monkeypatch, "armexp.stages.evaluate")
    where = f"tracking.runs_dir={runs_dir}"
    assert main(["eval", "tasks.targets=[]", where]) == 2
    line = one_line(capsys)
    assert line.startswith("armexp eval: tasks.targets=[] is not allowed: ")
    assert "eval.paper_tasks" in line and "play" not in line
    # Without the paper tasks, eval needs no task targets (play's are not its concern).
    assert main(["eval", "tasks.targets=[]", "eval.paper_tasks=false", where]) == 0
    assert len(calls) == 1


@pytest.mark.long
def test_play_without_task_targets_is_answered_about_tasks_targets(
    runs_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    calls = stub_stage(monkeypatch, "armexp.stages.play")
    where = f"tracking.runs_dir={runs_dir}"
    assert main(["play", "tasks.targets=[]", where]) == 2
    assert one_line(capsys).startswith(
        "armexp play: tasks.targets=[] is not allowed: play.tasks=[a, b, c, d] names tasks of it"
    )
    assert main(["play", "tasks.targets=[]", "play.tasks=[]", "play.targets=[[1.2,0.5]]",
                 where]) == 0  # fmt: skip
    assert len(calls) == 1


# ------------------------------------------------------------------------------- memory
@pytest.mark.parametrize(
    ("stage", "module", "value", "said"),
    [
        ("simulate", "armexp.stages.simulate", "scenario.duration=1e7",
         "scenario.duration=1e7 is not allowed: its 1 kHz trajectory would take about 3.8 TB"),
        ("train", "armexp.stages.train", "agent.buffer_size=100000000000",
         "agent.buffer_size=100000000000 is not allowed: its replay buffer would take about "
         "12.4 TB"),
        ("train", "armexp.stages.train", "agent.n_envs=100000",
         "agent.n_envs=100000 is not allowed: 100000 environments would take about 1.6 GB"),
    ],
)  # fmt: skip
def test_a_value_that_would_not_fit_in_memory_is_one_sentence_before_any_run(
    stage: str,
    module: str,
    value: str,
    said: str,
    runs_dir: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from armexp import resources

    calls = stub_stage(monkeypatch, module)
    monkeypatch.setattr(resources, "available_bytes", lambda: 1_000_000_000)
    assert main([stage, value, "train.gains=config", f"tracking.runs_dir={runs_dir}"]) == 2
    line = one_line(capsys)
    assert line.startswith(f"armexp {stage}: {said}"), line
    assert "1.0 GB of memory available" in line and "give at most" in line
    assert calls == [] and not (runs_dir / "mlflow.db").exists()


def test_the_paper_presets_fit_in_well_under_a_gigabyte() -> None:
    """Table II's buffer of 10^6 transitions of the paper arm among five obstacles: 13
    observation entries (twice: before and after), 2 actions, reward, done and time-out flags,
    each a float32."""
    from armexp import resources
    from armexp.config import compose_config

    paper = compose_config(["experiment=paper"])
    items = {i.key: i for i in resources.estimate(paper, "pipeline")}
    assert items["agent.buffer_size"].bytes == 1_000_000 * (2 * 13 + 2 + 3) * 4
    assert sum(i.bytes for i in items.values()) < 200e6
    assert resources.estimate(paper, "report") == []


# ------------------------------------------------------------------------------ report.filter
def test_a_report_filter_that_is_not_mlflows_syntax_is_one_sentence(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from armexp.config import compose_config

    where = f"tracking.runs_dir={runs_dir}"
    stage_runs.setup(compose_config([where]))  # a store with the experiment, and no runs
    assert main(["report", "report.filter='params.seed = '", where]) == 2
    line = one_line(capsys)
    assert line.startswith("armexp report: report.filter='params.seed = ' is not allowed: ")
    assert "MLflow search filter" in line and "params.seed = '0'" in line
    client = MlflowClient(f"sqlite:///{runs_dir}/mlflow.db")
    (exp,) = [e for e in client.search_experiments() if e.name == "armexp"]
    assert client.search_runs([exp.experiment_id]) == []


@pytest.mark.long
def test_a_sweep_that_stops_before_any_job_leaves_no_sweep_run(
    runs_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Whatever stops Hydra's launcher before a job starts, the sweep run that would group the
    jobs is not left behind (it goes to MLflow's deleted runs)."""
    from hydra._internal.core_plugins.basic_launcher import BasicLauncher
    from mlflow.entities import ViewType

    def broken(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("the launcher broke")

    monkeypatch.setattr(BasicLauncher, "launch", broken)
    assert main([*SIM, f"tracking.runs_dir={runs_dir}"]) == 1
    client = MlflowClient(f"sqlite:///{runs_dir}/mlflow.db")
    experiments = [e.experiment_id for e in client.search_experiments()]
    assert client.search_runs(experiments) == []
    (deleted,) = client.search_runs(experiments, run_view_type=ViewType.DELETED_ONLY)
    assert deleted.data.tags["armexp.stage"] == "sweep"


# ----------------------------------------------------------------------------- store address
@pytest.mark.long
@pytest.mark.parametrize("uri", ["file:./mlruns", "foo://bar", "./some/folder"])
def test_a_tracking_uri_no_store_behind_is_one_sentence(
    uri: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "scenario.duration=0.05", f"tracking.uri={uri}"]) == 2
    line = one_line(capsys)
    assert f"tracking.uri={uri} is not allowed" in line
    assert "sqlite:///" in line and "file store" in line
    assert not (tmp_path / "mlruns").exists()


@pytest.mark.long
def test_a_device_this_machine_lacks_is_one_sentence_before_any_run(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a CUDA device")
    where = f"tracking.runs_dir={tmp_path}"
    args = ["train", "experiment=smoke", "controller.gains=paper", "agent.device=cuda", where]
    assert main(args) == 2
    assert "agent.device=cuda is not allowed here: torch sees no such device" in one_line(capsys)
    client = MlflowClient(f"sqlite:///{tmp_path}/mlflow.db")
    experiments = [e.experiment_id for e in client.search_experiments()]
    assert client.search_runs(experiments) == []


# ---------------------------------------------------------------------------------- budgets
@pytest.mark.parametrize(
    ("budget", "said"),
    [
        (
            ["agent.max_env_steps=null", "agent.max_minutes=null"],
            "armexp train: agent.max_env_steps=null with agent.max_minutes=null is not allowed: "
            "a run needs a budget, agent.max_env_steps ≥ 1 (agent.max_minutes, when set, guards "
            "the wall time beside it).",
        ),
        (
            ["agent.max_env_steps=0"],
            "agent.max_env_steps=0 is not allowed: it must be ≥ 1, or null.",
        ),
    ],
)
def test_a_training_without_a_step_budget_is_one_sentence_and_no_run(
    budget: list[str], said: str, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["train", "experiment=demo", *budget, f"tracking.runs_dir={runs_dir}"]) == 2
    assert said in one_line(capsys)
    assert not (runs_dir / "mlflow.db").exists() or not MlflowClient(
        f"sqlite:///{runs_dir}/mlflow.db"
    ).search_runs(["0"])
