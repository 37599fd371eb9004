"""Which earlier run ``pipeline.reuse`` takes instead of running a stage again.

A stage run is tagged ``armexp.inputs_hash`` with the digest of the config keys its stage's
declaration hashes (`armexp.reads.Reads`, ``READS`` in the stage's module: the keys the stage
reads that change its result). A run is reused when its digest equals this config's: its inputs
match.

Runs made under an earlier declaration (``Reads.earlier``: the lists kept by hand before the
declarations, which left out keys the stages read, such as tune's and simulate's
``env.reference``; train and eval before they hashed ``tuner.seed``) carry that declaration's
digest. Such a run is still reused when its digest equals this config's under that earlier list
*and* its logged params (the flattened resolved config, `armexp.tracking.stage_runs.flatten`)
equal this config's on every key the declaration hashes, so an old run is taken only where it is
the run this config would make.
"""

from __future__ import annotations

from collections.abc import Callable

from mlflow.entities import Run
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig

from armexp.reads import Reads
from armexp.tracking import stage_runs, store
from armexp.tracking.tags import INPUTS_TAG, STAGE_TAG

#: How many of the newest runs with a digest are looked at (a resume skips FINISHED ones; an
#: old run's params are compared).
CANDIDATES = 20


def reusable(cfg: DictConfig, reads: Reads) -> str | None:
    """The newest FINISHED run of ``reads.stage`` whose inputs match ``cfg``'s (None: none)."""
    client = MlflowClient(store.store_uri(cfg))
    return _find(client, cfg, reads, "attributes.status = 'FINISHED'", lambda run: True)


def resumable(cfg: DictConfig, reads: Reads) -> str | None:
    """The newest KILLED or FAILED run of ``reads.stage`` with ``cfg``'s inputs and a
    checkpoint, to continue (None: none)."""
    client = MlflowClient(store.store_uri(cfg))

    def stopped_with_checkpoint(run: Run) -> bool:
        if run.info.status not in ("KILLED", "FAILED"):
            return False
        return bool(client.list_artifacts(run.info.run_id, "checkpoint"))

    return _find(client, cfg, reads, "", stopped_with_checkpoint)


def params_match(run: Run, cfg: DictConfig, reads: Reads) -> bool:
    """Whether ``run``'s logged params equal ``cfg``'s on every key ``reads`` hashes (a value
    cut to MLflow's length limit never matches)."""
    flat = stage_runs.flatten(cfg)
    want = {k: v for k, v in flat.items() if reads.hashes(k)}
    have = {k: v for k, v in run.data.params.items() if reads.hashes(k)}
    return want == have and all(len(v) < stage_runs.MAX_PARAM_LENGTH for v in want.values())


def _find(
    client: MlflowClient,
    cfg: DictConfig,
    reads: Reads,
    status: str,
    accept: Callable[[Run], bool],
) -> str | None:
    """The newest run of ``reads.stage`` in ``status`` (an MLflow filter clause; "": any) that
    ``accept`` takes, by ``cfg``'s digest, else by an earlier declaration's digest and params."""
    exp = client.get_experiment_by_name(str(cfg.tracking.experiment))
    if exp is None:
        return None

    def search(value: str) -> list[Run]:
        clauses = [
            f"tags.`{STAGE_TAG}` = '{reads.stage}'",
            f"tags.`{INPUTS_TAG}` = '{value}'",
            *([status] if status else []),
        ]
        found = store.retry(
            lambda: client.search_runs(
                [exp.experiment_id],
                " and ".join(clauses),
                order_by=["attributes.start_time DESC"],
                max_results=CANDIDATES,
            )
        )
        return list(found)

    current = reads.digest(cfg)
    for run in search(current):
        if accept(run):
            return str(run.info.run_id)
    for value in dict.fromkeys(d for d in reads.earlier_digests(cfg) if d != current):
        for run in search(value):
            if accept(run) and params_match(run, cfg, reads):
                return str(run.info.run_id)
    return None
