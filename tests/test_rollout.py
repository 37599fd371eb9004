"""Table III's per-episode quantities, measured on a scripted policy with a known outcome."""

from __future__ import annotations

import numpy as np
import pytest

from armexp.agents.rollout import convergence_metrics, episode_metrics, rollout
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.reach import ReachEnv


class Constant:
    """A policy with SB3's ``predict`` that always returns the same action."""

    def __init__(self, action: list[float]) -> None:
        self.action = np.asarray(action, dtype=np.float32)

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> tuple[np.ndarray, None]:
        return self.action, None


@pytest.fixture(scope="module")
def env() -> ReachEnv:
    return ReachEnv(settings_from_config(compose_config(["obstacles=none"])), record=True)


def test_metrics_of_a_scripted_reach(env: ReachEnv) -> None:
    policy = Constant([0.5, -1.0])
    # Where the tip is after 40 actions of this policy: put the target there.
    env.reset(seed=0, options={"target": (-1.0, -1.0)})
    for _ in range(40):
        env.step(policy.action)
    target = env.tip.copy()
    episode = rollout(env, policy, {"target": target}, seed=0)
    m = episode_metrics(episode, env.n, env.settings.plant.arm.lengths_array, 0.04)
    assert episode.reason == "reached" and m["success"] == 1.0 and m["collision"] == 0.0
    # Reached a little before step 40 (within the 4 cm threshold), first seen at 1 kHz.
    assert 0.6 < m["target_time"] <= m["steps"] * 0.03 <= 40 * 0.03
    assert m["final_error_cm"] < 4.0
    rows = episode.rows
    first = np.argmax(rows[:, -1] < 0.04)
    assert m["target_time"] == pytest.approx(rows[first, 0])
    assert m["max_abs_tau_1"] == pytest.approx(np.abs(rows[:, 9]).max())
    assert m["rms_e1"] < 0.01  # the tuned loop tracks the planned velocities closely
    assert m["tip_rms_cm"] < 1.0
    assert m["return"] == pytest.approx(episode.episode_return)
    # The episode starts with zero tracking error: nothing to converge from.
    assert "decay_rate" not in m
    assert np.isnan(convergence_metrics(episode, env.n, 0.005, 1.0, 1e-4)["decay_rate"])
    assert m["time_at_limit"] == pytest.approx(rows[:, 14:16].max(axis=1).sum() * 1e-3)


def test_convergence_from_a_reference_offset(env: ReachEnv) -> None:
    """A run started 5 mrad from the reference: Definition 1's constants of ‖e1‖, the settling
    time to max(2 % of the offset, the tolerance) and ITAE, over the first second."""
    policy = Constant([0.5, -1.0])
    options = {"target": (-1.0, -1.0), "reference_offset": [0.005, 0.005]}
    episode = rollout(env, policy, options, seed=0, max_steps=34)
    assert episode.steps == 34
    rows = episode.rows
    t = rows[:, 0]
    e1 = np.hypot(rows[:, 1] - rows[:, 3], rows[:, 2] - rows[:, 4])
    assert e1[0] == pytest.approx(0.005 * np.sqrt(2))
    m = convergence_metrics(episode, env.n, 0.005, 1.0, 1e-4)
    inside = t < 1.0
    assert m["ultimate_bound"] == pytest.approx(e1[inside & (t >= 0.75 * t[inside][-1])].max())
    assert m["ultimate_bound"] < 0.1 * e1[0]  # the paper's gains remove the offset
    assert 10.0 < m["decay_rate"] < 1000.0 and m["decay_overshoot"] > 0
    band = max(0.02 * 0.005, 1e-4)
    if np.isfinite(m["settling_time"]):
        k = int(np.searchsorted(t, m["settling_time"]))
        assert e1[k:][inside[k:]].max() <= band < e1[k - 1]
    else:
        assert e1[inside][-1] > band
    assert m["itae"] == pytest.approx(np.trapezoid(t[inside] * e1[inside], t[inside]))
    # The large offset: the same quantities, a larger bound on the way.
    options["reference_offset"] = [0.05, 0.05]
    large = convergence_metrics(rollout(env, policy, options, seed=0, max_steps=34),
                                env.n, 0.05, 1.0, 1e-4)  # fmt: skip
    assert large["itae"] > m["itae"]


def test_metrics_of_a_miss(env: ReachEnv) -> None:
    env_short = ReachEnv(
        settings_from_config(compose_config(["obstacles=none", "env.max_steps=20"])), record=True
    )
    episode = rollout(env_short, Constant([0.0, 0.0]), {"target": (0.5, -0.5)}, seed=1)
    m = episode_metrics(episode, 2, env_short.settings.plant.arm.lengths_array, 0.04)
    assert episode.reason == "time_limit" and m["success"] == 0.0
    assert np.isnan(m["target_time"])
    start_error = np.hypot(1.0 - 0.5, 0.8 + 0.5) * 100
    assert m["final_error_cm"] == pytest.approx(start_error, abs=0.5)
    assert m["steps"] == 20 and len(episode.rows) == 600


def test_reach_in_the_last_controller_step_still_has_a_target_time() -> None:
    from armexp.agents.rollout import Episode

    t = np.arange(60) * 1e-3
    rows = np.zeros((60, 17))
    rows[:, 0] = t
    rows[:, -1] = 0.05  # logged at each step's start: never inside the 4 cm threshold
    episode = Episode("reached", 2, 200.0, 0.039, np.zeros(2), rows)
    m = episode_metrics(episode, 2, np.array([1.0, 0.8]), 0.04)
    assert m["target_time"] == pytest.approx(0.060)
    missed = Episode("time_limit", 2, -1.0, 0.05, np.zeros(2), rows)
    assert np.isnan(episode_metrics(missed, 2, np.array([1.0, 0.8]), 0.04)["target_time"])
