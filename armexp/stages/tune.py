"""`armexp tune`: cuckoo search (Algorithm 2) of the configured controller's gains.

The search runs over `armexp.tune.space.SearchSpace` (log10 of the coordinates in
``controller.bounds`` with ``tuner.log_space``; the adaptive law over a0, a1, λ, γ) and scores each
point by `armexp.tune.objective.TuningObjective` under ``tuner.objective.criterion``. The
configured gains (``controller.gains``) take the place of the first of the initial nests.

Logs to one MLflow run: the tags ``armexp.criterion`` and ``armexp.horizon`` (the criterion and
the scenarios' length in s), the best objective per iteration (metric history
``best_objective``), evaluations, wall time, the objective of the paper's published gains and of
the configured gains on the same scenarios, the winning gains as params (``tuned.<gain>``) and
as ``gains.yaml`` (config form, ready for ``controller.gains``), their constraint figures
(``best_gain_margin`` over the pose grid, ``best_gain_margin_adapted`` with the adaptive term at
its peak ``best_sigma_max``, ``best_peak_torque``, ``best_time_at_limit``), the coordinates that
ended on a bound of the search box in its own scale (tag ``armexp.gains_on_bound``), every
candidate (``candidates.csv``: gains, and λ, γ for the adaptive law) and a convergence figure
(``convergence.png``).
"""

from __future__ import annotations

import time
from typing import Any

import mlflow
import numpy as np
import pandas as pd
import yaml
from omegaconf import DictConfig

from armexp import console
from armexp.builders import build_plant, controller_gains, controller_kind
from armexp.config import ConfigError
from armexp.reads import Reads
from armexp.sim.controllers import (
    ADAPTIVE,
    PAPER_GAINS,
    adaptive_rates,
    gain_mapping,
    gain_names,
    gain_vector,
)
from armexp.tracking import artifacts, stage_runs
from armexp.tracking.tags import CRITERION_TAG, GAINS_ON_BOUND_TAG, HORIZON_TAG
from armexp.tune.cuckoo import CuckooResult, cuckoo_search
from armexp.tune.objective import (
    ObjectiveSettings,
    TuningObjective,
    make_scenarios,
    resolved_horizon,
)
from armexp.tune.space import SearchSpace, coordinate_names
from armexp.tune.stability import pose_grid

FLUSH_EVERY = 25
#: What tune reads of the config (`armexp.reads`): the plant (``robot``, ``controller.dt``), the
#: controller's gains and search box, the search and its objective, and the reference between
#: actions the scenarios are driven with (``env.reference``); the progress bar, run name and
#: store are not hashed.
READS = Reads(
    "tune",
    hashed=("robot", "controller", "tuner", "env.reference"),
    unhashed=("tune.progress", "tune.run_name", "tracking"),
    earlier=(("seed", "robot", "controller", "tuner"),),  # before env.reference was hashed
)


def search_space(cfg: DictConfig) -> SearchSpace:
    """The box of ``controller.bounds`` over the controller's search coordinates, searched in
    log space with ``tuner.log_space``."""
    n = len(cfg.robot.lengths)
    kind = controller_kind(cfg)
    names = coordinate_names(kind, n)
    bounds = cfg.controller.bounds
    missing = [g for g in names if g not in bounds]
    extra = [g for g in bounds if g not in names]
    if missing or extra:
        what = f"lacks {', '.join(missing)}" if missing else f"has {', '.join(extra)}, unused"
        raise ConfigError(
            f"controller.bounds {what}: give [lower, upper] for exactly the search coordinates of "
            f"{cfg.controller.name} on a {n}-joint arm ({', '.join(names)})."
        )
    lower = np.array([float(bounds[g][0]) for g in names])
    upper = np.array([float(bounds[g][1]) for g in names])
    try:
        return SearchSpace(kind, tuple(names), lower, upper, log=bool(cfg.tuner.log_space))
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def objective_settings(cfg: DictConfig) -> ObjectiveSettings:
    """``tuner.objective`` with its horizon resolved (the criterion's default when null)."""
    fields = dict(cfg.tuner.objective)
    fields["horizon"] = resolved_horizon(str(fields["criterion"]), fields["horizon"])
    return ObjectiveSettings(**fields)


def build_objective(cfg: DictConfig, kind: int | None = None) -> TuningObjective:
    settings = objective_settings(cfg)
    robot = cfg.robot
    plant = build_plant(cfg)
    lower = np.asarray(list(robot.joint_lower), dtype=np.float64)
    upper = np.asarray(list(robot.joint_upper), dtype=np.float64)
    scenarios = make_scenarios(
        settings, lower, upper, np.asarray(list(robot.velocity_bound)), plant.dt
    )
    return TuningObjective(
        plant,
        controller_kind(cfg) if kind is None else kind,
        scenarios,
        settings,
        poses=pose_grid(lower, upper, settings.stability_points),
        ramp=str(cfg.env.reference) == "ramp",
    )


def _convergence_figure(result: CuckooResult, reference: dict[str, float], criterion: str) -> Any:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 4))
    finite = np.isfinite(result.scores)
    ax.scatter(
        result.iterations[finite],
        result.scores[finite],
        s=4,
        alpha=0.25,
        color="grey",
        label="candidates",
    )
    ax.plot(np.arange(1, len(result.history) + 1), result.history, color="C0", label="best")
    for i, (label, value) in enumerate(reference.items()):
        if np.isfinite(value):
            ax.axhline(value, ls="--", color=f"C{i + 1}", label=label)
    ax.set_yscale("log")
    ax.set_xlabel("iteration")
    ax.set_ylabel(f"objective ({criterion})")
    ax.set_title("Cuckoo search convergence")
    ax.legend(fontsize=8)
    fig.tight_layout()
    return fig


def _short(gains: dict[str, Any]) -> str:
    """``a0=46.8 a1=942`` (``kp=[8.03e+05,1.04e+04]`` per joint): the summary line's gains, to 3
    digits; ``gains.yaml`` and the ``tuned.*`` params hold them in full."""

    def text(value: Any) -> str:
        if isinstance(value, list | tuple):
            return "[" + ",".join(f"{float(v):.3g}" for v in value) + "]"
        return f"{float(value):.3g}"

    return " ".join(f"{k}={text(v)}" for k, v in gains.items())


def _search(
    cfg: DictConfig, space: SearchSpace, objective: TuningObjective
) -> tuple[CuckooResult, float]:
    """Cuckoo search over ``space`` with ``objective``, its best objective per iteration logged
    as it goes (kept when interrupted); the result and the wall time."""
    tuner = cfg.tuner
    pending: list[float] = []
    logged = 0
    bar = console.progress_bar(cfg.tune.progress, int(tuner.n_iterations), "tune", "it")

    def flush() -> None:
        nonlocal logged
        if pending:
            artifacts.log_metric_history("best_objective", pending, start_step=logged + 1)
            logged += len(pending)
            pending.clear()

    def on_iteration(iteration: int, partial: CuckooResult) -> None:
        pending.append(float(partial.best_f))
        if bar is not None:
            bar.update(1)
            bar.set_postfix(best=f"{partial.best_f:.4g}")
        if len(pending) >= FLUSH_EVERY:
            flush()

    start = time.perf_counter()
    try:
        result = cuckoo_search(
            space.objective(objective),
            space.search_lower,
            space.search_upper,
            n_nests=int(tuner.n_nests),
            n_iterations=int(tuner.n_iterations),
            pa=float(tuner.pa),
            beta=float(tuner.beta),
            step_scale=float(tuner.step_scale),
            abandon=str(tuner.abandon),
            seed=int(tuner.seed),
            callback=on_iteration,
            # The configured gains (the paper's, or a baseline's defaults) are one of the
            # first nests, so even a small budget starts from a feasible point.
            start=space.point(controller_gains(cfg)),
        )
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    finally:
        wall = time.perf_counter() - start
        flush()  # keep the history logged so far, even when interrupted
        if bar is not None:
            bar.close()
    return result, wall


def _candidates(space: SearchSpace, result: CuckooResult, n: int) -> pd.DataFrame:
    """Every evaluated candidate: its gains (and λ, γ for the adaptive law) and objective."""
    gains = space.gains(result.evaluations)
    table = pd.DataFrame(gains, columns=gain_names(space.kind, n))
    if space.kind == ADAPTIVE:
        rates = np.array([adaptive_rates(g) for g in gains]).reshape(-1, 2)
        table["lambda"], table["gamma"] = rates[:, 0], rates[:, 1]
    table.insert(0, "iteration", result.iterations)
    table["objective"] = result.scores
    return table


def _best_metrics(
    objective: TuningObjective, space: SearchSpace, best: np.ndarray
) -> tuple[dict[str, float], list[str]]:
    """The winning gains' criteria and constraint figures, and the coordinates on a bound."""
    crit = objective.criteria(best[None])
    sigma = float(crit.sigma_max[0])
    bound_hits = space.on_bound(best)
    metrics = {
        "best_criterion": float(crit.criterion[0]),
        "best_overshoot": float(crit.overshoot.mean()),
        "best_rise_time_s": float(crit.rise_time.mean()),
        "best_settling_time_s": float(crit.settling_time.mean()),
        "best_steady_state_error": float(crit.steady_state_error.mean()),
        "best_itae": float(crit.itae.sum(axis=-1).mean()),
        "best_gain_margin": objective.gain_margin(best),
        "best_sigma_max": sigma,
        "best_gain_margin_adapted": objective.gain_margin(best, sigma=sigma),
        "best_peak_torque": float(crit.peak_torque[0]),
        "best_time_at_limit": float(crit.time_at_limit[0]),
        "best_gains_on_bound": float(len(bound_hits)),
    }
    return metrics, bound_hits


def _reference(cfg: DictConfig, objective: TuningObjective, n: int) -> dict[str, float]:
    """The objective at the paper's adaptive gains (scored as the adaptive law, whatever the
    tuned controller) and at the configured gains."""
    paper = build_objective(cfg, kind=ADAPTIVE) if objective.kind != ADAPTIVE else objective
    return {
        "objective_paper_gains": float(paper(gain_vector(ADAPTIVE, PAPER_GAINS, n)[None])[0]),
        "objective_config_gains": float(objective(controller_gains(cfg)[None])[0]),
    }


def _log_best(
    cfg: DictConfig,
    space: SearchSpace,
    objective: TuningObjective,
    result: CuckooResult,
    wall: float,
) -> tuple[dict[str, float], list[str], dict[str, Any]]:
    """Log the winning gains (params, ``gains.yaml``), their metrics and the gains on a bound;
    returns the metrics, the gains on a bound and the gains by name."""
    n = len(cfg.robot.lengths)
    if not np.isfinite(result.best_f):
        raise ConfigError(
            f"tune found no feasible gains for {cfg.controller.name}: all "
            f"{result.n_evaluations} candidates in controller.bounds were unstable at some "
            f"pose (tuner.objective.gain_margin={cfg.tuner.objective.gain_margin}) or "
            "diverged; narrow the gains' upper bounds or raise the budget."
        )
    best = space.gains(result.best_x)[0]
    metrics, bound_hits = _best_metrics(objective, space, best)
    metrics.update(
        n_evaluations=float(result.n_evaluations),
        wall_time_s=wall,
        evaluations_per_s=result.n_evaluations / wall if wall > 0 else float("nan"),
    )
    # best_objective's last history point is the final value; not logged again here.
    mlflow.log_metrics({k: v for k, v in metrics.items() if np.isfinite(v)})
    mlflow.set_tag(GAINS_ON_BOUND_TAG, ", ".join(bound_hits) or "none")
    mapping = gain_mapping(objective.kind, best, n)
    names = gain_names(objective.kind, n)
    mlflow.log_params({f"tuned.{k}": v for k, v in zip(names, best, strict=True)})
    mlflow.log_text(yaml.safe_dump(mapping, sort_keys=False), "gains.yaml")
    return metrics, bound_hits, mapping


def run(composed: DictConfig) -> stage_runs.StageResult:
    """Tune on `READS`' view of the composed config; the run logs the composed config whole."""
    cfg = READS.view(composed)
    space = search_space(cfg)
    settings = objective_settings(cfg)
    criterion = settings.criterion
    with stage_runs.stage_run(composed, "tune", run_name=cfg.tune.run_name, reads=READS) as active:
        mlflow.set_tags({CRITERION_TAG: criterion, HORIZON_TAG: f"{settings.horizon:g}"})
        objective = build_objective(cfg)
        n = len(cfg.robot.lengths)
        reference = _reference(cfg, objective, n)
        mlflow.log_metrics({k: v for k, v in reference.items() if np.isfinite(v)})

        result, wall = _search(cfg, space, objective)
        artifacts.log_dataframe(_candidates(space, result, n), "candidates.csv")
        metrics, bound_hits, mapping = _log_best(cfg, space, objective, result, wall)
        fig = _convergence_figure(result, reference, criterion)
        mlflow.log_figure(fig, "convergence.png")
        import matplotlib.pyplot as plt

        plt.close(fig)  # a sweep or study tunes many times in one process

        print(
            f"tune: run {active.info.run_id} | {cfg.controller.name} | {criterion} over "
            f"{settings.horizon:g} s: best {result.best_f:.4g} "
            f"(paper gains {reference['objective_paper_gains']:.4g}) | gains {_short(mapping)} | "
            f"{result.n_evaluations} evaluations, {wall:.1f} s"
            + (f" | on a bound: {', '.join(bound_hits)}" if bound_hits else "")
        )
        summary = {"best_objective": float(result.best_f), **metrics, **reference}
        return stage_runs.StageResult(active.info.run_id, summary)
