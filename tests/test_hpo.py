"""Hyperparameter search: `armexp hpo` and ``hydra/sweeper=optuna`` write one HPO run with a
trial run per trial and the seeds' train runs under it, store a study that the same command
resumes, and refuse bad input with one sentence."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import optuna
import pytest
from mlflow.tracking import MlflowClient

from armexp.cli import main
from armexp.config import ConfigError
from armexp.hpo import parallel, space, study
from armexp.tracking import liveness
from armexp.tracking.tags import (
    HEARTBEAT_TAG,
    PARENT_TAG,
    PROCESS_TAG,
    STAGE_TAG,
    TRIAL_STATE_TAG,
)
from tests.helpers import stage_runs

# The smoke preset at the smallest budget with a held-out check: it learns nothing, it runs
# every part of a trial (two seeds, two checks each, the IQM).
TINY = [
    "agent.max_env_steps=200",
    "agent.learning_starts=50",
    "train.eval_every=100",
    "train.eval_targets=2",
    "train.checkpoint_every=200",
    "env.max_steps=50",
]


def _study(runs: Path, name: str | None = None) -> Any:
    url = f"sqlite:///{runs.resolve() / study.OPTUNA_DB}"
    if name is None:
        (name,) = optuna.get_all_study_names(url)
    return optuna.load_study(study_name=name, storage=url)


def _client(runs: Path) -> MlflowClient:
    return MlflowClient(f"sqlite:///{runs}/mlflow.db")


def _asked(runs: Path, name: str) -> tuple[Any, Any, dict[str, float]]:
    """A new study ``name`` in ``runs`` with one trial asked for hpo=smoke's two values: the
    study, the trial and its values."""
    runs.mkdir(parents=True)
    url = f"sqlite:///{runs.resolve() / study.OPTUNA_DB}"
    created = optuna.create_study(storage=url, study_name=name, direction="maximize")
    trial = created.ask()
    values = {"agent.learning_rate": trial.suggest_float("agent.learning_rate", 1e-4, 1e-2,
                                                        log=True),
              "agent.gamma": trial.suggest_float("agent.gamma", 0.9, 0.999)}  # fmt: skip
    return created, trial, values


@pytest.mark.long
def test_a_3_trial_hpo_writes_3_trial_runs_under_one_hpo_run_and_resumes(runs_dir: Path) -> None:
    where = f"tracking.runs_dir={runs_dir}"
    assert main(["hpo", "hpo=smoke", *TINY, where]) == 0
    (hpo,) = stage_runs(runs_dir, "hpo")
    trials = stage_runs(runs_dir, "trial", newest_first=False)
    assert [t.info.run_name for t in trials] == ["trial-0", "trial-1", "trial-2"]
    assert {t.data.tags[PARENT_TAG] for t in trials} == {hpo.info.run_id}
    assert {t.data.tags[TRIAL_STATE_TAG] for t in trials} == {"COMPLETE"}
    trains = stage_runs(runs_dir, "train")
    assert len(trains) == 6  # two seeds per trial, each under its trial run
    assert {r.data.tags[PARENT_TAG] for r in trains} == {t.info.run_id for t in trials}
    assert all("final/held_out_success" in r.data.metrics for r in trains)
    first = _study(runs_dir)
    assert [t.state.name for t in first.trials] == ["COMPLETE"] * 3
    assert first.user_attrs[study.HPO_RUN_ATTR] == hpo.info.run_id
    assert first.trials[0].value == trials[0].data.metrics["hpo/objective"]

    # The same command with one trial more: exactly one trial runs, in the same HPO run, with
    # values of its own (a seeded sampler in a new process would repeat the first trial's).
    assert main(["hpo", "hpo=smoke", "hpo.n_trials=4", *TINY, where]) == 0
    assert [r.info.run_id for r in stage_runs(runs_dir, "hpo")] == [hpo.info.run_id]
    assert len(stage_runs(runs_dir, "trial")) == 4
    assert len(stage_runs(runs_dir, "train")) == 8
    resumed = _study(runs_dir)
    assert [t.state.name for t in resumed.trials] == ["COMPLETE"] * 4
    assert resumed.trials[3].params not in [t.params for t in resumed.trials[:3]]
    client = _client(runs_dir)
    assert client.get_run(hpo.info.run_id).info.status == "FINISHED"
    records = json.loads(
        Path(client.download_artifacts(hpo.info.run_id, "hpo/trials.json")).read_text()
    )
    assert [r["number"] for r in records] == [0, 1, 2, 3]

    # The report reads the HPO from the MLflow store alone.
    (runs_dir / study.OPTUNA_DB).unlink()
    assert main(["report", f"report.hpo_runs=[{hpo.info.run_id}]", where]) == 0
    report = runs_dir / "report"
    tag = resumed.study_name.removeprefix("hpo-").replace("-", "_")
    assert resumed.study_name in (report / "index.html").read_text()
    assert (report / "figures" / f"hpo_objective_{tag}.png").stat().st_size > 0
    best = (report / "tables" / f"hpo_best_{tag}.csv").read_text().splitlines()
    assert best[0].startswith("trial,value,agent.learning_rate,agent.gamma")
    assert len(best) == 5
    shown = (report / "tables" / f"hpo_best_{tag}.md").read_text()
    assert f"Trial {int(best[1].split(',')[0])}'s values, to train on fresh seeds" in shown
    assert "`agent.learning_rate=" in shown and " agent.gamma=" in shown

    # An eval run in the store joins the report only when a selection names it.
    evaluate = ["eval", "controller.gains=paper", "eval.baseline_gains=config",
                "eval.baselines=[]", "tasks.n_random=1", where]  # fmt: skip
    assert main(evaluate) == 0
    assert main(["report", f"report.hpo_runs=[{hpo.info.run_id}]", where]) == 0
    assert not (report / "runs.csv").exists()
    assert not list((report / "figures").glob("fig3*"))
    (evaluated,) = stage_runs(runs_dir, "eval")
    both = ["report", f"report.hpo_runs=[{hpo.info.run_id}]",
            f"report.eval_runs=[{evaluated.info.run_id}]", where]  # fmt: skip
    assert main(both) == 0
    assert (report / "runs.csv").exists()
    assert (report / "figures" / f"hpo_objective_{tag}.png").stat().st_size > 0


@pytest.mark.long
def test_two_processes_share_one_study_and_one_hpo_run(runs_dir: Path) -> None:
    """hpo.n_jobs=2 starts a copy of the command as a worker; a worker asks the same study for
    trials and hangs them under the same HPO run, with values of its own."""
    import os
    import subprocess
    import sys

    where = f"tracking.runs_dir={runs_dir}"
    assert main(["hpo", "hpo=smoke", "hpo.n_jobs=2", "hpo.n_trials=3", *TINY, where]) == 0
    (hpo,) = stage_runs(runs_dir, "hpo")
    done = _study(runs_dir)
    held = len(done.trials)
    assert held >= 3  # each process asks while fewer are held: at most one more
    assert {t.state.name for t in done.trials} == {"COMPLETE"}
    # The worker was started with the command's own overrides, in a folder of its own.
    (started,) = runs_dir.glob("hydra/hpo/*/worker-1/.hydra/overrides.yaml")
    assert "hpo.n_jobs=2" in started.read_text()
    client = _client(runs_dir)
    assert client.get_run(hpo.info.run_id).info.status == "FINISHED"
    records = json.loads(
        Path(client.download_artifacts(hpo.info.run_id, "hpo/trials.json")).read_text()
    )
    assert len(records) == held  # the last snapshot waits for the worker

    # A worker as the command starts one (this process as its owner): two trials more, under
    # the same HPO run, drawn from its own stream (not the command's values again).
    env = {**os.environ, parallel.WORKER_ENV: hpo.info.run_id, parallel.INDEX_ENV: "1",
           parallel.OWNER_ENV: str(os.getpid())}  # fmt: skip
    line = [sys.executable, "-m", "armexp", "hpo", "hpo=smoke", f"hpo.n_trials={held + 2}", *TINY,
            where]  # fmt: skip
    assert subprocess.run(line, env=env, capture_output=True, timeout=600).returncode == 0
    after = _study(runs_dir)
    joined = [t for t in after.trials if t.user_attrs[parallel.PROCESS_ATTR] == 1]
    assert len(after.trials) == held + 2 and len(joined) >= 2
    assert {t.state.name for t in after.trials} == {"COMPLETE"}
    values = [tuple(sorted(t.params.items())) for t in after.trials]
    assert len(set(values)) == len(values)
    trials = stage_runs(runs_dir, "trial")
    assert len(trials) == held + 2 and {t.data.tags[PARENT_TAG] for t in trials} == {
        hpo.info.run_id
    }
    assert len(stage_runs(runs_dir, "train")) == 2 * (held + 2)


@pytest.mark.slow
def test_stopping_a_parallel_search_interrupts_every_process_and_the_command_resumes(
    runs_dir: Path, tmp_path: Path
) -> None:
    """SIGTERM to the command mid-trial reaches its worker: both trials are marked interrupted
    (none left RUNNING), and the same command runs their values again before new ones."""
    import signal
    import subprocess
    import sys
    import time

    line = [sys.executable, "-m", "armexp", "hpo", "hpo=smoke", "hpo.n_jobs=2", "hpo.n_trials=3",
            "agent.max_env_steps=4000", "train.eval_every=2000", "train.eval_targets=2",
            "env.max_steps=50", f"tracking.runs_dir={runs_dir}"]  # fmt: skip
    log = tmp_path / "hpo.log"
    with log.open("w") as out:
        proc = subprocess.Popen(line, stdout=out, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 300
        while log.read_text().count("hpo: trial ") < 2 and time.monotonic() < deadline:
            time.sleep(0.5)
        time.sleep(3)  # both inside their first seed's training
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=120) == 143
    stopped = _study(runs_dir)
    assert {t.state.name for t in stopped.trials} == {"FAIL"}
    assert all(t.user_attrs[study.INTERRUPTED] for t in stopped.trials)
    assert {t.user_attrs[parallel.PROCESS_ATTR] for t in stopped.trials} == {0, 1}
    interrupted = [t.number for t in stopped.trials]  # the study object reads the store live

    assert subprocess.run(line, capture_output=True, timeout=600).returncode == 0
    after = _study(runs_dir)
    retried = sorted(t.user_attrs[study.RETRY_OF] for t in after.trials
                     if study.RETRY_OF in t.user_attrs)  # fmt: skip
    assert retried == interrupted
    assert sum(t.state.name == "COMPLETE" for t in after.trials) >= 3


@pytest.mark.long
def test_a_trial_left_running_by_a_killed_process_is_failed_and_run_again(runs_dir: Path) -> None:
    """A killed command leaves its trial RUNNING in the study and its HPO run RUNNING in
    MLflow: the same command marks the trial FAIL (interrupted) and runs its values again, in
    the same HPO run; the interrupted trial does not count towards n_trials."""
    where = f"tracking.runs_dir={runs_dir}"
    killed, _, values = _asked(runs_dir, "killed")
    client = _client(runs_dir)
    experiment = client.create_experiment("armexp")
    gone = f"{liveness.socket.gethostname()}:1:0"  # pid 1 with another start: a process gone
    dead = client.create_run(experiment, tags={STAGE_TAG: "hpo", PROCESS_TAG: gone})
    killed.set_user_attr(study.HPO_RUN_ATTR, dead.info.run_id)

    args = ["hpo", "hpo=smoke", "hpo.study_name=killed", "hpo.n_trials=1", *TINY, where]
    assert main(args) == 0
    after = _study(runs_dir, "killed")
    assert [t.state.name for t in after.trials] == ["FAIL", "COMPLETE"]
    assert after.trials[0].user_attrs[study.INTERRUPTED] is True
    assert after.trials[1].user_attrs[study.RETRY_OF] == 0
    assert after.trials[1].params == values
    assert [r.info.run_id for r in stage_runs(runs_dir, "hpo")] == [dead.info.run_id]
    assert client.get_run(dead.info.run_id).info.status == "FINISHED"
    assert main(args) == 0  # nothing left to run, nothing run again
    assert len(_study(runs_dir, "killed").trials) == 2


@pytest.mark.long
def test_a_trial_that_failed_on_its_own_runs_again_only_when_asked(runs_dir: Path) -> None:
    """A failed trial counts as done; ``hpo.retry_failed=true`` queues its values again once
    (a failure since fixed), and the retry then counts in its place."""
    where = f"tracking.runs_dir={runs_dir}"
    broken, trial, values = _asked(runs_dir, "broken")
    broken.tell(trial, state=optuna.trial.TrialState.FAIL)
    args = ["hpo", "hpo=smoke", "hpo.study_name=broken", "hpo.n_trials=1", *TINY, where]

    assert main(args) == 0
    assert [t.state.name for t in _study(runs_dir, "broken").trials] == ["FAIL"]
    assert main([*args, "hpo.retry_failed=true"]) == 0
    after = _study(runs_dir, "broken")
    assert [t.state.name for t in after.trials] == ["FAIL", "COMPLETE"]
    assert after.trials[1].user_attrs[study.RETRY_OF] == 0
    assert after.trials[1].params == values
    assert main([*args, "hpo.retry_failed=true"]) == 0  # retried once: nothing run again
    assert len(_study(runs_dir, "broken").trials) == 2


@pytest.mark.long
def test_a_study_another_process_runs_is_refused(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    where = f"tracking.runs_dir={runs_dir}"
    runs_dir.mkdir(parents=True)
    url = f"sqlite:///{runs_dir.resolve() / study.OPTUNA_DB}"
    busy = optuna.create_study(storage=url, study_name="busy", direction="maximize")
    client = _client(runs_dir)
    live = client.create_run(client.create_experiment("armexp"), tags={
        STAGE_TAG: "hpo", PROCESS_TAG: liveness.process_identity(),
        HEARTBEAT_TAG: f"{liveness.time.time():.0f}"})  # fmt: skip
    busy.set_user_attr(study.HPO_RUN_ATTR, live.info.run_id)
    assert main(["hpo", "hpo=smoke", "hpo.study_name=busy", *TINY, where]) == 2
    err = capsys.readouterr().err
    assert f"its HPO run {live.info.run_id} is still running in another process" in err
    assert stage_runs(runs_dir, "trial") == []


@pytest.mark.long
def test_the_optuna_sweeper_runs_2_trials_through_the_launcher(runs_dir: Path) -> None:
    where = f"tracking.runs_dir={runs_dir}"
    args = ["train", "-m", "hydra/sweeper=optuna", "hydra.sweeper.n_trials=2",
            "hydra/sweeper/sampler=random", "hydra.sweeper.sampler.seed=3", "agent=sac_smoke",
            "controller.gains=paper", "train.progress=false", *TINY,
            "agent.learning_rate=tag(log, interval(1e-4, 1e-2))", "agent.n_steps=choice(1,3)",
            where]  # fmt: skip
    assert main(args) == 0
    (hpo,) = stage_runs(runs_dir, "hpo")
    trials = stage_runs(runs_dir, "trial")
    assert {t.data.tags[PARENT_TAG] for t in trials} == {hpo.info.run_id}
    assert {t.data.tags[TRIAL_STATE_TAG] for t in trials} == {"COMPLETE"}
    trains = stage_runs(runs_dir, "train")
    assert sorted(r.data.params["seed"] for r in trains) == ["0", "0", "1", "1"]
    assert {r.data.tags[PARENT_TAG] for r in trains} == {t.info.run_id for t in trials}
    found = _study(runs_dir)
    assert [t.state.name for t in found.trials] == ["COMPLETE"] * 2
    assert set(found.trials[0].params) == {"agent.learning_rate", "agent.n_steps"}
    (results,) = runs_dir.glob("hydra/multirun/train/*/optimization_results.yaml")
    assert "best_value" in results.read_text()


@pytest.mark.long
def test_the_optuna_sweeper_goes_on_in_the_hpo_run_a_stopped_search_left(runs_dir: Path) -> None:
    """Run again after a stop (the HPO run FAILED with an error tag, as a signal leaves it),
    the sweep continues the study in the same HPO run, which ends FINISHED without the tag."""
    args = ["train", "-m", "hydra/sweeper=optuna", "hydra/sweeper/sampler=random",
            "hydra.sweeper.sampler.seed=3", "agent=sac_smoke", "controller.gains=paper",
            "train.progress=false", *TINY, "agent.learning_rate=tag(log, interval(1e-4, 1e-2))",
            f"tracking.runs_dir={runs_dir}"]  # fmt: skip
    assert main([*args, "hydra.sweeper.n_trials=1"]) == 0
    (hpo,) = stage_runs(runs_dir, "hpo")
    client = _client(runs_dir)
    client.set_tag(hpo.info.run_id, "armexp.error", "interrupted")
    client.set_terminated(hpo.info.run_id, "FAILED")
    assert main([*args, "hydra.sweeper.n_trials=2"]) == 0
    (again,) = stage_runs(runs_dir, "hpo")
    assert again.info.run_id == hpo.info.run_id
    assert again.info.status == "FINISHED"
    assert "armexp.error" not in again.data.tags
    assert len(stage_runs(runs_dir, "trial")) == 2
    assert [t.state.name for t in _study(runs_dir).trials] == ["COMPLETE"] * 2


SMOKE = ["hpo", "hpo=smoke"]
SWEEP = ["train", "-m", "hydra/sweeper=optuna", "train.eval_every=100"]


@pytest.mark.long
@pytest.mark.parametrize(
    ("args", "sentence"),
    [
        ([*SMOKE, "agent.gamma=interval(1,1)"],
         "hpo.params.agent.gamma=interval(1,1) is not allowed: the interval is empty"),
        ([*SMOKE, "hpo.params.agent.learning_rate=interval(2e-3,1e-3)"],
         "hpo.params.agent.learning_rate=interval(2e-3,1e-3) is not allowed: the interval is "
         "empty"),
        ([*SWEEP, "agent.gamma=interval(2,1)"],
         "agent.gamma=interval(2,1) is not allowed: the interval is empty"),
        ([*SWEEP, "agent.n_steps=range(3,3)"],
         "agent.n_steps=range(3,3) is not allowed: the range is empty"),
        ([*SMOKE, "hpo.sampler.name=anneal"], "hpo.sampler.name='anneal' is not allowed"),
        ([*SMOKE, "hpo.pruner.name=patient"], "hpo.pruner.name='patient' is not allowed"),
        ([*SWEEP, "hydra/sweeper/sampler=anneal", "agent.gamma=interval(0.9,0.99)"],
         "hydra/sweeper/sampler=anneal is not a known option; choose one of: cmaes, gp, qmc, "
         "random, tpe."),
        ([*SMOKE, "hpo.seeds=[0]"], "hpo.seeds=[0] is not allowed: give two or more"),
        ([*SMOKE, "train.eval_every=0"], "train.eval_every=0 is not allowed with armexp hpo"),
        ([*SMOKE, "agent.gamma=interval(0.5,1.5)"],
         "agent.gamma=1.5 is not allowed: it must lie in [0.0, 1.0] (a value the search can "
         "reach)."),
        ([*SMOKE, "seed=choice(0,1)"], "hpo.params.seed=choice(0,1) is not allowed: a trial "
         "sets seed itself"),
        (["tune", "-m", "hydra/sweeper=optuna", "tuner.pa=interval(0.1,0.3)"],
         "hydra/sweeper=optuna is not allowed with armexp tune"),
    ],
)  # fmt: skip
def test_bad_search_input_is_one_sentence(
    args: list[str], sentence: str, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([*args, f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and sentence in err[0], err
    assert not (runs_dir / "mlflow.db").exists() or stage_runs(runs_dir, "trial") == []


@pytest.mark.parametrize(
    ("missing", "args", "sentence"),
    [
        ("cmaes", [*SMOKE, "hpo.sampler.name=cmaes"],
         'hpo.sampler.name=cmaes is not allowed here: it needs the cmaes package, which is not '
         'installed; pip install "armexp[hpo]".'),
        ("cmaes", [*SWEEP, "hydra/sweeper/sampler=cmaes", "agent.gamma=interval(0.9,0.99)"],
         "hydra/sweeper/sampler=cmaes is not allowed here: it needs the cmaes package"),
        ("optuna", [*SWEEP, "agent.gamma=interval(0.9,0.99)"],
         'hydra/sweeper=optuna is not allowed here: it needs Optuna, which is not installed; '
         'pip install "armexp[hpo]".'),
        ("optuna", SMOKE, 'armexp hpo needs Optuna, which is not installed; pip install '
         '"armexp[hpo]".'),
    ],
)  # fmt: skip
def test_a_search_option_missing_from_the_install_names_the_extra(
    missing: str, args: list[str], sentence: str, runs_dir: Path,
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch,
) -> None:  # fmt: skip
    real = study.installed
    monkeypatch.setattr(study, "installed", lambda module: module != missing and real(module))
    assert main([*args, f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and sentence in err[0], err


def test_the_search_space_reads_hydras_sweep_grammar(compose: Any) -> None:
    import optuna.distributions as d

    cfg = compose()
    found = space.parse(
        ["agent.learning_rate=tag(log, interval(1e-4, 1e-2))", "agent.batch_size=interval(32,512)",
         "agent.gamma=interval(0.9,0.99)", "agent.n_steps=range(1,7,2)",
         "agent.net_arch=choice([64,64],[256,256])", "agent.tau=0.01", "seed=3"], cfg)  # fmt: skip
    assert found.distributions == {
        "agent.learning_rate": d.FloatDistribution(1e-4, 1e-2, log=True),
        "agent.batch_size": d.IntDistribution(32, 512),  # an integer key: integers
        "agent.gamma": d.FloatDistribution(0.9, 0.99),
        "agent.n_steps": d.IntDistribution(1, 5, step=2),  # Hydra's range: stop excluded
        "agent.net_arch": d.CategoricalDistribution(["[64,64]", "[256,256]"]),
    }
    assert found.fixed == ["agent.tau=0.01"]  # the seed is the trial's (hpo.seeds)
    assert space.as_params(["agent.gamma=interval(0.9,0.99)", "agent.tau=0.01"]) == [
        "++hpo.params.agent.gamma='interval(0.9,0.99)'", "agent.tau=0.01"]  # fmt: skip
    nested = space.from_mapping({"agent": {"gamma": "choice(0.9,0.99)"}}, cfg, "hpo.params.")
    assert list(nested.distributions) == ["agent.gamma"]
    with pytest.raises(ConfigError, match="fewer than two integers"):
        space.parse(["agent.batch_size=tag(int, interval(1.2,1.8))"], cfg)


def test_the_study_is_stored_beside_the_mlflow_store_never_in_it(compose: Any) -> None:
    cfg = compose()
    assert study.storage_url(cfg, None).endswith("/runs/optuna.db")
    assert study.storage_url(cfg, "sqlite:////x/y.db") == "sqlite:////x/y.db"


def test_the_held_out_checks_prune_a_trial_and_stop_its_training() -> None:
    from armexp.hpo.pruning import ReportChecks, _Reporter

    class Trial:
        def __init__(self) -> None:
            self.reported: list[tuple[float, int]] = []

        def report(self, value: float, step: int) -> None:
            self.reported.append((value, step))

        def should_prune(self) -> bool:
            return self.reported[-1][0] < 0.5

    class Checks:
        def __init__(self) -> None:
            self.history: list[dict[str, float]] = []

    trial, checks = Trial(), Checks()
    addon = ReportChecks(trial, offset=1000)  # the trial's second seed at a 1000-step budget
    reporter = _Reporter(addon, checks)  # type: ignore[arg-type]
    assert reporter._on_step()  # no new check: nothing reported
    checks.history.append({"step": 100.0, "eval/success_rate": 0.8})
    assert reporter._on_step()
    checks.history.append({"step": 200.0, "eval/success_rate": 0.2})
    assert not reporter._on_step()  # SB3 stops training when a callback returns False
    assert trial.reported == [(0.8, 1100), (0.2, 1200)]
    assert addon.pruned_at == 1200


@pytest.mark.long
def test_the_report_shows_optunas_parameter_importances(tmp_path: Path) -> None:
    from armexp.report import hpo

    dists = {"agent.gamma": {"name": "FloatDistribution", "attributes": {
        "low": 0.9, "high": 0.999, "log": False, "step": None}},
        "agent.n_steps": {"name": "IntDistribution", "attributes": {
            "low": 1, "high": 5, "log": False, "step": 1}}}  # fmt: skip
    trials = [{"number": i, "state": "COMPLETE", "value": gamma * 0.5 + n * 0.01,
               "params": {"agent.gamma": gamma, "agent.n_steps": n}}
              for i, (gamma, n) in enumerate([(0.9, 1), (0.95, 3), (0.99, 5), (0.92, 2),
                                              (0.97, 4), (0.91, 5)])]  # fmt: skip
    found = hpo.Hpo("abc", "hpo-x-1", "maximize", trials, dists, {"seeds": [0, 1]})
    weights, note = hpo.importances(found)
    assert note == ""
    assert set(weights) == {"agent.gamma", "agent.n_steps"}
    assert sum(weights.values()) == pytest.approx(1.0)
    best, importance = hpo.tables_of(found, weights, note)
    assert list(best.numbers.trial[:2]) == [2, 4]  # highest values first
    assert list(importance.numbers.parameter) == list(weights)
    pictures: list[str] = []
    (tmp_path / "tables").mkdir()
    (tmp_path / "figures").mkdir()

    class Reader:
        def yaml(self, run_id: str, artifact: str) -> Any:
            return {"hpo/trials.json": trials, "hpo/space.json": {"space": dists},
                    "hpo/study.json": {"study": "hpo-x-1"}}[artifact]  # fmt: skip

    def save(fig: Any, name: str, caption: str) -> None:
        from armexp.report.figures import save as write

        write(fig, tmp_path / "figures", name)
        pictures.append(name)

    hpo.section(Reader(), ["abc"], tmp_path, save)  # type: ignore[arg-type]
    assert pictures == ["hpo_objective_x_1", "hpo_importance_x_1"]
    assert (tmp_path / "tables" / "hpo_importance_x_1.csv").exists()
    assert (tmp_path / "tables" / "hpo_trials_x_1.csv").read_text().count("\n") == 7
