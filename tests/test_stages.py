"""The CLI and the stages against a real MLflow store in tmp_path."""

from __future__ import annotations

import itertools
import os
import subprocess
import sys
from pathlib import Path

import mlflow
import numpy as np
import pandas as pd
import pytest
import yaml
from mlflow.tracking import MlflowClient

from armexp.cli import main
from tests.helpers import config_dir_with_my_arm, stage_runs


def sqlite_uri(runs_dir: Path) -> str:
    return f"sqlite:///{runs_dir}/mlflow.db"


def _runs(runs_dir: Path, stage: str) -> list[mlflow.entities.Run]:
    return stage_runs(runs_dir, stage)


def _artifact(run: mlflow.entities.Run, path: str, runs_dir: Path, tmp: Path) -> Path:
    mlflow.set_tracking_uri(sqlite_uri(runs_dir))
    return Path(
        mlflow.artifacts.download_artifacts(
            run_id=run.info.run_id, artifact_path=path, dst_path=str(tmp)
        )
    )


def test_help_lists_every_stage(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for stage in ("tune", "train", "eval", "report", "pipeline", "simulate"):
        assert stage in out
    assert "not built yet" not in out


def test_unknown_stage_exits_2(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["fly"]) == 2
    assert "stage=fly is not a known stage" in capsys.readouterr().err


@pytest.mark.long
def test_bad_value_exits_2_with_one_line_and_no_traceback(tmp_path: Path) -> None:
    res = subprocess.run(
        [
            sys.executable,
            "-m",
            "armexp",
            "simulate",
            "controller.gains.a0=-1",
            f"tracking.runs_dir={tmp_path}",
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ},
    )
    assert res.returncode == 2
    assert "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.strip()]
    assert lines == [
        "armexp simulate: controller.gains.a0=-1.0 is not allowed: it must be a number > 0."
    ]
    assert not (tmp_path / "mlflow.db").exists()


def test_cfg_job_prints_the_composed_config(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["simulate", "--cfg", "job", "robot=three_link"]) == 0
    cfg = yaml.safe_load(capsys.readouterr().out)
    assert cfg["robot"]["name"] == "three_link" and "hydra" not in cfg


def test_simulate_logs_a_finished_run_with_trajectory(runs_dir: Path, tmp_path: Path) -> None:
    rc = main(
        [
            "simulate",
            "scenario=hold",
            "scenario.duration=0.3",
            "seed=4",
            "robot.torque_limit=null",  # the paper's gains need ~120 kN.m for this offset
            f"tracking.runs_dir={runs_dir}",
        ]
    )
    assert rc == 0
    (run,) = _runs(runs_dir, "simulate")
    assert run.info.status == "FINISHED"
    assert run.data.params["robot.lengths"] == "[1.0, 0.8]"
    assert run.data.params["controller.gains.a0"] == "668.0"
    assert run.data.params["seed"] == "4"
    m = run.data.metrics
    assert m["diverged"] == 0.0 and m["n_steps"] == 300
    assert m["convergence_time"] < 0.1  # 0.05 rad offset removed by the paper's gains
    df = pd.read_parquet(_artifact(run, "trajectory.parquet", runs_dir, tmp_path))
    assert list(df.columns) == [
        "t",
        "q_1",
        "q_2",
        "q_d_1",
        "q_d_2",
        "dq_1",
        "dq_2",
        "dq_d_1",
        "dq_d_2",
        "tau_1",
        "tau_2",
        "rho_hat",
        "tip_x",
        "tip_y",
        "sat_1",
        "sat_2",
    ]
    assert not df.sat_1.any() and not df.sat_2.any()  # no limit: never saturated
    assert len(df) == 300 and np.allclose(np.diff(df.t), 0.001)
    assert np.isclose(df.q_1[0] - df.q_d_1[0], 0.05)
    cfg = yaml.safe_load(_artifact(run, "config.yaml", runs_dir, tmp_path).read_text())
    assert cfg["scenario"]["kind"] == "hold"


@pytest.mark.long
def test_multirun_sweep_makes_one_run_per_job(runs_dir: Path) -> None:
    rc = main(
        ["simulate", "-m", "seed=0,1", "scenario.duration=0.06", f"tracking.runs_dir={runs_dir}"]
    )
    assert rc == 0
    runs = _runs(runs_dir, "simulate")
    assert sorted(r.data.params["seed"] for r in runs) == ["0", "1"]
    assert all(r.info.status == "FINISHED" for r in runs)
    assert (runs_dir / "hydra" / "multirun").is_dir()


@pytest.mark.long
def test_tune_stage_logs_history_gains_and_artifacts(runs_dir: Path, tmp_path: Path) -> None:
    rc = main(
        [
            "tune",
            "tuner=cso_fast",
            "tuner.n_iterations=6",
            "tuner.objective.n_scenarios=2",
            "tuner.objective.horizon=0.2",
            f"tracking.runs_dir={runs_dir}",
        ]
    )
    assert rc == 0
    (run,) = _runs(runs_dir, "tune")
    assert run.info.status == "FINISHED"
    client = MlflowClient(sqlite_uri(runs_dir))
    history = client.get_metric_history(run.info.run_id, "best_objective")
    values = [m.value for m in sorted(history, key=lambda m: m.step)]
    assert [m.step for m in sorted(history, key=lambda m: m.step)] == list(range(1, 7))
    assert all(b <= a for a, b in itertools.pairwise(values))
    m = run.data.metrics
    assert m["n_evaluations"] == 8 * (1 + 2 * 6)
    assert m["best_objective"] == values[-1] <= m["objective_config_gains"]
    assert (
        m["objective_paper_gains"] == m["objective_config_gains"]
    )  # default gains are the paper's
    assert m["wall_time_s"] > 0
    gains = yaml.safe_load(_artifact(run, "gains.yaml", runs_dir, tmp_path).read_text())
    assert set(gains) == {"a0", "a1", "b1", "c1", "r1"}
    for k, v in gains.items():
        assert float(run.data.params[f"tuned.{k}"]) == pytest.approx(v)
    # The search coordinates (a0, a1, λ = c1 r1, γ = b1² c1) lie in the box.
    coordinates = {
        "a0": gains["a0"], "a1": gains["a1"], "lambda": gains["c1"] * gains["r1"],
        "gamma": gains["b1"] ** 2 * gains["c1"],
    }  # fmt: skip
    for k, v in coordinates.items():
        lo, hi = (float(b) for b in yaml.safe_load(run.data.params[f"controller.bounds.{k}"]))
        assert lo <= v * (1 + 1e-12) and v <= hi * (1 + 1e-12), k
    assert run.data.params["tuner.objective.criterion"] == "itae"
    assert run.data.tags["armexp.criterion"] == "itae"
    assert float(run.data.tags["armexp.horizon"]) == 0.2
    assert m["best_sigma_max"] >= 0
    assert m["best_gain_margin_adapted"] <= m["best_gain_margin"] * (1 + 1e-6)  # bisection
    table = pd.read_csv(_artifact(run, "candidates.csv", runs_dir, tmp_path))
    assert len(table) == m["n_evaluations"]
    assert table.objective.min() == pytest.approx(m["best_objective"])
    assert _artifact(run, "convergence.png", runs_dir, tmp_path).stat().st_size > 1000


@pytest.mark.parametrize(
    ("override", "words"),
    [
        ("controller.bounds.gamma=[2,1]", ["controller.bounds.gamma=[2.0, 1.0]", "lower bound"]),
        ("controller.bounds.gamma=[3,3]", ["controller.bounds.gamma=[3.0, 3.0]", "lower bound"]),
        ("controller.bounds.a0=[0,10]", ["controller.bounds.a0=[0.0, 10.0]", "log space", "> 0"]),
        ("tuner.objective.criterion=foo", ["tuner.objective.criterion='foo'", "gaing, itae, iae"]),
        ("tuner.objective.horizon=0", ["tuner.objective.horizon=0", "> 0, or null"]),
        ("+controller.bounds.b1=[1,2]", ["controller.bounds has b1", "a0, a1, lambda, gamma"]),
    ],
)
def test_tune_bad_box_or_objective_exits_2(
    override: str, words: list[str], runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["tune", override, f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0, err
    for w in words:
        assert w in err, (w, err)


@pytest.mark.slow  # about 25 s; test_cli covers the same check at combination 67
def test_a_bad_value_late_in_a_sweep_stops_it_before_any_job(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    values = ",".join([*(str(v) for v in range(1, 80)), "-1"])  # job 80 is the bad one
    rc = main(["simulate", "-m", f"controller.gains.a0={values}", f"tracking.runs_dir={runs_dir}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "controller.gains.a0=-1" in err[0]
    assert not (runs_dir / "mlflow.db").exists()  # no run, no store


def test_a_config_dir_given_on_the_command_line_is_seen_by_the_pre_run_check(
    runs_dir: Path, tmp_path: Path
) -> None:
    conf = config_dir_with_my_arm(tmp_path)
    rc = main(["simulate", "--config-dir", str(conf), "robot=my_arm", "scenario=hold",
               "scenario.duration=0.05", f"tracking.runs_dir={runs_dir}"])  # fmt: skip
    assert rc == 0
    (run,) = _runs(runs_dir, "simulate")
    assert run.data.params["robot.name"] == "my_arm"
