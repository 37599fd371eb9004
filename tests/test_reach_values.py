"""The diagnostics of docs/plain_agent.md ("Which postures the misses need"): the posture a target
needs, and the best return Table I's reward allows from the start."""

from __future__ import annotations

import importlib.util
import math
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import numpy as np
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
    # γ 0.996 is the lowest of those tried at which the optimum swings to task (b) under the
    # guard, with the obstacles as without them; at 0.995 it parks with them too.
    value, end, steps = reach.optimal(grid, (-0.02, -0.60), gamma=0.996, guard=True,
                                      obstacles=True)  # fmt: skip
    assert end == "reached" and 330 < steps < 340 and value == pytest.approx(-69.2, abs=0.5)
    _, end, _ = reach.optimal(grid, (-0.02, -0.60), gamma=0.995, guard=True, obstacles=True)
    assert end == "stays"


def test_the_obstacle_test_over_arrays_is_the_environments() -> None:
    from armexp.config import compose_config
    from armexp.envs.factory import settings_from_config
    from armexp.envs.geometry import segment_hits

    reach = _script("reach_values")
    obstacles = settings_from_config(compose_config([])).obstacles
    rng = np.random.default_rng(0)
    before, after = rng.uniform(-2, 2, (2, 2000, 2))
    after = before + (after - before) * 0.2  # short paths as well as long
    hits = reach._enters(before, after, obstacles)
    expected = [segment_hits(b, a, obstacles) for b, a in zip(before, after, strict=True)]
    assert hits.tolist() == expected and 50 < hits.sum() < 1950


@pytest.mark.long
def test_a_collision_ends_the_greedy_episode_when_it_is_the_best_ending() -> None:
    import dataclasses

    from armexp.config import compose_config
    from armexp.envs.factory import settings_from_config

    reach = _script("reach_values")
    settings = settings_from_config(compose_config([]))
    # A target at the centre of a 0.7 m obstacle: at γ 0.998 staying outside it, 0.7 m or more
    # away, costs log10(1.66) / 0.002 = 110 or more, so running into it (-100) is the best ending.
    ring = reach.JointGrid(dataclasses.replace(settings, obstacles=np.array([[1.3, -0.5, 0.7]])))
    value, end, steps = reach.optimal(ring, (1.3, -0.5), gamma=0.998, guard=True, obstacles=True)
    assert end == "collision" and -130 < value < -100 * 0.998 ** (steps - 1)
    # Without the obstacles the same target is reached.
    _, end, _ = reach.optimal(ring, (1.3, -0.5), gamma=0.998, guard=True)
    assert end == "reached"


def test_the_scripted_swing_reaches_task_b_and_is_worth_less_the_slower_it_is_made() -> None:
    from armexp.agents.self_imitation import discounted_returns

    swing = _script("swing_returns")
    _, q1, q2 = _script("misses_by_posture").posture_needed(-0.02, -0.60)
    assert (q1, q2) == pytest.approx((-0.677, -2.498), abs=1e-3)  # the elbow's far side
    reason, rewards, error = swing.swing((-0.02, -0.60), 1.0)
    # The joints' straight path clears every obstacle; the elbow's 4.07 rad at its 0.4 rad/s
    # bound take about 340 actions of 30 ms.
    assert reason == "reached" and error < 0.04 and 330 < len(rewards) < 360
    assert rewards[-1] == 200.0 and np.all(rewards[:-1] < 0)
    full = discounted_returns(rewards, 0.996)[0]
    assert full == pytest.approx(-72.3, abs=1.0)  # docs/plain_agent.md, "Aimed at task (b)"
    reason, slower, _ = swing.swing((-0.02, -0.60), 0.8)
    assert reason == "reached" and len(slower) > len(rewards)
    assert discounted_returns(slower, 0.996)[0] < full - 25  # the same swing, 20 % slower
    reason, still, error = swing.swing((-0.02, -0.60), None)
    assert reason == "time_limit" and len(still) == 1000 and error > 1.7
    closed_form = np.sum(still * 0.996 ** np.arange(1000))
    assert discounted_returns(still, 0.996)[0] == pytest.approx(closed_form)


def test_the_aimed_training_draws_every_target_near_the_centre() -> None:
    # In a child process: the aim patches the environment class for the process it runs in.
    code = (
        "import sys, numpy as np; sys.path.insert(0, 'scripts'); import aimed_training as a;"
        "from armexp.envs.factory import make_reach; from armexp.agents.curriculum import "
        "WideningReach; a.aim((-0.02, -0.60), 0.15); env = make_reach();"
        "env.set_target_reach(WideningReach(1.0, 1.0, lambda: 0.0).radius());"  # held at 0.15
        "t = np.array([env.reset()[0][:2] for _ in range(300)]);"
        "print(np.hypot(*(t - [-0.02, -0.60]).T).max(), len({tuple(x) for x in t}))"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=SCRIPTS.parent, check=True,
                         capture_output=True, text=True).stdout.split()  # fmt: skip
    farthest, distinct = float(out[0]), int(out[1])
    assert farthest <= 0.15 and distinct > 30  # a draw among the ~86 points there


@pytest.mark.long
def test_an_aimed_run_trains_and_logs_its_held_radius(runs_dir: Path) -> None:
    from tests.helpers import SMALL_TRAIN, stage_runs

    argv = [sys.executable, str(SCRIPTS / "aimed_training.py"), "--radius", "0.2", "--",
            *SMALL_TRAIN, "agent.privileged=false", "controller.gains=paper",
            "train.gains=config", f"tracking.runs_dir={runs_dir}"]  # fmt: skip
    subprocess.run(argv, check=True, capture_output=True, cwd=runs_dir.parent)
    (run,) = stage_runs(runs_dir, "train")
    assert run.data.metrics["final/curriculum_reach"] == pytest.approx(0.2)
