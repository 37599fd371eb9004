"""armexp train and armexp eval on a real MLflow store: lineage, metrics, artifacts, resume."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import mlflow
import numpy as np
import pandas as pd
import pytest
import yaml
from mlflow.tracking import MlflowClient

from armexp.agents.sac import ResumableSAC
from armexp.cli import main
from armexp.sim.convergence import definition_one
from armexp.sim.trajectory import trajectory_columns
from tests.helpers import SMALL_TRAIN, interrupt_training_at, pid_baseline, stage_runs

#: A baseline with configured gains: an eval that needs no tune run.
CONFIG_BASELINE = ["eval.baselines=[pid_gaing]", "eval.baseline_gains=config"]


def _client(runs_dir: Path) -> MlflowClient:
    return MlflowClient(f"sqlite:///{runs_dir}/mlflow.db")


def _runs(runs_dir: Path, stage: str) -> list[Any]:
    return stage_runs(runs_dir, stage)


def _download(runs_dir: Path, run_id: str, path: str, dst: Path) -> Path:
    mlflow.set_tracking_uri(f"sqlite:///{runs_dir}/mlflow.db")
    return Path(
        mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path=path, dst_path=str(dst))
    )


@pytest.mark.long
def test_train_run_finishes_with_metrics_lineage_and_a_loadable_model(
    store: Path, tmp_path: Path
) -> None:
    (train,) = _runs(store, "train")
    adaptive_tune = next(
        r for r in _runs(store, "tune") if r.data.params["controller.name"] == "subsystem_adaptive"
    )
    assert train.info.status == "FINISHED"
    assert train.data.tags["armexp.tune_run"] == adaptive_tune.info.run_id
    m = train.data.metrics
    assert m["final/env_steps"] == 600
    client = _client(store)
    # SB3's own metrics and the per-episode ones, streamed with their step.
    assert client.get_metric_history(train.info.run_id, "train/actor_loss")
    episodes = client.get_metric_history(train.info.run_id, "episode/reward")
    assert len(episodes) == m["final/episodes"] >= 1
    assert all(0 < e.step <= 600 for e in episodes)
    gains = yaml.safe_load(_download(store, train.info.run_id, "gains.yaml", tmp_path).read_text())
    tuned = yaml.safe_load(
        _download(store, adaptive_tune.info.run_id, "gains.yaml", tmp_path / "t").read_text()
    )
    assert gains == tuned
    model = ResumableSAC.load(
        str(_download(store, train.info.run_id, "model/model.zip", tmp_path / "m"))
    )
    assert model.num_timesteps == 600
    action, _ = model.predict(np.zeros(13, dtype=np.float32), deterministic=True)
    assert action.shape == (2,) and np.all(np.abs(action) <= 1)


@pytest.mark.long
def test_eval_logs_per_label_metrics_trajectories_and_controllers(
    store: Path, tmp_path: Path
) -> None:
    (ev,) = _runs(store, "eval")
    (train,) = _runs(store, "train")
    tunes = {r.data.params["controller.name"]: r.info.run_id for r in _runs(store, "tune")}
    pid = pid_baseline()
    labels = ["adaptive", "adaptive_off", pid]
    assert ev.info.status == "FINISHED"
    tags = ev.data.tags
    assert tags["armexp.train_run"] == train.info.run_id
    assert tags["armexp.tune_run"] == tunes["subsystem_adaptive"]
    assert tags["armexp.tune_run.adaptive"] == tags["armexp.tune_run.adaptive_off"]
    assert tags["armexp.tune_run.adaptive"] == tunes["subsystem_adaptive"]
    assert tags[f"armexp.tune_run.{pid}"] == tunes["pid"]
    criterion = pid.removeprefix("pid_")
    described = yaml.safe_load(
        _download(store, ev.info.run_id, "controllers.yaml", tmp_path / "c").read_text()
    )
    assert list(described) == labels
    assert [described[k]["role"] for k in labels] == ["proposed", "ablation", "baseline"]
    assert [described[k]["controller"] for k in labels] == ["subsystem_adaptive"] * 2 + ["pid"]
    assert {described[k]["criterion"] for k in labels} == {criterion}
    assert [described[k]["compare_with"] for k in labels] == [None, None, "adaptive"]
    assert described[pid]["tune_run"] == tunes["pid"]
    assert described["adaptive"]["horizon"] == 0.2  # the tune run's (SMALL_TUNE)
    on, off = described["adaptive"]["gains"], described["adaptive_off"]["gains"]
    assert off == {**on, "b1": 0.0} and on["b1"] > 0
    m = ev.data.metrics
    assert not [k for k in m if k.endswith(("convergence_time", "e1_settling_time"))]
    for label in labels:
        for task in "abcd":
            for key in ("success", "final_error_cm", "rms_e1", "tip_rms_cm", "max_abs_tau_1",
                        "max_abs_tau_2", "collision", "steps", "ultimate_bound", "itae",
                        "ultimate_bound_large", "itae_large"):  # fmt: skip
                assert f"{label}.{task}.{key}" in m, (label, task, key)
            path = _download(
                store, ev.info.run_id, f"trajectories/{label}/{task}.parquet", tmp_path / label
            )
            frame = pd.read_parquet(path)
            assert list(frame.columns) == [*trajectory_columns(2), "target_error"]
            assert len(frame) == 30 * m[f"{label}.{task}.steps"]
            np.testing.assert_allclose(np.diff(frame.t.to_numpy()), 1e-3, rtol=1e-6)
            assert frame.target_error.iloc[-1] * 100 == pytest.approx(
                m[f"{label}.{task}.final_error_cm"], abs=2.0
            )
            # Adaptation off: ρ̂ stays 0; on, it grows from 0.
            assert (frame.rho_hat == 0).all() == (label != "adaptive")
        assert m[f"{label}.random.episodes"] == 2
        # The perturbed runs: 1 s from the offsets, measured by Definition 1.
        for suffix, offset in (("", 0.005), ("_large", 0.05)):
            where = f"trajectories/{label}/b_offset{suffix}.parquet"
            run = pd.read_parquet(_download(store, ev.info.run_id, where, tmp_path / where))
            e1 = np.hypot((run.q_1 - run.q_d_1).to_numpy(), (run.q_2 - run.q_d_2).to_numpy())
            assert len(run) == 1020 and e1[0] == pytest.approx(offset * np.sqrt(2))
            again = definition_one(run.t.to_numpy(), e1, offset, 1.0, 1e-4)
            for key, value in again.items():
                logged = m.get(f"{label}.b.{key}{suffix}", math.nan)
                assert logged == pytest.approx(value, nan_ok=True) or not math.isfinite(value)
    table = pd.read_csv(_download(store, ev.info.run_id, "episodes.csv", tmp_path))
    assert len(table) == 3 * (4 + 2)
    assert list(table.controller.unique()) == labels and set(table.criterion) == {criterion}
    assert table[table.task.str.startswith("random_")].decay_rate.isna().all()
    # Every label sees the same targets.
    a = table[table.controller == "adaptive"].set_index("task")
    for label in labels[1:]:
        other = table[table.controller == label].set_index("task")
        np.testing.assert_array_equal(a.target_x, other.target_x)


def test_eval_without_a_train_run_is_one_sentence(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["eval", f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "eval.train_run" in err and "armexp train" in err


@pytest.mark.long
def test_train_with_paper_gains_needs_no_tune_run(runs_dir: Path) -> None:
    rc = main(
        [
            "train",
            "controller.gains=paper",
            *SMALL_TRAIN,
            "agent.max_env_steps=150",
            "train.eval_every=60",
            "train.eval_targets=2",
            f"tracking.runs_dir={runs_dir}",
        ]
    )
    assert rc == 0
    (run,) = _runs(runs_dir, "train")
    assert run.data.tags["armexp.gains_source"] == "config"
    assert "armexp.tune_run" not in run.data.tags
    # Held-out checks while training: at steps 60 and 120 (2 environments: 2 steps per call),
    # and at the end of the budget, whose check is the run's final/held_out_success.
    held_out = _client(runs_dir).get_metric_history(run.info.run_id, "eval/success_rate")
    assert sorted(m.step for m in held_out) == [60, 120, 150]
    assert all(0.0 <= m.value <= 1.0 for m in held_out)
    last = max(held_out, key=lambda m: m.step).value
    assert run.data.metrics["final/held_out_success"] == last


@pytest.mark.long
def test_interrupted_train_is_killed_with_a_checkpoint_and_resume_finishes_it(
    runs_dir: Path,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    where = f"tracking.runs_dir={runs_dir}"
    interrupt_training_at(monkeypatch, 450)
    rc = main(
        ["train", "controller.gains=paper", *SMALL_TRAIN, "train.checkpoint_every=100000", where]
    )
    assert rc == 130
    (run,) = _runs(runs_dir, "train")
    assert run.info.status == "KILLED"
    state = json.loads(
        _download(runs_dir, run.info.run_id, "checkpoint/state.json", tmp_path).read_text()
    )
    assert state["num_timesteps"] == 450
    assert len(state["recent"]) == state["episodes"] > 0  # the rolling window is saved
    assert state["replay_buffer"] is True  # kept with the interruption's checkpoint
    kept = pd.read_pickle(
        _download(runs_dir, run.info.run_id, "checkpoint/replay_buffer.pkl", tmp_path / "b")
    )
    # Every transition but those of the step it stopped in (2 environments), stored after it.
    assert kept.n_envs * kept.pos == 448
    assert run.data.tags["armexp.error"] == "interrupted"
    monkeypatch.undo()  # training runs to its end again
    # Anything but the budget would be ignored by a resume: refused, nothing run.
    assert main(["train", f"train.resume={run.info.run_id}", "agent.gamma=0.5", where]) == 2
    assert _runs(runs_dir, "train")[0].info.status == "KILLED"
    # The run's own command typed again, with a larger budget: the same config, applied.
    again = ["controller.gains=paper", *SMALL_TRAIN, "train.checkpoint_every=100000"]
    resume = [f"train.resume={run.info.run_id}", "agent.max_env_steps=700", where]
    capsys.readouterr()
    rc = main(["train", *again, *resume])
    assert rc == 0
    assert f"resuming run {run.info.run_id} from step 450, with its replay buffer" in (
        capsys.readouterr().out
    )
    (resumed,) = _runs(runs_dir, "train")
    assert resumed.info.run_id == run.info.run_id and resumed.info.status == "FINISHED"
    assert resumed.data.tags["armexp.resumed_from_step"] == "450"
    assert "armexp.error" not in resumed.data.tags
    assert resumed.data.metrics["final/env_steps"] == 700
    final = json.loads(
        _download(runs_dir, run.info.run_id, "model/state.json", tmp_path / "f").read_text()
    )
    assert final["num_timesteps"] == 700
    listed = [a.path for a in _client(runs_dir).list_artifacts(run.info.run_id, "checkpoint")]
    assert listed == ["checkpoint/model.zip", "checkpoint/state.json"]  # the kept buffer deleted
    # The success rate over the last 100 episodes counts the episodes before the interruption.
    client = _client(runs_dir)
    successes = [m.value for m in client.get_metric_history(run.info.run_id, "episode/success")]
    assert len(final["recent"]) == min(len(successes), 100)
    assert resumed.data.metrics["final/success_rate_100"] == pytest.approx(
        float(np.mean(successes[-100:]))
    )
    steps = [
        m.step for m in _client(runs_dir).get_metric_history(run.info.run_id, "episode/length")
    ]
    assert steps == sorted(steps)


@pytest.mark.long
def test_resume_of_a_finished_run_is_refused(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    where = f"tracking.runs_dir={runs_dir}"
    assert (
        main(["train", "controller.gains=paper", *SMALL_TRAIN, "agent.max_env_steps=120", where])
        == 0
    )
    (run,) = _runs(runs_dir, "train")
    capsys.readouterr()
    assert main(["train", f"train.resume={run.info.run_id}", where]) == 2
    err = capsys.readouterr().err.strip()
    assert "FINISHED" in err and err.count("\n") == 0


AIDS = {
    "demonstrations": "{_target_:armexp.agents.demonstrations.PlannerDemonstrations,episodes:6}",
    "cloning": "{_target_:armexp.agents.cloning.BehaviourCloning,weight:0.5}",
    "pretraining": "{_target_:armexp.agents.pretraining.DemonstrationPretraining,gradient_steps:6}",
    "expert": "{_target_:armexp.agents.expert.DaggerExpert}",
}


@pytest.mark.parametrize(
    "gradients",
    ["autograd", pytest.param("compiled", marks=pytest.mark.slow)],  # it compiles
)
def test_train_with_demonstrations_cloning_and_the_expert_logs_the_demonstrations(
    runs_dir: Path, gradients: str
) -> None:
    aids = [f"+agent.aids.{name}={spec}" for name, spec in AIDS.items()]
    rc = main(
        ["train", "controller.gains=paper", *SMALL_TRAIN, "agent.max_env_steps=150", *aids,
         "env.max_steps=1000", f"agent.gradients={gradients}", f"tracking.runs_dir={runs_dir}"]
    )  # fmt: skip
    assert rc == 0
    (run,) = _runs(runs_dir, "train")
    assert run.info.status == "FINISHED"
    m = run.data.metrics
    assert m["demonstrations/episodes"] == 6
    assert m["demonstrations/success_rate"] >= 5 / 6  # the planner's paths reach (98 % of 200)
    assert m["demonstrations/steps"] > 6 * 50  # whole episodes of seconds, not single steps
    # The demonstrations do not count as the agent's own environment steps.
    assert m["final/env_steps"] <= 152
    assert m["pretraining/gradient_steps"] == 6  # before the first environment step
    assert run.data.params["agent.gradients"] == gradients


@pytest.mark.long
@pytest.mark.parametrize(
    ("aids", "wrong"),
    [
        ([f"+agent.aids.cloning={AIDS['cloning']}"], "without a PlannerDemonstrations listed"),
        (["+agent.aids.x={_target_:collections.OrderedDict}"], "is not a training add-on"),
        (["+agent.aids.x={_target_:armexp.agents.cloning.BehaviourCloning,weight:-1}"],
         "weight=-1 must be greater than 0"),
    ],
)  # fmt: skip
def test_a_bad_aid_is_one_sentence_before_any_run(
    runs_dir: Path, capsys: pytest.CaptureFixture[str], aids: list[str], wrong: str
) -> None:
    rc = main(["train", "controller.gains=paper", *SMALL_TRAIN, *aids,
               f"tracking.runs_dir={runs_dir}"])  # fmt: skip
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and wrong in err[0] and "agent.aids." in err[0], err
    assert not (runs_dir / "mlflow.db").exists()  # stopped before the store was opened


@pytest.mark.long
def test_parallel_environments_log_one_row_per_episode(runs_dir: Path) -> None:
    """8 environments with 10-step episodes end their episodes on the same steps with the same
    values; every episode still gets its own metric row."""
    rc = main(
        ["train", "controller.gains=paper", *SMALL_TRAIN, "agent.n_envs=8", "env.max_steps=10",
         "agent.max_env_steps=400", "agent.learning_starts=50", f"tracking.runs_dir={runs_dir}"]
    )  # fmt: skip
    assert rc == 0
    run = _runs(runs_dir, "train")[0]
    episodes = int(run.data.metrics["final/episodes"])
    assert episodes >= 32
    client = _client(runs_dir)
    for key in ("episode/length", "episode/success", "episode/collision", "episode/reward"):
        assert len(client.get_metric_history(run.info.run_id, key)) == episodes, key


@pytest.mark.long
def test_a_full_disk_fails_the_run_with_one_sentence(
    runs_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    import errno

    from armexp.stages import train

    def full(*args: Any, **kwargs: Any) -> None:
        raise OSError(errno.ENOSPC, "No space left on device", "model/model.zip")

    monkeypatch.setattr(train, "log_model", full)  # the fault: the final model's write
    where = f"tracking.runs_dir={runs_dir}"
    assert main(["train", "controller.gains=paper", *SMALL_TRAIN, where]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "the disk is full (No space left on device" in err[0]
    (run,) = _runs(runs_dir, "train")
    assert run.info.status == "FAILED"
    assert "No space left on device" in run.data.tags["armexp.error"]
    assert run.data.metrics["rollout/episodes"] > 0  # what it logged before is kept


@pytest.mark.long
def test_an_interrupted_eval_keeps_the_episodes_it_ran(
    runs_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from armexp.stages import evaluate

    where = f"tracking.runs_dir={runs_dir}"
    assert main(["train", "controller.gains=paper", *SMALL_TRAIN, where]) == 0
    real, calls = evaluate.rollout, []

    def interrupted_later(*args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        if len(calls) == 10:  # tasks (a)-(c) and their two offset runs each done
            raise KeyboardInterrupt
        return real(*args, **kwargs)

    monkeypatch.setattr(evaluate, "rollout", interrupted_later)
    assert main(["eval", *CONFIG_BASELINE, "tasks.n_random=2", where]) == 130
    (ev,) = _runs(runs_dir, "eval")
    assert ev.info.status == "KILLED"
    rows = pd.read_csv(_download(runs_dir, ev.info.run_id, "episodes.csv", tmp_path))
    assert list(rows.task) == ["a", "b", "c"] and set(rows.controller) == {"adaptive"}


@pytest.mark.long
def test_eval_does_not_take_a_policy_trained_among_other_obstacles(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    where = f"tracking.runs_dir={runs_dir}"
    assert main(["train", "controller.gains=paper", *SMALL_TRAIN, where]) == 0
    moved = "obstacles.circles.0.x=0.45"  # same set name, other circles
    assert main(["eval", moved, *CONFIG_BASELINE, "tasks.n_random=0", where]) == 2
    assert "eval.train_run" in capsys.readouterr().err
