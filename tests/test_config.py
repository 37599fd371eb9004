"""The config tree composes for every option, and bad values stop with one sentence."""

from __future__ import annotations

from collections.abc import Callable

import pytest
from omegaconf import DictConfig

from armexp.config import ConfigError, compose_config, group_options

GROUPS = [
    "robot",
    "obstacles",
    "controller",
    "tuner",
    "agent",
    "env",
    "tasks",
    "scenario",
    "tracking",
    "experiment",
]


def test_every_group_of_the_design_exists_with_options() -> None:
    for group in GROUPS:
        assert group_options(group), group


@pytest.mark.long
@pytest.mark.parametrize("group", GROUPS)
def test_every_option_composes_and_validates(
    group: str, compose: Callable[..., DictConfig]
) -> None:
    for option in group_options(group):
        cfg = compose(f"{group}={option}")
        if group not in ("experiment", "scenario", "tracking", "env"):
            assert cfg[group].name == option


def test_default_config_values_match_the_paper(compose: Callable[..., DictConfig]) -> None:
    cfg = compose()
    assert cfg.robot.name == "two_link_paper"
    assert list(cfg.robot.lengths) == [1.0, 0.8] and list(cfg.robot.masses) == [20.0, 15.0]
    assert dict(cfg.controller.gains) == {
        "a0": 668.0,
        "a1": 552.0,
        "b1": 1.8,
        "c1": 0.001,
        "r1": 0.69,
    }
    assert (cfg.tuner.n_nests, cfg.tuner.n_iterations, cfg.tuner.pa, cfg.tuner.beta) == (
        15,
        200,
        0.25,
        1.5,
    )
    a = cfg.agent
    assert (
        a.batch_size,
        a.tau,
        a.buffer_size,
        a.learning_starts,
        a.gamma,
        a.learning_rate,
        a.episodes,
    ) == (512, 0.001, 1_000_000, 1000, 0.995, 0.001, 20000)
    assert list(cfg.robot.velocity_bound) == [0.1, 0.4]
    assert cfg.env.reach_threshold == 0.04 and cfg.env.max_steps == 1000


@pytest.mark.long
def test_gains_preset_override_and_experiment_preset(compose: Callable[..., DictConfig]) -> None:
    assert compose("controller.gains=paper").controller.gains.a0 == 668.0
    smoke = compose("experiment=smoke")
    assert smoke.tuner.name == "cso_fast" and smoke.agent.name == "sac_smoke"
    # The README's first line: sac_quick's aids and networks, smaller critics, a step budget.
    demo, quick = compose("experiment=demo").agent, compose("experiment=quick").agent
    assert demo.name == "sac_demo" and demo.max_env_steps == 240_000
    assert demo.critic_arch == [64, 64] and quick.critic_arch is None
    assert demo.aids == quick.aids and demo.net_arch == quick.net_arch == [128, 128]
    # The demo in 100 k steps: the same agent at two gradient steps per environment step.
    fast = compose("experiment=demo", "agent=sac_demo_100k").agent
    assert fast.max_env_steps == 100_000 and fast.gradient_steps == 16 and fast.n_envs == 8
    differs = {k for k in demo if k != "name" and fast[k] != demo[k]}
    assert differs == {"gradient_steps", "max_env_steps"}


@pytest.mark.parametrize(
    ("overrides", "words"),
    [
        (["controller.gains.a0=-1"], ["controller.gains.a0=-1", "> 0"]),
        (["robot=four_link"], ["robot=four_link", "three_link", "two_link_paper"]),
        (["controller.bounds.a0=[5,1]"], ["controller.bounds.a0", "lower bound 5.0"]),
        (["controller.gains.a1=abc"], ["controller.gains.a1=abc", "number"]),
        (["tuner.pa=1.5"], ["tuner.pa=1.5", "[0.0, 1.0]"]),
        (["tuner.n_nests=1"], ["tuner.n_nests=1", "≥ 2"]),
        (["tuner.abandon=best"], ["tuner.abandon='best'", "worst, per_component"]),
        (
            ["robot=three_link", "controller=pid", "controller.gains.kp=[1.0,2.0]"],
            ["controller.gains.kp", "3 joints"],
        ),
        (["robot.q0=[3.0,0.0]"], ["robot.q0[0]=3.0", "within"]),
        (["nonsense_key=1"], ["nonsense_key", "not a config key"]),
        (["scenario.kind=zigzag"], ["scenario.kind='zigzag'", "switching, hold, sine"]),
        (["seed=0,1"], ["-m"]),
        (["env.action_period=0.0305"], ["env.action_period=0.0305", "whole number"]),
        (["tuner.objective.switch_period=0.0005"], ["switch_period=0.0005", "controller.dt"]),
        (["agent.vec_env=threads"], ["agent.vec_env='threads'", "dummy, subproc"]),
        (["train.gains=best"], ["train.gains='best'", "tuned, config"]),
        (["agent.n_envs=0"], ["agent.n_envs=0", "≥ 1"]),
        (["agent.critic_arch=[64,0]"], ["agent.critic_arch=[64, 0]", "≥ 1"]),
        (["+agent.aids.x=3"], ["agent.aids.x=3", "_target_"]),
        # Values of the right type that make no sense: one sentence, not a traceback.
        (["agent.device=foo"], ["agent.device='foo'", "cpu, auto, mps, cuda"]),
        (["agent.ent_coef=abc"], ["agent.ent_coef='abc'", "'auto'"]),
        (["train.torch_threads=-2"], ["train.torch_threads=-2", "≥ 1, or null"]),
        (["tracking.experiment=''"], ["tracking.experiment=''", "non-empty"]),
        (["controller.gains.a0=inf"], ["controller.gains.a0=inf", "> 0"]),
        (["agent.max_env_steps=-5"], ["agent.max_env_steps=-5", "≥ 1, or null"]),
        (["agent.max_minutes=-1"], ["agent.max_minutes=-1", "> 0, or null"]),
        (["agent.max_env_steps=0"], ["agent.max_env_steps=0", "≥ 1, or null"]),
        (
            ["agent.max_env_steps=null", "agent.max_minutes=null"],
            ["agent.max_env_steps=null with agent.max_minutes=null", "needs a budget"],
        ),
        (["report.fig6_task=z"], ["report.fig6_task='z'", "a, b, c, d"]),
        (["tuner.n_iterations=0"], ["tuner.n_iterations=0", "≥ 1"]),
        (["controller.gains=nonexistent"], ["controller.gains=nonexistent", "one of: paper"]),
        (["+controller.gains.zz=1"], ["controller.gains.zz is not a config key", "a0, a1"]),
        # From the fields of Hydra's and OmegaConf's exceptions: the schema's declared type.
        (["robot.lengths=[a,b]"], ["robot.lengths[0]=a", "a number"]),
        (["robot.lengths=3"], ["robot.lengths=3", "a list"]),
        (["robot.lengths.5=1"], ["robot.lengths.5=1", "no entry [5]"]),
        (["agent.max_env_steps=abc"], ["agent.max_env_steps=abc", "an integer, or null"]),
        (["train.progress=maybe"], ["train.progress=maybe", "true or false"]),
        (["robot.uncertainty=5"], ["robot.uncertainty=5", "a group of settings"]),
        (["hydra/launcher=nope"], ["hydra/launcher=nope", "basic, joblib"]),
        (["robot.lengths=[1,"], ["robot.lengths=[1, is not a valid override"]),
        (["seed=range(3)"], ["seed=range(3) is a sweep", "-m"]),
        (["tasks.targets.0.x=3.0"], ["tasks.targets[0]", "outside the arm's reach"]),
        (["tasks.targets.0.x=0.5", "tasks.targets.0.y=1.3"], ["inside obstacles.circles[0]"]),
        (
            ["obstacles.circles.0.x=1.0", "obstacles.circles.0.y=0.4"],
            ["obstacles.circles[0]", "covers link 2", "robot.q0"],
        ),
    ],
)
def test_bad_values_give_one_sentence(overrides: list[str], words: list[str]) -> None:
    with pytest.raises(ConfigError) as info:
        compose_config(overrides)
    msg = str(info.value)
    assert "\n" not in msg and msg.endswith(".")
    for w in words:
        assert w in msg, (w, msg)
