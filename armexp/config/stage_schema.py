"""Structured configs of the stages' own keys (``simulate.*``, ``tune.*``, ``train.*``,
``eval.*``, ``play.*``, ``report.*``, ``ui.*``, ``pipeline.*``); the root config that holds them
and the config groups' schemas are in `armexp.config.schema`."""

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
    nonnegative,
    one_of,
    or_null,
    positive,
)
from armexp.hpo.names import PRUNER_NAMES, SAMPLER_NAMES

_pos = positive()


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
    #: controller, the policy's robot and its criterion, the config's ``tuner.seed`` first:
    #: `armexp.gains.tuned`) or ``config`` (each controller's
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
    #: HPO runs (`armexp hpo`, ``hydra/sweeper=optuna``) whose best trials, objective and
    #: parameter importances the report adds: beside the eval runs of a selection set above, or
    #: without one a report of these alone.
    hpo_runs: list[str] = field(default_factory=list)
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
class StudyAgent:
    """One more agent of a study (`armexp.stages.study`): trained and evaluated beside
    ``agent`` at each of its seeds, on the same tuned gains and held-out targets."""

    #: Its preset, an option of the ``agent`` config group (``sac_plain``).
    preset: str = MISSING
    #: The seeds it runs at, each one of ``pipeline.seeds`` (empty: all of them).
    seeds: list[int] = field(default_factory=list)
    #: Agent keys set on the preset (``max_env_steps: 1000000``); the study's ``agent.*``
    #: settings are ``agent``'s own and do not reach it.
    agent: dict[str, Any] = field(default_factory=dict)


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
    #: In a study, more agents beside ``agent``, each with its own seeds and budget.
    agents: list[StudyAgent] = field(default_factory=list)


@dataclass
class HpoSamplerConfig:
    """Optuna's sampler (`armexp.hpo.study.SAMPLERS`; cmaes needs the cmaes package)."""

    name: str = checked("tpe", one_of(*SAMPLER_NAMES))
    seed: int | None = checked(None, or_null(at_least(0)))


@dataclass
class HpoPrunerConfig:
    """Optuna's pruner, fed by the held-out checks: ``median`` (MedianPruner: after
    ``n_startup_trials`` trials and ``n_warmup_steps`` steps), ``hyperband`` (HyperbandPruner,
    ``reduction_factor``) or ``none``."""

    name: str = checked("median", one_of(*PRUNER_NAMES))
    n_startup_trials: int = checked(5, at_least(0))
    n_warmup_steps: int = checked(0, at_least(0))
    reduction_factor: int = checked(3, at_least(2))


@dataclass
class HpoStageConfig:
    """`armexp hpo` (docs/hpo.md); ``seeds`` also serve ``hydra/sweeper=optuna``."""

    run_name: str | None = None
    #: null: derived from what the trials depend on, so the same command resumes the study.
    study_name: str | None = None
    #: An Optuna database URL; null: optuna.db beside the MLflow store (`armexp.hpo.study`).
    storage: str | None = None
    #: The trials the study holds when the command ends (finished, pruned or failed).
    n_trials: int = checked(20, at_least(1))
    #: Queue every trial that failed on its own again, once, with its values (a failure since
    #: fixed); false: a failed trial counts as done, as Optuna counts it.
    retry_failed: bool = False
    #: Processes asking for trials at once (Optuna's parallel search: the command and
    #: ``n_jobs - 1`` copies of it sharing the study; `armexp.hpo.parallel`).
    n_jobs: int = checked(1, at_least(1))
    #: Each trial trains these seeds; its value is the IQM of their final held-out success.
    seeds: list[int] = checked(factory=lambda: [0, 1], check=each(at_least(0)))
    sampler: HpoSamplerConfig = field(default_factory=HpoSamplerConfig)
    pruner: HpoPrunerConfig = field(default_factory=HpoPrunerConfig)
    #: The search space: config key -> Hydra sweep (``interval(…)``, ``choice(…)``, ``range(…)``).
    params: dict[str, Any] = field(default_factory=dict)
