"""The diagnostics of docs/plain_agent.md ("Which postures the misses need"): the posture a target
needs, and the best return Table I's reward allows from the start."""

from __future__ import annotations

import importlib.util
import math
import sys
from pathlib import Path
from types import ModuleType

import pytest

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _script(name: str) -> ModuleType:
    sys.path.insert(0, str(SCRIPTS))  # reach_values imports misses_by_posture as its neighbour
    spec = importlib.util.spec_from_file_location(name, SCRIPTS / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_posture_a_target_needs() -> None:
    needed = _script("misses_by_posture").elbow_needed
    start_side, q2 = needed(1.0, 0.8)  # the start's own tip
    assert start_side and q2 == pytest.approx(math.pi / 2)
    start_side, q2 = needed(-0.02, -0.60)  # task (b): only the other side is within the limits
    assert not start_side and q2 == pytest.approx(-2.498, abs=1e-3)


def test_a_target_next_to_the_start_is_worth_reaching_at_once() -> None:
    reach = _script("reach_values")
    value, end, steps = reach.optimal(reach.JointGrid(), (1.0, 0.72), gamma=0.9)
    assert end == "reached" and steps < 20  # 8 cm to the target, 4 cm to its threshold
    # the +200 discounted to the start, less a few small distance costs on the way
    assert 200 * 0.9 ** (steps - 1) - 0.5 < value <= 200 * 0.9 ** (steps - 1)


@pytest.mark.long
def test_at_table_twos_gamma_task_b_is_not_worth_reaching_and_a_nearer_target_is() -> None:
    reach = _script("reach_values")
    grid = reach.JointGrid()
    value, end, _ = reach.optimal(grid, (-0.02, -0.60), gamma=0.995)
    assert end == "joint_limit" and value == pytest.approx(-58.7, abs=0.5)
    value, end, steps = reach.optimal(grid, (0.32, -0.80), gamma=0.995)
    assert end == "reached" and 300 < steps < 320 and value == pytest.approx(-33.4, abs=0.5)
    # Under the joint-limit guard no episode ends at a limit: task (b) is parked beside it, at a
    # lower value than the fold's.
    value, end, _ = reach.optimal(grid, (-0.02, -0.60), gamma=0.995, guard=True)
    assert end == "stays" and value < -58.7
