"""The controllers an eval run ran, by label, and how each was tuned (docs/design.md §4, §5, §8).

An eval run names what it ran in its ``controllers.yaml`` artifact: per label (the ``controller``
column of ``episodes.csv``, the first part of its metric names and its trajectory folder) the
controller, its role — ``proposed`` (the policy's own controller), ``reference`` (the proposed
law tuned under a baseline's criterion: the proposed side of that baseline's comparison),
``ablation`` (the adaptive law with adaptation off) or ``baseline`` —, the tuning criterion and
horizon, the tune run, the gains, and for a baseline the proposed label it is compared with
(``compare_with``).

Eval runs made before ``controllers.yaml`` ran the labels ``adaptive`` and ``pid``. They read as
the proposed ``adaptive`` against the baseline ``pid_gaing``: the PID tuned under the paper's
criterion (Gaing's W, 0.6 s), which is what ``pid`` was. The criterion and horizon of such a
label are its tune run's (tune runs that predate the criterion tags: ``gaing`` and their logged
``tuner.objective.horizon``, else 0.6 s), ``config`` when the run used configured gains; a PID
whose tune run names another criterion is reported under it (``pid_itae``).

`annotate` writes each run's labels into its episodes as the columns of `LABEL_COLUMNS`, so that
every table works from the episodes frame alone; `ensure` gives a frame without them (old runs'
episodes, or a frame built by hand) the old runs' reading.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass
from typing import Any

import pandas as pd
from mlflow.entities import Run

from armexp.tracking.tags import (
    ADAPTIVE_GAINS_TAG,
    CRITERION_TAG,
    HORIZON_TAG,
    PID_TUNE_RUN_TAG,
    TUNE_RUN_PREFIX,
    TUNE_RUN_TAG,
)

#: The artifact in which an eval run names its labels.
CONTROLLERS_FILE = "controllers.yaml"
#: Roles in the order tables list them.
ROLES = ("proposed", "reference", "ablation", "baseline")
#: Old eval runs: the PID's label as stored, and the name it is reported under.
OLD_PID, OLD_PID_NAME = "pid", "pid_gaing"
#: What old runs and old tune runs were tuned under (the paper's objective, tuner=cso_paper).
OLD_CRITERION, OLD_HORIZON = "gaing", 0.6
#: The criterion of gains that were configured, not tuned.
CONFIGURED = "config"
#: Controller names of the old labels.
OLD_CONTROLLERS = {"adaptive": "subsystem_adaptive", OLD_PID: "pid"}
#: Said wherever a label was tuned under Gaing's W (docs/design.md §5).
GAING_NOTE = (
    "gaing: the paper's objective W (Gaing 2004) over its horizon. When a joint does not settle "
    "within the horizon its settling time is the horizon, so W then rewards the slowest rise, "
    "and integral action only raises W: at a short horizon W starves a PID of integral action. "
    "The itae rows tune the same controllers on a standard integral criterion."
)
#: The columns `annotate` adds to an eval run's episodes (one value per label and run).
LABEL_COLUMNS = (
    "stored_label", "controller_name", "role", "criterion", "horizon", "compare_with",
    "tune_run", "tuner_seed", "gains_text",
)  # fmt: skip


@dataclass(frozen=True)
class Label:
    """One label of one eval run, as the report names it."""

    name: str
    #: The label as the eval run stored it (artifact folders, metric names).
    stored: str
    controller: str
    role: str
    criterion: str
    #: Seconds; nan for configured gains.
    horizon: float
    #: The proposed label a baseline is compared with; "" for the other roles.
    compare_with: str = ""
    #: The tune run of the gains; "" when they were configured or its tag is missing.
    tune_run: str = ""
    #: The tune run's ``tuner.seed``; nan when not tuned or not logged.
    tuner_seed: float = math.nan
    #: The gain vector as text (`gains_text`); "" when unknown.
    gains: str = ""


def _float(value: Any) -> float:
    try:
        out = float(value)
    except (TypeError, ValueError):
        return math.nan
    return out


def flat_gains(mapping: Mapping[str, Any] | None) -> dict[str, float]:
    """A gains mapping in config form as flat names: ``a0`` …, or ``kp_1`` … for per-joint
    lists (the names the tune stage gives its bounds and ``tuned.*`` params)."""
    out: dict[str, float] = {}
    for key, value in (mapping or {}).items():
        if isinstance(value, list | tuple):
            out.update({f"{key}_{j + 1}": _float(v) for j, v in enumerate(value)})
        else:
            out[str(key)] = _float(value)
    return out


def gains_text(gains: Mapping[str, float]) -> str:
    """A gain vector as comparable text (6 significant digits), "" for none."""
    return ", ".join(f"{k}={v:.6g}" for k, v in gains.items())


def tuned_params(run: Run) -> dict[str, float]:
    """A tune run's best gains from its ``tuned.<name>`` params, in logged order."""
    prefix = "tuned."
    return {k[len(prefix) :]: _float(v) for k, v in run.data.params.items() if k.startswith(prefix)}


def tune_criterion(run: Run) -> tuple[str, float]:
    """(criterion, horizon s) of a tune run: its tags, else its logged config, else the old
    runs' reading (``gaing``, 0.6 s)."""
    tags, params = run.data.tags, run.data.params
    criterion = tags.get(CRITERION_TAG) or params.get("tuner.objective.criterion") or OLD_CRITERION
    horizon = _float(tags.get(HORIZON_TAG))
    if math.isnan(horizon):
        horizon = _float(params.get("tuner.objective.horizon"))
    if math.isnan(horizon) and criterion == OLD_CRITERION:
        horizon = OLD_HORIZON
    return str(criterion), horizon


def _tuning(tune_id: str, tunes: Mapping[str, Run]) -> dict[str, Any]:
    """What a label's tune run says: its seed, gains, criterion and horizon (when stored)."""
    run = tunes.get(tune_id) if tune_id else None
    if run is None:
        return {}
    criterion, horizon = tune_criterion(run)
    return {
        "tuner_seed": _float(run.data.params.get("tuner.seed")),
        "gains": gains_text(tuned_params(run)),
        "criterion": criterion,
        "horizon": horizon,
    }


def _declared(
    declared: Mapping[str, Any], tags: Mapping[str, str], tunes: Mapping[str, Run]
) -> dict[str, Label]:
    out = {}
    for stored, entry in declared.items():
        entry = entry or {}
        tune_id = str(entry.get("tune_run") or tags.get(TUNE_RUN_PREFIX + str(stored)) or "")
        tuned = _tuning(tune_id, tunes)
        criterion = str(entry.get("criterion") or tuned.get("criterion") or CONFIGURED)
        horizon = _float(entry.get("horizon"))
        if math.isnan(horizon):
            horizon = tuned.get("horizon", math.nan)
        out[str(stored)] = Label(
            name=str(stored),
            stored=str(stored),
            controller=str(entry.get("controller") or "?"),
            role=str(entry.get("role") or "baseline"),
            criterion=criterion,
            horizon=horizon if criterion != CONFIGURED else math.nan,
            compare_with=str(entry.get("compare_with") or ""),
            tune_run=tune_id,
            tuner_seed=tuned.get("tuner_seed", math.nan),
            gains=gains_text(flat_gains(entry.get("gains"))) or tuned.get("gains", ""),
        )
    return out


def _old(
    stored_labels: Iterable[str],
    tags: Mapping[str, str],
    params: Mapping[str, str],
    tunes: Mapping[str, Run],
) -> dict[str, Label]:
    """An eval run made before ``controllers.yaml``: ``adaptive`` (proposed) and ``pid``
    (reported as ``pid_gaing``, compared with ``adaptive``); a run of a PID-trained policy
    without ``adaptive`` has ``pid`` as its own, proposed controller."""
    present = [s for s in dict.fromkeys(stored_labels) if s in OLD_CONTROLLERS]
    own = "adaptive" if "adaptive" in present else (present[0] if present else "adaptive")
    out = {}
    for stored in present:
        is_own = stored == own
        tune_id = tags.get(TUNE_RUN_TAG if is_own else PID_TUNE_RUN_TAG, "")
        configured = (
            tags.get(ADAPTIVE_GAINS_TAG) == CONFIGURED
            if is_own
            else str(params.get("eval.pid_gains", "tuned")) == CONFIGURED
        )
        tuned = {} if configured else _tuning(tune_id, tunes)
        criterion = tuned.get("criterion", OLD_CRITERION)
        name = stored if is_own else OLD_PID_NAME
        if not is_own and not configured and criterion != OLD_CRITERION:
            name = f"{OLD_PID}_{criterion}"  # its tune run says which criterion it was tuned under
        out[name] = Label(
            name=name,
            stored=stored,
            controller=OLD_CONTROLLERS[stored],
            role="proposed" if is_own else "baseline",
            criterion=CONFIGURED if configured else criterion,
            horizon=math.nan if configured else tuned.get("horizon", OLD_HORIZON),
            compare_with="" if is_own else own,
            tune_run="" if configured else tune_id,
            tuner_seed=tuned.get("tuner_seed", math.nan),
            gains=tuned.get("gains", ""),
        )
    return out


def of_run(
    declared: Mapping[str, Any] | None,
    stored_labels: Iterable[str],
    tags: Mapping[str, str],
    params: Mapping[str, str],
    tunes: Mapping[str, Run],
) -> dict[str, Label]:
    """The labels of one eval run by reported name: from its ``controllers.yaml`` (``declared``),
    or, for a run made before it (None), the old runs' reading. ``tunes``: the tune runs in the
    store by id (seeds, gains and old runs' criteria are read from them)."""
    if isinstance(declared, Mapping) and declared:
        return _declared(declared, tags, tunes)
    return _old(stored_labels, tags, params, tunes)


def annotate(frame: pd.DataFrame, labels: Mapping[str, Label]) -> pd.DataFrame:
    """An eval run's episodes with its labels' columns (`LABEL_COLUMNS`), ``controller`` renamed
    to the reported label; rows of a label the run does not name keep the old runs' reading."""
    by_stored = {lab.stored: asdict(lab) for lab in labels.values()}
    rows = [by_stored.get(s) for s in frame["controller"].astype(str)]
    if not any(rows):
        return ensure(frame)
    return _merge(frame.copy(), rows)


def _merge(frame: pd.DataFrame, rows: list[dict[str, Any] | None]) -> pd.DataFrame:
    fields = {
        "stored_label": "stored", "controller_name": "controller", "role": "role",
        "criterion": "criterion", "horizon": "horizon", "compare_with": "compare_with",
        "tune_run": "tune_run", "tuner_seed": "tuner_seed", "gains_text": "gains",
    }  # fmt: skip
    default = {"stored": "", "controller": "?", "role": "baseline", "criterion": CONFIGURED,
               "horizon": math.nan, "compare_with": "", "tune_run": "",
               "tuner_seed": math.nan, "gains": ""}  # fmt: skip
    original = frame["controller"].astype(str).tolist()
    frame["controller"] = [r["name"] if r else c for r, c in zip(rows, original, strict=True)]
    for column, key in fields.items():
        values: list[Any] = [r[key] if r else default[key] for r in rows]
        if key == "stored":
            values = [v or c for v, c in zip(values, original, strict=True)]
        frame[column] = values
    return frame


def ensure(episodes: pd.DataFrame) -> pd.DataFrame:
    """Episodes with the label columns: unchanged when they have them, else read as old runs
    (``pid`` renamed ``pid_gaing`` and compared with ``adaptive``, both tuned under ``gaing``
    over 0.6 s; a ``criterion`` column the frame has is kept)."""
    if "role" in episodes.columns:
        return episodes
    out = episodes.copy()
    stored = out["controller"].astype(str)
    has_adaptive = bool((stored == "adaptive").any())
    own = stored.map(lambda s: s == "adaptive" or (s == OLD_PID and not has_adaptive))
    out["stored_label"] = stored
    out["controller"] = [
        s if o or s != OLD_PID else OLD_PID_NAME for s, o in zip(stored, own, strict=True)
    ]
    out["controller_name"] = stored.map(lambda s: OLD_CONTROLLERS.get(s, s))
    out["role"] = ["proposed" if o else "baseline" for o in own]
    if "criterion" not in out.columns:
        out["criterion"] = OLD_CRITERION
    if "horizon" not in out.columns:
        out["horizon"] = [OLD_HORIZON if c == OLD_CRITERION else math.nan for c in out["criterion"]]
    out["compare_with"] = ["" if o else "adaptive" for o in own]
    for column, value in (("tune_run", ""), ("tuner_seed", math.nan), ("gains_text", "")):
        if column not in out.columns:
            out[column] = value
    return out


def ordered(episodes: pd.DataFrame) -> list[str]:
    """The labels of ``episodes`` (with label columns), proposed first, then references,
    ablations and baselines, each in the order the runs list them."""
    first = episodes.drop_duplicates("controller")
    rank = {r: i for i, r in enumerate(ROLES)}
    keyed = [
        (rank.get(str(r.role), len(ROLES)), i, str(r.controller))
        for i, r in enumerate(first.itertuples())
    ]
    return [label for _, _, label in sorted(keyed)]


def info(episodes: pd.DataFrame, label: str) -> dict[str, Any]:
    """A label's role, controller, criterion, horizon and comparison (its first row's)."""
    rows = episodes[episodes.controller == label]
    if rows.empty:
        return {}
    first = rows.iloc[0]
    return {
        c: first[c] for c in ("role", "controller_name", "criterion", "horizon", "compare_with")
    }


def comparisons(episodes: pd.DataFrame) -> list[tuple[str, str]]:
    """(baseline, proposed label) of every baseline in ``episodes`` (with label columns) whose
    proposed side is there too, in the order of `ordered`."""
    present = set(episodes.controller)
    out = []
    for label in ordered(episodes):
        got = info(episodes, label)
        partner = str(got.get("compare_with") or "")
        if got.get("role") == "baseline" and partner in present:
            out.append((label, partner))
    return out


def ablations(episodes: pd.DataFrame) -> list[tuple[str, str]]:
    """(ablation label, proposed label): each ablation against the proposed adaptive law."""
    proposed = [
        label for label in ordered(episodes)
        if info(episodes, label).get("role") == "proposed"
    ]  # fmt: skip
    out = []
    for label in ordered(episodes):
        if info(episodes, label).get("role") == "ablation" and proposed:
            out.append((label, proposed[0]))
    return out


def tuning(criterion: Any, horizon: Any) -> str:
    """How a label's gains were chosen: ``itae over 1.5 s``, ``configured gains``."""
    crit = str(criterion or CONFIGURED)
    if crit == CONFIGURED:
        return "configured gains"
    h = _float(horizon)
    return f"{crit} over {h:g} s" if math.isfinite(h) else crit


def describe(episodes: pd.DataFrame, label: str) -> str:
    """``pid_itae (pid, itae over 1.5 s)``: a label, its controller and how it was tuned."""
    got = info(episodes, label)
    if not got:
        return label
    return f"{label} ({got['controller_name']}, {tuning(got['criterion'], got['horizon'])})"
