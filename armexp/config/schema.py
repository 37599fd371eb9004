"""Structured configs: the typed schema behind every group of ``conf/``.

Each group's YAML files start from one of these dataclasses (registered in Hydra's ConfigStore as
``<group>/<name>_schema``), so OmegaConf rejects unknown keys and wrong types, and
`armexp.config.validate` checks the values (``metadata['check']``) and the cross-field rules.
Joint numbers in configs are 1-based, as in the paper (q1, q2).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING

from armexp.baselines import ADAPTIVE_OFF, BASELINES, DEFAULT_BASELINES, OWN_LABELS, PLAY_LABELS
from armexp.config.checks import (
    Check,
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


# ------------------------------------------------------------------------------------- agent
@dataclass
class AgentConfig:
    """SB3 SAC hyper-parameters (Table II for ``sac_paper``)."""

    name: str = MISSING
    algo: str = checked("sac", one_of("sac"))
    batch_size: int = checked(512, at_least(1))
    tau: float = checked(0.001, between(0.0, 1.0, lo_open=True))
    buffer_size: int = checked(1_000_000, at_least(1))
    learning_starts: int = checked(1000, at_least(0))
    gamma: float = checked(0.995, between(0.0, 1.0))
    learning_rate: float = checked(0.001, _pos)
    episodes: int = checked(20000, at_least(1))
    train_freq: int = checked(1, at_least(1))
    gradient_steps: int = checked(1, at_least(1))
    ent_coef: str = checked(
        "auto",
        matches(
            r"auto(_\d+(\.\d*)?([eE][-+]?\d+)?)?|\d+(\.\d*)?([eE][-+]?\d+)?",
            "'auto', 'auto_<initial value>' or a number ≥ 0 (SB3's ent_coef)",
        ),
    )
    #: n-step returns for the critic targets (SB3's n_steps; 1 = plain SAC).
    n_steps: int = checked(1, at_least(1))
    net_arch: list[int] = checked(factory=lambda: [256, 256], check=each(at_least(1)))
    #: The critics' hidden layers, where they differ from the actor's (None: ``net_arch``).
    critic_arch: list[int] | None = checked(None, or_null(each(at_least(1))))
    #: Parallel environments (SB3 VecEnv); ``vec_env`` dummy = in process, subproc = processes.
    n_envs: int = checked(1, at_least(1))
    vec_env: str = checked("dummy", one_of("dummy", "subproc"))
    #: Extra caps on the budget besides ``episodes`` (None: none): environment steps, minutes.
    max_env_steps: int | None = checked(None, or_null(at_least(1)))
    max_minutes: float | None = checked(None, or_null(_pos))
    device: str = checked(
        "cpu", matches(r"cpu|auto|mps|cuda(:\d+)?", "cpu, auto, mps, cuda or cuda:<index>")
    )
    #: How the update runs: ``autograd`` (SB3's update through torch's autograd, eager) or
    #: ``compiled`` (the same losses as one torch.compile graph, `armexp.agents.compiled`).
    #: ``analytic`` (gradients written out by hand) was removed: ``compiled`` is faster.
    gradients: str = checked(
        "autograd",
        Check(
            lambda v: v in ("autograd", "compiled"),
            "autograd or compiled (the hand-written analytic gradients were removed; use compiled)",
        ),
    )
    #: Learning aids, by name, in the order they apply: each a config with a ``_target_``
    #: (`armexp.agents.addons`). None for the paper's plain SAC.
    aids: dict[str, Any] = field(default_factory=dict)


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


# ---------------------------------------------------------------------------------- stages
@dataclass
class SimulateStageConfig:
    run_name: str | None = None


@dataclass
class TuneStageConfig:
    run_name: str | None = None
    #: A progress bar over iterations: true, false, or null (when stderr is a terminal).
    progress: bool | None = None


@dataclass
class TrainStageConfig:
    run_name: str | None = None
    #: Gains source: ``tuned`` = a tune run (``tune_run`` or the latest matching one),
    #: ``config`` = ``controller.gains`` as composed (e.g. ``controller.gains=paper``).
    gains: str = checked("tuned", one_of("tuned", "config"))
    tune_run: str | None = None
    #: A KILLED or FAILED train run to continue from its latest checkpoint.
    resume: str | None = None
    checkpoint_every: int = checked(10_000, at_least(1))
    log_every: int = checked(2_000, at_least(1))
    #: Held-out evaluation while training: every ``eval_every`` steps (0: never), the
    #: deterministic policy on ``eval_targets`` random targets drawn with ``eval_seed`` (kept
    #: apart from `armexp eval`'s ``tasks.random_seed``). Its time is not training time.
    eval_every: int = checked(0, at_least(0))
    eval_targets: int = checked(50, at_least(1))
    eval_seed: int = checked(10_007, at_least(0))
    #: Callbacks by name, each a config with a ``_target_`` (`armexp.agents.addons`); the
    #: held-out checks take the three settings above.
    callbacks: dict[str, Any] = field(
        default_factory=lambda: {
            "held_out": {
                "_target_": "armexp.agents.callbacks.HeldOutChecks",
                "every": "${train.eval_every}",
                "targets": "${train.eval_targets}",
                "seed": "${train.eval_seed}",
            }
        }
    )
    #: A progress bar over environment steps: true, false, or null (when stderr is a terminal).
    progress: bool | None = None
    #: Torch threads of the training process (null: torch's default, one per core). One by
    #: default, so that jobs sharing a machine do not slow each other down
    #: (benchmarks/contention.py).
    torch_threads: int | None = checked(1, or_null(at_least(1)))


def _labels_check(labels: list[str], what: str) -> Check:
    """One of ``labels`` (``what`` says what they are)."""
    return Check(lambda v: v in labels, f"choose {what}")


_BASELINE_NAMES = ", ".join(BASELINES)
_baselines_check = Check(
    lambda v: all(b in BASELINES for b in v) and len(set(v)) == len(v),
    f"each entry must be one of the baselines {_BASELINE_NAMES}, listed once",
)
_tune_runs_check = Check(
    lambda v: all(
        (k in BASELINES or re.fullmatch(r"adaptive_[a-z]+", k)) and k != ADAPTIVE_OFF
        and isinstance(r, str) and r for k, r in v.items()
    ),
    f"map a baseline ({_BASELINE_NAMES}) or adaptive_<criterion> to a tune run id",
)  # fmt: skip


@dataclass
class EvalStageConfig:
    """`armexp eval` (docs/design.md §8): the labels it runs are those of `armexp.baselines`."""

    run_name: str | None = None
    #: The train run whose policy is evaluated (None: the latest FINISHED one that matches).
    train_run: str | None = None
    #: Baselines run beside the policy's own controller, by name (`armexp.baselines.BASELINES`).
    baselines: list[str] = checked(factory=lambda: list(DEFAULT_BASELINES), check=_baselines_check)
    #: Also run the policy's adaptive law with adaptation off (b1 = 0, ρ̂ ≡ 0): ``adaptive_off``.
    ablation: bool = True
    #: Baseline gains: ``tuned`` (``tune_runs.<baseline>`` or the latest FINISHED tune run of its
    #: controller, the policy's robot and its criterion) or ``config`` (each controller's
    #: configured gains for the policy's robot).
    baseline_gains: str = checked("tuned", one_of("tuned", "config"))
    #: Tune run ids by label: a baseline's, or ``adaptive_<criterion>``'s (the adaptive law tuned
    #: under a baseline's criterion, where that differs from the policy's). The pipeline fills it.
    tune_runs: dict[str, str] = checked(factory=dict, check=_tune_runs_check)
    #: Adaptive gains: ``tuned`` (those the policy was trained with, its train run's
    #: ``gains.yaml``) or ``config`` (``controller.gains`` as composed, e.g. the paper's).
    adaptive_gains: str = checked("tuned", one_of("tuned", "config"))
    #: Evaluate the paper tasks (a)-(d); plus tasks.n_random held-out random targets.
    paper_tasks: bool = True
    random_trajectories: bool = False
    deterministic: bool = True
    #: Convergence (Definition 1, `armexp.sim.convergence`): each paper task is run again for
    #: ``convergence_window`` s with the reference started this far (rad, every joint) from the
    #: arm: small enough not to saturate the torques.
    initial_offset: float = checked(0.005, _pos)
    #: ... and once more this far (rad; null: no second run), the metrics suffixed ``_large``.
    large_offset: float | None = checked(0.05, or_null(_pos))
    convergence_window: float = checked(1.0, _pos)
    #: The settling band is max(2 % of the offset, this) (rad).
    convergence_tolerance: float = checked(1e-4, nonnegative())
    #: Each paper task's episode per controller as an animated GIF and MP4 (a few seconds each).
    animations: bool = True

    #: A progress bar over episodes: true, false, or null (when stderr is a terminal).
    progress: bool | None = None


@dataclass
class PlayStageConfig:
    """`armexp play`: a train run's policy on chosen tasks and targets, animated."""

    run_name: str | None = None
    #: The train run whose policy plays (None: the latest FINISHED one that matches, as eval).
    train_run: str | None = None
    #: A label as eval names it: the policy's own controller (``adaptive``, ``pid`` or
    #: ``computed_torque``), ``adaptive_off`` or a baseline's name; null: the policy's own.
    controller: str | None = checked(
        None,
        or_null(
            _labels_check(
                PLAY_LABELS,
                "the policy's own controller (" + ", ".join(OWN_LABELS) + f"), {ADAPTIVE_OFF} or "
                f"a baseline ({_BASELINE_NAMES})",
            )
        ),
    )
    #: Gains as `armexp eval` takes them (``eval.adaptive_gains``, ``eval.baseline_gains``,
    #: ``eval.tune_runs``).
    adaptive_gains: str = checked("tuned", one_of("tuned", "config"))
    baseline_gains: str = checked("tuned", one_of("tuned", "config"))
    tune_runs: dict[str, str] = checked(factory=dict, check=_tune_runs_check)
    #: Names of ``tasks.targets``, then extra targets ``[[x, y], …]`` (m; typed loosely because
    #: OmegaConf does not turn an int into a float inside a nested list, `validate` checks them).
    tasks: list[str] = field(default_factory=lambda: ["a", "b", "c", "d"])
    targets: list[Any] = field(default_factory=list)
    formats: list[str] = checked(factory=lambda: ["gif", "mp4"], check=each(one_of("gif", "mp4")))
    deterministic: bool = True


@dataclass
class ReportStageConfig:
    run_name: str | None = None
    #: Where the report folder goes (None: ``<tracking.runs_dir>/report``).
    out_dir: str | None = None
    #: Run selection, first that is set wins: explicit eval run ids, the eval runs of one pipeline
    #: parent run, an MLflow filter on eval runs (e.g. ``tags.sweep = 'seeds'``); none set: the
    #: latest pipeline's eval runs, else the latest eval run.
    eval_runs: list[str] = field(default_factory=list)
    pipeline_run: str | None = None
    filter: str | None = None
    #: Experiment to read (None: ``tracking.experiment``).
    experiment: str | None = None
    fig6_task: str = checked("a", one_of("a", "b", "c", "d"))
    #: The seeds the selection should hold (a study sets them): those without a FINISHED eval
    #: run are named as missing in the report.
    seeds: list[int] = field(default_factory=list)


@dataclass
class UiStageConfig:
    #: Where `armexp ui` serves (loopback by default: the store is not shared by accident).
    host: str = "127.0.0.1"
    port: int = checked(5000, between(1, 65535))


@dataclass
class PipelineStageConfig:
    run_name: str | None = None
    #: Reuse a FINISHED run whose stage inputs match instead of running the stage again.
    reuse: bool = False
    #: A study (`armexp.stages.study`): one pipeline per seed under one parent run, then one
    #: report over them all (empty: a single pipeline with ``seed``).
    seeds: list[int] = field(default_factory=list)
    #: In a study, each seed's policy is also evaluated with the paper's adaptive gains
    #: (``eval.adaptive_gains=config eval.baselines=[] eval.ablation=false``).
    paper_gains_row: bool = False


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
