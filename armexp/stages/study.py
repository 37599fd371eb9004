"""A study: ``armexp pipeline pipeline.seeds=[0,1,2,3,4]`` (``experiment=reproduce``).

One parent pipeline run (tag ``armexp.study``) holds one child pipeline per seed: the policy's
controller and every baseline tuned with that seed (the reproduce preset sets
``tuner.seed: ${seed}``; `armexp.stages.pipeline.tune_steps`), the agent trained, and its policy
evaluated with its controller, the ablation and the baselines (and, with
``pipeline.paper_gains_row``, alone with the paper's adaptive gains). Then one report over every
seed's eval runs, with the statistics over seeds (`armexp.report.stats`, `armexp.report.claims`).

With ``pipeline.agents`` the study trains and evaluates more agents beside ``agent``: each
its own preset, seeds (some or all of ``pipeline.seeds``) and budget (`agent_configs`), in a
pipeline of its own per seed that reuses that seed's tune runs; the report shows every agent
side by side (experiment=reproduce: the aided ``sac_quick``, the non-privileged ``sac_plain``
and Table II's ``sac_paper_fast``).

A seed whose pipeline fails is recorded (``armexp.failed_seeds``) and the study goes on; the report
names it as missing. Re-running the same command finishes an interrupted study: the study always
runs with ``pipeline.reuse=true``, so every stage whose inputs match a FINISHED run is reused.
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import mlflow
from omegaconf import DictConfig, OmegaConf, open_dict

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
    if not cfg.pipeline.seeds and cfg.pipeline.agents:
        presets = [str(a.preset) for a in cfg.pipeline.agents]
        raise ConfigError(
            f"pipeline.agents (presets {', '.join(presets)}) is not allowed without "
            "pipeline.seeds: only a study runs other agents; give pipeline.seeds=[…] or "
            "pipeline.agents=[]."
        )
    return run_study(cfg) if cfg.pipeline.seeds else pipeline.run_one(cfg)


def agent_configs(cfg: DictConfig) -> list[tuple[str, set[int], DictConfig]]:
    """The study's other agents (``pipeline.agents``): for each, its preset, its seeds and the
    study's config with its agent in place of ``agent``. The preset is composed alone, so the
    study's own ``agent.*`` settings (``experiment=reproduce``'s budget for ``sac_quick``) do
    not reach it; its ``agent`` keys are set on it."""
    from armexp.config import group_options, validate

    seeds = {int(s) for s in cfg.pipeline.seeds}
    out = []
    for i, entry in enumerate(cfg.pipeline.agents):
        key = f"pipeline.agents[{i}]"
        preset = str(entry.preset)
        options = group_options("agent")
        if preset not in options:
            raise ConfigError(
                f"{key}.preset={preset} is not allowed: choose an agent preset ("
                f"{', '.join(options)})."
            )
        own = {int(s) for s in entry.seeds} or seeds
        if not own <= seeds:
            raise ConfigError(
                f"{key}.seeds={sorted(own)} is not allowed: each must be one of pipeline.seeds="
                f"{sorted(seeds)}, whose tune runs the agent shares."
            )
        agent = _compose_agent(preset)
        with open_dict(agent):
            agent.merge_with(entry.agent)
        other = copy.deepcopy(cfg)
        with open_dict(other):
            other.agent = agent
        try:
            validate(other)
        except ConfigError as exc:
            raise ConfigError(f"{key} (agent={preset}): {exc}") from None
        out.append((preset, own, other))
    return out


def _compose_agent(preset: str) -> DictConfig:
    """The ``agent`` section of ``agent=<preset>`` composed without the job's overrides."""
    from hydra import compose
    from hydra.core.global_hydra import GlobalHydra

    from armexp.config import compose_unchecked

    if GlobalHydra.instance().is_initialized():
        composed = compose(config_name="config", overrides=[f"agent={preset}"])
    else:
        composed = compose_unchecked([f"agent={preset}"])
    return composed.agent


def run_study(cfg: DictConfig) -> stage_runs.StageResult:
    from armexp.stages import pipeline, report

    seeds = [int(s) for s in cfg.pipeline.seeds]
    if len(set(seeds)) != len(seeds):
        raise ConfigError(f"pipeline.seeds={seeds} is not allowed: each seed must appear once.")
    others = agent_configs(cfg)
    ids: dict[str, str] = {}
    failed: dict[int, str] = {}
    failed_agents: dict[str, str] = {}
    evals: list[str] = []
    with stage_runs.stage_run(
        cfg, "pipeline", extra_tags={STUDY_TAG: ",".join(map(str, seeds))}
    ) as parent:
        parent_id = parent.info.run_id

        def one(base: DictConfig, seed: int, main: bool) -> Mapping[str, Any] | None:
            seed_cfg = pipeline.with_values(
                base,
                {"seed": seed, "pipeline.seeds": [], "pipeline.agents": [], "pipeline.reuse": True},
            )
            what = f"seed {seed}" + ("" if main else f", agent {seed_cfg.agent.name}")
            print(f"study: {what} ({seeds.index(seed) + 1} of {len(seeds)})")
            try:
                with stage_runs.parent(parent_id):
                    return pipeline.run_one(
                        seed_cfg,
                        # A study's own pipeline.run_name names the study, not each seed.
                        run_name=run_names.describe(seed_cfg, "pipeline"),
                        paper_gains_row=main and bool(cfg.pipeline.paper_gains_row),
                        report_=False,
                    ).summary
            except (KeyboardInterrupt, SystemExit):
                raise
            except Exception as exc:  # the other seeds still run and are reported
                reason = f"{type(exc).__name__}: {exc}".splitlines()[0]
                print(f"study: {what} failed ({reason}); going on")
                if main:
                    failed[seed] = reason
                    mlflow.set_tag(FAILED_SEEDS_TAG, ",".join(map(str, sorted(failed))))
                else:
                    failed_agents[f"{seed_cfg.agent.name}.{seed}"] = reason
                return None

        for seed in seeds:
            runs = [(cfg, "", True)] + [
                (other, f"{preset}.", False) for preset, own, other in others if seed in own
            ]
            for base, prefix, main in runs:
                steps = one(base, seed, main)
                if steps is None:
                    continue
                for step, run_id in steps.items():
                    ids[f"{step}.{prefix}{seed}"] = run_id
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
        if failed_agents:
            summary["failed_agents"] = failed_agents
        mlflow.log_text(OmegaConf.to_yaml(OmegaConf.create(summary)), "runs.yaml")
        print(
            f"study: run {parent_id} | {len(seeds) - len(failed)} of {len(seeds)} seeds"
            + (f" (failed: {', '.join(map(str, sorted(failed)))})" if failed else "")
            + (f" | other agents failed: {', '.join(failed_agents)}" if failed_agents else "")
            + f" | report: {report.out_dir(cfg) / 'index.html'}"
        )
    return stage_runs.StageResult(parent_id, ids)
