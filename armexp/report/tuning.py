"""The tune runs behind the selected eval runs: the CSO gains table and the tuning spread
(docs/design.md §5, §9).

An eval run names the tune run of each label's gains (``armexp.tune_run.<label>``; older runs
``armexp.tune_run`` and ``armexp.pid_tune_run``). The spread table groups those tune runs by
controller and criterion and shows what the tuner seeds changed: how many distinct gain vectors
came out, the best objective's IQM and range, each gain's range and the gains that ended on a
bound of the search box (the tune run's tag ``armexp.gains_on_bound``). When the tuner returned
the same gains at every seed, the spread of a study's results over seeds holds no tuning
variation, and the table says so.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from typing import Any

import numpy as np
import pandas as pd

from armexp import paper
from armexp.report import labels, stats
from armexp.report.formatting import Table, number
from armexp.report.labels import Label
from armexp.report.runs import Reader, Selection
from armexp.tags import GAINS_ON_BOUND_TAG

ADAPTIVE = "subsystem_adaptive"


def _used_by(run_labels: Mapping[str, Mapping[str, Label]]) -> dict[str, list[str]]:
    """Tune run id → the labels whose gains it gave, over the eval runs."""
    out: dict[str, list[str]] = {}
    for by_name in run_labels.values():
        for name, lab in by_name.items():
            if lab.tune_run and name not in out.setdefault(lab.tune_run, []):
                out[lab.tune_run].append(name)
    return out


def tunes_of(
    selection: Selection, reader: Reader, run_labels: Mapping[str, Mapping[str, Label]]
) -> list[dict[str, Any]]:
    """One record per tune run of the selection: its controller, criterion and horizon, tuner
    seed, best gains (flat names, from ``gains.yaml``, else its ``tuned.*`` params), best and
    paper-gains objective, the gains on a bound (None: not logged), its objective history and
    the labels that used it. Sorted by controller, criterion and run id."""
    used = _used_by(run_labels)
    out = []
    for run_id, run in selection.tunes.items():
        m, tags = run.data.metrics, run.data.tags
        criterion, horizon = labels.tune_criterion(run)
        gains = labels.flat_gains(reader.yaml(run_id, "gains.yaml")) or labels.tuned_params(run)
        bound = tags.get(GAINS_ON_BOUND_TAG)
        seed = run.data.params.get("tuner.seed")
        out.append(
            {
                "run_id": run_id,
                "controller": run.data.params.get("controller.name", "?"),
                "criterion": criterion,
                "horizon": horizon,
                "tuner_seed": int(seed) if seed not in (None, "", "None") else None,
                "gains": gains,
                "best": m.get("best_objective", math.nan),
                "paper_objective": m.get("objective_paper_gains", math.nan),
                "on_bound": None if bound is None else [] if bound == "none" else bound.split(", "),
                "history": reader.history(run_id, "best_objective"),
                "labels": used.get(run_id, []),
            }
        )
    return sorted(out, key=lambda t: (t["controller"], t["criterion"], t["run_id"]))


def cso_table(tunes: list[dict[str, Any]]) -> Table:
    """Each tune run's best gains beside the paper's (adaptive law only), and the objective."""
    published = paper.GAINS
    shown_rows, numbers = [], []
    for tune in tunes:
        adaptive = tune["controller"] == ADAPTIVE
        how = labels.tuning(tune["criterion"], tune["horizon"])
        for gain, v in tune["gains"].items():
            printed = published.get(gain, math.nan) if adaptive else math.nan
            shown_rows.append({"Controller": tune["controller"], "Criterion": how, "Gain": gain,
                               "Tuned (CSO)": f"{v:.6g}",
                               "Paper": f"{printed:g}" if math.isfinite(printed) else "–",
                               })  # fmt: skip
            numbers.append({"run_id": tune["run_id"], "controller": tune["controller"],
                            "criterion": tune["criterion"], "gain": gain, "tuned": v,
                            "paper": printed})  # fmt: skip
        shown_rows.append({"Controller": tune["controller"], "Criterion": how,
                           "Gain": f"objective ({tune['criterion']})",
                           "Tuned (CSO)": number(tune["best"]),
                           "Paper": number(tune["paper_objective"]) if adaptive else "–",
                           })  # fmt: skip
        numbers.append({"run_id": tune["run_id"], "controller": tune["controller"],
                        "criterion": tune["criterion"], "gain": "objective",
                        "tuned": tune["best"], "paper": tune["paper_objective"]})  # fmt: skip
    return Table(
        "cso_gains",
        "CSO results: tuned gains and best objective (lower is better)",
        pd.DataFrame(shown_rows),
        pd.DataFrame(numbers),
        ["Objective: the tune run's criterion (gaing: the paper's W; itae, iae: integral "
         "criteria) over its horizon; values of different criteria are not comparable."],
    )  # fmt: skip


def _range(values: Iterable[float]) -> str:
    v = [x for x in values if math.isfinite(x)]
    if not v:
        return "–"
    lo, hi = min(v), max(v)
    return f"{lo:.4g}" if lo == hi else f"{lo:.4g}–{hi:.4g}"


def _bounds(group: list[dict[str, Any]]) -> str:
    logged = [t["on_bound"] for t in group if t["on_bound"] is not None]
    if not logged:
        return "not logged"
    counts: dict[str, int] = {}
    for hits in logged:
        for hit in hits:
            counts[hit] = counts.get(hit, 0) + 1
    if not counts:
        return f"none (0/{len(logged)})"
    return ", ".join(f"{hit} ({n}/{len(logged)})" for hit, n in counts.items())


def spread(tunes: list[dict[str, Any]]) -> dict[tuple[str, str, float], dict[str, Any]]:
    """Per (controller, criterion, horizon): the tune runs, distinct tuner seeds, distinct gain
    vectors (to 6 significant digits), the best objective's IQM/min/max, each gain's min/max,
    the gains on a bound and whether all seeds returned identical gains."""
    groups: dict[tuple[str, str, float], list[dict[str, Any]]] = {}
    for t in tunes:
        key = (t["controller"], t["criterion"], t["horizon"])
        match = next((k for k in groups if k[:2] == key[:2] and _same(k[2], key[2])), key)
        groups.setdefault(match, []).append(t)
    out = {}
    for key, group in groups.items():
        seeds = sorted({t["tuner_seed"] for t in group if t["tuner_seed"] is not None})
        vectors = {labels.gains_text(t["gains"]) for t in group}
        best = np.array([t["best"] for t in group], dtype=float)
        finite = best[np.isfinite(best)]
        names = list(dict.fromkeys(g for t in group for g in t["gains"]))
        out[key] = {
            "runs": len(group),
            "run_ids": [t["run_id"] for t in group],
            "seeds": seeds,
            "vectors": len(vectors),
            "identical": len(vectors) == 1 and len(seeds) > 1,
            "best_iqm": float(stats.iqm(finite)) if finite.size else math.nan,
            "best_min": float(finite.min()) if finite.size else math.nan,
            "best_max": float(finite.max()) if finite.size else math.nan,
            "gains": {g: [t["gains"].get(g, math.nan) for t in group] for g in names},
            "on_bound": _bounds(group),
        }
    return out


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == b


def _seeds(seeds: list[int], runs: int) -> str:
    if not seeds:
        return "not logged"
    text = ", ".join(map(str, seeds))
    return text if len(seeds) > 1 or runs == 1 else f"{text} (all {runs} runs)"


def spread_table(tunes: list[dict[str, Any]]) -> Table:
    """The tuning spread over tuner seeds, per controller and criterion (docs/design.md §9: the
    uncertainty includes tuning only where the tuner seeds vary)."""
    shown_rows, numbers, notes = [], [], []
    for (controller, criterion, horizon), g in spread(tunes).items():
        how = labels.tuning(criterion, horizon)
        vectors = f"{g['vectors']} of {g['runs']}"
        if g["identical"]:
            vectors += f": identical at all {len(g['seeds'])} seeds"
            notes.append(
                f"{controller}, {how}: the tuner returned identical gains at all "
                f"{len(g['seeds'])} seeds ({', '.join(map(str, g['seeds']))}), so the spread "
                "over seeds holds no tuning variation for it."
            )
        best = number(g["best_iqm"])
        if g["runs"] > 1:
            best += f" [{number(g['best_min'])}, {number(g['best_max'])}]"
        shown_rows.append(
            {
                "Controller": controller,
                "Criterion": how,
                "Tune runs": g["runs"],
                "Tuner seeds": _seeds(g["seeds"], g["runs"]),
                "Distinct gain vectors": vectors,
                "Best objective IQM [min, max]": best,
                "Gains (min–max)": "; ".join(f"{k} {_range(v)}" for k, v in g["gains"].items()),
                "On a bound": g["on_bound"],
            }
        )
        row: dict[str, Any] = {"controller": controller, "criterion": criterion,
                               "horizon": horizon, "tune_runs": g["runs"],
                               "tuner_seeds": " ".join(map(str, g["seeds"])),
                               "distinct_gain_vectors": g["vectors"],
                               "identical_gains": g["identical"], "best_iqm": g["best_iqm"],
                               "best_min": g["best_min"], "best_max": g["best_max"],
                               "on_bound": g["on_bound"],
                               "run_ids": " ".join(g["run_ids"])}  # fmt: skip
        for gain, values in g["gains"].items():
            finite = [v for v in values if math.isfinite(v)]
            row[f"{gain}_min"] = min(finite) if finite else math.nan
            row[f"{gain}_max"] = max(finite) if finite else math.nan
        numbers.append(row)
    if any(t["criterion"] == "gaing" for t in tunes):
        notes.append(labels.GAING_NOTE)
    notes += [
        "Per controller and tuning criterion, over the tune runs whose gains the selected eval "
        "runs used. Distinct gain vectors: to 6 significant digits. Best objective: the tune "
        "run's criterion over its horizon (not comparable between criteria). On a bound: the gains "
        f"each tune run reported on a bound of its search box (tag {GAINS_ON_BOUND_TAG}), with "
        "the share of tune runs.",
    ]
    return Table(
        "tuning_spread",
        "Tuning spread over tuner seeds",
        pd.DataFrame(shown_rows),
        pd.DataFrame(numbers),
        notes,
    )
