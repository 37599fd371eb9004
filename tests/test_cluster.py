"""Sweeps on real clusters and a real team server, each in a network namespace of its own
(`tests.scale_scenarios`): Ray (head + one worker node), submitit's local executor, an
`mlflow server` on PostgreSQL, and a worker SIGKILLed in the middle of a pipeline sweep.

Slow (minutes on 2 cores) and root-only (``unshare --net``); ``nox -s scale`` runs them.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import sys
from pathlib import Path
from typing import Any

import pytest

from armexp.config import compose_config
from armexp.stages.pipeline import tune_steps
from tests.cluster import in_netns
from tests.scale_scenarios import PIPELINE, summary

ROOT = Path(__file__).resolve().parents[1]

pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        os.geteuid() != 0 or shutil.which("unshare") is None,
        reason="needs root and unshare for a private network namespace",
    ),
]


NEEDS = {"ray": ("hydra_plugins.hydra_ray_launcher", "psycopg2"),
         "optuna": ("hydra_plugins.hydra_ray_launcher", "psycopg2", "optuna"),
         "submitit": ("hydra_plugins.hydra_submitit_launcher",),
         "server": ("psycopg2",),
         "fault": ("hydra_plugins.hydra_ray_launcher", "psycopg2")}  # fmt: skip


def _scenario(name: str, tmp_path: Path, timeout: float = 1500) -> dict[str, Any]:
    for module in NEEDS[name]:
        pytest.importorskip(module, reason="armexp[cluster] is not installed")
    work = tmp_path / name
    path = os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])
    env = {**os.environ, "PYTHONPATH": path}
    res = in_netns([sys.executable, "-m", "tests.scale_scenarios", name, str(work)], timeout,
                   cwd=ROOT, env=env, capture_output=True, text=True)  # fmt: skip
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-5000:]
    result: dict[str, Any] = json.loads((work / "result.json").read_text())
    print("\n".join(summary(name, result)))
    return result


def _sweep_points(runs: list[dict[str, Any]], stage: str) -> tuple[dict, list[dict]]:
    (sweep,) = [r for r in runs if r["stage"] == "sweep"]
    return sweep, [r for r in runs if r["stage"] == stage and r["parent"] == sweep["id"]]


def _lineage_of_simulate_sweep(result: dict[str, Any]) -> None:
    (sweep_cmd,) = result["sweeps"]
    assert sweep_cmd["rc"] == 0, sweep_cmd["out"]
    sweep, points = _sweep_points(result["runs"], "simulate")
    assert sweep["status"] == "FINISHED"
    assert sorted(r["seed"] for r in points) == ["0", "1", "2", "3"]
    assert all(r["status"] == "FINISHED" for r in points)
    assert all(r["armexp.sweep"] == sweep["id"] and r["armexp.git_commit"] for r in points)
    # Each point ran in a process of its own, none of them the driver's.
    pids = {r["armexp.process"] for r in points}
    assert len(pids) == 4 and sweep["armexp.process"] not in pids


def test_a_sweep_on_a_ray_cluster_logs_every_point_to_the_postgres_server(tmp_path: Path) -> None:
    result = _scenario("ray", tmp_path)
    _lineage_of_simulate_sweep(result)
    assert "Connected to Ray cluster" in result["sweeps"][0]["out"]
    assert all(r["artifact_uri"].startswith("mlflow-artifacts:") for r in result["runs"])


def test_a_sweep_through_submitit_pickles_and_logs_every_point(tmp_path: Path) -> None:
    result = _scenario("submitit", tmp_path)
    _lineage_of_simulate_sweep(result)
    assert "Submitit 'local' sweep output dir" in result["sweeps"][0]["out"]


def test_a_pipeline_sweep_against_mlflow_server_on_postgresql(tmp_path: Path) -> None:
    result = _scenario("server", tmp_path)
    (cmd,) = result["sweeps"]
    assert cmd["rc"] == 0, cmd["out"]
    runs = result["runs"]
    sweep, pipelines = _sweep_points(runs, "pipeline")
    assert sweep["status"] == "FINISHED" and len(pipelines) == 2
    counts = {s: sum(r["stage"] == s for r in runs) for s in ("tune", "train", "eval", "report")}
    assert counts == {"tune": 4, "train": 2, "eval": 2, "report": 2}
    by_id = {r["id"]: r for r in runs}
    for run in runs:
        assert run["status"] == "FINISHED"
        if run["stage"] in ("tune", "train", "eval", "report"):
            assert by_id[run["parent"]]["stage"] == "pipeline"  # nested under its pipeline
            assert run["armexp.sweep"] == sweep["id"]
        assert run["artifact_uri"].startswith("mlflow-artifacts:")


def test_a_worker_killed_mid_sweep_is_failed_with_a_reason_and_reuse_completes_it(
    tmp_path: Path,
) -> None:
    result = _scenario("fault", tmp_path)
    first, second = result["sweeps"]
    killed = result["killed"]
    assert killed, "no pipeline run was caught between stages"
    assert first["rc"] == 1
    lost = re.findall(r"sweep job #\d \(([^)]*)\) was lost: The worker died", first["out"])
    assert lost and f"seed={killed['seed']}" in lost[-1].split()
    before = result["runs_after_first"]
    sweep1, points1 = _sweep_points(before, "pipeline")
    assert sweep1["status"] == "FAILED" and len(points1) == 4
    assert sweep1["armexp.error"] == "a job failed: 1 of its 4 jobs did not finish"
    status = {r["seed"]: r["status"] for r in points1}
    assert status == {s: ("FAILED" if s == killed["seed"] else "FINISHED") for s in "0123"}
    dead = next(r for r in points1 if r["seed"] == killed["seed"])
    assert dead["armexp.error"] == f"process stopped: {dead['armexp.process']} is gone"
    # Nothing stays RUNNING: the killed point's stage runs ended with it, with the reason.
    assert not [r for r in before if r["status"] == "RUNNING"]
    stopped = [r for r in before if r["status"] != "FINISHED" and r["stage"] != "sweep"]
    # The point's pipeline run, and the stage run it was in when the kill came after that run
    # was made (maybe before its params were logged)
    assert dead in stopped and len(stopped) <= 2
    assert all(r["parent"] == dead["id"] for r in stopped if r is not dead)
    assert all(r["armexp.error"] == dead["armexp.error"] for r in stopped)
    # The re-run: all four points FINISHED, and only the killed point's missing stages ran.
    assert second["rc"] == 0, second["out"]
    runs = result["runs"]
    sweep2 = next(r for r in runs if r["stage"] == "sweep" and r["id"] != sweep1["id"])
    points2 = [r for r in runs if r["stage"] == "pipeline" and r["parent"] == sweep2["id"]]
    assert sweep2["status"] == "FINISHED"
    assert sorted((r["seed"], r["status"]) for r in points2) == [(s, "FINISHED") for s in "0123"]
    fresh = [r for r in runs if r["armexp.sweep"] == sweep2["id"]
             and r["stage"] in ("tune", "train", "eval")]  # fmt: skip
    assert fresh and {r["seed"] for r in fresh} == {killed["seed"]}
    for point in points2:
        reused = set(point["reused"])
        if point["seed"] == killed["seed"]:
            assert "eval" not in reused and "tune" in reused
        else:
            assert reused == {*tune_steps(compose_config(PIPELINE[1:])), "train", "eval"}


def test_an_optuna_search_runs_its_trials_on_ray_and_keeps_its_study_on_postgresql(
    tmp_path: Path,
) -> None:
    """`hydra/sweeper=optuna` through the Ray launcher, MLflow on PostgreSQL: every trial's seeds
    are train runs under its trial run under one HPO run, the study sits in the server's
    ``mlflow_optuna``, and the same command with n_trials=3 runs exactly one more trial."""
    result = _scenario("optuna", tmp_path)
    assert [c["rc"] for c in result["sweeps"]] == [0, 0], result["sweeps"]
    assert "Connected to Ray cluster" in result["sweeps"][0]["out"]
    assert result["storage"].endswith("/mlflow_optuna")
    assert [t["state"] for t in result["trials"]] == ["COMPLETE"] * 3
    params = [tuple(t["params"].items()) for t in result["trials"]]
    assert len(set(params)) == 3  # the resumed command drew values of its own
    runs = result["runs"]
    (hpo,) = [r for r in runs if r["stage"] == "hpo"]
    trials = [r for r in runs if r["stage"] == "trial"]
    assert len(trials) == 3 and {t["parent"] for t in trials} == {hpo["id"]}
    trains = [r for r in runs if r["stage"] == "train"]
    assert sorted(r["seed"] for r in trains) == ["0", "0", "0", "1", "1", "1"]
    assert {r["parent"] for r in trains} == {t["id"] for t in trials}
    assert all(r["status"] == "FINISHED" for r in [hpo, *trials, *trains])
    # The train jobs ran in Ray's worker processes, not in the command's (the HPO run's).
    assert hpo["armexp.process"] not in {r["armexp.process"] for r in trains}
