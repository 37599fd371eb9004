"""SAC built from the ``agent`` config (armexp.agents.sac)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from omegaconf import DictConfig, OmegaConf
from stable_baselines3 import SAC

from armexp.agents.sac import ResumableSAC, build_sac, load_sac, sac_kwargs
from armexp.agents.vec import make_vec_env
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.report.tables import table_two


def _sac(*overrides: str) -> tuple[ResumableSAC, DictConfig]:
    cfg = compose_config(["controller.gains=paper", "agent=sac_quick", *overrides])
    env = make_vec_env(settings_from_config(cfg), 1, "dummy", 0)
    return build_sac(cfg.agent, env, 0), cfg.agent


def _widths(net: torch.nn.Module) -> list[int]:
    return [m.out_features for m in net.modules() if isinstance(m, torch.nn.Linear)]


def test_the_critics_take_their_own_hidden_layers_and_keep_them_through_a_save(
    tmp_path: Path,
) -> None:
    model, agent = _sac("agent.critic_arch=[64,64]")
    assert _widths(model.actor.latent_pi) == [128, 128]
    for q in (*model.critic.q_networks, *model.critic_target.q_networks):
        assert _widths(q) == [64, 64, 1]
    model.save(tmp_path / "m.zip")
    loaded = load_sac(str(tmp_path / "m.zip"), None, agent)
    assert [_widths(q) for q in loaded.critic.q_networks] == [[64, 64, 1]] * 2
    same, _ = _sac()
    assert [_widths(q) for q in same.critic.q_networks] == [[128, 128, 1]] * 2


def _table_two(row: str, *overrides: str) -> str:
    """Table II's value in ``row`` for the config of ``overrides``."""
    cfg = OmegaConf.to_container(compose_config(list(overrides)), resolve=True)
    shown = table_two(cfg).shown  # type: ignore[arg-type]
    (value,) = shown.loc[shown.iloc[:, 0] == row].iloc[:, 1]
    return str(value)


def test_table_ii_names_the_critics_hidden_layers_where_they_differ() -> None:
    assert _table_two("Hidden layers", "experiment=demo") == "actor 128×128, critics 64×64"
    assert _table_two("Hidden layers", "experiment=quick") == "128×128"


@pytest.mark.long
def test_table_ii_says_how_the_gradients_were_computed() -> None:
    assert _table_two("Gradients", "experiment=demo") == "compiled"
    assert _table_two("Gradients", "experiment=quick") == "compiled"
    assert _table_two("Gradients", "experiment=reproduce") == "autograd"
    assert _table_two("Gradients", "experiment=quick", "agent.gradients=autograd") == "autograd"


@pytest.mark.long
def test_the_lean_update_gives_the_parameters_of_sb3s_update() -> None:
    class Reference(ResumableSAC):
        train = SAC.train  # SB3's own update

    def trained(cls: type[ResumableSAC]) -> tuple[torch.Tensor, dict[str, float]]:
        cfg = compose_config(
            ["controller.gains=paper", "experiment=demo", "agent.learning_starts=100"]
        )
        env = make_vec_env(settings_from_config(cfg), 2, "dummy", 0)
        model = cls("MlpPolicy", env, seed=0, verbose=0, **sac_kwargs(cfg.agent))
        model.learn(600)
        logged = {k: float(v) for k, v in model.logger.name_to_value.items() if "loss" in k}
        tensors = [p.detach().flatten() for p in model.policy.parameters()]
        assert model.log_ent_coef is not None  # ent_coef "auto"
        return torch.cat([*tensors, model.log_ent_coef.detach().flatten()]), logged

    (ours, our_log), (sb3, sb3_log) = trained(ResumableSAC), trained(Reference)
    assert ours.numel() > 10_000 and torch.equal(ours, sb3)
    assert our_log == sb3_log and set(our_log) == {
        "train/actor_loss", "train/critic_loss", "train/ent_coef_loss"
    }  # fmt: skip
