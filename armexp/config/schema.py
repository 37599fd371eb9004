"""Structured configs: the typed schema behind every group of ``conf/``.

Each group's YAML files start from one of these dataclasses (registered in Hydra's ConfigStore as
``<group>/<name>_schema``), so OmegaConf rejects unknown keys and wrong types, and
`armexp.config.validate` checks the values (``metadata['check']``) and the cross-field rules.
Joint numbers in configs are 1-based, as in the paper (q1, q2).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING

from armexp.config.agent_schema import AgentConfig
from armexp.config.checks import (
    at_least,
    between,
    checked,
    each,
    matches,
    nonnegative,
    one_of,
    or_null,
    positive,
)
from armexp.config.stage_schema import (
    EvalStageConfig,
    HpoStageConfig,
    PipelineStageConfig,
    PlayStageConfig,
    ReportStageConfig,
    SimulateStageConfig,
    TrainStageConfig,
    TuneStageConfig,
    UiStageConfig,
)

_pos = positive()


# --------------------------------------------------------------------------------------- robot
@dataclass
class FTermConfig:
    """One cosine term of F(q, q̇): ``amp · cos(freq · x)`` added to joint ``joint``."""

    joint: int = checked(1, at_least(1))
    amp: float = 0.0
    freq: float = 0.0
    source: str = checked("q", one_of("q", "dq"))
    of: int = checked(1, at_least(1))


@dataclass
class UncertaintyConfig:
    """The unknown terms of eq. 2 (eq. 40 for the paper arm); all off by default."""

    enabled: bool = True
    f_terms: list[FTermConfig] = field(default_factory=list)
    tau_d_cos_amp: list[float] | None = None
    tau_d_cos_freq: list[float] | None = None
    tau_d_rand_amp: list[float] | None = None


@dataclass
class RobotConfig:
    name: str = MISSING
    lengths: list[float] = checked(factory=list, check=each(_pos))
    masses: list[float] = checked(factory=list, check=each(_pos))
    gravity: float = checked(9.81, nonnegative())
    q0: list[float] = field(default_factory=list)
    joint_lower: list[float] = field(default_factory=list)
    joint_upper: list[float] = field(default_factory=list)
    velocity_bound: list[float] = checked(factory=list, check=each(_pos))
    #: Per-joint actuator limit |τ_j| ≤ torque_limit[j] (N·m) for every controller; null: none.
    torque_limit: list[float] | None = None
    uncertainty: UncertaintyConfig = field(default_factory=UncertaintyConfig)


# ---------------------------------------------------------------------------------- controller
@dataclass
class AdaptiveGains:
    """B = [a0, a1, b1, c1, r1] of Algorithm 3 (eqs. 5, 11, 12); all > 0."""

    a0: float = checked(MISSING, _pos)
    a1: float = checked(MISSING, _pos)
    b1: float = checked(MISSING, _pos)
    c1: float = checked(MISSING, _pos)
    r1: float = checked(MISSING, _pos)


@dataclass
class PIDGains:
    """Per-joint gains of τ = −(kp e1 + ki ∫e1 + kd e2)."""

    kp: list[float] = checked(factory=list, check=each(nonnegative()))
    ki: list[float] = checked(factory=list, check=each(nonnegative()))
    kd: list[float] = checked(factory=list, check=each(nonnegative()))


@dataclass
class ComputedTorqueGains:
    """Per-joint gains of τ = M(q)(q̈_d − kp e1 − ki ∫e1 − kd e2)."""

    kp: list[float] = checked(factory=list, check=each(nonnegative()))
    ki: list[float] = checked(factory=list, check=each(nonnegative()))
    kd: list[float] = checked(factory=list, check=each(nonnegative()))


@dataclass
class ControllerConfig:
    name: str = MISSING
    dt: float = checked(0.001, _pos)
    #: CSO search box per search coordinate: ``{name: [lower, upper]}`` (the adaptive law:
    #: a0, a1, lambda, gamma; PID and computed torque: kp_1, …, kd_n).
    bounds: dict[str, list[float]] = field(default_factory=dict)


@dataclass
class AdaptiveControllerConfig(ControllerConfig):
    name: str = checked("subsystem_adaptive", one_of("subsystem_adaptive"))
    gains: AdaptiveGains = field(default_factory=AdaptiveGains)


@dataclass
class PIDControllerConfig(ControllerConfig):
    name: str = checked("pid", one_of("pid"))
    gains: PIDGains = field(default_factory=PIDGains)


@dataclass
class ComputedTorqueControllerConfig(ControllerConfig):
    name: str = checked("computed_torque", one_of("computed_torque"))
    gains: ComputedTorqueGains = field(default_factory=ComputedTorqueGains)


# ---------------------------------------------------------------------------------- scenario
@dataclass
class ScenarioConfig:
    """A reference for `armexp simulate`: q̇_d commands from the initial state, plus an offset.

    kind=switching: q̇_d uniform within ``scale`` × the robot's velocity bounds, redrawn every
    ``switch_period`` s (what the agent produces); kind=hold: q̇_d = 0 (pure regulation of the
    offset); kind=sine: q̇_d = scale × bound × sin(2π t / period).
    """

    kind: str = checked("switching", one_of("switching", "hold", "sine"))
    duration: float = checked(2.0, _pos)
    switch_period: float = checked(0.03, _pos)
    scale: float = checked(1.0, between(0.0, 1.0))
    period: float = checked(2.0, _pos)
    offset: list[float] = field(default_factory=lambda: [0.05])
    seed: int = checked(0, at_least(0))


# ------------------------------------------------------------------------------------ tuner
@dataclass
class ObjectiveConfig:
    """The CSO objective (docs/design.md §5): a criterion of the tracking error over seeded
    reference scenarios, with the stability and effort constraints."""

    #: gaing: the paper's W (Gaing 2004); itae, iae: integral criteria (`armexp.tune.objective`).
    criterion: str = checked("itae", one_of("gaing", "itae", "iae"))
    #: The scenarios' length in s; null: the criterion's own (gaing 0.6, itae and iae 1.5).
    horizon: float | None = checked(None, or_null(_pos))
    n_scenarios: int = checked(8, at_least(1))
    switch_period: float = checked(0.03, _pos)
    offset: float = checked(0.05, _pos)
    seed: int = checked(2024, at_least(0))
    gaing_beta: float = checked(1.0, _pos)
    settle_band: float = checked(0.02, between(0.0, 1.0, lo_open=True))
    rise_high: float = checked(0.9, between(0.0, 1.0, lo_open=True))
    rise_low: float = checked(0.1, between(0.0, 1.0, lo_open=True))
    steady_window: float = checked(0.2, between(0.0, 1.0, lo_open=True))
    #: Share of the scenarios that start at the straight arm (joints 2..n at 0).
    straight_share: float = checked(0.25, between(0.0, 1.0))
    #: Stability constraint: the sampled loop with every gain × gain_margin is stable at every
    #: pose of a grid with stability_points per joint 2..n (straight arm included); null: off.
    gain_margin: float | None = checked(1.25, or_null(at_least(1.0)))
    stability_points: int = checked(9, at_least(2))
    #: Effort penalty: effort_weight × peak |τ|/limit + saturation_weight × share of time at
    #: the torque limit, over each scenario from effort_from × horizon on (after the offset is
    #: removed), averaged over the scenarios (0 without torque limits).
    effort_weight: float = checked(0.1, nonnegative())
    saturation_weight: float = checked(1.0, nonnegative())
    effort_from: float = checked(0.5, between(0.0, 0.99))


@dataclass
class TunerConfig:
    name: str = MISSING
    n_nests: int = checked(15, at_least(2))
    n_iterations: int = checked(200, at_least(1))
    pa: float = checked(0.25, between(0.0, 1.0))
    beta: float = checked(1.5, between(0.0, 2.0, lo_open=True))
    step_scale: float = checked(0.01, _pos)
    #: Abandonment rule (docs/design.md §5): "worst" discards the P_a share of the worst nests
    #: (Algorithm 2 line 9); "per_component" rebuilds each component with probability P_a.
    abandon: str = checked("per_component", one_of("worst", "per_component"))
    seed: int = checked(0, at_least(0))
    #: Search log10 of the coordinates in controller.bounds (each bound must then be > 0).
    log_space: bool = True
    objective: ObjectiveConfig = field(default_factory=ObjectiveConfig)


# --------------------------------------------------------------------------------------- env
@dataclass
class EnvConfig:
    """The reaching environment (Table I)."""

    id: str = "armexp/Reach-v0"
    action_period: float = checked(0.03, _pos)
    max_steps: int = checked(1000, at_least(1))
    reach_threshold: float = checked(0.04, _pos)
    reach_reward: float = 200.0
    boundary_penalty: float = 50.0
    collision_penalty: float = 100.0
    growth_penalty: float = 1.0
    #: Targets: ≥ target_margin from every obstacle, ≥ min_target_distance from the initial
    #: tip, reachable within max_target_time s at the velocity bounds without the tip coming
    #: within path_margin of an obstacle (`armexp.envs.workspace`).
    target_margin: float = checked(0.05, nonnegative())
    path_margin: float = checked(0.02, nonnegative())
    min_target_distance: float = checked(0.2, nonnegative())
    max_target_time: float = checked(12.0, _pos)
    workspace_cells: int = checked(40_000, at_least(100))
    #: Reference between actions: q̇_d ramps from the previous action to the new one across the
    #: action period (``ramp``), or jumps to it (``hold``). Also used by `tune` and `simulate`.
    reference: str = checked("ramp", one_of("ramp", "hold"))


@dataclass
class Obstacle:
    x: float = 0.0
    y: float = 0.0
    r: float = checked(0.1, _pos)


@dataclass
class ObstaclesConfig:
    name: str = MISSING
    circles: list[Obstacle] = field(default_factory=list)


@dataclass
class TaskTarget:
    name: str = MISSING
    x: float = 0.0
    y: float = 0.0


@dataclass
class TasksConfig:
    name: str = MISSING
    targets: list[TaskTarget] = field(default_factory=list)
    n_random: int = checked(20, at_least(0))
    random_seed: int = checked(7, at_least(0))


# ---------------------------------------------------------------------------------- tracking
@dataclass
class TrackingConfig:
    """Where runs go. ``uri`` None means ``sqlite:///<runs_dir>/mlflow.db``."""

    uri: str | None = None
    experiment: str = checked("armexp", matches(r".*\S.*", "a non-empty experiment name"))
    runs_dir: str = "runs"
    artifact_root: str | None = None
    #: Seconds armexp waits for a tracking server or database that does not answer before it
    #: stops the run (`armexp.remote`); at most an hour (MLflow caps the waits between retries).
    timeout_s: float = checked(60.0, between(5, 3600))
    #: Set by `armexp <stage> -m`: the sweep's parent run, which every job's run hangs under.
    sweep_run: str | None = None
    #: Set by `armexp <stage> -m`: the keys the sweep varies, whose values each job's run name
    #: shows (`armexp.run_names`).
    swept: list[str] = field(default_factory=list)


@dataclass
class ArmexpConfig:
    """The root config every stage composes (``conf/config.yaml``)."""

    seed: int = checked(0, at_least(0))
    robot: RobotConfig = MISSING
    obstacles: ObstaclesConfig = MISSING
    controller: Any = MISSING
    tuner: TunerConfig = MISSING
    agent: AgentConfig = MISSING
    env: EnvConfig = MISSING
    tasks: TasksConfig = MISSING
    scenario: ScenarioConfig = MISSING
    tracking: TrackingConfig = MISSING
    simulate: SimulateStageConfig = field(default_factory=SimulateStageConfig)
    tune: TuneStageConfig = field(default_factory=TuneStageConfig)
    train: TrainStageConfig = field(default_factory=TrainStageConfig)
    eval: EvalStageConfig = field(default_factory=EvalStageConfig)
    play: PlayStageConfig = field(default_factory=PlayStageConfig)
    report: ReportStageConfig = field(default_factory=ReportStageConfig)
    pipeline: PipelineStageConfig = field(default_factory=PipelineStageConfig)
    ui: UiStageConfig = field(default_factory=UiStageConfig)
    hpo: HpoStageConfig = field(default_factory=HpoStageConfig)


SCHEMAS: dict[str, type] = {
    "robot/robot_schema": RobotConfig,
    "controller/subsystem_adaptive_schema": AdaptiveControllerConfig,
    "controller/pid_schema": PIDControllerConfig,
    "controller/computed_torque_schema": ComputedTorqueControllerConfig,
    "scenario/scenario_schema": ScenarioConfig,
    "tuner/tuner_schema": TunerConfig,
    "agent/agent_schema": AgentConfig,
    "env/env_schema": EnvConfig,
    "obstacles/obstacles_schema": ObstaclesConfig,
    "tasks/tasks_schema": TasksConfig,
    "tracking/tracking_schema": TrackingConfig,
}
