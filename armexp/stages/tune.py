"""`armexp tune`: cuckoo search (Algorithm 2) of the configured controller's gains.

Logs to one MLflow run: the best objective per iteration (metric history ``best_objective``),
evaluations, wall time, the objective of the paper's published gains and of the configured gains
on the same scenarios, the winning gains as params (``tuned.<gain>``) and as ``gains.yaml``
(config form, ready for ``controller.gains``), their constraint figures (``best_gain_margin``
over the pose grid, ``best_peak_torque``, ``best_time_at_limit``), the gains that ended on a
bound of the search box (tag ``armexp.gains_on_bound``), every candidate (``candidates.csv``)
and a convergence figure (``convergence.png``).
"""

from __future__ import annotations

import time
from typing import Any

import mlflow
import numpy as np
import pandas as pd
import yaml
from omegaconf import DictConfig

from armexp import console, tracking
from armexp.builders import build_plant, controller_gains, controller_kind
from armexp.config import ConfigError
from armexp.sim.controllers import ADAPTIVE, PAPER_GAINS, gain_mapping, gain_names, gain_vector
from armexp.tune.cuckoo import CuckooResult, cuckoo_search
from armexp.tune.objective import ObjectiveSettings, TuningObjective, make_scenarios
from armexp.tune.stability import pose_grid

FLUSH_EVERY = 25


def search_box(cfg: DictConfig) -> tuple[list[str], np.ndarray, np.ndarray]:
    """Gain names and their [lower, upper] from ``controller.bounds``."""
    n = len(cfg.robot.lengths)
    names = gain_names(controller_kind(cfg), n)
    bounds = cfg.controller.bounds
    missing = [g for g in names if g not in bounds]
    if missing:
        raise ConfigError(
            f"controller.bounds lacks {', '.join(missing)}: give [lower, upper] for every gain of "
            f"{cfg.controller.name} on a {n}-joint arm ({', '.join(names)})."
        )
    lower = np.array([float(bounds[g][0]) for g in names])
    upper = np.array([float(bounds[g][1]) for g in names])
    return names, lower, upper


def build_objective(cfg: DictConfig, kind: int | None = None) -> TuningObjective:
    settings = ObjectiveSettings(**dict(cfg.tuner.objective))
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


def on_bound(names: list[str], x: np.ndarray, lower: np.ndarray, upper: np.ndarray) -> list[str]:
    """The gains within 0.1 % of the box width from a bound, as ``name=lower|upper``."""
    tol = 1e-3 * (upper - lower)
    out = []
    for g, v, lo, hi, t in zip(names, x, lower, upper, tol, strict=True):
        if v - lo <= t:
            out.append(f"{g}=lower")
        elif hi - v <= t:
            out.append(f"{g}=upper")
    return out


def _convergence_figure(result: CuckooResult, reference: dict[str, float]) -> Any:
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
    ax.set_ylabel("objective W (Gaing)")
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


def run(cfg: DictConfig) -> tracking.StageResult:
    names, lower, upper = search_box(cfg)
    with tracking.stage_run(cfg, "tune", run_name=cfg.tune.run_name) as active:
        objective = build_objective(cfg)
        n = len(cfg.robot.lengths)
        kind = objective.kind
        reference: dict[str, float] = {}
        paper = build_objective(cfg, kind=ADAPTIVE) if kind != ADAPTIVE else objective
        reference["objective_paper_gains"] = float(
            paper(gain_vector(ADAPTIVE, PAPER_GAINS, n)[None])[0]
        )
        reference["objective_config_gains"] = float(objective(controller_gains(cfg)[None])[0])
        mlflow.log_metrics({k: v for k, v in reference.items() if np.isfinite(v)})

        tuner = cfg.tuner
        pending: list[float] = []
        logged = 0
        bar = console.progress_bar(cfg.tune.progress, int(tuner.n_iterations), "tune", "it")

        def flush() -> None:
            nonlocal logged
            if pending:
                tracking.log_metric_history("best_objective", pending, start_step=logged + 1)
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
                objective,
                lower,
                upper,
                n_nests=int(tuner.n_nests),
                n_iterations=int(tuner.n_iterations),
                pa=float(tuner.pa),
                beta=float(tuner.beta),
                step_scale=float(tuner.step_scale),
                abandon=str(tuner.abandon),
                seed=int(tuner.seed),
                callback=on_iteration,
            )
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        finally:
            wall = time.perf_counter() - start
            flush()  # keep the history logged so far, even when interrupted
            if bar is not None:
                bar.close()

        table = pd.DataFrame(result.evaluations, columns=names)
        table.insert(0, "iteration", result.iterations)
        table["objective"] = result.scores
        tracking.log_dataframe(table, "candidates.csv")
        if not np.isfinite(result.best_f):
            raise ConfigError(
                f"tune found no feasible gains for {cfg.controller.name}: all "
                f"{result.n_evaluations} candidates in controller.bounds were unstable at some "
                f"pose (tuner.objective.gain_margin={cfg.tuner.objective.gain_margin}) or "
                "diverged; narrow the gains' upper bounds or raise the budget."
            )
        crit = objective.criteria(result.best_x[None])
        bound_hits = on_bound(names, result.best_x, lower, upper)
        # best_objective's last history point is the final value; not logged again here.
        metrics = {
            "n_evaluations": float(result.n_evaluations),
            "wall_time_s": wall,
            "evaluations_per_s": result.n_evaluations / wall if wall > 0 else float("nan"),
            "best_overshoot": float(crit.overshoot.mean()),
            "best_rise_time_s": float(crit.rise_time.mean()),
            "best_settling_time_s": float(crit.settling_time.mean()),
            "best_steady_state_error": float(crit.steady_state_error.mean()),
            "best_gain_margin": objective.gain_margin(result.best_x),
            "best_peak_torque": float(crit.peak_torque[0]),
            "best_time_at_limit": float(crit.time_at_limit[0]),
            "best_gains_on_bound": float(len(bound_hits)),
        }
        mlflow.log_metrics({k: v for k, v in metrics.items() if np.isfinite(v)})
        mlflow.set_tag("armexp.gains_on_bound", ", ".join(bound_hits) or "none")
        mapping = gain_mapping(kind, result.best_x, n)
        mlflow.log_params({f"tuned.{k}": v for k, v in zip(names, result.best_x, strict=True)})
        mlflow.log_text(yaml.safe_dump(mapping, sort_keys=False), "gains.yaml")
        fig = _convergence_figure(result, reference)
        mlflow.log_figure(fig, "convergence.png")
        import matplotlib.pyplot as plt

        plt.close(fig)  # a sweep or study tunes many times in one process

        print(
            f"tune: run {active.info.run_id} | {cfg.controller.name} | best W {result.best_f:.4g} "
            f"(paper gains {reference['objective_paper_gains']:.4g}) | gains {_short(mapping)} | "
            f"{result.n_evaluations} evaluations, {wall:.1f} s"
            + (f" | on a bound: {', '.join(bound_hits)}" if bound_hits else "")
        )
        summary = {"best_objective": float(result.best_f), **metrics, **reference}
        return tracking.StageResult(active.info.run_id, summary)
