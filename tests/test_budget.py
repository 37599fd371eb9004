"""Training against a budget: the share of it spent is the furthest of episodes, steps and
time (what weight averaging follows)."""

from __future__ import annotations

import pytest

from armexp.agents.callbacks import Budget, EpisodeStats


def test_budget_share_is_the_furthest_of_episodes_steps_and_time() -> None:
    stats = EpisodeStats("run", 1000, start_episode=10)
    stats.wall = lambda: 30.0  # type: ignore[method-assign]
    assert Budget(stats, 100, 1000, 60.0).used(200) == pytest.approx(0.5)
    assert Budget(stats, 100, 1000, None).used(200) == pytest.approx(0.2)
    assert Budget(stats, 20, None, None).used(200) == pytest.approx(0.5)
    assert Budget(stats, 20, 100, None).used(200) == 1.0
