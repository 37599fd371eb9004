"""The scale scenarios, each run inside its own network namespace (`tests.cluster.in_netns`):

  python -m tests.scale_scenarios <ray|submitit|server|fault> <work folder>

Each starts what it needs (Ray cluster, PostgreSQL, `mlflow server`), runs armexp sweeps as a user
would (``python -m armexp ...``), reads the store, tears everything down and writes
``<work>/result.json``: per sweep its command's exit code, wall time and output tail, and every
run of the store (stage, status, error, lineage tags). The tests assert on that file; `summary`
turns it into the lines ``nox -s scale`` prints.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from tests.cluster import mlflow_server, postgres, ray_cluster
from tests.helpers import SMALL_TRAIN

SIMULATE = ["simulate", "-m", "seed=0,1,2,3", "scenario.duration=0.5", "robot.torque_limit=null"]
PIPELINE = [
    "pipeline",
    "experiment=smoke",
    "tuner.n_iterations=2",
    "tuner.objective.n_scenarios=2",
    "tuner.objective.horizon=0.2",
    *SMALL_TRAIN,
    "eval.animations=false",
    "tasks.n_random=1",
    "eval.baselines=[pid_gaing]",
]
RAY = ["hydra/launcher=ray", "hydra.launcher.ray.remote.num_cpus=1"]
TAGS = ("armexp.error", "armexp.sweep", "armexp.process",
        "armexp.git_commit", "armexp.inputs_hash", "armexp.failed_stage")  # fmt: skip


def armexp(args: list[str], env: dict[str, str] | None = None, timeout: float = 900) -> dict:
    """One armexp command as a user runs it: exit code, wall time, output tail."""
    start = time.time()
    res = subprocess.run([sys.executable, "-m", "armexp", *args], capture_output=True, text=True,
                         env={**os.environ, **(env or {})}, timeout=timeout)  # fmt: skip
    return {"args": args, "rc": res.returncode, "wall_s": round(time.time() - start, 1),
            "out": res.stdout[-3000:] + res.stderr[-6000:]}  # fmt: skip


def runs_of(uri: str) -> list[dict[str, Any]]:
    """Every run of experiment 'armexp' with what the tests look at."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(uri)
    exp = client.get_experiment_by_name("armexp")
    if exp is None:
        return []
    out = []
    for r in client.search_runs([exp.experiment_id], max_results=5000):
        tags = r.data.tags
        out.append({
            "id": r.info.run_id, "stage": tags.get("armexp.stage"), "status": r.info.status,
            "seed": r.data.params.get("seed"), "artifact_uri": r.info.artifact_uri,
            "start": r.info.start_time,
            "parent": tags.get("mlflow.parentRunId"), **{k: tags.get(k) for k in TAGS},
            "reused": {k.rpartition(".")[2]: v for k, v in tags.items()
                       if k.startswith("armexp.reused.")},
        })  # fmt: skip
    return out


@contextlib.contextmanager
def server(work: Path) -> Iterator[str]:
    with postgres(work) as db, mlflow_server(work, db) as url:
        yield url


def at_server(url: str, work: Path) -> list[str]:
    return ["tracking=server", f"tracking.uri={url}", f"tracking.runs_dir={work / 'runs'}"]


def scenario_ray(work: Path) -> dict:
    with server(work) as url, ray_cluster(work) as address:
        sweep = armexp([*SIMULATE, *RAY, *at_server(url, work)], {"RAY_ADDRESS": address})
        return {"sweeps": [sweep], "runs": runs_of(url), "launcher": "ray"}


def scenario_submitit(work: Path) -> dict:
    runs = work / "runs"
    sweep = armexp([*SIMULATE, "hydra/launcher=submitit_local", f"tracking.runs_dir={runs}"])
    return {"sweeps": [sweep], "runs": runs_of(f"sqlite:///{runs}/mlflow.db"),
            "launcher": "submitit_local"}  # fmt: skip


def scenario_server(work: Path) -> dict:
    with server(work) as url:
        args = [*PIPELINE, "-m", "seed=0,1", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2"]
        sweep = armexp([*args, *at_server(url, work)])
        return {"sweeps": [sweep], "runs": runs_of(url), "launcher": "joblib"}


def _kill_one_midway(url: str, stop: threading.Event, killed: dict) -> None:
    """SIGKILL the worker of the first pipeline run whose tune step has finished (so the point
    is caught between stages), taking its pid from the run's ``armexp.process`` tag."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(url)
    while not stop.wait(0.5):
        with contextlib.suppress(Exception):
            exp = client.get_experiment_by_name("armexp")
            assert exp is not None  # not yet made: look again (suppressed like the rest)
            runs = client.search_runs(
                [exp.experiment_id],
                "tags.`armexp.stage` = 'pipeline' and attributes.status = 'RUNNING'",
            )
            for run in runs:
                if "armexp.run.tune" in run.data.tags:
                    pid = int(run.data.tags["armexp.process"].split(":")[1])
                    os.kill(pid, signal.SIGKILL)
                    killed.update(run=run.info.run_id, pid=pid, seed=run.data.params["seed"])
                    return


def scenario_fault(work: Path) -> dict:
    with server(work) as url, ray_cluster(work) as address:
        args = [*PIPELINE, "-m", "seed=0,1,2,3", "pipeline.reuse=true", *RAY]
        args += at_server(url, work)
        killed: dict = {}
        stop = threading.Event()
        killer = threading.Thread(target=_kill_one_midway, args=(url, stop, killed))
        killer.start()
        try:
            first = armexp(args, {"RAY_ADDRESS": address})
        finally:
            stop.set()
            killer.join()
        after_first = runs_of(url)
        second = armexp(args, {"RAY_ADDRESS": address})
        return {"sweeps": [first, second], "killed": killed, "runs_after_first": after_first,
                "runs": runs_of(url), "launcher": "ray"}  # fmt: skip


#: An Optuna search of a smoke agent: two trials, then the same command with a third.
OPTUNA = ["train", "-m", "hydra/sweeper=optuna", "hydra/sweeper/sampler=random",
          "hydra.sweeper.sampler.seed=3", "controller.gains=paper", "train.gains=config",
          *SMALL_TRAIN, "agent.max_env_steps=200", "agent.learning_starts=50",
          "train.eval_every=100", "train.eval_targets=2",
          "agent.learning_rate=tag(log, interval(1e-4, 1e-2))"]  # fmt: skip


def scenario_optuna(work: Path) -> dict:
    """The Optuna sweeper's trials through the Ray launcher, MLflow on PostgreSQL and the study
    in the database beside it (``mlflow_optuna``, made by the administrator); then the same
    command with one trial more resumes the study."""
    import optuna

    with postgres(work) as db, ray_cluster(work) as address:
        created = create_database(db, "mlflow_optuna")
        at = [f"tracking.uri={db}", f"tracking.runs_dir={work / 'runs'}", *RAY]
        env = {"RAY_ADDRESS": address}
        sweeps = [armexp([*OPTUNA, "hydra.sweeper.n_trials=2", *at], env),
                  armexp([*OPTUNA, "hydra.sweeper.n_trials=3", *at], env)]  # fmt: skip
        (name,) = optuna.get_all_study_names(created)
        trials = [{"number": t.number, "state": t.state.name, "params": t.params}
                  for t in optuna.load_study(study_name=name, storage=created).trials]  # fmt: skip
        return {"sweeps": sweeps, "runs": runs_of(db), "launcher": "ray", "study": name,
                "storage": created.rpartition("@")[2], "trials": trials}  # fmt: skip


def create_database(uri: str, name: str) -> str:
    """A database ``name`` on the server of ``uri``; its URI."""
    from urllib.parse import urlsplit, urlunsplit

    from tests.cluster import PG_USER, _as_pg, _pg_bin

    parts = urlsplit(uri)
    _as_pg([_pg_bin("createdb"), "-h", str(parts.hostname), "-p", str(parts.port), "-U",
            PG_USER, name], capture_output=True)  # fmt: skip
    return urlunsplit(parts._replace(path=f"/{name}"))


SCENARIOS = {"ray": scenario_ray, "submitit": scenario_submitit, "server": scenario_server,
             "fault": scenario_fault, "optuna": scenario_optuna}  # fmt: skip


def summary(name: str, result: dict) -> list[str]:
    """What ``nox -s scale`` prints for one scenario: per sweep its exit code and wall time,
    points launched and how they ended (with the reasons of those that did not finish), and
    how many stage runs were reused instead of run."""
    runs = result["runs"]
    if "trials" in result:  # an Optuna search: one HPO run across its commands
        states = [t["state"] for t in result["trials"]]
        return [f"{name} command {i} via {result['launcher']}: exit {cmd['rc']}, "
                f"{cmd['wall_s']:.1f} s wall" for i, cmd in enumerate(result["sweeps"], 1)] + [
            f"{name}: study {result['study']} in {result['storage']}: {len(states)} trials "
            f"({', '.join(states)}); train runs {sum(r['stage'] == 'train' for r in runs)}"
        ]  # fmt: skip
    sweeps = sorted((r for r in runs if r["stage"] == "sweep"), key=lambda r: r["start"])
    lines = []
    for i, (cmd, sweep) in enumerate(zip(result["sweeps"], sweeps, strict=True), 1):
        points = [r for r in runs if r["parent"] == sweep["id"]]
        ended = {s: sum(r["status"] == s for r in points) for s in ("FINISHED", "FAILED", "KILLED")}
        stages = [r for r in runs if r["armexp.sweep"] == sweep["id"]]
        reused = sum(len(r["reused"]) for r in points)
        lines.append(
            f"{name} sweep {i} via {result['launcher']}: exit {cmd['rc']}, {cmd['wall_s']:.1f} s "
            f"wall | points launched {len(points)}: FINISHED {ended['FINISHED']}, FAILED "
            f"{ended['FAILED']}, KILLED {ended['KILLED']} | stage runs {len(stages)}, reused "
            f"{reused}"
        )
        for r in stages:
            if r["status"] in ("FAILED", "KILLED"):
                lines.append(f"  {r['stage']} seed={r['seed']} {r['status']}: {r['armexp.error']}")
    return lines


def main() -> None:
    name, work = sys.argv[1], Path(sys.argv[2])
    work.mkdir(parents=True, exist_ok=True)
    result = SCENARIOS[name](work)
    (work / "result.json").write_text(json.dumps(result, indent=1))
    print("\n".join(summary(name, result)))


if __name__ == "__main__":
    main()
