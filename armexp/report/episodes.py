"""Selecting and extending the episodes of the selected eval runs, for every table that shows
them: the derived columns (`with_derived`), the agents and their short names, the runs and seeds
behind a set of rows, and the proposed control's labels.

Convergence (docs/design.md §8, the paper's Definition 1): after an initial reference offset the
eval run fits ‖e1(t)‖ ≤ ᾱ‖e1(0)‖e^(−αt) + α* and logs the decay rate α (``decay_rate``, 1/s),
the ultimate bound α* (``ultimate_bound``, rad), the settling time of ‖e1‖ and its ITAE, at the
small offset and (suffix ``_large``) at the large one. The claim check compares time constants
1/α (`with_derived`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from armexp.report import labels


def _inverse(rate: pd.Series) -> pd.Series:
    """1/rate: inf where the rate is ≤ 0 (no decay), nan where it is nan."""
    r = rate.to_numpy(dtype=float)
    with np.errstate(divide="ignore"):
        out = np.where(r > 0, 1.0 / np.where(r > 0, r, 1.0), np.where(np.isnan(r), np.nan, np.inf))
    return pd.Series(out, index=rate.index)


def with_derived(episodes: pd.DataFrame) -> pd.DataFrame:
    """Episodes with their label columns (`armexp.report.labels.ensure`) and the derived
    columns: ``max_torque`` (over joints), ``time_constant`` = 1/``decay_rate`` (s; inf for no
    decay) and ``ultimate_bound_mrad``, each also with suffix ``_large`` where logged."""
    out = labels.ensure(episodes).copy()
    taus = [c for c in out.columns if c.startswith("max_abs_tau_")]
    out["max_torque"] = out[taus].max(axis=1) if taus else np.nan
    for suffix in ("", "_large"):
        rate, bound = f"decay_rate{suffix}", f"ultimate_bound{suffix}"
        if rate in out.columns:
            out[f"time_constant{suffix}"] = _inverse(out[rate])
        if bound in out.columns:
            out[f"ultimate_bound{suffix}_mrad"] = out[bound].astype(float) * 1000.0
    return out


def has_values(episodes: pd.DataFrame, key: str) -> bool:
    """Whether any episode has a value of ``key`` (old eval runs lack the Definition-1 ones)."""
    return key in episodes.columns and bool(episodes[key].notna().any())


def torque_joints(episodes: pd.DataFrame) -> list[int]:
    return sorted(
        int(c.rsplit("_", 1)[1]) for c in episodes.columns if c.startswith("max_abs_tau_")
    )


def agents(episodes: pd.DataFrame) -> list[Any]:
    return list(dict.fromkeys(episodes["agent"])) if "agent" in episodes.columns else [None]


def of_agent(episodes: pd.DataFrame, agent: Any) -> pd.DataFrame:
    return episodes if agent is None else episodes[episodes["agent"] == agent]


def agent_names(episodes: pd.DataFrame) -> dict[Any, str]:
    """Short names of the agents when a table shows several (none: one agent, no column)."""
    labels = agents(episodes)
    if len(labels) <= 1:
        return {}
    short = {}
    for label in labels:
        first = of_agent(episodes, label).iloc[0]
        preset = str(first.get("agent_preset", label))
        name = f"{preset} (aided)" if bool(first.get("aided", False)) else f"{preset} (plain)"
        gains = str(first.get("gains", "") or "")
        short[label] = f"{name}, {gains}" if gains else name
    if len(set(short.values())) < len(short):
        return {label: str(label) for label in labels}
    return short


def agent_columns(rows: pd.DataFrame, agent: Any) -> dict[str, Any]:
    aided = bool(rows["aided"].iloc[0]) if "aided" in rows.columns and len(rows) else math.nan
    return {"agent": "" if agent is None else agent, "aided": aided}


def run_counts(ep: pd.DataFrame) -> tuple[int, int]:
    if "eval_run" not in ep.columns or not len(ep):
        return 0, 0
    seeds = ep["seed"].nunique() if "seed" in ep.columns else ep.eval_run.nunique()
    return int(ep.eval_run.nunique()), int(seeds)


def proposed_labels(episodes: pd.DataFrame) -> list[str]:
    """The labels with role ``proposed`` (episodes with label columns), in table order."""
    return [
        label for label in labels.ordered(episodes)
        if labels.info(episodes, label).get("role") == "proposed"
    ]  # fmt: skip
