"""Training's pace line: steps per second over the last lines and the ETA of whichever budget
ends first."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from armexp.agents.callbacks import PaceLine


def _line(total: int, seconds: float | None, steps: int, wall: float) -> PaceLine:
    stats = SimpleNamespace(wall=lambda: wall, success_rate=0.5)
    line = PaceLine(total, stats, seconds)  # type: ignore[arg-type]
    line.marks.append((0.0, 0))
    line.num_timesteps = steps
    return line


def test_pace_and_eta_of_the_step_budget(capsys: pytest.CaptureFixture[str]) -> None:
    line = _line(total=1000, seconds=None, steps=250, wall=10.0)
    line.say(10.0)
    out = capsys.readouterr().out
    assert "250 of 1,000 steps | 25 steps/s | ETA 0.5 min" in out  # 750 steps at 25/s = 30 s
    assert line.next_at == 70.0


def test_eta_of_a_time_budget_that_ends_first() -> None:
    line = _line(total=1000, seconds=20.0, steps=250, wall=10.0)
    line.say(10.0)
    assert "ETA 0.2 min" in line.lines[-1]  # 10 s left of 20, before the 30 s the steps need


def test_the_eta_follows_the_recent_pace_not_the_runs_average() -> None:
    # 100 steps/s for 10 minutes, then 25 steps/s (a late phase's more updates per step).
    line = _line(total=200_000, seconds=None, steps=0, wall=0.0)
    for minute in range(1, 21):
        line.num_timesteps = 6000 * min(minute, 10) + 1500 * max(minute - 10, 0)
        line.say(60.0 * minute)
    # The last five minutes ran at 25 steps/s: 60,000 + 15,000 done, 125,000 left = 83.3 min.
    assert "75,000 of 200,000 steps | 25 steps/s | ETA 83.3 min" in line.lines[-1]
    # The run's average (62.5 steps/s) would have said 33.3 min.
    assert "| 100 steps/s | ETA 23.3 min" in line.lines[9]  # at 10 min: 60,000 done, 140,000 left
