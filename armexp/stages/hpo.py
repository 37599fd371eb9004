"""`armexp hpo`: a hyperparameter search of the agent with Optuna, pruned on the held-out checks.

``hpo.params`` maps config keys to Hydra sweeps (``interval(…)``, ``choice(…)``, ``range(…)``,
``tag(log, …)``; `armexp.hpo.space`); each trial trains the seeds of ``hpo.seeds`` one after
the other in this process and is scored by the interquartile mean of their final held-out
success; the pruner (``hpo.pruner``) sees every held-out check. One HPO run records the study
(`armexp.hpo.record`), each trial is a run under it and each seed's train run a run under that.
Re-running the same command resumes the study (`armexp.hpo.study`); the loop is
`armexp.hpo.search`.
"""

from __future__ import annotations

from omegaconf import DictConfig

from armexp import tracking


def run(cfg: DictConfig) -> tracking.StageResult:
    from armexp.hpo import search

    return search.run(cfg)
