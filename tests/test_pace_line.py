"""Training's pace line: steps per second and the ETA of whichever budget ends first."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from armexp.agents.callbacks import PaceLine


def _line(total: int, seconds: float | None, steps: int, wall: float) -> PaceLine:
    stats = SimpleNamespace(wall=lambda: wall, success_rate=0.5)
    line = PaceLine(total, stats, seconds)  # type: ignore[arg-type]
    line.first_step, line.first_wall = 0, 0.0
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
