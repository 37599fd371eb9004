"""armexp pipeline: one parent run, a FINISHED child per stage with lineage, reuse, failure."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest
from omegaconf import OmegaConf

from armexp.cli import main
from armexp.config import compose_config, group_options
from armexp.gains import criterion_of, run_criterion, with_criterion
from armexp.stages.pipeline import (
    eval_config,
    eval_tune_runs,
    paper_gains_config,
    report_config,
    train_config,
    tune_steps,
)
from tests.helpers import SMALL_TRAIN, interrupt_training_at, pid_baseline, stage_runs

SMALL = [
    "experiment=smoke",
    "tuner.n_iterations=2",
    "tuner.objective.n_scenarios=2",
    "tuner.objective.horizon=0.2",
    *SMALL_TRAIN,
    "eval.animations=false",  # the renderer has its own tests
    "tasks.n_random=1",
]
#: Both PID baselines (computed torque has a pipeline test of its own).
BASELINES_RUN = "eval.baselines=[pid_gaing,pid_itae]"
SMALL.append(BASELINES_RUN)


def _other(criterion: str) -> str:
    return "itae" if criterion == "gaing" else "gaing"


def _runs(runs: Path, stage: str) -> list[Any]:
    return stage_runs(runs, stage, newest_first=False)


@pytest.fixture(scope="module")
def pipeline_store(tmp_path_factory: pytest.TempPathFactory) -> Path:
    runs = tmp_path_factory.mktemp("pipe") / "runs"
    assert main(["pipeline", *SMALL, f"tracking.runs_dir={runs}"]) == 0
    return runs


@pytest.mark.long
def test_pipeline_makes_one_parent_and_a_finished_child_per_stage(pipeline_store: Path) -> None:
    (parent,) = _runs(pipeline_store, "pipeline")
    assert parent.info.status == "FINISHED"
    pid = parent.info.run_id
    children = {s: _runs(pipeline_store, s) for s in ("tune", "train", "eval", "report")}
    n_tunes = 4
    assert [len(children[s]) for s in ("tune", "train", "eval", "report")] == [n_tunes, 1, 1, 1]
    for group in children.values():
        for run in group:
            assert run.info.status == "FINISHED"
            assert run.data.tags["mlflow.parentRunId"] == pid
    # Every controller of the comparison tuned under each criterion a baseline needs.
    tunes = {(r.data.params["controller.name"], run_criterion(r)): r.info.run_id
             for r in children["tune"]}  # fmt: skip
    comparison = criterion_of(compose_config(SMALL))
    other = _other(comparison)
    expected = tune_steps(compose_config(SMALL))
    assert set(expected) == {"tune", "tune_pid_gaing", "tune_pid_itae", f"tune_adaptive_{other}"}
    assert set(tunes) == set(expected.values())
    steps = {k.removeprefix("armexp.run."): v for k, v in parent.data.tags.items()
             if k.startswith("armexp.run.tune")}  # fmt: skip
    assert steps == {step: tunes[kind] for step, kind in expected.items()}
    (train,), (ev,), (report,) = children["train"], children["eval"], children["report"]
    # Lineage: every child names its upstream runs, all inside this pipeline.
    assert train.data.tags["armexp.tune_run"] == tunes["subsystem_adaptive", comparison]
    assert ev.data.tags["armexp.train_run"] == train.info.run_id
    assert ev.data.tags["armexp.tune_run.pid_gaing"] == tunes["pid", "gaing"]
    assert ev.data.params["eval.tune_runs.pid_gaing"] == tunes["pid", "gaing"]
    labels = {k.split(".")[0] for k in ev.data.metrics}
    references = (("pid_itae", tunes["pid", "itae"]),
                  (f"adaptive_{other}", tunes["subsystem_adaptive", other]))  # fmt: skip
    for label, run_id in references:
        assert ev.data.tags[f"armexp.tune_run.{label}"] == run_id
        assert ev.data.params[f"eval.tune_runs.{label}"] == run_id
    assert labels == {"adaptive", "adaptive_off", "pid_gaing", "pid_itae", f"adaptive_{other}"}
    assert report.data.tags["armexp.report_runs"] == ev.info.run_id
    assert parent.data.tags["armexp.run.train"] == train.info.run_id
    index = pipeline_store / "report" / "index.html"
    assert index.exists() and ev.info.run_id in index.read_text()


@pytest.mark.slow
def test_pipeline_reuse_skips_stages_whose_inputs_match(pipeline_store: Path) -> None:
    before = {s: len(_runs(pipeline_store, s)) for s in ("tune", "train", "eval")}
    assert (
        main(["pipeline", *SMALL, "pipeline.reuse=true", f"tracking.runs_dir={pipeline_store}"])
        == 0
    )
    after = {s: len(_runs(pipeline_store, s)) for s in ("tune", "train", "eval")}
    assert after == before
    second = _runs(pipeline_store, "pipeline")[-1]
    first_train = _runs(pipeline_store, "train")[0]
    assert second.data.tags["armexp.reused.train"] == first_train.info.run_id
    reused = {*tune_steps(compose_config(SMALL)), "train", "eval"}
    assert {f"armexp.reused.{s}" for s in reused} <= set(second.data.tags)
    # A changed input runs that stage (and everything downstream of it) again.
    assert (
        main(
            [
                "pipeline",
                *SMALL,
                "pipeline.reuse=true",
                "seed=5",
                f"tracking.runs_dir={pipeline_store}",
            ]
        )
        == 0
    )
    assert len(_runs(pipeline_store, "train")) == before["train"] + 1


@pytest.mark.slow
def test_reuse_runs_a_stage_again_when_a_key_it_reads_changed(pipeline_store: Path) -> None:
    """``env.reference`` is read by tune (the tuning scenarios' reference): a pipeline with
    ``hold`` must not reuse the tune runs made with ``ramp``, and its tune runs record ``hold``."""
    runs = pipeline_store
    before = {r.info.run_id for r in _runs(runs, "tune")}
    command = ["pipeline", *SMALL, "pipeline.reuse=true", "env.reference=hold"]
    assert main([*command, f"tracking.runs_dir={runs}"]) == 0
    parent = _runs(runs, "pipeline")[-1]
    reused = [k for k in parent.data.tags if k.startswith("armexp.reused.tune")]
    assert reused == []
    tunes = {k.removeprefix("armexp.run."): v for k, v in parent.data.tags.items()
             if k.startswith("armexp.run.tune")}  # fmt: skip
    assert set(tunes) == set(tune_steps(compose_config(SMALL)))
    assert not set(tunes.values()) & before
    for run in _runs(runs, "tune"):
        if run.info.run_id in tunes.values():
            assert run.data.params["env.reference"] == "hold"
    # The same command again reuses what the first made with hold.
    assert main([*command, f"tracking.runs_dir={runs}"]) == 0
    again = _runs(runs, "pipeline")[-1]
    assert {again.data.tags[f"armexp.reused.{s}"] for s in tunes} == set(tunes.values())
    assert "armexp.reused.train" in again.data.tags


@pytest.mark.long
def test_failing_stage_fails_the_parent_and_names_itself(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from armexp.stages import train

    def bogus(*args: Any, **kwargs: Any) -> Any:
        raise RuntimeError("bogus value met while training (injected)")

    monkeypatch.setattr(train, "_learn", bogus)
    runs = tmp_path / "runs"
    assert main(["pipeline", *SMALL, f"tracking.runs_dir={runs}"]) == 1
    assert "pipeline: train failed" in capsys.readouterr().out
    (parent,) = _runs(runs, "pipeline")
    assert parent.info.status == "FAILED"
    assert parent.data.tags["armexp.failed_stage"] == "train"
    assert "bogus" in parent.data.tags["armexp.error"]
    (train_run,) = _runs(runs, "train")
    assert train_run.info.status == "FAILED"
    assert all(r.info.status == "FINISHED" for r in _runs(runs, "tune"))


#: In the slow set: the default arm's pipeline is this module's fixture, and the three-link
#: arm's runs every stage in test_computed_torque_through_every_stage_on_every_shipped_robot.
@pytest.mark.slow
@pytest.mark.parametrize("robot", group_options("robot"))
def test_smoke_pipeline_runs_on_every_shipped_robot(tmp_path: Path, robot: str) -> None:
    """Choosing a robot is enough: both controllers get that arm's gains, search box and torque
    limits in every stage, and the eval torques stay within its limits."""
    runs = tmp_path / "runs"
    pid = pid_baseline()  # one baseline, of the comparison's criterion: two tune runs
    command = ["pipeline", *SMALL, f"robot={robot}", f"eval.baselines=[{pid}]"]
    assert main([*command, f"tracking.runs_dir={runs}"]) == 0
    (parent,) = _runs(runs, "pipeline")
    assert parent.info.status == "FINISHED"
    n = len(compose_config([f"robot={robot}"]).robot.lengths)
    limit = list(compose_config([f"robot={robot}"]).robot.torque_limit)
    tunes = _runs(runs, "tune")
    assert sorted(r.data.params["controller.name"] for r in tunes) == ["pid", "subsystem_adaptive"]
    for run in tunes:
        assert run.data.params["robot.name"] == robot
        assert run.data.metrics["best_gain_margin"] >= 1.25
    (ev,) = _runs(runs, "eval")
    for label in ("adaptive", "adaptive_off", pid):
        for j in range(1, n + 1):
            assert ev.data.metrics[f"{label}.a.max_abs_tau_{j}"] <= limit[j - 1]


@pytest.mark.slow
def test_reuse_resumes_an_interrupted_train_run_instead_of_starting_over(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    runs = tmp_path / "runs"
    interrupt_training_at(monkeypatch, 450)
    command = ["pipeline", *SMALL, "pipeline.reuse=true", f"tracking.runs_dir={runs}"]
    assert main(command) == 130
    (stopped,) = _runs(runs, "train")
    assert stopped.info.status == "KILLED"
    monkeypatch.undo()  # training runs to its end again
    assert main(command) == 0
    (train,) = _runs(runs, "train")  # the same run, continued, not a second one
    assert train.info.run_id == stopped.info.run_id and train.info.status == "FINISHED"
    assert int(train.data.tags["armexp.resumed_from_step"]) >= 400
    assert train.data.metrics["final/env_steps"] == 600
    second = _runs(runs, "pipeline")[-1]
    assert second.data.tags["armexp.resumed.train"] == train.info.run_id
    (ev,) = _runs(runs, "eval")
    assert ev.data.tags["armexp.train_run"] == train.info.run_id


def _steps(criterion: str, *overrides: str) -> dict[str, tuple[str, str]]:
    return tune_steps(with_criterion(compose_config(list(overrides)), criterion))


@pytest.mark.long
def test_tune_steps_tune_every_baseline_and_the_references_it_needs() -> None:
    both = "eval.baselines=[pid_gaing,pid_itae]"
    assert _steps("gaing", both) == {
        "tune": ("subsystem_adaptive", "gaing"), "tune_pid_gaing": ("pid", "gaing"),
        "tune_pid_itae": ("pid", "itae"), "tune_adaptive_itae": ("subsystem_adaptive", "itae"),
    }  # fmt: skip
    assert _steps("itae", both) == {
        "tune": ("subsystem_adaptive", "itae"), "tune_pid_gaing": ("pid", "gaing"),
        "tune_pid_itae": ("pid", "itae"), "tune_adaptive_gaing": ("subsystem_adaptive", "gaing"),
    }  # fmt: skip
    # Trained with configured gains: the reference of the comparison's criterion is `tune`.
    assert set(_steps("itae", both, "train.gains=config")) == {
        "tune", "tune_pid_gaing", "tune_pid_itae", "tune_adaptive_gaing"
    }  # fmt: skip
    assert _steps("itae", both, "eval.baseline_gains=config") == {
        "tune": ("subsystem_adaptive", "itae")
    }
    assert _steps("itae", "eval.baselines=[]") == {"tune": ("subsystem_adaptive", "itae")}
    # A PID policy: its own tune run serves the baseline of the same criterion.
    assert _steps("itae", both, "controller=pid") == {
        "tune": ("pid", "itae"), "tune_pid_gaing": ("pid", "gaing")
    }  # fmt: skip


def test_eval_tune_runs_maps_labels_to_the_tune_steps_runs() -> None:
    cfg = with_criterion(compose_config(["eval.baselines=[pid_gaing,pid_itae]"]), "itae")
    ids = {"tune": "A", "tune_pid_gaing": "B", "tune_pid_itae": "C", "tune_adaptive_gaing": "D"}
    assert eval_tune_runs(cfg, ids) == {
        "pid_gaing": "B", "pid_itae": "C", "adaptive_itae": "A", "adaptive_gaing": "D"
    }  # fmt: skip
    pid = with_criterion(compose_config(["controller=pid", "eval.baselines=[pid_itae]"]), "itae")
    assert eval_tune_runs(pid, {"tune": "P"}) == {"pid_itae": "P"}


def test_the_paper_gains_row_runs_the_policy_alone_with_configured_gains() -> None:
    cfg = compose_config(["eval.tune_runs.pid_itae=X"])
    paper = paper_gains_config(cfg)
    assert list(paper.eval.baselines) == [] and paper.eval.ablation is False
    assert paper.eval.adaptive_gains == "config" and dict(paper.eval.tune_runs) == {}
    assert list(cfg.eval.baselines) == ["pid_gaing", "pid_itae", "computed_torque"]


@pytest.mark.long
def test_each_step_gets_a_config_of_its_own_with_its_upstream_run_ids() -> None:
    cfg = with_criterion(compose_config(["eval.baselines=[pid_itae]"]), "itae")
    before = OmegaConf.to_container(cfg)
    ids = {"tune": "A", "tune_pid_itae": "C", "tune_adaptive_gaing": "D", "train": "R"}
    train_cfg = train_config(cfg, ids)
    assert train_cfg.train.tune_run == "A"
    eval_cfg = eval_config(train_cfg, ids)
    assert eval_cfg.eval.train_run == "R" and eval_cfg.train.tune_run == "A"
    assert dict(eval_cfg.eval.tune_runs) == {"pid_itae": "C", "adaptive_itae": "A"}
    report_cfg = report_config(eval_cfg, "P", ["E"])
    assert report_cfg.report.pipeline_run == "P" and list(report_cfg.report.eval_runs) == ["E"]
    assert report_cfg.eval.train_run == "R"  # the report run's params record the whole chain
    # The pipeline's own config, and each step's, stay as they were.
    assert OmegaConf.to_container(cfg) == before
    assert train_cfg.eval.train_run is None and eval_cfg.report.pipeline_run is None
    # Configured gains: no tune run is wired into train; configured baselines: none into eval.
    assert train_config(compose_config(["train.gains=config"]), ids).train.tune_run is None
    configured = eval_config(compose_config(["eval.baseline_gains=config"]), ids)
    assert dict(configured.eval.tune_runs) == {}


def test_computed_torque_is_tuned_under_the_comparisons_criterion() -> None:
    steps = _steps("itae", "eval.baselines=[pid_gaing,pid_itae,computed_torque]")
    assert steps["tune_computed_torque"] == ("computed_torque", "itae")
    assert _steps("gaing", "eval.baselines=[computed_torque]")["tune_computed_torque"] == (
        "computed_torque", "gaing"
    )  # fmt: skip


#: The three-link arm in the default set (the more general case); the others with the slow set.
@pytest.mark.long
@pytest.mark.parametrize(
    "robot",
    [
        pytest.param(r, marks=() if r == "three_link" else pytest.mark.slow)
        for r in group_options("robot")
    ],
)
def test_computed_torque_through_every_stage_on_every_shipped_robot(
    tmp_path: Path, robot: str, capsys: pytest.CaptureFixture[str]
) -> None:
    """controller=computed_torque as the policy's own controller: simulate, then a pipeline
    (tune, train with it in the loop, eval against every baseline, report), then play, on the
    arm's own gains and box."""
    runs = tmp_path / "runs"
    where = [f"robot={robot}", "controller=computed_torque", f"tracking.runs_dir={runs}"]
    assert main(["simulate", "scenario.duration=0.3", *where]) == 0
    assert main(["pipeline", *SMALL, "eval.baselines=[pid_gaing,pid_itae,computed_torque]",
                 *where]) == 0  # fmt: skip
    (parent,) = _runs(runs, "pipeline")
    (train,), (ev,) = _runs(runs, "train"), _runs(runs, "eval")
    tune = parent.data.tags["armexp.run.tune"]
    assert train.data.tags["armexp.tune_run"] == tune
    assert train.data.params["controller.name"] == "computed_torque"
    n = len(compose_config([f"robot={robot}"]).robot.lengths)
    assert ev.data.params["robot.name"] == robot
    labels = {k.split(".")[0] for k in ev.data.metrics}
    # The policy's own controller is computed torque: it is not run again as a baseline.
    assert labels == {"computed_torque", "pid_gaing", "pid_itae"}
    for j in range(1, n + 1):
        assert f"computed_torque.a.max_abs_tau_{j}" in ev.data.metrics
    assert (runs / "report" / "index.html").exists()
    capsys.readouterr()
    assert main(["play", "play.tasks=[d]", "play.formats=[gif]", *where]) == 0
    (play,) = _runs(runs, "play")
    assert play.info.status == "FINISHED"
    assert play.data.params["play.controller"] == "computed_torque"
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert "| computed_torque, " in line and "animations (gif) of d in " in line, line
    assert line.endswith(str(Path("animations") / "computed_torque")), line
