"""A study: ``armexp pipeline pipeline.seeds=[0,1,2,3,4]`` (``experiment=reproduce``).

One parent pipeline run (tag ``armexp.study``) holds one child pipeline per seed: the policy's
controller and every baseline tuned with that seed (the reproduce preset sets
``tuner.seed: ${seed}``; `armexp.stages.pipeline.tune_steps`), the agent trained, and its policy
evaluated with its controller, the ablation and the baselines (and, with
``pipeline.paper_gains_row``, alone with the paper's adaptive gains). Then one report over every
seed's eval runs, with the statistics over seeds (`armexp.report.stats`, `armexp.report.claims`).

A seed whose pipeline fails is recorded (``armexp.failed_seeds``) and the study goes on; the report
names it as missing. Re-running the same command finishes an interrupted study: the study always
runs with ``pipeline.reuse=true``, so every stage whose inputs match a FINISHED run is reused.
"""

from __future__ import annotations

from typing import Any

import mlflow
from omegaconf import DictConfig, OmegaConf

from armexp.config import ConfigError
from armexp.gains import job_overrides, with_train_source
from armexp.tracking import run_names, stage_runs
from armexp.tracking.tags import FAILED_SEEDS_TAG, RUN_PREFIX, STUDY_TAG


def run(cfg: DictConfig) -> stage_runs.StageResult:
    """`armexp pipeline`: one pipeline (`armexp.stages.pipeline.run_one`), or with
    ``pipeline.seeds`` a study of one pipeline per seed; the parent run, with the stage runs'
    ids by step as its summary. The command lives here so that the study, which runs
    pipelines, is the only module that knows both. Its ``train.gains`` is as the command meant
    it (`armexp.gains.with_train_source`)."""
    from armexp.stages import pipeline

    cfg = with_train_source(cfg, job_overrides())
    return run_study(cfg) if cfg.pipeline.seeds else pipeline.run_one(cfg)


def run_study(cfg: DictConfig) -> stage_runs.StageResult:
    from armexp.stages import pipeline, report

    seeds = [int(s) for s in cfg.pipeline.seeds]
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"pipeline.seeds={seeds} is not allowed: each seed must appear once.")
    ids: dict[str, str] = {}
    failed: dict[int, str] = {}
    evals: list[str] = []
    with stage_runs.stage_run(
        cfg, "pipeline", extra_tags={STUDY_TAG: ",".join(map(str, seeds))}
    ) as parent:
        parent_id = parent.info.run_id
        for seed in seeds:
            seed_cfg = pipeline.with_values(
                cfg, {"seed": seed, "pipeline.seeds": [], "pipeline.reuse": True}
            )
            print(f"study: seed {seed} ({seeds.index(seed) + 1} of {len(seeds)})")
            try:
                with stage_runs.parent(parent_id):
                    seed_run = pipeline.run_one(
                        seed_cfg,
                        # A study's own pipeline.run_name names the study, not each seed.
                        run_name=run_names.describe(seed_cfg, "pipeline"),
                        paper_gains_row=bool(cfg.pipeline.paper_gains_row),
                        report_=False,
                    )
            except (KeyboardInterrupt, SystemExit):
                raise
            except Exception as exc:  # the other seeds still run and are reported
                failed[seed] = f"{type(exc).__name__}: {exc}".splitlines()[0]
                print(f"study: seed {seed} failed ({failed[seed]}); going on")
                mlflow.set_tag(FAILED_SEEDS_TAG, ",".join(map(str, sorted(failed))))
                continue
            steps = seed_run.summary
            for step, run_id in steps.items():
                ids[f"{step}.{seed}"] = run_id
            evals += [steps[s] for s in ("eval", "eval_paper") if s in steps]
        if not evals:
            raise RuntimeError(f"every seed of the study failed: {failed}")
        report_cfg = pipeline.with_values(
            pipeline.report_config(cfg, parent_id, evals), {"report.seeds": seeds}
        )
        with stage_runs.parent(parent_id):
            ids["report"] = report.run(report_cfg).run_id
        mlflow.set_tag(RUN_PREFIX + "report", ids["report"])
        summary: dict[str, Any] = {"runs": ids, "failed_seeds": failed}
        mlflow.log_text(OmegaConf.to_yaml(OmegaConf.create(summary)), "runs.yaml")
        print(
            f"study: run {parent_id} | {len(seeds) - len(failed)} of {len(seeds)} seeds"
            + (f" (failed: {', '.join(map(str, sorted(failed)))})" if failed else "")
            + f" | report: {report.out_dir(cfg) / 'index.html'}"
        )
    return stage_runs.StageResult(parent_id, ids)
