"""The command line: Hydra's flags and overrides told apart, every sweep job checked before any
runs, and what a stage's run returns."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
import yaml

from armexp.cli import main, split_args
from armexp.tracking.stage_runs import StageResult
from armexp.tracking.sweeps import fixed_overrides, sweep_combinations
from tests.helpers import config_dir_with_my_arm, stage_runs


def test_flags_and_overrides_are_told_apart_by_hydras_grammar() -> None:
    line = split_args(["a=1", "--cfg", "job", "-m", "b=2,3", "--info", "-cd", "d", "~c", "+e=4"])
    assert line.overrides == ["a=1", "b=2,3", "~c", "+e=4"]
    assert line.flags == ["--cfg", "job", "-m", "--info", "-cd", "d"]
    assert line.multirun and line.shows_config and line.runs_no_job
    assert line.config_dirs() == ["d"]
    assert split_args(["--config-dir=e"]).config_dirs() == ["e"]


def test_sweeps_expand_like_hydras_basic_sweeper() -> None:
    args = ["x=1,2", "y=range(0,3)", "z=choice(a,b)", "w=[1,2]", "hydra/launcher=joblib"]
    jobs = sweep_combinations(args)
    assert len(jobs) == 2 * 3 * 2
    assert jobs[0] == ["x=1", "y=0", "z=a", "w=[1,2]"] and jobs[-1] == [
        "x=2",
        "y=2",
        "z=b",
        "w=[1,2]",
    ]
    assert fixed_overrides(["x=1,2", "w=[1,2]", "hydra.launcher.n_jobs=2"]) == ["w=[1,2]"]
    # An interval is for an optimising sweeper to sample: left to it.
    assert sweep_combinations(["x=interval(0,1)", "y=1"]) == [["y=1"]]


@pytest.mark.long
def test_a_bad_value_at_sweep_combination_67_stops_the_sweep_before_any_job(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Two axes: a1 (outer) and seed (inner, 33 values), so a1=-2 first appears in job 67."""
    args = ["controller.gains.a1=1,2,-2", "seed=range(0,33)", f"tracking.runs_dir={runs_dir}"]
    jobs = sweep_combinations(args)
    first_bad = next(i for i, job in enumerate(jobs, 1) if "controller.gains.a1=-2" in job)
    assert len(jobs) == 99 and first_bad == 67
    rc = main(["simulate", "-m", *args, "hydra/launcher=joblib"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and err == [
        "armexp simulate: controller.gains.a1=-2.0 is not allowed: it must be a number > 0."
    ]
    assert not (runs_dir / "mlflow.db").exists() and not (runs_dir / "hydra").exists()


def test_a_malformed_override_is_one_sentence(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "-m", "robot.lengths=[1,"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "robot.lengths=[1, is not a valid override" in err[0]


def test_cfg_job_with_flags_between_overrides(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "robot=three_link", "--cfg", "job", "seed=3"]) == 0
    cfg = yaml.safe_load(capsys.readouterr().out)
    assert cfg["robot"]["name"] == "three_link" and cfg["seed"] == 3


@pytest.mark.long
def test_a_stages_help_is_hydras_and_checks_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main(["simulate", "--help"]) == 0
    out = capsys.readouterr().out
    assert "== Configuration groups ==" in out
    assert "controller: computed_torque, computed_torque_schema, pid" in out
    assert list(tmp_path.iterdir()) == []  # no runs folder made


@pytest.mark.long
def test_a_config_dir_is_seen_by_the_check_of_every_sweep_job(
    runs_dir: Path, tmp_path: Path
) -> None:
    conf = config_dir_with_my_arm(tmp_path)
    where = f"tracking.runs_dir={runs_dir}"
    rc = main(["simulate", "-m", "-cd", str(conf), "robot=my_arm", "seed=0,1",
               "scenario=hold", "scenario.duration=0.05", where])  # fmt: skip
    assert rc == 0
    runs = stage_runs(runs_dir, "simulate")
    assert sorted(r.data.params["seed"] for r in runs) == ["0", "1"]
    assert {r.data.params["robot.name"] for r in runs} == {"my_arm"}


@pytest.mark.long
@pytest.mark.parametrize(
    ("where", "said"),
    [("setup", "no run was started."), ("build_plant", "the MLflow run is marked KILLED.")],
)
def test_an_interrupt_says_whether_a_run_was_started(
    where: str,
    said: str,
    runs_dir: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:

    def stop(*args: Any, **kwargs: Any) -> Any:
        raise KeyboardInterrupt

    where_module = "armexp.tracking.stage_runs" if where == "setup" else "armexp.stages.simulate"
    monkeypatch.setattr(f"{where_module}.{where}", stop)
    rc = main(["simulate", "scenario.duration=0.05", f"tracking.runs_dir={runs_dir}"])
    assert rc == 130
    assert capsys.readouterr().err.strip().endswith(f"interrupted; {said}")
    if where == "build_plant":
        (run,) = stage_runs(runs_dir, "simulate")
        assert run.info.status == "KILLED"


def test_a_stage_returns_its_run_id_and_summary(compose: Any, runs_dir: Path) -> None:
    from armexp.stages import simulate

    result = simulate.run(compose("scenario=hold", "scenario.duration=0.05"))
    assert isinstance(result, StageResult)
    (run,) = stage_runs(runs_dir, "simulate")
    assert result.run_id == run.info.run_id
    assert result.summary["n_steps"] == run.data.metrics["n_steps"] == 50
