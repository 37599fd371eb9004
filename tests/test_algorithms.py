"""``agent.algo``: one factory builds SAC, TD3, TQC, CrossQ and PPO from the ``agent`` config
(armexp.agents.factory); every preset composes; add-ons refuse the algorithms they do not apply
to; Table II and run names carry the algorithm."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig, OmegaConf
from sb3_contrib import TQC, CrossQ
from stable_baselines3 import PPO, SAC, TD3
from stable_baselines3.common.logger import Logger

from armexp.agents.algorithms import ResumeRefill
from armexp.agents.factory import ALGORITHM, build_agent, load_agent, mark_resumed, usage
from armexp.agents.vec import make_vec_env
from armexp.aids import OFF_POLICY
from armexp.cli import main
from armexp.config import ALGORITHMS, ConfigError, compose_config, config_dir
from armexp.config.agent_schema import agent_label
from armexp.envs.factory import settings_from_config
from armexp.report.agent import AgentInfo
from armexp.report.tables import table_two
from tests.helpers import SMALL_TRAIN, interrupt_training_at, stage_runs

#: A small agent on 100-step episodes: seconds to train a few hundred steps.
SMALL = ["controller.gains=paper", "agent=sac_smoke", "agent.net_arch=[32,32]",
         "agent.learning_starts=100", "agent.batch_size=32", "agent.ppo.n_steps=64",
         "agent.tqc.n_quantiles=5",
         "env.max_steps=100"]  # fmt: skip
AVERAGING = "+agent.aids.averaging={_target_: armexp.agents.averaging.WeightAveraging, tail: 0.2}"
PRESETS = sorted(p.stem for p in (config_dir() / "agent").glob("*.yaml"))


def _agent(algo: str, *overrides: str) -> tuple[Any, DictConfig]:
    cfg = compose_config([*SMALL, f"agent.algo={algo}", *overrides])
    env = make_vec_env(settings_from_config(cfg, with_tasks=False), 1, "dummy", 0)
    model = build_agent(cfg.agent, env, 0)
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model, cfg.agent


# --------------------------------------------------------------------------------- presets
@pytest.mark.parametrize("preset", PRESETS)
def test_every_agent_preset_composes_and_names_an_algorithm(preset: str) -> None:
    agent = compose_config([f"agent={preset}"]).agent
    assert agent.algo in ALGORITHMS
    assert agent.max_env_steps is not None  # budgets are in environment steps


@pytest.mark.long
@pytest.mark.parametrize("preset", PRESETS)
def test_a_preset_without_sac_only_options_composes_with_every_algorithm(preset: str) -> None:
    agent = compose_config([f"agent={preset}"]).agent
    if agent.aids or agent.gradients == "compiled":
        pytest.skip(f"{preset} carries SAC's aids or compiled update (refused elsewhere)")
    for algo in ALGORITHMS:
        assert compose_config([f"agent={preset}", f"agent.algo={algo}"]).agent.algo == algo


@pytest.mark.long
def test_each_quick_preset_is_its_algorithm() -> None:
    for algo in ALGORITHMS:
        assert compose_config([f"agent={algo}_quick"]).agent.algo == algo


# --------------------------------------------------------------------------------- factory
@pytest.mark.long
def test_the_factory_builds_each_algorithm_with_its_hyperparameters() -> None:
    classes = {"sac": SAC, "td3": TD3, "tqc": TQC, "crossq": CrossQ, "ppo": PPO}
    for algo, cls in classes.items():
        model, _ = _agent(algo, "agent.gamma=0.97", "agent.learning_rate=0.002")
        assert isinstance(model, cls), algo
        assert model.gamma == pytest.approx(0.97), algo
        assert model.lr_schedule(1.0) == pytest.approx(0.002), algo

    td3, _ = _agent("td3", "agent.td3.policy_delay=3", "agent.td3.target_policy_noise=0.3",
                    "agent.td3.action_noise=0.2", "agent.tau=0.02")  # fmt: skip
    assert (td3.policy_delay, td3.target_policy_noise, td3.tau) == (3, 0.3, 0.02)
    assert np.allclose(td3.action_noise._sigma, [0.2, 0.2])
    quiet, _ = _agent("td3", "agent.td3.action_noise=0")
    assert quiet.action_noise is None

    tqc, _ = _agent("tqc", "agent.tqc.n_quantiles=10", "agent.tqc.n_critics=3",
                    "agent.tqc.top_quantiles_to_drop_per_net=1")  # fmt: skip
    assert (tqc.critic.n_quantiles, tqc.critic.n_critics) == (10, 3)
    assert tqc.top_quantiles_to_drop_per_net == 1

    crossq, _ = _agent("crossq", "agent.crossq.policy_delay=2", "agent.critic_arch=[48,48]")
    assert crossq.policy_delay == 2
    widths = [m.out_features for m in crossq.critic.modules() if isinstance(m, torch.nn.Linear)]
    assert widths[:3] == [48, 48, 1]

    ppo, _ = _agent("ppo", "agent.ppo.n_epochs=4", "agent.ppo.clip_range=0.1",
                    "agent.critic_arch=[16]", "agent.batch_size=16")  # fmt: skip
    assert (ppo.n_steps, ppo.n_epochs, ppo.batch_size) == (64, 4, 16)
    assert ppo.clip_range(1.0) == pytest.approx(0.1)
    value = [m.out_features for m in ppo.policy.mlp_extractor.value_net.modules()
             if isinstance(m, torch.nn.Linear)]  # fmt: skip
    assert value == [16]


@pytest.mark.long
def test_what_each_algorithm_maps_or_leaves_out_is_said_in_one_line() -> None:
    lines = {a: usage(compose_config([*SMALL, f"agent.algo={a}"]).agent).line("sac_smoke")
             for a in ALGORITHMS}  # fmt: skip
    assert lines["sac"] == lines["tqc"] == ""
    assert lines["td3"] == "agent.algo=td3 on agent=sac_smoke: agent.ent_coef does not apply."
    assert lines["crossq"] == "agent.algo=crossq on agent=sac_smoke: agent.tau does not apply."
    assert lines["ppo"].startswith(
        "agent.algo=ppo on agent=sac_smoke: agent.batch_size is PPO's minibatch size; agent.tau, "
        "agent.buffer_size, agent.learning_starts, agent.train_freq, agent.gradient_steps, "
    )
    # An option the algorithm has no use for is said once it is set.
    td3 = compose_config([*SMALL, "agent.algo=td3", "agent.target_entropy=-1.0"]).agent
    assert usage(td3).line("sac_smoke") == (
        "agent.algo=td3 on agent=sac_smoke: agent.ent_coef, agent.target_entropy do not apply."
    )
    assert set(ALGORITHM) == set(ALGORITHMS)
    assert {a.name for a in ALGORITHM.values() if a.off_policy} == OFF_POLICY


@pytest.mark.long
@pytest.mark.parametrize("algo", ALGORITHMS)
def test_each_algorithm_trains_saves_and_loads(algo: str, tmp_path: Path) -> None:
    model, agent = _agent(algo)
    model.learn(300)
    assert model.num_timesteps >= 300
    model.save(tmp_path / "m.zip")
    loaded = load_agent(str(tmp_path / "m.zip"), None, agent)
    assert type(loaded) is type(model)
    obs = np.asarray(model.get_env().reset())  # type: ignore[union-attr]
    ours, _ = model.predict(obs, deterministic=True)
    theirs, _ = loaded.predict(obs, deterministic=True)
    assert np.allclose(ours, theirs)


@pytest.mark.long
@pytest.mark.parametrize("algo", ["td3", "tqc", "crossq"])
def test_a_resumed_off_policy_model_refills_its_buffer_with_its_policy(
    algo: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    model, agent = _agent(algo)
    model.learn(150)
    model.save(tmp_path / "m.zip")
    loaded = load_agent(str(tmp_path / "m.zip"), model.get_env(), agent)
    mark_resumed(loaded, 100)
    assert isinstance(loaded, ResumeRefill) and loaded.resumed
    assert loaded.learning_starts == loaded.num_timesteps + 100

    def uniform() -> Any:
        raise AssertionError("a resumed model samples uniform random actions")

    monkeypatch.setattr(loaded.action_space, "sample", uniform)
    loaded._last_obs = model.get_env().reset()
    loaded._sample_action(loaded.learning_starts, loaded.action_noise, 1)


def test_ppo_resumes_from_its_step_count_without_a_buffer_to_refill(tmp_path: Path) -> None:
    model, agent = _agent("ppo")
    model.learn(128)
    model.save(tmp_path / "m.zip")
    loaded = load_agent(str(tmp_path / "m.zip"), model.get_env(), agent)
    mark_resumed(loaded, 100)
    assert not isinstance(loaded, ResumeRefill)
    loaded.learn(128, reset_num_timesteps=False)
    assert loaded.num_timesteps == 256


# ------------------------------------------------------------------------------ bad input
def _refused(overrides: list[str], runs_dir: Path, capsys: pytest.CaptureFixture[str]) -> str:
    """The one line ``armexp train`` answers ``overrides`` with (exit 2), having made no run."""
    assert main(["train", *overrides, f"tracking.runs_dir={runs_dir}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    db = runs_dir / "mlflow.db"
    assert not db.exists() or not MlflowClient(f"sqlite:///{db}").search_runs(["0"])
    return err[0]


@pytest.mark.parametrize(
    ("overrides", "said"),
    [
        (
            ["agent=sac_quick", "agent.gradients=autograd", "agent.algo=ppo"],
            "agent.aids.demonstrations is not allowed with agent.algo=ppo: PlannerDemonstrations "
            "applies to agent.algo=sac, td3, tqc, crossq only; remove it "
            "(~agent.aids.demonstrations) or use one of those.",
        ),
        (
            ["agent=sac_quick", "agent.gradients=autograd", "agent.algo=td3"],
            "agent.aids.cloning is not allowed with agent.algo=td3: BehaviourCloning applies to "
            "agent.algo=sac only; remove it (~agent.aids.cloning) or use agent.algo=sac.",
        ),
        (
            ["agent=ppo_quick", AVERAGING],
            "agent.aids.averaging is not allowed with agent.algo=ppo: WeightAveraging applies to "
            "agent.algo=sac, td3, tqc, crossq only;",
        ),
        (
            ["agent=sac_smoke", "agent.algo=foo"],
            "agent.algo='foo' is not allowed: allowed: sac, td3, tqc, crossq, ppo.",
        ),
        (
            ["agent=sac_smoke", "agent.algo=tqc", "agent.gradients=compiled"],
            "agent.gradients=compiled is not allowed with agent.algo=tqc: the compiled update is "
            "SAC's own; use agent.gradients=autograd (tqc runs its library's update) or "
            "agent.algo=sac.",
        ),
        (
            ["agent=sac_smoke", "agent.algo=ppo", "agent.ppo.n_steps=2048"],
            "agent.ppo.n_steps=2048 is not allowed with agent.n_envs=2 and "
            "agent.max_env_steps=2000: one PPO rollout (4096 steps) must fit the budget, so give "
            "agent.ppo.n_steps ≤ 1000.",
        ),
    ],
)
def test_a_misapplied_option_is_one_sentence_and_no_run(
    overrides: list[str], said: str, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert said in _refused(overrides, runs_dir, capsys)


def test_the_factory_refuses_what_the_config_check_refuses() -> None:
    from armexp.agents.addons import build_addons

    aids = compose_config(["agent=sac_quick"]).agent.aids
    with pytest.raises(ConfigError, match=r"^agent\.aids\.demonstrations is not allowed with"):
        build_addons(aids, algo="ppo")
    assert len(build_addons(aids, algo="sac")) == 4


# ------------------------------------------------------------------- names and Table II
def test_names_carry_the_algorithm_where_the_preset_is_another_algorithms() -> None:
    assert agent_label("sac_smoke", "td3") == "sac_smoke-td3"
    assert agent_label("td3_quick", "td3") == "td3_quick"
    assert agent_label("sac_quick", None) == "sac_quick"  # a run stored before agent.algo
    assert AgentInfo("r", "sac_smoke-ppo", algo="ppo").label == (
        "sac_smoke-ppo (plain PPO, no learning aids)"
    )


def _rows(*overrides: str, agents: tuple[AgentInfo, ...] = ()) -> dict[str, str]:
    cfg = OmegaConf.to_container(compose_config(list(overrides)), resolve=True)
    shown = table_two(cfg, agents).shown  # type: ignore[arg-type]
    return dict(zip(shown.iloc[:, 0], shown.iloc[:, 1], strict=True))


def test_table_ii_names_the_algorithm_and_its_own_values() -> None:
    rows = _rows("agent=td3_quick", "agent.td3.policy_delay=4")
    assert rows["Algorithm"] == "TD3"
    assert rows["TD3: policy_delay"] == "4"
    assert "Entropy coefficient" not in rows
    assert _rows("agent=sac_paper")["Algorithm"] == "SAC"
    info = AgentInfo("r", "sac_smoke-ppo", algo="ppo", left_out=("tau", "buffer_size"))
    ppo = _rows("agent=sac_smoke", "agent.algo=ppo", agents=(info,))
    assert ppo["Algorithm"] == "PPO"
    assert ppo["Target smoothing factor"] == "– (not PPO's)"
    assert ppo["PPO: n_steps"] == "256"


@pytest.mark.long
@pytest.mark.parametrize("algo", ["td3", "ppo"])
def test_a_train_run_tags_its_algorithm_and_is_named_after_it(
    algo: str, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    args = ["train", *SMALL_TRAIN, "train.gains=config", "controller.gains=paper",
            f"agent.algo={algo}", "agent.ppo.n_steps=128"]  # fmt: skip
    assert main([*args, f"tracking.runs_dir={runs_dir}"]) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.data.tags["armexp.agent_algo"] == algo
    assert run.data.tags["mlflow.runName"] == f"train-sac_smoke-{algo}-s0"
    left_out = run.data.tags["armexp.agent_left_out"].split(",")
    unset = {"target_entropy", "critic_dropout"}  # null in the preset: not applied, not left out
    assert left_out == (
        ["ent_coef"]
        if algo == "td3"
        else [k for k in ALGORITHM["ppo"].leaves_out if k not in unset]
    )
    mapped = run.data.tags.get("armexp.agent_mapped")
    assert mapped == ("batch_size=minibatch size" if algo == "ppo" else None)
    assert f"train: agent.algo={algo} on agent=sac_smoke: " in capsys.readouterr().out


def test_ppo_is_sized_by_its_rollout_not_by_a_replay_buffer() -> None:
    from armexp.resources import estimate

    (sac, _) = estimate(compose_config(["agent=sac_paper"]), "train")
    (ppo, _) = estimate(compose_config(["agent=sac_paper", "agent.algo=ppo"]), "train")
    assert (sac.key, ppo.key) == ("agent.buffer_size", "agent.ppo.n_steps")
    assert ppo.bytes == sac.bytes // 1_000_000 * 2048


@pytest.mark.long
@pytest.mark.parametrize("algo", ["td3", "ppo"])
def test_an_interrupted_run_of_another_algorithm_resumes_to_its_budget(
    algo: str, runs_dir: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    where = f"tracking.runs_dir={runs_dir}"
    command = ["train", *SMALL_TRAIN, "train.gains=config", "controller.gains=paper",
               f"agent.algo={algo}", "agent.ppo.n_steps=128", where]  # fmt: skip
    interrupt_training_at(monkeypatch, 300)
    assert main(command) == 130
    monkeypatch.undo()
    (run,) = stage_runs(runs_dir, "train")
    assert main([*command, f"train.resume={run.info.run_id}"]) == 0
    (resumed,) = stage_runs(runs_dir, "train")
    assert resumed.info.run_id == run.info.run_id and resumed.info.status == "FINISHED"
    assert resumed.data.tags["armexp.resumed_from_step"] == "300"
    assert resumed.data.metrics["final/env_steps"] == 600
