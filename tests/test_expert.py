"""The planner as a feedback policy, its time-to-go map, and DAgger labels for cloning
(armexp.agents.expert)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from armexp.agents.cloning import DemonstrationCloning
from armexp.agents.demonstrations import Demonstration, demonstrations
from armexp.agents.expert import ExpertLabels, TimeToGoExpert, TimeToGoMap
from armexp.agents.rollout import rollout
from armexp.config import compose_config
from armexp.envs.factory import settings_from_config
from armexp.envs.geometry import segment_hits, tips
from armexp.envs.observation import TARGET
from armexp.envs.reach import ReachEnv, ReachSettings
from armexp.envs.workspace import breadth_first_times, fill_unreached, time_to_go
from tests.helpers import small_sac


def _blank_obs(env: ReachEnv) -> np.ndarray:
    """An observation of zeros, filled in by each test."""
    shape = env.observation_space.shape
    assert shape is not None  # a Box always has one
    return np.zeros(shape)


@pytest.fixture(scope="module")
def env() -> ReachEnv:
    return ReachEnv(settings_from_config(compose_config(["controller.gains=paper"])))


@pytest.fixture(scope="module")
def settings(env: ReachEnv) -> ReachSettings:
    return env.settings


@pytest.fixture(scope="module")
def expert(env: ReachEnv) -> TimeToGoExpert:
    return TimeToGoExpert(env.settings, 0.10)


@pytest.fixture(scope="module")
def demos(env: ReachEnv) -> list[Demonstration]:
    return demonstrations(env, 4, seed=5)


@pytest.mark.long
def test_the_expert_reaches_held_out_targets_and_a_dear_margin_keeps_it_off_the_obstacles(
    env: ReachEnv, expert: TimeToGoExpert
) -> None:
    rng = np.random.default_rng(99)
    targets = [env.workspace.sample(rng) for _ in range(40)]

    def reasons(policy: TimeToGoExpert) -> Counter[str]:
        episodes = (rollout(env, policy, {"target": t}, seed=i) for i, t in enumerate(targets))
        return Counter(e.reason for e in episodes)

    margin = env.settings.path_margin
    dear = reasons(TimeToGoExpert(env.settings, margin, lookahead=1))
    cheap = reasons(TimeToGoExpert(env.settings, margin, lookahead=1, inside_cost=1.0))
    # When a cell inside the margin costs what a free one does, once the tracking lag carries
    # the tip in, the map leads it on through the obstacle: more collisions.
    assert reasons(expert)["reached"] >= 39
    assert dear["reached"] >= 39
    assert dear["collision"] + 4 <= cheap["collision"]


def test_the_expert_commands_full_speed_towards_the_target_and_holds_on_it(
    env: ReachEnv, expert: TimeToGoExpert
) -> None:
    obs, _ = env.reset(seed=0, options={"target": env.workspace.points[0]})
    action = expert(obs)
    assert action.shape == (1, 2) and set(np.abs(action).ravel()) <= {0.0, 1.0}
    assert np.abs(action).sum() > 0  # the arm starts away from every target
    # With the tip on the target there is nowhere to go: hold still (up to the workspace
    # table's float32 rounding of the target).
    config = env.workspace.configs[0]
    on_target = obs.copy()
    on_target[6:8] = config
    np.testing.assert_allclose(expert(on_target), [[0.0, 0.0]], atol=1e-3)
    # Batched rows are labelled one by one.
    both = expert(np.stack([obs, on_target]))
    np.testing.assert_array_equal(both, [action[0], expert(on_target)[0]])


def test_near_the_target_the_expert_moves_the_tip_straight_at_it_and_its_labels_are_smooth(
    env: ReachEnv, expert: TimeToGoExpert
) -> None:
    lengths = np.asarray(env.settings.plant.arm.lengths_array)
    step = np.asarray(env.settings.velocity_bound) * env.settings.action_period
    grown = env.settings.obstacles + np.array([0.0, 0.0, env.settings.path_margin])
    rng = np.random.default_rng(3)
    checked = 0
    for config in env.workspace.configs[rng.choice(len(env.workspace.configs), 200)]:
        target = tips(config, lengths)
        q = config + rng.normal(0.0, 0.05, 2)
        error = target - tips(q, lengths)
        distance = float(np.linalg.norm(error))
        if not 0.01 < distance < expert.approach or segment_hits(tips(q, lengths), target, grown):
            continue
        obs = _blank_obs(env)
        obs[TARGET], obs[env.layout.joints] = target, q
        action = expert(obs)[0]
        moved = tips(q + action * step, lengths) - tips(q, lengths)
        # One step of the label moves the tip towards the target, along the line to it, with
        # its fastest joint at the bound (the greedy labels are bang-bang and flip sign here).
        assert np.dot(moved, error) / (np.linalg.norm(moved) * distance) > 0.99
        assert np.abs(action).max() == pytest.approx(1.0)
        # A tenth of a milliradian changes the label by a little, not a sign.
        nudged = obs.copy()
        nudged[env.layout.joints] += 1e-4
        assert np.abs(expert(nudged)[0] - action).max() < 0.05
        checked += 1
    assert checked >= 50
    # Beyond the approach radius the greedy least-time labels are back.
    far = TimeToGoExpert(env.settings, 0.10, approach=0.0)
    obs, _ = env.reset(seed=0, options={"target": env.workspace.points[0]})
    np.testing.assert_array_equal(far(obs), expert(obs))


def test_inside_its_margin_the_expert_backs_away_from_the_obstacle(env: ReachEnv) -> None:
    # A state the learner reached on task (a) (then at (0.15, 1.55), behind the obstacle at
    # (0.50, 1.30)): the tip 3 cm from that obstacle, deep inside the expert's 10 cm margin.
    # Filled cells that cost what free ones do make the straight line through the obstacle
    # look as short as any other (the learner's collision); costing ten free moves a cell,
    # the way out comes first.
    lengths = np.asarray(env.settings.plant.arm.lengths_array)
    obstacle = np.array([0.50, 1.30, 0.12])
    obs = _blank_obs(env)
    obs[TARGET], obs[env.layout.joints] = [0.15, 1.55], [0.46, 1.47]
    here = env.layout.q(obs)

    def clearance_after(expert: TimeToGoExpert) -> float:
        q = here + expert(obs)[0] * np.asarray(env.settings.velocity_bound) * 0.03 * 5
        return float(np.linalg.norm(tips(q, lengths) - obstacle[:2]) - obstacle[2])

    now = float(np.linalg.norm(tips(here, lengths) - obstacle[:2]) - obstacle[2])
    assert 0.0 < now < 0.05
    assert clearance_after(TimeToGoExpert(env.settings, 0.10)) > now
    assert clearance_after(TimeToGoExpert(env.settings, 0.10, inside_cost=1.0)) < now


def test_added_steps_are_cloned_beside_the_demonstrations_and_replace_the_oldest(
    env: ReachEnv, demos: list[Demonstration]
) -> None:
    model = small_sac(env.settings)
    fixed = sum(len(d) for d in demos if d.reason == "reached")
    cloning = DemonstrationCloning(model, demos, 1.0, seed=0, capacity=5)
    demo_obs = cloning.obs[:fixed].clone()
    dim = demo_obs.shape[1]
    cloning.add(np.full((3, dim), 1.0), np.full((3, 2), 0.5))
    assert len(cloning) == fixed + 3
    cloning.add(np.full((4, dim), 2.0), np.full((4, 2), -0.5))
    assert len(cloning) == fixed + 5  # full: the two oldest added rows are gone
    added = cloning.obs[fixed:, 0].tolist()
    assert sorted(added) == [1.0, 2.0, 2.0, 2.0, 2.0]
    assert (cloning.obs[:fixed] == demo_obs).all()  # the demonstrations stay
    with pytest.raises(ValueError, match="without room"):
        DemonstrationCloning(model, demos, 1.0, seed=0).add(np.zeros((1, dim)), np.zeros((1, 2)))


def test_training_labels_every_visited_state_with_the_experts_action(
    env: ReachEnv, expert: TimeToGoExpert, demos: list[Demonstration]
) -> None:
    model = small_sac(env.settings, n_envs=2, batch_size=32)
    fixed = sum(len(d) for d in demos if d.reason == "reached")
    cloning = DemonstrationCloning(model, demos, 1.0, seed=0, capacity=1000)
    model.learn(total_timesteps=40, callback=ExpertLabels(expert, cloning))
    assert len(cloning) == fixed + 40  # 20 steps of 2 environments
    added = cloning.obs[fixed : fixed + 40].numpy()
    np.testing.assert_array_equal(cloning.actions[fixed : fixed + 40].numpy(), expert(added))
    # The states are the agent's own: they move, and not along one demonstrated episode.
    assert np.ptp(added[:, 6:8], axis=0).max() > 0


def test_the_expert_commands_every_joint_of_the_three_link_arm() -> None:
    settings = settings_from_config(compose_config(["controller.gains=paper", "robot=three_link"]))
    env = ReachEnv(settings)
    obs, _ = env.reset(seed=0)
    action = TimeToGoExpert(settings, 0.10)(obs)
    assert action.shape == (1, 3) and set(np.abs(action).ravel()) <= {0.0, 1.0}
    assert np.abs(action).sum() > 0


def test_time_to_go_is_the_least_time_from_the_start_to_any_goal_cell(
    settings: ReachSettings,
) -> None:
    grid, ws = TimeToGoMap(settings).grid, ReachEnv(settings).workspace
    start = np.zeros(grid.free.shape, dtype=bool)
    start[grid.cell(settings.q0)] = True
    from_start = breadth_first_times(grid.free | start, start, grid.dt, grid.free.size)
    for index in np.random.default_rng(0).integers(len(ws), size=8):
        target = ws.points[index]
        to_go = time_to_go(grid, target, settings.reach_threshold)
        goal = np.linalg.norm(grid.tip - target, axis=-1) < settings.reach_threshold
        assert np.all(to_go[goal & grid.free] == 0.0)
        # Moves are symmetric: searching from the goal equals searching from the start.
        assert to_go[grid.cell(settings.q0)] == pytest.approx(from_start[goal].min())
        assert to_go[grid.cell(settings.q0)] <= ws.times[index] + 1e-9


def test_filled_times_are_finite_and_grow_one_cell_at_a_time() -> None:
    times = np.full((6, 5), np.inf)
    times[0, 0] = 0.0
    times[5, 4] = 1.0
    filled = fill_unreached(times, 0.5)
    assert np.isfinite(filled).all() and filled[0, 0] == 0.0 and filled[5, 4] == 1.0
    assert filled[2, 1] == 1.0  # two Chebyshev moves from (0, 0)
    assert filled[4, 4] == 1.5  # one move from (5, 4) beats four from (0, 0)
    # A finite time is never shortened by a path through filled cells, and a filled cell gets
    # its least time even where a dearer finite cell is nearer.
    line = fill_unreached(np.array([[0.0, np.inf, np.inf, np.inf, np.inf, np.inf, 9.0]]), 0.5)
    np.testing.assert_array_equal(line, [[0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 9.0]])


def test_a_dearer_inside_makes_the_time_grow_faster_with_depth_into_the_margin(
    settings: ReachSettings,
) -> None:
    cheap_map = TimeToGoMap(settings)
    target = ReachEnv(settings).workspace.points[0]
    cheap = cheap_map.times(target)
    dear = TimeToGoMap(settings, inside_cost=10.0).times(target)
    grid = cheap_map.grid
    free = np.isfinite(time_to_go(grid, target, settings.reach_threshold))
    assert (~free).any()
    np.testing.assert_array_equal(dear[free], cheap[free])
    # A filled cell d ≥ 1 moves from free cell f: dear = T_f + 10·d·dt ≥ cheap + 9·d·dt.
    assert np.all(dear[~free] - cheap[~free] >= 9 * grid.dt - 1e-9)


def _reference_layers(free: np.ndarray, start: np.ndarray, layers: int) -> np.ndarray:
    """Breadth-first search written out in Python: grid moves from the start cells (−1 beyond
    ``layers``), at most one cell per axis per move."""
    depth = np.where(start, 0, -1)
    moves = [m for m in np.ndindex(*(3,) * free.ndim) if any(c != 1 for c in m)]
    frontier = list(zip(*np.nonzero(start), strict=True))
    for layer in range(1, layers + 1):
        grown = []
        for cell in frontier:
            for move in moves:
                other = tuple(c + m - 1 for c, m in zip(cell, move, strict=True))
                inside = all(0 <= o < k for o, k in zip(other, free.shape, strict=True))
                if inside and free[other] and depth[other] < 0:
                    depth[other] = layer
                    grown.append(other)
        frontier = grown
    return depth


@pytest.mark.parametrize("shape", [(13, 9), (7, 6, 5)])
def test_the_compiled_search_matches_a_plain_breadth_first_search(shape: tuple[int, ...]) -> None:
    rng = np.random.default_rng(len(shape))
    free = rng.random(shape) < 0.7
    start = np.zeros(shape, dtype=bool)
    start[(0,) * len(shape)] = True  # a start cell need not be free
    start[tuple(k - 2 for k in shape)] = True
    for layers in (3, free.size):
        expected = _reference_layers(free, start, layers)
        times = breadth_first_times(free, start, 0.25, layers)
        np.testing.assert_array_equal(times, np.where(expected >= 0, expected * 0.25, np.inf))
    # Filling what the search left out: from each unreached cell, the cheapest way out through
    # unreached cells, in moves of 0.5 s; the edge of the grid is no way out.
    times = breadth_first_times(free, start, 0.25, free.size)
    filled = fill_unreached(times, 0.5)
    reached = np.isfinite(times)
    np.testing.assert_array_equal(filled[reached], times[reached])
    for cell in zip(*np.nonzero(~reached), strict=True):
        out = [
            filled[o] + 0.5
            for o in np.ndindex(*shape)
            if max(abs(a - b) for a, b in zip(o, cell, strict=True)) == 1
        ]
        assert filled[cell] == min(out)


def test_a_batch_of_observations_gets_the_labels_each_gets_alone(
    env: ReachEnv, expert: TimeToGoExpert, demos: list[Demonstration]
) -> None:
    # Rows of a few episodes (shared targets) and of several targets, near and far, in one call.
    obs = np.concatenate([d.obs for d in demos])[::3]
    batch = expert(obs)
    alone = np.concatenate([expert(row) for row in obs])
    np.testing.assert_array_equal(batch, alone)
    assert len(np.unique(obs[:, TARGET], axis=0)) > 1
