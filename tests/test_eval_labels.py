"""The controllers an eval runs (`armexp.stages.controller_set`): labels, roles, criteria, the
proposed label each baseline is compared with, where the gains come from, and bad input."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from omegaconf import DictConfig

from armexp.baselines import BASELINES, PLAY_LABELS, reference_criteria, title
from armexp.cli import main
from armexp.config import ConfigError
from armexp.gains import Gains, with_criterion
from armexp.stages.controller_set import (
    Entry,
    Policy,
    controller_set,
    lineage_tags,
    play_entry,
)
from tests.helpers import logged_tune_run, pid_baseline, stage_runs

ADAPTIVE_GAINS = "a0: 600.0\na1: 500.0\nb1: 2.0\nc1: 0.001\nr1: 0.5\n"
PID_GAINS = "kp: [1000.0, 100.0]\nki: [10.0, 1.0]\nkd: [50.0, 5.0]\n"


def _policy(cfg: DictConfig, controller: str = "subsystem_adaptive", criterion: str = "gaing",
            tune_run: str | None = "t0") -> Policy:  # fmt: skip
    """A policy trained with ``controller``'s gains tuned under ``criterion`` (no model: the
    controller set does not run it)."""
    label = "adaptive" if controller == "subsystem_adaptive" else controller
    own = Gains(controller, {"a0": 1.0, "b1": 2.0}, criterion, 0.6, tune_run)
    return Policy("train0", cfg, None, Entry(label, "proposed", own), {})


@pytest.fixture
def tuned(compose: Callable[..., DictConfig]) -> dict[str, str]:
    """Tune runs in the test's store, by (controller, criterion), the newest of each last."""
    base = compose()
    ids = {}
    for controller, criterion, text in (
        ("pid", "gaing", PID_GAINS), ("pid", "itae", PID_GAINS),
        ("subsystem_adaptive", "gaing", ADAPTIVE_GAINS),
        ("subsystem_adaptive", "itae", ADAPTIVE_GAINS),
    ):  # fmt: skip
        cfg = with_criterion(compose(f"controller={controller}") if controller == "pid" else base,
                             criterion)  # fmt: skip
        logged_tune_run(cfg, text)  # an older one: the latest is taken
        ids[f"{controller}_{criterion}"] = logged_tune_run(cfg, text)
    return ids


def _cfg(compose: Callable[..., DictConfig], criterion: str, *overrides: str) -> DictConfig:
    return with_criterion(compose(*overrides), criterion)


@pytest.mark.long
def test_a_tuned_adaptive_policy_gets_its_ablation_baselines_and_the_references_they_need(
    compose: Callable[..., DictConfig], tuned: dict[str, str]
) -> None:
    cfg = _cfg(compose, "gaing", "eval.baselines=[pid_gaing,pid_itae]")
    entries = controller_set(cfg, _policy(cfg, criterion="gaing"))
    rows = {e.label: e for e in entries}
    assert list(rows) == ["adaptive", "adaptive_off", "pid_gaing", "pid_itae", "adaptive_itae"]
    assert [e.role for e in entries] == ["proposed", "ablation", "baseline", "baseline",
                                         "reference"]  # fmt: skip
    assert [e.gains.criterion for e in entries] == ["gaing", "gaing", "gaing", "itae", "itae"]
    # Each baseline is compared with the proposed law tuned under its own criterion.
    assert rows["pid_gaing"].compare_with == "adaptive"
    assert rows["pid_itae"].compare_with == "adaptive_itae"
    assert rows["adaptive_off"].gains.values == {"a0": 1.0, "b1": 0.0}
    for label, key in (("pid_gaing", "pid_gaing"), ("pid_itae", "pid_itae"),
                       ("adaptive_itae", "subsystem_adaptive_itae")):  # fmt: skip
        assert rows[label].gains.tune_run == tuned[key]
    assert rows["pid_itae"].gains.values["kp"] == [1000.0, 100.0]
    assert rows["adaptive_itae"].controller == "subsystem_adaptive"
    assert lineage_tags(entries) == {
        "armexp.tune_run.adaptive": "t0", "armexp.tune_run.adaptive_off": "t0",
        "armexp.tune_run.pid_gaing": tuned["pid_gaing"],
        "armexp.tune_run.pid_itae": tuned["pid_itae"],
        "armexp.tune_run.adaptive_itae": tuned["subsystem_adaptive_itae"],
    }  # fmt: skip
    record = rows["pid_itae"].record()
    assert record == {"controller": "pid", "role": "baseline", "criterion": "itae",
                      "horizon": 1.5, "tune_run": tuned["pid_itae"],
                      "gains": rows["pid_itae"].gains.values,
                      "compare_with": "adaptive_itae"}  # fmt: skip


@pytest.mark.long
def test_the_comparison_criterion_decides_which_reference_is_needed(
    compose: Callable[..., DictConfig], tuned: dict[str, str]
) -> None:
    cfg = _cfg(compose, "itae", "eval.baselines=[pid_gaing,pid_itae]", "eval.ablation=false")
    entries = controller_set(cfg, _policy(cfg, criterion="itae"))
    assert [e.label for e in entries] == ["adaptive", "pid_gaing", "pid_itae", "adaptive_gaing"]
    rows = {e.label: e for e in entries}
    assert rows["pid_gaing"].compare_with == "adaptive_gaing"
    assert rows["pid_itae"].compare_with == "adaptive"
    assert rows["adaptive_gaing"].gains.tune_run == tuned["subsystem_adaptive_gaing"]


@pytest.mark.long
def test_configured_adaptive_gains_need_a_reference_for_every_tuned_baseline(
    compose: Callable[..., DictConfig], tuned: dict[str, str]
) -> None:
    cfg = _cfg(compose, "itae", "eval.baselines=[pid_gaing,pid_itae]")
    entries = controller_set(cfg, _policy(cfg, criterion="config", tune_run=None))
    assert [e.label for e in entries][-2:] == ["adaptive_gaing", "adaptive_itae"]
    assert "armexp.tune_run.adaptive" not in lineage_tags(entries)
    assert reference_criteria(["pid_gaing", "pid_itae"], "itae", "itae") == ["gaing"]


@pytest.mark.long
def test_configured_baselines_need_no_tune_run_and_no_reference(
    compose: Callable[..., DictConfig],
) -> None:
    cfg = _cfg(compose, "itae", "eval.baselines=[pid_itae,pid_gaing]", "eval.baseline_gains=config")
    entries = controller_set(cfg, _policy(cfg, criterion="gaing"))
    assert [e.label for e in entries] == ["adaptive", "adaptive_off", "pid_itae", "pid_gaing"]
    pid = compose("controller=pid").controller.gains
    for entry in entries[2:]:
        assert entry.gains.criterion == "config" and entry.gains.tune_run is None
        assert entry.gains.values == {k: list(v) for k, v in pid.items()}
        assert entry.compare_with == "adaptive"


@pytest.mark.long
def test_a_pid_trained_policy_has_no_ablation_and_no_reference(
    compose: Callable[..., DictConfig], tuned: dict[str, str]
) -> None:
    cfg = _cfg(compose, "itae", "eval.baselines=[pid_gaing]")
    entries = controller_set(cfg, _policy(cfg, controller="pid", criterion="itae"))
    assert [(e.label, e.role, e.compare_with) for e in entries] == [
        ("pid", "proposed", None), ("pid_gaing", "baseline", "pid")
    ]  # fmt: skip


@pytest.mark.long
def test_tune_runs_given_by_label_are_used_and_checked(
    compose: Callable[..., DictConfig], tuned: dict[str, str]
) -> None:
    older = logged_tune_run(with_criterion(compose("controller=pid"), "itae"), PID_GAINS)
    logged_tune_run(with_criterion(compose("controller=pid"), "itae"), PID_GAINS)
    cfg = _cfg(compose, "gaing", "eval.baselines=[pid_itae]", f"eval.tune_runs.pid_itae={older}",
               f"eval.tune_runs.adaptive_itae={tuned['subsystem_adaptive_itae']}")  # fmt: skip
    rows = {e.label: e for e in controller_set(cfg, _policy(cfg))}
    assert rows["pid_itae"].gains.tune_run == older
    wrong = tuned["subsystem_adaptive_itae"]
    cfg = _cfg(compose, "gaing", "eval.baselines=[pid_itae]", f"eval.tune_runs.pid_itae={wrong}")
    with pytest.raises(ConfigError) as bad:
        controller_set(cfg, _policy(cfg))
    assert str(bad.value) == (
        f"eval.tune_runs.pid_itae={wrong} is not allowed: that tune run has "
        "controller.name=subsystem_adaptive, and controller.name=pid is needed here."
    )
    other = tuned["pid_gaing"]
    cfg = _cfg(compose, "gaing", "eval.baselines=[pid_itae]", f"eval.tune_runs.pid_itae={other}")
    with pytest.raises(ConfigError, match=r"tuned under tuner\.objective\.criterion=gaing, and "):
        controller_set(cfg, _policy(cfg))


def test_a_reference_without_a_tune_run_is_one_sentence_naming_its_key(
    compose: Callable[..., DictConfig],
) -> None:
    logged_tune_run(with_criterion(compose("controller=pid"), "itae"), PID_GAINS)
    cfg = _cfg(compose, "gaing", "eval.baselines=[pid_itae]")
    with pytest.raises(ConfigError) as bad:
        controller_set(cfg, _policy(cfg))
    assert str(bad.value).startswith(
        "eval.tune_runs.adaptive_itae is not set and no FINISHED tune run with "
        "controller.name=subsystem_adaptive, robot.name=two_link_paper, "
        "tuner.objective.criterion=itae exists in experiment 'armexp'"
    )


@pytest.mark.long
def test_play_takes_a_label(compose: Callable[..., DictConfig], tuned: dict[str, str]) -> None:
    cfg = _cfg(compose, "gaing")
    policy = _policy(cfg)
    assert play_entry(cfg, policy) is policy.own  # null: the policy's own controller
    cfg.play.controller = "adaptive_off"
    assert play_entry(cfg, policy).gains.values["b1"] == 0.0
    cfg.play.controller = "pid_itae"
    entry = play_entry(cfg, policy)
    assert (entry.role, entry.gains.tune_run) == ("baseline", tuned["pid_itae"])
    cfg.play.controller = "pid"
    with pytest.raises(ConfigError, match="choose adaptive, adaptive_off, or a baseline"):
        play_entry(cfg, policy)
    assert set(BASELINES) < set(PLAY_LABELS)


@pytest.mark.long
def test_computed_torque_is_tuned_under_the_comparisons_criterion(
    compose: Callable[..., DictConfig],
) -> None:
    for criterion in ("gaing", "itae"):
        cfg = with_criterion(compose("controller=computed_torque"), criterion)
        logged_tune_run(cfg, "kp: [1.0, 1.0]\nki: [0.0, 0.0]\nkd: [1.0, 1.0]\n")
    cfg = _cfg(compose, "itae", "eval.baselines=[computed_torque]")
    logged_tune_run(with_criterion(compose(), "itae"), ADAPTIVE_GAINS)
    rows = {e.label: e for e in controller_set(cfg, _policy(cfg, criterion="gaing"))}
    assert rows["computed_torque"].gains.criterion == "itae"
    assert rows["computed_torque"].compare_with == "adaptive_itae"
    assert "adaptive_itae" in rows


def test_titles_name_every_label() -> None:
    assert title("adaptive") == "proposed (adaptive)"
    assert title("adaptive_off") == "adaptive, adaptation off"
    assert title("adaptive_gaing") == "adaptive (tuned on W)"
    assert title("adaptive_itae") == "adaptive (tuned on ITAE)"
    assert title("pid_itae") == "PID (tuned on ITAE)"


def test_an_unknown_baseline_is_one_sentence_naming_the_allowed_ones(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["eval", "eval.baselines=[foo]", f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "armexp eval: eval.baselines=['foo'] is not allowed: each entry must be one of the "
        "baselines pid_gaing, pid_itae, computed_torque, listed once."
    ]


@pytest.mark.long
def test_a_tune_run_of_another_controller_for_a_baseline_is_one_sentence(
    store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pid = pid_baseline()
    adaptive = next(r.info.run_id for r in stage_runs(store, "tune")
                    if r.data.params["controller.name"] == "subsystem_adaptive")  # fmt: skip
    before = len(stage_runs(store, "eval"))
    command = ["eval", f"eval.baselines=[{pid}]", f"eval.tune_runs.{pid}={adaptive}",
               "tasks.n_random=0", f"tracking.runs_dir={store}"]  # fmt: skip
    assert main(command) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"eval.tune_runs.{pid}={adaptive} is not allowed" in err[0], err
    assert "controller.name=pid is needed here" in err[0]
    assert len(stage_runs(store, "eval")) == before


def test_tune_runs_by_label_on_the_command_line() -> None:
    from armexp.config import compose_config

    overrides = ["eval.tune_runs.pid_itae=abc", "eval.tune_runs.pid_itae=abd",
                 "eval.tune_runs={adaptive_gaing: x}", "play.tune_runs.pid_gaing=y"]  # fmt: skip
    cfg = compose_config(overrides)
    assert dict(cfg.eval.tune_runs) == {"pid_itae": "abd", "adaptive_gaing": "x"}
    assert dict(cfg.play.tune_runs) == {"pid_gaing": "y"}
    with pytest.raises(ConfigError, match=r"map a baseline .* or adaptive_<criterion> to a tune"):
        compose_config(["eval.tune_runs.adaptive_off=x"])
    with pytest.raises(ConfigError, match=r"eval\.large_offset=4\.0 is not allowed: .*joint range"):
        compose_config(["eval.large_offset=4"])
    assert compose_config(["eval.large_offset=null"]).eval.large_offset is None


def test_the_summary_line_names_every_label(capsys: pytest.CaptureFixture[str]) -> None:
    import pandas as pd

    from armexp.stages.evaluate import _print_summary

    rows = [{"controller": label, "task": task, "success": 1.0, "collision": 0.0,
             "decay_rate": 20.0 if task == "a" else float("nan")}
            for label in ("adaptive", "adaptive_off", "pid_itae", "adaptive_gaing")
            for task in ("a", "random_000")]  # fmt: skip
    _print_summary("run1", "train123456", pd.DataFrame(rows), 1.0)
    line = capsys.readouterr().out.strip()
    assert line.count("\n") == 0
    for label in ("adaptive:", "adaptive_off:", "pid_itae:", "adaptive_gaing:"):
        assert f"| {label} success 1.00, collisions 0.00 on 1 targets, tasks reached 1/1" in line
    assert "decay 20/s" in line
