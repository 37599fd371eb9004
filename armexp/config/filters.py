"""``report.filter``: an MLflow search filter, checked with MLflow's own parser before the report
reads the store, so a typo is one sentence instead of the store's traceback."""

from __future__ import annotations

from omegaconf import DictConfig

from armexp.config.checks import ConfigError

#: What a filter looks like, for the sentence that refuses one.
EXAMPLE = (
    "write an MLflow search filter such as params.seed = '0' and tags.sweep = 'seeds' (clauses "
    "joined by 'and', text values in single quotes, keys with dots in backticks: "
    "params.`robot.name` = 'three_link')"
)


def filter_problem(text: str) -> str | None:
    """MLflow's reason to refuse the filter ``text``, or None when it parses."""
    from mlflow.exceptions import MlflowException
    from mlflow.utils.search_utils import SearchUtils

    try:
        SearchUtils.parse_search_filter(text)
    except MlflowException as exc:
        lines = str(exc.message).strip().splitlines()
        return (lines[0] if lines else "MLflow cannot parse it").rstrip(".")
    return None


def check_filter(cfg: DictConfig) -> None:
    report = cfg.get("report")
    text = None if report is None else report.get("filter")
    if text is None:
        return
    problem = filter_problem(str(text)) if str(text).strip() else "it is empty"
    if problem:
        raise ConfigError(f"report.filter={str(text)!r} is not allowed: {problem}; {EXAMPLE}.")
