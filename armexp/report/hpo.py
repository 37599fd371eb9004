"""An HPO in the report (``report.hpo_runs``): its best trials, the objective against trial
number and the parameter importances, read from the HPO run's files (`armexp.hpo.record`), never
from the Optuna database.

Importances are Optuna's own (`optuna.importance.get_param_importances`, its default fANOVA
evaluator) over the complete trials, computed on an in-memory copy of the study rebuilt from
``hpo/trials.json`` and ``hpo/space.json``.
"""

from __future__ import annotations

import html
import json
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

from armexp.report.formatting import Table
from armexp.report.runs import Reader

#: Rows of the best-trials table.
BEST_ROWS = 10


@dataclass
class Hpo:
    run_id: str
    study: str
    direction: str
    trials: list[dict[str, Any]]
    space: dict[str, Any]
    about: dict[str, Any] = field(default_factory=dict)

    def complete(self) -> list[dict[str, Any]]:
        return [t for t in self.trials if t["state"] == "COMPLETE" and t["value"] is not None]


def read(reader: Reader, run_id: str) -> Hpo | None:
    """The HPO recorded on run ``run_id``; None when it records none."""
    trials = reader.yaml(run_id, "hpo/trials.json")
    space = reader.yaml(run_id, "hpo/space.json")
    about = reader.yaml(run_id, "hpo/study.json") or {}
    if trials is None or space is None:
        return None
    return Hpo(
        run_id,
        str(about.get("study", run_id)),
        str(about.get("direction", "maximize")),
        list(trials),
        dict(space.get("space", {})),
        dict(about),
    )


def importances(hpo: Hpo) -> tuple[dict[str, float], str]:
    """Optuna's parameter importances, and a note when they cannot be computed."""
    complete = hpo.complete()
    if len({t["value"] for t in complete}) < 2:
        return {}, "Parameter importances need two complete trials with different values."
    try:
        import optuna
        from optuna.distributions import json_to_distribution
    except ImportError:
        return {}, 'Parameter importances need Optuna: pip install "armexp[hpo]".'
    dists = {k: json_to_distribution(json.dumps(v)) for k, v in hpo.space.items()}
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    study = optuna.create_study(direction=hpo.direction)  # type: ignore[arg-type]
    for t in complete:
        params = {k: v for k, v in t["params"].items() if k in dists}
        used = {k: dists[k] for k in params}
        study.add_trial(
            optuna.trial.create_trial(params=params, distributions=used, value=float(t["value"]))
        )
    try:
        found = optuna.importance.get_param_importances(study)
    except (RuntimeError, ValueError) as exc:
        return {}, f"Parameter importances could not be computed ({exc})."
    return {k: float(v) for k, v in found.items()}, ""


def tables_of(hpo: Hpo, weights: dict[str, float], note: str) -> list[Table]:
    best = sorted(hpo.complete(), key=lambda t: t["value"], reverse=hpo.direction == "maximize")
    rows = [{"trial": t["number"], "value": t["value"], **t["params"]} for t in best[:BEST_ROWS]]
    numbers = pd.DataFrame(rows)
    shown = numbers.map(lambda v: f"{v:.4g}" if isinstance(v, float) else str(v))
    states = pd.Series([t["state"] for t in hpo.trials]).value_counts().to_dict()
    counts = ", ".join(f"{n} {str(s).lower()}" for s, n in sorted(states.items(), key=str))
    tag = hpo.study.removeprefix("hpo-").replace("-", "_")
    title = f"HPO {hpo.study}: best trials"
    made = [
        Table(
            f"hpo_best_{tag}",
            title,
            shown,
            numbers,
            notes=[
                f"{len(hpo.trials)} trials ({counts}) of {hpo.about.get('how', 'an HPO')}; "
                "value: the interquartile mean of the final held-out success over seeds "
                f"{hpo.about.get('seeds')}.",
                *_retrain_note(best),
            ],
            caption=f"HPO run {hpo.run_id}",
        )
    ]
    imp = pd.DataFrame({"parameter": list(weights), "importance": list(weights.values())})
    imp_shown = imp.assign(importance=[f"{v:.3f}" for v in imp.importance])
    made.append(
        Table(
            f"hpo_importance_{tag}",
            f"HPO {hpo.study}: parameter importances",
            imp_shown,
            imp,
            notes=[note or "Optuna's fANOVA importances (sum 1)."],
        )
    )
    return made


def _retrain_note(best: list[dict[str, Any]]) -> list[str]:
    """The best trial's values as overrides, to train them on fresh seeds: the HPO's targets
    chose them, so they are no longer held out for it (docs/hpo.md)."""
    if not best:
        return []
    values = " ".join(f"{k}={_override(v)}" for k, v in best[0]["params"].items())
    return [
        f"Trial {best[0]['number']}'s values, to train on fresh seeds (with the HPO command's "
        f"own overrides, e.g. its `hpo=` preset, and a seed outside its seeds): `{values}`."
    ]


def _override(value: Any) -> str:
    """A value as Hydra's override grammar reads it back (a list without spaces)."""
    if isinstance(value, list | tuple):
        return "[" + ",".join(_override(v) for v in value) + "]"
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def objective_figure(hpo: Hpo) -> Any:
    """Each trial's value against its number (pruned trials at their last check), and the best
    so far."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 3.5))
    done = hpo.complete()
    xs, ys = [t["number"] for t in done], [float(t["value"]) for t in done]
    ax.plot(xs, ys, "o", color="#1f77b4", label="complete")
    pruned = [t for t in hpo.trials if t["state"] == "PRUNED" and t["value"] is not None]
    if pruned:
        ax.plot(
            [t["number"] for t in pruned],
            [t["value"] for t in pruned],
            "x",
            color="#d62728",
            label="pruned (last check)",
        )
    if ys:
        pick = max if hpo.direction == "maximize" else min
        best = [pick(ys[: i + 1]) for i in range(len(ys))]
        ax.step(xs, best, where="post", color="#555", label="best so far")
    ax.set_xlabel("trial")
    ax.set_ylabel("IQM held-out success")
    ax.legend(loc="best", fontsize=8)
    ax.set_title(hpo.study, fontsize=9)
    return fig


def importance_figure(weights: dict[str, float], study: str) -> Any:
    import matplotlib.pyplot as plt

    names = list(weights)[::-1]
    fig, ax = plt.subplots(figsize=(6.5, 0.4 * len(names) + 1.2))
    ax.barh(names, [weights[n] for n in names], color="#2ca02c")
    ax.set_xlabel("importance (fANOVA)")
    ax.set_title(study, fontsize=9)
    return fig


def section(
    reader: Reader, run_ids: Sequence[str], folder: Path, save: Callable[[Any, str, str], None]
) -> list[Table]:
    """Tables (written into ``folder/tables``) and figures (through ``save``) of each HPO run."""
    made: list[Table] = []
    for run_id in run_ids:
        hpo = read(reader, str(run_id))
        if hpo is None:
            continue
        weights, note = importances(hpo)
        tables = tables_of(hpo, weights, note)
        for t in tables:
            t.write(folder / "tables")
        tag = hpo.study.removeprefix("hpo-").replace("-", "_")
        save(
            objective_figure(hpo),
            f"hpo_objective_{tag}",
            f"HPO {hpo.study}: each trial's value against its number, and the best so far.",
        )
        if weights:
            save(
                importance_figure(weights, hpo.study),
                f"hpo_importance_{tag}",
                f"HPO {hpo.study}: Optuna's parameter importances.",
            )
        pd.DataFrame(
            [
                {
                    **{k: v for k, v in t.items() if k != "params"},
                    **{f"params.{k}": v for k, v in t["params"].items()},
                }
                for t in hpo.trials
            ]
        ).to_csv(folder / "tables" / f"hpo_trials_{tag}.csv", index=False)
        made += tables
    return made


def page(folder: Path, made: list[Table], pictures: list[tuple[str, str]]) -> None:
    """``index.html`` of a report of HPOs alone (no eval runs selected)."""
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>armexp HPO report</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto;padding:1em}"
        "table{border-collapse:collapse}td,th{border-bottom:1px solid #ccc;padding:.2em .6em}"
        "img{max-width:100%}.note{color:#555;font-size:90%}</style></head><body>",
        "<h1>armexp report: hyperparameter search</h1>",
        "<p>Tables are also in <code>tables/</code> (Markdown, LaTeX, CSV; every trial in "
        "<code>hpo_trials_*.csv</code>), figures in <code>figures/</code>.</p>",
        *(t.html() for t in made),
        *(
            f"<figure><img src='figures/{n}.png' alt='{html.escape(c)}'><figcaption>"
            f"{html.escape(c)}</figcaption></figure>"
            for n, c in pictures
        ),
        "</body></html>",
    ]
    (folder / "index.html").write_text("\n".join(parts))
