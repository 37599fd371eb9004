"""The count bonus: β(t)/√N over the observed posture's cell, added to the rewards the replay
buffer stores and to nothing else, falling to 0; a non-privileged preset takes the aid."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from stable_baselines3 import SAC
from stable_baselines3.common.callbacks import BaseCallback, CallbackList
from stable_baselines3.common.vec_env import DummyVecEnv

from armexp import aids
from armexp.agents.novelty import PostureCounts
from armexp.cli import main
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.observation import ObservationLayout
from armexp.envs.reach import ReachEnv
from tests.helpers import plain_train, refused_in_one_sentence, stage_runs

COUNT = "+agent.aids.count_bonus={_target_:armexp.agents.novelty.CountBonus,beta:0.3}"
LAYOUT = ObservationLayout(2, 5)


class EnvRewards(BaseCallback):
    """Keeps a copy of each step's rewards as the environments gave them, with the postures
    reached (the terminal one where an episode ended)."""

    def __init__(self) -> None:
        super().__init__()
        self.rewards: list[np.ndarray] = []
        self.reached: list[np.ndarray] = []
        self.ended = 0

    def _on_step(self) -> bool:
        self.rewards.append(np.array(self.locals["rewards"], copy=True))
        obs = np.array(self.locals["new_obs"], copy=True)
        for i, info in enumerate(self.locals["infos"]):
            if self.locals["dones"][i]:
                obs[i] = info["terminal_observation"]
                self.ended += 1
        self.reached.append(LAYOUT.q(obs))
        return True


def test_the_bonus_is_counted_per_cell_and_falls_to_zero() -> None:
    used = [0.0]
    counts = PostureCounts(LAYOUT, beta=0.5, cell=0.1, until=0.5, used=lambda: used[0])
    obs = np.zeros((3, LAYOUT.size))
    obs[:, LAYOUT.joints] = [[0.01, 1.57], [0.02, 1.58], [0.31, -2.2]]  # two share a cell
    assert counts.bonus(obs) == pytest.approx([0.5, 0.5 / np.sqrt(2), 0.5])
    used[0] = 0.25  # half way to `until`
    assert counts.bonus(obs[2:]) == pytest.approx([0.25 / np.sqrt(2)])
    used[0] = 0.6
    assert counts.bonus(obs) == pytest.approx([0.0, 0.0, 0.0])
    assert sum(counts.counts.values()) == 7 and len(counts.counts) == 2


def test_the_replay_buffer_stores_the_environments_reward_plus_the_bonus() -> None:
    settings = settings_from_config(compose_config(["controller.gains=paper"]))
    venv = DummyVecEnv([lambda: ReachEnv(settings)] * 2)
    model = SAC("MlpPolicy", venv, learning_starts=10_000, buffer_size=5000, seed=1, device="cpu")
    spy = EnvRewards()
    counts = PostureCounts(LAYOUT, beta=0.4, cell=0.2, until=1.0, used=lambda: 0.0)
    model.learn(2400, callback=CallbackList([spy, counts]))  # past the first episode's end
    assert model.replay_buffer is not None and spy.ended > 0
    stored = model.replay_buffer.rewards[: len(spy.rewards)]
    seen: Counter[tuple[int, ...]] = Counter()
    want = []
    for rewards, q in zip(spy.rewards, spy.reached, strict=True):
        row = []
        for reward, posture in zip(rewards, q, strict=True):
            key = tuple(np.floor(posture / 0.2).astype(int))
            seen[key] += 1
            row.append(reward + 0.4 / np.sqrt(seen[key]))
        want.append(row)
    assert stored == pytest.approx(np.array(want), rel=1e-5)
    assert counts.paid > 0 and seen == counts.counts


@pytest.mark.long
def test_a_non_privileged_preset_trains_with_the_count_bonus_and_others_are_refused(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert aids.COUNT_BONUS.privileged is False
    base = plain_train(runs_dir)
    assert main([*base, COUNT]) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.data.params["agent.aids.count_bonus.beta"] == "0.3"
    assert run.data.metrics["final/count_bonus_cells"] > 1
    assert run.data.metrics["final/count_bonus_paid"] > 0
    refused_in_one_sentence(
        runs_dir, capsys,
        [*base, COUNT, "agent=ppo_quick", "agent.max_env_steps=600", "agent.ppo.n_steps=64"],
        "agent.aids.count_bonus is not allowed with agent.algo=ppo",
    )  # fmt: skip
    refused_in_one_sentence(
        runs_dir, capsys, [*base, COUNT.replace("beta:0.3", "beta:0")],
        "agent.aids.count_bonus is not allowed", "beta=0",
    )  # fmt: skip
    her = "+agent.aids.her={_target_:armexp.agents.relabel.GoalRelabelling,ratio:0.5}"
    refused_in_one_sentence(
        runs_dir, capsys, [*base, "agent.n_steps=1", her, COUNT],
        "agent.aids.count_bonus is not allowed with agent.aids.her", "~agent.aids.her",
    )  # fmt: skip
    hindsight = her.replace("aids.her", "aids.hindsight")  # HER under another name is HER
    refused_in_one_sentence(
        runs_dir, capsys, [*base, "agent.n_steps=1", hindsight, COUNT],
        "agent.aids.count_bonus is not allowed with agent.aids.hindsight",
    )  # fmt: skip
