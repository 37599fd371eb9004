"""Self-imitation: the agent's own reaching episodes are kept with the returns of the
environment's own rewards, the term clones only where such a return beat the critic, and a
non-privileged preset takes the aid."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from stable_baselines3.common.vec_env import DummyVecEnv

from armexp import aids
from armexp.agents.expert import TimeToGoExpert
from armexp.agents.sac import ResumableSAC, build_sac
from armexp.agents.self_imitation import OwnReaches, ReachingEpisodes, discounted_returns
from armexp.cli import main
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv
from tests.helpers import plain_train, refused_in_one_sentence, stage_runs

SELF = (
    "+agent.aids.self_imitation="
    "{_target_:armexp.agents.self_imitation.SelfImitation,weight:0.5,capacity:2000}"
)
GAMMA = 0.99


def test_returns_are_the_discounted_sums_to_the_episodes_end() -> None:
    rewards = np.array([-1.0, -0.5, 2.0, 200.0])
    want = [sum(GAMMA**k * r for k, r in enumerate(rewards[t:])) for t in range(4)]
    assert discounted_returns(rewards, GAMMA) == pytest.approx(want, rel=1e-12)


def _model(env: DummyVecEnv) -> ResumableSAC:
    cfg = compose_config(["controller.gains=paper", "agent=sac_smoke", "agent.net_arch=[16,16]"])
    return build_sac(cfg.agent, env, 0)


def test_the_reaching_episodes_are_kept_with_their_observations_actions_and_returns() -> None:
    settings = settings_from_config(compose_config(["controller.gains=paper"]))
    venv = DummyVecEnv([lambda: ReachEnv(settings)])
    model = _model(venv)
    kept = OwnReaches(model, 1.0, capacity=5000, seed=0)
    callback = ReachingEpisodes(kept, GAMMA)
    callback.init_callback(model)
    callback.on_training_start({}, {})
    expert = TimeToGoExpert(settings, margin=0.10)
    venv.seed(4)
    obs = np.asarray(venv.reset())
    seen: list[tuple[np.ndarray, np.ndarray, float]] = []
    episodes: list[tuple[bool, list[tuple[np.ndarray, np.ndarray, float]]]] = []
    # Two episodes: the planner's reach, then one that drives the elbow into its limit.
    while len(episodes) < 2:
        actions = expert(obs) if not episodes else np.array([[0.0, 1.0]])
        model._last_obs = obs  # as SB3 holds it while the callback runs
        new_obs, rewards, dones, infos = venv.step(actions)
        new_obs = np.asarray(new_obs)
        seen.append((obs[0].copy(), actions[0].copy(), float(rewards[0])))
        callback.update_locals(
            {"buffer_actions": actions, "rewards": rewards, "dones": dones, "infos": infos}
        )
        callback.on_step()
        obs = new_obs
        if dones[0]:
            episodes.append((bool(infos[0]["is_success"]), seen))
            seen = []
    (reached, first), (limit, second) = episodes
    assert reached and not limit and second[-1][2] == -50.0  # Table I's joint-limit reward
    assert callback.reached == 1 and len(kept) == len(first) > 50
    assert torch.equal(kept.obs[: len(first)], torch.as_tensor(np.stack([s[0] for s in first])))
    assert torch.equal(kept.actions[: len(first)], torch.as_tensor(np.stack([s[1] for s in first])))
    rewards = np.array([s[2] for s in first])
    assert rewards[-1] == 200.0  # Table I's reach reward, as env.step gave it
    want = discounted_returns(rewards, GAMMA)
    assert kept.returns[: len(first)].numpy() == pytest.approx(want, rel=1e-6)
    assert kept.attached == (len(first) >= model.batch_size)


def test_the_term_clones_only_where_the_return_beat_the_critic() -> None:
    settings = settings_from_config(compose_config(["controller.gains=paper"]))
    model = _model(DummyVecEnv([lambda: ReachEnv(settings)]))
    term = OwnReaches(model, 2.0, capacity=10, seed=0)
    mode = torch.tensor([[0.1, 0.2], [0.3, -0.4], [0.0, 0.5], [-0.2, 0.1]], requires_grad=True)
    actions = torch.tensor([[0.5, 0.2], [0.3, 0.4], [-1.0, 0.5], [0.2, 0.3]])
    q = torch.tensor([1.0, -2.0, 3.0, -4.0])
    returns = torch.tensor([2.0, -3.0, 3.0, 0.0])  # beat, fell short, level, beat
    loss = term.value(mode, actions, q, returns)
    error = ((mode - actions) ** 2).mean(dim=1).detach()
    assert float(loss.detach()) == pytest.approx(2.0 * 2.5 * float(error[0] + error[3]) / 4)
    loss.backward()
    assert mode.grad is not None
    assert torch.count_nonzero(mode.grad[1:3]) == 0 and torch.count_nonzero(mode.grad[0]) > 0


def test_only_the_last_capacity_steps_are_kept() -> None:
    settings = settings_from_config(compose_config(["controller.gains=paper"]))
    model = _model(DummyVecEnv([lambda: ReachEnv(settings)]))
    term = OwnReaches(model, 1.0, capacity=4, seed=0)
    d = model.observation_space.shape[0]  # type: ignore[index]
    for start in (0, 3):
        steps = np.arange(start, start + 3, dtype=np.float32)
        term.add(np.repeat(steps[:, None], d, axis=1), np.zeros((3, 2)), steps)
    assert len(term) == 4 and term.added == 6
    assert sorted(term.returns.tolist()) == [2.0, 3.0, 4.0, 5.0]
    term.add(np.zeros((9, d)), np.zeros((9, 2)), np.arange(9.0))  # more than it holds
    assert sorted(term.returns.tolist()) == [5.0, 6.0, 7.0, 8.0] and term.added == 15


@pytest.mark.long
def test_a_non_privileged_preset_trains_with_self_imitation_and_others_are_refused(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert aids.SELF_IMITATION.privileged is False
    base = plain_train(runs_dir)
    assert main([*base, SELF]) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.data.params["agent.aids.self_imitation.weight"] == "0.5"
    assert run.data.metrics["final/self_imitation_steps"] >= 0
    refused_in_one_sentence(
        runs_dir, capsys, [*base, SELF, "agent=td3_quick", "agent.max_env_steps=600"],
        "agent.aids.self_imitation is not allowed with agent.algo=td3",
    )  # fmt: skip
    refused_in_one_sentence(
        runs_dir, capsys, [*base, SELF.replace("weight:0.5", "weight:0")],
        "agent.aids.self_imitation is not allowed", "weight=0",
    )  # fmt: skip
