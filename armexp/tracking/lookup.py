"""Finding the upstream run a stage consumes: the one given by id (or a unique prefix of one,
`armexp.tracking.run_ids`), else the latest FINISHED run of that stage whose params match."""

from __future__ import annotations

import logging
from collections.abc import Callable, Mapping

from mlflow.entities import Run
from mlflow.exceptions import MlflowException
from mlflow.tracking import MlflowClient
from omegaconf import DictConfig

from armexp.config import ConfigError
from armexp.tracking import run_ids
from armexp.tracking.stage_runs import setup
from armexp.tracking.store import hide_password, retry, store_uri
from armexp.tracking.tags import STAGE_TAG

log = logging.getLogger(__name__)


def find_stage_run(
    cfg: DictConfig,
    stage: str,
    run_id: str | None = None,
    match: Mapping[str, str] | None = None,
    key: str = "run",
    statuses: tuple[str, ...] = ("FINISHED",),
    accept: Callable[[Run], bool] | None = None,
    wanted: str = "",
) -> Run:
    """The upstream run a stage consumes: ``run_id`` if given, else the latest FINISHED run of
    ``stage`` in the configured experiment whose params equal ``match`` (and, with ``accept``,
    for which ``accept(run)`` holds: a condition a search filter cannot say, such as a param that
    older runs lack; ``wanted`` describes it in the error). A given ``run_id`` is not held to
    ``match`` or ``accept``: the caller checks it and names what is wrong.

    Raises `ConfigError` with one sentence when the id does not exist, belongs to another stage,
    is not in one of ``statuses``, or when no run matches. ``key`` names the config key that
    carries the id.
    """
    experiment_id = setup(cfg)
    client = MlflowClient(store_uri(cfg))
    match = dict(match or {})
    if run_id:
        run_id = run_ids.resolve(client, str(run_id), key, hide_password(store_uri(cfg)))
        try:
            run = client.get_run(run_id)
        except MlflowException:
            raise ConfigError(
                f"{key}={run_id} is not allowed: no run with that id exists in the store "
                f"{store_uri(cfg)}."
            ) from None
        got = run.data.tags.get(STAGE_TAG)
        if got != stage:
            raise ConfigError(
                f"{key}={run_id} is not allowed: it is a {got or 'non-armexp'} run, and a "
                f"{stage} run is needed here."
            )
        if run.info.status not in statuses:
            raise ConfigError(
                f"{key}={run_id} is not allowed: that {stage} run is {run.info.status}, and only "
                f"{' or '.join(statuses)} runs can be used here."
            )
        return run
    clauses = [f"tags.`{STAGE_TAG}` = '{stage}'", "attributes.status = 'FINISHED'"]
    clauses += [f"params.`{k}` = '{v}'" for k, v in match.items()]
    found = _latest(client, experiment_id, " and ".join(clauses), accept)
    if found is None:
        what = ", ".join([*(f"{k}={v}" for k, v in match.items()), *([wanted] if wanted else [])])
        raise ConfigError(
            f"{key} is not set and no FINISHED {stage} run with {what or 'any config'} exists in "
            f"experiment '{cfg.tracking.experiment}' at {store_uri(cfg)}; run `armexp {stage}` "
            f"with those settings first or pass {key}=<run id>."
        )
    log.info("using %s run %s (latest matching %s)", stage, found.info.run_id, match)
    return found


def _latest(
    client: MlflowClient,
    experiment_id: str,
    filter_string: str,
    accept: Callable[[Run], bool] | None,
) -> Run | None:
    """The newest run that the filter selects and ``accept`` (if given) takes, page by page."""
    token = None
    while True:
        page = retry(
            lambda t=token: client.search_runs(  # type: ignore[misc]
                [experiment_id],
                filter_string=filter_string,
                order_by=["attributes.start_time DESC"],
                max_results=1 if accept is None else 100,
                page_token=t,
            )
        )
        for run in page:
            if accept is None or accept(run):
                return run
        token = page.token
        if accept is None or not token:
            return None
