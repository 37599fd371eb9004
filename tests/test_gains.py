"""The gains resolver (`armexp.gains`): configured gains, a tune run by id, or the latest tune
run of a controller, robot and criterion; tune runs made before the criterion was a choice."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from omegaconf import DictConfig

from armexp import gains
from armexp.config import ConfigError
from armexp.stages import evaluate, train
from armexp.stages.train import controller_gains_for
from armexp.tracking import stage_runs
from armexp.tracking.tags import TUNE_RUN_TAG
from tests.helpers import logged_tune_run


def test_lookup_errors_name_the_key(compose: Callable[..., DictConfig]) -> None:
    cfg = compose()
    robot = str(cfg.robot.name)
    with pytest.raises(ConfigError, match=r"no FINISHED tune run with controller\.name="):
        gains.tuned(cfg, "subsystem_adaptive", robot, "itae")
    with stage_runs.stage_run(cfg, "simulate") as run:
        pass
    with pytest.raises(ConfigError, match="it is a simulate run, and a tune run is needed"):
        gains.tuned(cfg, "subsystem_adaptive", robot, "gaing", run_id=run.info.run_id)
    with pytest.raises(ConfigError, match=r"tune_run=nope is not allowed: a run id is 32 hex"):
        gains.tuned(cfg, "subsystem_adaptive", robot, "gaing", run_id="nope")
    with pytest.raises(ConfigError, match=r"tune_run=0{32} is not allowed: no run"):
        gains.tuned(cfg, "subsystem_adaptive", robot, "gaing", run_id="0" * 32)


def test_latest_matching_tune_run_is_found(compose: Callable[..., DictConfig]) -> None:
    cfg = compose()
    criterion = gains.criterion_of(cfg)
    ids = [logged_tune_run(cfg, f"a0: {a0}\n") for a0 in (100.0, 200.0)]
    logged_tune_run(compose("controller=pid"), "kp: [1, 2]\n")
    found = gains.resolve(cfg, "subsystem_adaptive", "two_link_paper", "tuned")
    assert found.tune_run == ids[-1] and found.values == {"a0": 200.0}
    assert found.criterion == criterion and found.controller == "subsystem_adaptive"
    assert gains.resolve(
        cfg, "subsystem_adaptive", "two_link_paper", "tuned", run_id=ids[0]
    ).values == {"a0": 100.0}


def test_the_latest_tune_run_of_the_configs_seed_comes_first(
    compose: Callable[..., DictConfig], caplog: pytest.LogCaptureFixture
) -> None:
    # A seeded study tunes every seed into one store; seed 1's eval means seed 1's tune.
    robot = str(compose().robot.name)
    first = logged_tune_run(compose("tuner.seed=1"), "a0: 1.0\n")
    newest = logged_tune_run(compose("tuner.seed=2"), "a0: 2.0\n")
    criterion = gains.criterion_of(compose())
    with caplog.at_level("WARNING", logger="armexp.gains"):
        found = gains.tuned(compose("tuner.seed=1"), "subsystem_adaptive", robot, criterion)
        assert (found.tune_run, found.values) == (first, {"a0": 1.0})
        assert gains.tuned(compose("tuner.seed=2"), "subsystem_adaptive", robot,
                           criterion).tune_run == newest  # fmt: skip
        assert not caplog.records
        # No tune of the config's seed: the latest of any seed, and a warning naming it.
        found = gains.tuned(compose("tuner.seed=3"), "subsystem_adaptive", robot, criterion,
                            key="eval.tune_runs.adaptive_itae")  # fmt: skip
    assert found.tune_run == newest
    assert [r.getMessage() for r in caplog.records] == [
        "eval.tune_runs.adaptive_itae: no FINISHED tune run of subsystem_adaptive with "
        f"tuner.seed=3; using the latest, {newest} (tuner.seed=2); pass "
        "eval.tune_runs.adaptive_itae=<run id> to choose"
    ]
    # A given id is taken whatever its seed.
    assert gains.tuned(compose("tuner.seed=2"), "subsystem_adaptive", robot, criterion,
                       run_id=first).tune_run == first  # fmt: skip
    # The same through the views train and eval run on (armexp.reads), which declare tuner.seed.
    seed_1 = compose("tuner.seed=1")
    assert controller_gains_for(train.READS.view(seed_1))[1][TUNE_RUN_TAG] == first
    assert gains.tuned(evaluate.READS.view(seed_1), "subsystem_adaptive", robot,
                       criterion).tune_run == first  # fmt: skip


def test_the_latest_run_of_the_criterion_is_found_and_older_runs_are_gaing(
    compose: Callable[..., DictConfig],
) -> None:
    cfg = compose()
    robot = str(cfg.robot.name)
    itae = logged_tune_run(gains.with_criterion(cfg, "itae"), "a0: 1.0\n")
    gaing = logged_tune_run(gains.with_criterion(cfg, "gaing"), "a0: 2.0\n")
    newest_itae = logged_tune_run(gains.with_criterion(cfg, "itae"), "a0: 3.0\n")
    found = gains.tuned(cfg, "subsystem_adaptive", robot, "gaing")
    assert found.tune_run == gaing and found.values == {"a0": 2.0}
    found = gains.tuned(cfg, "subsystem_adaptive", robot, "itae")
    assert (found.tune_run, found.criterion) == (newest_itae, "itae")
    assert itae != newest_itae
    with pytest.raises(
        ConfigError, match=r"no FINISHED tune run with .*tuner\.objective\.criterion=iae"
    ):
        gains.tuned(cfg, "subsystem_adaptive", robot, "iae")
    # A given run must be of the criterion asked for (and of the controller).
    with pytest.raises(ConfigError) as bad:
        gains.tuned(cfg, "subsystem_adaptive", robot, "gaing", run_id=itae, key="eval.tune_runs.x")
    assert str(bad.value) == (
        f"eval.tune_runs.x={itae} is not allowed: that tune run was tuned under "
        "tuner.objective.criterion=itae, and gaing is needed here."
    )
    with pytest.raises(ConfigError, match=r"that tune run has controller\.name=subsystem_adaptive"):
        gains.tuned(cfg, "pid", robot, "itae", run_id=itae)


def test_a_run_without_a_criterion_is_gaing_over_its_logged_horizon() -> None:
    from mlflow.entities import Param, Run, RunData, RunInfo, RunTag

    def run(params: dict[str, str], tags: dict[str, str] | None = None) -> Run:
        info = RunInfo("r", "0", "u", "FINISHED", 0, None, "active")
        data = RunData(params=[Param(k, v) for k, v in params.items()],
                       tags=[RunTag(k, v) for k, v in (tags or {}).items()])  # fmt: skip
        return Run(info, data)

    old = run({"tuner.objective.horizon": "0.6"})
    assert gains.run_criterion(old) == "gaing" and gains.run_horizon(old) == 0.6
    assert gains.run_horizon(run({"tuner.objective.horizon": "0.2"})) == 0.2
    assert gains.run_horizon(run({})) == gains.OLD_HORIZON
    new = run({"tuner.objective.criterion": "itae", "tuner.objective.horizon": "None"})
    assert gains.run_criterion(new) == "itae"
    assert gains.run_horizon(new) == gains.resolved_horizon("itae", None)
    tagged = run({"tuner.objective.criterion": "itae"}, {"armexp.criterion": "iae",
                                                         "armexp.horizon": "2.5"})  # fmt: skip
    assert gains.run_criterion(tagged) == "iae" and gains.run_horizon(tagged) == 2.5


def test_configured_gains_are_the_composed_or_the_per_robot_defaults(
    compose: Callable[..., DictConfig],
) -> None:
    cfg = compose("controller.gains.a0=500")
    own = gains.resolve(cfg, "subsystem_adaptive", "two_link_paper", "config")
    assert own.values["a0"] == 500.0  # the user's override
    assert (own.criterion, own.horizon, own.tune_run) == ("config", None, None)
    pid = gains.resolve(cfg, "pid", "three_link", "config")
    defaults = compose("controller=pid", "robot=three_link").controller.gains
    assert pid.values == {k: list(v) for k, v in defaults.items()}
    assert len(pid.values["kp"]) == 3


def test_train_takes_the_latest_tune_run_of_its_criterion(
    compose: Callable[..., DictConfig],
) -> None:
    cfg = compose()
    other = "itae" if gains.criterion_of(cfg) == "gaing" else "gaing"
    mine = logged_tune_run(gains.with_criterion(cfg, gains.criterion_of(cfg)), "a0: 1.0\n")
    logged_tune_run(gains.with_criterion(cfg, other), "a0: 2.0\n")  # newer, another criterion
    values, tags = controller_gains_for(cfg)
    assert values == {"a0": 1.0} and tags["armexp.tune_run"] == mine
    values, tags = controller_gains_for(gains.with_criterion(cfg, other))
    assert values == {"a0": 2.0} and tags["armexp.gains_source"] == "tune"


def test_without_adaptation_sets_b1_to_zero_on_a_copy() -> None:
    on = {"a0": 1.0, "a1": 2.0, "b1": 3.0, "c1": 4.0, "r1": 5.0}
    off = gains.without_adaptation(on)
    assert off == {**on, "b1": 0.0} and on["b1"] == 3.0


def test_with_criterion_copies(compose: Callable[..., DictConfig]) -> None:
    cfg = compose()
    before = gains.criterion_of(cfg)
    changed = gains.with_criterion(cfg, "iae")
    assert gains.criterion_of(changed) == "iae" and gains.criterion_of(cfg) == before


@pytest.mark.parametrize(
    ("overrides", "source"),
    [
        ([], "tuned"),
        (["seed=3", "controller.dt=0.002"], "tuned"),
        (["controller.gains=paper"], "config"),
        (["controller/gains=paper"], "config"),
        (["controller.gains.a0=500"], "config"),
        (["controller.gains=paper", "train.gains=tuned"], "tuned"),
    ],
)
def test_gains_typed_on_the_command_are_the_ones_train_takes(
    compose: Callable[..., DictConfig], overrides: list[str], source: str
) -> None:
    cfg = compose(*overrides)
    assert gains.train_source(cfg, overrides) == source
    out = gains.with_train_source(cfg, overrides)
    assert out.train.gains == source
    assert cfg.train.gains == "tuned"  # the given config is left as it was
    assert (out is cfg) == (source == "tuned")
