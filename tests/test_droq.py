"""``agent.critic_dropout``: SAC with DroQ's critics (armexp.agents.droq) — dropout and layer
normalisation in each Q-network, dropout in the target critics too, SB3's update, save and load
on them; the compiled update and a rate outside (0, 1) are refused in one sentence."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3.common.logger import Logger
from torch import nn

from armexp.agents.droq import DroQPolicy
from armexp.agents.factory import build_agent, load_agent
from armexp.agents.sac import ResumableSAC
from armexp.agents.vec import make_vec_env
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from tests.test_algorithms import SMALL, _refused
from tests.test_sac import _table_two


def _sac(*overrides: str) -> ResumableSAC:
    cfg = compose_config([*SMALL, "agent.gradients=autograd", *overrides])
    env = make_vec_env(settings_from_config(cfg, with_tasks=False), 1, "dummy", 0)
    model = build_agent(cfg.agent, env, 0)
    model.set_logger(Logger(folder=None, output_formats=[]))
    assert isinstance(model, ResumableSAC)
    return model


def _layers(net: nn.Module) -> list[str]:
    return [type(m).__name__ for m in net.children()]


def test_the_critics_are_droqs_and_the_actor_is_sb3s() -> None:
    model = _sac("agent.critic_dropout=0.05", "agent.net_arch=[32,16]")
    assert isinstance(model.policy, DroQPolicy)
    for critic in (model.critic, model.critic_target):
        assert len(critic.q_networks) == 2
        for q_net in critic.q_networks:
            assert _layers(q_net) == ["Linear", "Dropout", "LayerNorm", "ReLU"] * 2 + ["Linear"]
            assert [m.p for m in q_net.modules() if isinstance(m, nn.Dropout)] == [0.05, 0.05]
            widths = [m.out_features for m in q_net.modules() if isinstance(m, nn.Linear)]
            assert widths == [32, 16, 1]
    assert not any(isinstance(m, nn.Dropout | nn.LayerNorm) for m in model.actor.modules())
    # SB3's plain critics where the key is unset.
    plain = _sac("agent.net_arch=[32,16]")
    assert type(plain.policy).__name__ == "SACPolicy"
    assert _layers(plain.critic.q_networks[0]) == ["Linear", "ReLU", "Linear", "ReLU", "Linear"]


def test_dropout_acts_in_the_update_in_the_target_too_and_not_when_acting() -> None:
    model = _sac("agent.critic_dropout=0.5")
    obs = torch.rand(64, model.observation_space.shape[0])  # type: ignore[index]
    act = torch.rand(64, 2) * 2 - 1
    model.policy.set_training_mode(True)  # as SB3's train does
    for critic in (model.critic, model.critic_target):
        assert critic.training
        first, second = critic(obs, act)[0], critic(obs, act)[0]
        assert not torch.allclose(first, second)  # a fresh dropout mask per evaluation
    model.policy.set_training_mode(False)  # as predict does: the acting actor has no dropout
    a1, _ = model.predict(obs.numpy(), deterministic=True)
    a2, _ = model.predict(obs.numpy(), deterministic=True)
    assert np.array_equal(a1, a2)
    model.critic.set_training_mode(False)
    assert torch.equal(model.critic(obs, act)[0], model.critic(obs, act)[0])


def test_it_trains_saves_and_loads_with_its_rate(tmp_path: Path) -> None:
    model = _sac("agent.critic_dropout=0.02")
    before = [p.detach().clone() for p in model.critic.parameters()]
    model.learn(300)
    assert model._n_updates > 0
    after = list(model.critic.parameters())
    assert any(not torch.equal(b, a) for b, a in zip(before, after, strict=True))
    model.save(tmp_path / "m.zip")
    cfg = compose_config([*SMALL, "agent.gradients=autograd", "agent.critic_dropout=0.02"])
    loaded = load_agent(str(tmp_path / "m.zip"), None, cfg.agent)
    assert isinstance(loaded, ResumableSAC)
    assert isinstance(loaded.policy, DroQPolicy) and loaded.policy.critic_dropout == 0.02
    for ours, theirs in zip(model.critic.state_dict().values(),
                            loaded.critic.state_dict().values(), strict=True):  # fmt: skip
        assert torch.equal(ours, theirs)
    obs = np.asarray(model.get_env().reset())  # type: ignore[union-attr]
    assert np.allclose(model.predict(obs, deterministic=True)[0],
                       loaded.predict(obs, deterministic=True)[0])  # fmt: skip


@pytest.mark.parametrize(
    ("overrides", "said"),
    [
        (
            ["agent=sac_smoke", "agent.critic_dropout=0.01", "agent.gradients=compiled"],
            "agent.critic_dropout=0.01 is not allowed with agent.gradients=compiled: the compiled "
            "update does not cover dropout critics; use agent.gradients=autograd.",
        ),
        (
            ["agent=sac_smoke", "agent.critic_dropout=1.0"],
            "agent.critic_dropout=1.0 is not allowed: a rate in (0, 1), or null.",
        ),
    ],
)
def test_a_rate_the_update_cannot_take_is_one_sentence_and_no_run(
    overrides: list[str], said: str, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _refused(overrides, runs_dir, capsys) == f"armexp train: {said}"


def test_table_ii_lists_the_dropout_as_a_change_left_open() -> None:
    row, plain = "Changed from Table II", "agent=sac_plain"
    dropout = _table_two(row, plain, "agent.critic_dropout=0.01", "agent.gradients=autograd")
    assert "critic dropout (DroQ) – → 0.01" in dropout
    assert "critic dropout" not in _table_two(row, plain)
