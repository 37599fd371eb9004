"""One pipeline of `armexp pipeline` (the command's entry is `armexp.stages.study.run`): tune
(the policy's controller and every baseline) → train → eval → report under one parent run.

Each stage runs as a nested child run of the pipeline's run, wired to its upstream runs by id
(``train.tune_run``, ``eval.train_run``, ``eval.tune_runs``, ``report.pipeline_run``), so the
lineage tags point inside this pipeline. Each step runs on a config of its own, a copy of the
pipeline's with its upstream ids set (`train_config`, `eval_config`, `report_config`); the
pipeline's own config is never changed. The tune steps (`tune_steps`): ``tune``, the configured
controller under the comparison's criterion (``tuner.objective.criterion``); ``tune_<baseline>``
for every baseline of ``eval.baselines`` under its own criterion (``tune_pid_gaing``,
``tune_pid_itae``, ``tune_computed_torque``); and ``tune_adaptive_<criterion>``, the adaptive law
under each other criterion a baseline needs (the proposed side of that comparison). With
``eval.baseline_gains=config`` only ``tune`` runs. With ``pipeline.reuse=true`` a stage whose
inputs match a FINISHED run's is not run again: that run's id is used and tagged on the parent
(``armexp.reused.<step>``). A stage's inputs are the config keys it reads that change its result,
upstream run ids included, as its module declares them (``READS``, `armexp.reads`; the stage runs
on a view of the config that lets it read nothing else); `armexp.tracking.reuse` finds the run.
A failing stage marks the parent FAILED and names itself in ``armexp.failed_stage``.
"""

from __future__ import annotations

import copy
import logging
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import mlflow
from omegaconf import DictConfig, OmegaConf, open_dict

from armexp.baselines import (
    ADAPTIVE,
    BASELINES,
    CONFIG,
    baseline_criterion,
    reference_criteria,
    reference_label,
)
from armexp.config import ConfigError, validate
from armexp.gains import criterion_of, with_criterion
from armexp.reads import Reads
from armexp.tracking import reuse, run_end, stage_runs
from armexp.tracking.tags import FAILED_STAGE_TAG, RESUMED_PREFIX, REUSED_PREFIX, RUN_PREFIX

log = logging.getLogger(__name__)


def controller_config(cfg: DictConfig, controller: str) -> DictConfig:
    """The same run with ``controller=<controller>`` (its per-robot parts from
    ``conf/per_robot/<controller>_<robot>.yaml``): composed by Hydra from this job's overrides,
    with this config's other sections (a study sets the seed per seed)."""
    from hydra import compose
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig

    if str(cfg.controller.name) == controller:
        return copy.deepcopy(cfg)
    overrides: list[str] = []
    if HydraConfig.initialized():
        overrides = [o for o in HydraConfig.get().overrides.task if not o.startswith("controller")]
    if not GlobalHydra.instance().is_initialized():
        from armexp.config import compose_config

        other = compose_config([*overrides, f"controller={controller}"])
    else:
        other = compose(config_name="config", overrides=[*overrides, f"controller={controller}"])
    # Hydra records the job's overrides resolved (``tuner.seed=${seed}`` as ``tuner.seed=0``):
    # every section but the controller is taken from the job's own config instead.
    with open_dict(other):
        for key in cfg:
            if key != "controller":
                other[key] = copy.deepcopy(cfg[key])
    validate(other)
    return other


def tune_steps(cfg: DictConfig) -> dict[str, tuple[str, str]]:
    """The pipeline's tune steps: step name → (controller, criterion), ``tune`` first. A
    baseline with the configured controller and the comparison's criterion is ``tune`` itself."""
    comparison = criterion_of(cfg)
    own = str(cfg.controller.name)
    steps = {"tune": (own, comparison)}
    if str(cfg.eval.baseline_gains) != "tuned":
        return steps
    names = [str(b) for b in cfg.eval.baselines]
    for name in names:
        wanted = (BASELINES[name].controller, baseline_criterion(name, comparison))
        if wanted != steps["tune"]:
            steps[f"tune_{name}"] = wanted
    if own == ADAPTIVE:
        own_criterion = comparison if cfg.train.gains == "tuned" else CONFIG
        for criterion in reference_criteria(names, own_criterion, comparison):
            if criterion != comparison:
                steps[f"tune_{reference_label(criterion)}"] = (ADAPTIVE, criterion)
    return steps


def eval_tune_runs(cfg: DictConfig, ids: Mapping[str, str]) -> dict[str, str]:
    """``eval.tune_runs`` from the tune steps' run ids (`tune_steps`): each baseline's, and each
    ``adaptive_<criterion>`` reference's."""
    steps = tune_steps(cfg)
    by_kind = {kind: ids[step] for step, kind in steps.items() if step in ids}
    out: dict[str, str] = {}
    comparison = criterion_of(cfg)
    for name in cfg.eval.baselines:
        kind = (BASELINES[str(name)].controller, baseline_criterion(str(name), comparison))
        if kind in by_kind:
            out[str(name)] = by_kind[kind]
    for (controller, criterion), run_id in by_kind.items():
        if controller == ADAPTIVE:
            out[reference_label(criterion)] = run_id
    return out


def with_values(cfg: DictConfig, values: Mapping[str, Any]) -> DictConfig:
    """A copy of ``cfg`` with each dotted key of ``values`` set to its value (a mapping replaces
    the node, it is not merged into it); ``cfg`` is left as it was."""
    out = copy.deepcopy(cfg)
    with open_dict(out):
        for key, value in values.items():
            OmegaConf.update(out, key, value, merge=False)
    return out


def train_config(cfg: DictConfig, ids: Mapping[str, str]) -> DictConfig:
    """The train step's config: with tuned gains, ``train.tune_run`` is this pipeline's ``tune``
    run (tagged ``armexp.tune_run`` on the train run and hashed into its inputs)."""
    return with_values(cfg, {"train.tune_run": ids["tune"]} if cfg.train.gains == "tuned" else {})


def eval_config(cfg: DictConfig, ids: Mapping[str, str]) -> DictConfig:
    """The eval step's config: ``eval.train_run`` is this pipeline's train run and, with tuned
    baseline gains, ``eval.tune_runs`` its tune steps' runs (`eval_tune_runs`)."""
    values: dict[str, Any] = {"eval.train_run": ids["train"]}
    if cfg.eval.baseline_gains == "tuned":
        values["eval.tune_runs"] = eval_tune_runs(cfg, ids)
    return with_values(cfg, values)


def paper_gains_config(cfg: DictConfig) -> DictConfig:
    """The paper-gains row of a study: the policy with the configured (the paper's) adaptive
    gains, alone."""
    return with_values(
        cfg,
        {"eval.adaptive_gains": "config", "eval.baselines": [], "eval.ablation": False,
         "eval.tune_runs": {}},
    )  # fmt: skip


def report_config(cfg: DictConfig, pipeline_run: str, eval_runs: Sequence[str]) -> DictConfig:
    """The report step's config: the report of ``pipeline_run`` over ``eval_runs``."""
    return with_values(
        cfg, {"report.pipeline_run": pipeline_run, "report.eval_runs": list(eval_runs)}
    )


def run_one(
    cfg: DictConfig,
    run_name: str | None = None,
    paper_gains_row: bool = False,
    report_: bool = True,
) -> stage_runs.StageResult:
    """The tune steps (`tune_steps`) → train → eval (→ eval_paper: the adaptive controller with
    the paper's gains) (→ report) under one parent run; its id, and the ids of the stage runs by
    step."""
    from armexp.stages import evaluate, report, train, tune

    seed = int(cfg.seed)
    tune_cfgs = {
        step: with_criterion(
            with_values(controller_config(cfg, controller), {"seed": seed}), criterion
        )
        for step, (controller, criterion) in tune_steps(cfg).items()
    }
    ids: dict[str, str] = {}
    name = run_name if run_name is not None else cfg.pipeline.run_name
    with stage_runs.stage_run(cfg, "pipeline", run_name=name) as parent:
        parent_id = parent.info.run_id

        def step(
            name: str,
            reads: Reads | None,
            stage_cfg: DictConfig,
            fn: Callable[[DictConfig], stage_runs.StageResult],
        ) -> str:
            if cfg.pipeline.reuse and reads is not None:
                found = reuse.reusable(stage_cfg, reads)
                if found:
                    print(f"pipeline: {name} reuses run {found}")
                    mlflow.set_tag(f"{REUSED_PREFIX}{name}", found)
                    ids[name] = found
                    return found
            print(f"pipeline: {name} ...")
            try:
                with stage_runs.parent(parent_id):
                    result = fn(stage_cfg)
            except BaseException as exc:
                with run_end.while_stopping(exc):
                    mlflow.set_tag(FAILED_STAGE_TAG, name)
                if isinstance(exc, ConfigError):
                    raise ConfigError(f"the pipeline stopped at {name}: {exc}") from None
                if not isinstance(exc, KeyboardInterrupt | SystemExit):
                    print(f"pipeline: {name} failed: {type(exc).__name__}: {exc}")
                raise
            ids[name] = result.run_id
            mlflow.set_tag(f"{RUN_PREFIX}{name}", ids[name])
            return ids[name]

        for tune_step, tune_cfg in tune_cfgs.items():
            step(tune_step, tune.READS, tune_cfg, tune.run)
        # Each step gets a config of its own with its upstream run ids (`train_config`,
        # `eval_config`, `report_config`), the keys a stage reads them from when run alone.
        train_cfg = train_config(cfg, ids)
        stopped = reuse.resumable(train_cfg, train.READS) if cfg.pipeline.reuse else None
        if stopped and not reuse.reusable(train_cfg, train.READS):
            print(f"pipeline: train resumes the interrupted run {stopped}")
            mlflow.set_tag(RESUMED_PREFIX + "train", stopped)
            step("train", train.READS, with_values(train_cfg, {"train.resume": stopped}),
                 lambda c: train.resume(c, check_overrides=False))  # fmt: skip
        else:
            step("train", train.READS, train_cfg, train.run)
        eval_cfg = eval_config(train_cfg, ids)
        step("eval", evaluate.READS, eval_cfg, evaluate.run)
        if paper_gains_row:
            step("eval_paper", evaluate.READS, paper_gains_config(eval_cfg), evaluate.run)
        if report_:
            step("report", None, report_config(eval_cfg, parent_id, [ids["eval"]]), report.run)
        mlflow.log_text(OmegaConf.to_yaml(OmegaConf.create(ids)), "runs.yaml")
        print(
            f"pipeline: run {parent_id} | "
            + " | ".join(f"{k} {v[:8]}" for k, v in ids.items())
            + (f" | report: {report.out_dir(cfg) / 'index.html'}" if report_ else "")
        )
    return stage_runs.StageResult(parent_id, ids)
