"""``armexp diff <run> <run> [tracking overrides]``: what differs between two runs — their config
(params), their last metric values, and what ran (commit, dirty flag, package versions)."""

from __future__ import annotations

import sys
from collections.abc import Mapping, Sequence

from mlflow.entities import Run

from armexp.config import ConfigError
from armexp.tracking.tags import COMMIT_TAG, DIRTY_TAG, STAGE_TAG, VERSION_TAG

USAGE = "usage: armexp diff <run id> <run id> [tracking.runs_dir=... | tracking=server ...]"
#: How a value absent from one run is shown.
ABSENT = "-"


def _changed(a: Mapping[str, str], b: Mapping[str, str]) -> list[tuple[str, str, str]]:
    keys = sorted(set(a) | set(b))
    return [(k, a.get(k, ABSENT), b.get(k, ABSENT)) for k in keys if a.get(k) != b.get(k)]


def _table(rows: list[tuple[str, str, str]], extra: list[str] | None = None) -> list[str]:
    width = max(len(r[0]) for r in rows)
    left = max(len(r[1]) for r in rows)
    return [f"  {k:<{width}}  {x:<{left}}  {y}" + (f"  {extra[i]}" if extra else "")
            for i, (k, x, y) in enumerate(rows)]  # fmt: skip


def _shorten(text: str, limit: int = 60) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


def diff_lines(ra: Run, rb: Run) -> list[str]:
    """The printed comparison of MLflow runs ``ra`` (A) and ``rb`` (B)."""
    ida, idb = ra.info.run_id, rb.info.run_id
    lines = [f"armexp diff: A {ida} vs B {idb}"]
    params = _changed(ra.data.params, rb.data.params)
    lines.append(f"config: {len(params)} of the params differ" if params else "config: the same")
    if params:
        lines += _table([(k, _shorten(x), _shorten(y)) for k, x, y in params])
    ma, mb = ra.data.metrics, rb.data.metrics
    metrics = [(k, f"{ma[k]:.6g}" if k in ma else ABSENT, f"{mb[k]:.6g}" if k in mb else ABSENT)
               for k in sorted(set(ma) | set(mb)) if ma.get(k) != mb.get(k)]  # fmt: skip
    lines.append(f"metrics: {len(metrics)} differ" if metrics else "metrics: the same")
    if metrics:
        delta = [
            f"(B-A {mb[k] - ma[k]:+.4g})" if k in ma and k in mb else "" for k, _, _ in metrics
        ]
        lines += _table(metrics, delta)

    def ran(run: Run) -> dict[str, str]:
        tags = run.data.tags
        keep = (STAGE_TAG, COMMIT_TAG, DIRTY_TAG)
        return {k: v for k, v in tags.items() if k in keep or k.startswith(VERSION_TAG)}

    code = _changed(ran(ra), ran(rb))
    lines.append(f"what ran: {len(code)} differ" if code else "what ran: the same")
    if code:
        lines += _table(code)
    return lines


def main(args: Sequence[str]) -> int:
    """Print the differences of two runs; a bad argument is one sentence and exit code 2. It
    only reads: a store that does not exist is not created, and a read-only one is read."""
    if any(a in ("-h", "--help") for a in args):
        print(USAGE)
        return 0
    ids = [a for a in args if "=" not in a and not a.startswith("-")]
    overrides = [a for a in args if "=" in a and not a.startswith("-")]
    flags = [a for a in args if a.startswith("-")]
    try:
        if flags:
            raise ConfigError(
                f"{flags[0].partition('=')[0]} is not an option of armexp diff, which takes two "
                f"run ids and tracking overrides only; {USAGE}."
            )
        if len(ids) != 2:
            raise ConfigError(
                f"armexp diff takes exactly two run ids and got {len(ids)} ({' '.join(ids)}); "
                f"{USAGE}."
            )
        from mlflow.exceptions import MlflowException
        from mlflow.tracking import MlflowClient

        from armexp.config import compose_config
        from armexp.tracking import run_ids, store

        uri = store.store_uri(compose_config(overrides), reading=True)
        client = MlflowClient(uri)
        runs = []
        for given in ids:
            run_id = run_ids.resolve(client, given, "run id", store.hide_password(uri))
            try:
                runs.append(client.get_run(run_id))
            except MlflowException:
                raise ConfigError(
                    f"run id {run_id} is not allowed: no run with that id exists in the store "
                    f"{store.hide_password(uri)}."
                ) from None
    except ConfigError as exc:
        print(f"armexp diff: {exc}", file=sys.stderr)
        return 2
    print("\n".join(diff_lines(runs[0], runs[1])))
    return 0
