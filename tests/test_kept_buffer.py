"""An interrupted off-policy run keeps its replay buffer with its checkpoint
(`armexp.agents.kept_buffer`): the resumed run learns on it at once, and the interrupted
episodes end where they were cut (no n-step return or relabelled goal runs on into the
resumed run's first episode)."""

from __future__ import annotations

import errno
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from stable_baselines3.common.logger import Logger

from armexp.agents import kept_buffer
from armexp.agents.factory import build_agent, load_agent
from armexp.agents.relabel import RelabellingReplayBuffer
from armexp.agents.vec import make_vec_env
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import reward_params
from tests.helpers import plain_train, stop_and_resume

HER = "+agent.aids.her={_target_:armexp.agents.relabel.GoalRelabelling,ratio:0.8}"
SMALL = ["controller.gains=paper", "agent=sac_smoke", "agent.net_arch=[32,32]",
         "agent.learning_starts=50", "agent.batch_size=32", "env.max_steps=100"]  # fmt: skip


def _trained(steps: int, *overrides: str) -> tuple[Any, Any]:
    cfg = compose_config([*SMALL, *overrides])
    env = make_vec_env(settings_from_config(cfg, with_tasks=False), 1, "dummy", 0)
    model = build_agent(cfg.agent, env, 0)
    model.set_logger(Logger(folder=None, output_formats=[]))
    model.learn(steps)
    return model, cfg.agent


def test_a_kept_n_step_buffer_comes_back_whole_and_its_open_episode_ends_where_it_was_cut(
    tmp_path: Path,
) -> None:
    model, agent = _trained(130, "agent.n_steps=5")  # 100-step episodes: the second one is open
    buffer = model.replay_buffer
    newest = buffer.pos - 1
    assert buffer.dones[newest, 0] == 0 and buffer.timeouts[newest, 0] == 0
    before = buffer.timeouts[:130].copy()
    assert kept_buffer.save(model, tmp_path)
    model.save(tmp_path / "model.zip")
    loaded: Any = load_agent(str(tmp_path / "model.zip"), model.get_env(), agent)
    kept_buffer.restore(loaded, tmp_path / kept_buffer.BUFFER_FILE)
    kept = loaded.replay_buffer
    assert type(kept) is type(buffer) and kept.pos == buffer.pos == 130
    # Only the 130 filled rows of 20,000 were written, and both buffers are whole again.
    assert (tmp_path / kept_buffer.BUFFER_FILE).stat().st_size < 100_000
    assert kept.observations.shape == buffer.observations.shape == (20_000, 1, *buffer.obs_shape)
    assert not hasattr(buffer, kept_buffer.CUT_KEY) and not hasattr(kept, kept_buffer.CUT_KEY)
    assert np.array_equal(kept.observations[:130], buffer.observations[:130])
    assert np.array_equal(kept.rewards[:130], buffer.rewards[:130])
    assert kept.timeouts[newest, 0] == 1  # the cut episode ends there, and nothing else changed
    assert np.array_equal(np.delete(kept.timeouts[:130], newest, 0), np.delete(before, newest, 0))
    # The resumed run's first transition follows it: a 5-step return from 2 steps before the
    # cut sums those 3 rewards only and bootstraps from the cut's next observation.
    obs = np.zeros((1, *kept.obs_shape), np.float32)
    kept.add(obs, obs + 1, np.zeros((1, kept.action_dim)), np.array([100.0]), np.array([False]),
             [{}])  # fmt: skip
    start = newest - 2
    sample = kept._get_samples(np.array([start]))
    gamma = kept.gamma
    want = sum(gamma**i * kept.rewards[start + i, 0] for i in range(3))
    assert sample.rewards.item() == pytest.approx(want, rel=1e-5)
    assert sample.discounts.item() == pytest.approx(gamma**3, rel=1e-5)
    assert np.allclose(sample.next_observations.numpy(), kept.next_observations[newest])


def test_a_full_buffer_is_kept_whole(tmp_path: Path) -> None:
    model, agent = _trained(130, "agent.buffer_size=100")
    buffer = model.replay_buffer
    assert buffer.full and kept_buffer.save(model, tmp_path)
    model.save(tmp_path / "model.zip")
    loaded: Any = load_agent(str(tmp_path / "model.zip"), model.get_env(), agent)
    kept_buffer.restore(loaded, tmp_path / kept_buffer.BUFFER_FILE)
    kept = loaded.replay_buffer
    assert kept.full and kept.pos == buffer.pos == 30
    assert np.array_equal(kept.observations, buffer.observations)
    assert np.array_equal(kept.timeouts, buffer.timeouts)


def test_a_model_without_transitions_keeps_no_buffer(tmp_path: Path) -> None:
    model, _ = _trained(0)
    assert not kept_buffer.save(model, tmp_path)
    assert not (tmp_path / kept_buffer.BUFFER_FILE).exists()


def test_a_buffer_that_cannot_be_written_leaves_no_cut_off_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    model, _ = _trained(60)

    def full_disk(path: Path) -> None:
        Path(path).write_bytes(b"cut off")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(model, "save_replay_buffer", full_disk)
    assert not kept_buffer.save(model, tmp_path)
    assert list(tmp_path.iterdir()) == []


def test_a_relabelling_buffer_closes_its_open_episodes() -> None:
    cfg = compose_config(SMALL)
    env = make_vec_env(settings_from_config(cfg, with_tasks=False), 2, "dummy", 0)
    buffer = RelabellingReplayBuffer(
        20, env.observation_space, env.action_space,
        reward_params(settings_from_config(cfg, with_tasks=False)), 0.8, "cpu", 2,
    )  # fmt: skip
    obs = np.zeros((2, *buffer.obs_shape), np.float32)
    act = np.zeros((2, buffer.action_dim), np.float32)
    for done in ([False, False], [False, True], [False, False]):
        buffer.add(obs, obs, act, np.zeros(2), np.array(done), [{}, {}])
    # env 0: one open episode of 3 steps; env 1: an episode of 2 ended, one of 1 open.
    assert buffer.last[:3, 0].tolist() == [-1, -1, -1]
    assert buffer.last[:3, 1].tolist() == [1, 1, -1]
    kept_buffer.end_open_episodes(buffer)
    assert buffer.last[:3, 0].tolist() == [2, 2, 2]
    assert buffer.last[:3, 1].tolist() == [1, 1, 2]
    assert buffer.timeouts[2].tolist() == [1.0, 1.0]
    assert buffer._start.tolist() == [3, 3]


@pytest.mark.long
def test_an_interrupted_run_with_goal_relabelling_resumes_on_its_relabelling_buffer(
    runs_dir: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    base = plain_train(runs_dir, HER, "agent.n_steps=1", "train.checkpoint_every=100000")
    _, resumed = stop_and_resume(runs_dir, monkeypatch, capsys, base, at=450)
    assert resumed.data.metrics["final/env_steps"] == 600
    assert resumed.data.metrics["final/her_ratio"] == 0.8
