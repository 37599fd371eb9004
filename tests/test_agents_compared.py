"""The report's agents table: what the aids buy, each agent of a study side by side (steps to
90 % on the held-out checks, the last check, held-out success and tasks in `armexp eval`)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
from mlflow.tracking import MlflowClient

from armexp.cli import main
from tests.test_report import _hand_store


def _checks(runs: Path, train_id: str, values: list[float]) -> None:
    client = MlflowClient(f"sqlite:///{runs}/mlflow.db")
    for i, v in enumerate(values, 1):
        client.log_metric(train_id, "eval/success_rate", v, step=i * 50_000)


def _report(runs: Path, evals: list[str], name: str) -> Path:
    folder = runs.parent / name
    where = [f"tracking.runs_dir={runs}", f"report.out_dir={folder}"]
    assert main(["report", *where, f"report.eval_runs=[{','.join(evals)}]"]) == 0
    return folder / "tables"


@pytest.mark.long
def test_two_agents_are_compared_on_steps_to_90_percent_success_and_tasks(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    aided_train, aided_eval = _hand_store(runs, "sac_quick")
    plain_train, plain_eval = _hand_store(runs, "sac_plain")
    _checks(runs, aided_train, [0.5, 0.92, 0.95])
    _checks(runs, plain_train, [0.2, 0.4, 0.6])

    tables = _report(runs, [aided_eval, plain_eval], "both")
    numbers = pd.read_csv(tables / "agents.csv").set_index("aided")
    aided, plain = numbers.loc[True], numbers.loc[False]
    assert aided.agent.startswith("sac_quick (aided)") and plain.agent.startswith("sac_plain")
    assert aided.steps_to_competent_median == 100_000 and aided.runs_competent == 1
    assert pd.isna(plain.steps_to_competent_median) and plain.runs_competent == 0
    assert (aided.last_check_iqm, plain.last_check_iqm) == (0.95, 0.6)
    assert aided.env_steps == plain.env_steps == 123456
    # The hand episodes: the adaptive law reaches its one held-out target and all four tasks.
    assert aided.held_out_success_iqm == plain.held_out_success_iqm == 1.0
    assert aided.tasks_reached_iqm == 4
    shown = (tables / "agents.md").read_text()
    assert "| 100 k (1 of 1 runs) |" in shown and "| not reached (0 of 1) |" in shown
    assert "The agents side by side" in (tables.parent / "index.html").read_text()

    # One agent: nothing to compare, no table.
    assert not (_report(runs, [aided_eval], "one") / "agents.md").exists()


@pytest.mark.long
def test_an_agent_the_command_names_is_an_agent_of_its_own(runs_dir: Path) -> None:
    """agent.name=… on a preset's changed values: the train run, its name and the report call it
    so (a study comparing it with the preset it came from keeps them apart)."""
    from tests.helpers import SMALL_TRAIN, stage_runs

    args = ["train", *SMALL_TRAIN, "agent.name=sac_smoke_best", "agent.learning_rate=0.002",
            "train.gains=config", "controller.gains=paper",
            f"tracking.runs_dir={runs_dir}"]  # fmt: skip
    assert main(args) == 0
    (run,) = stage_runs(runs_dir, "train")
    assert run.data.tags["armexp.agent_preset"] == "sac_smoke_best"
    assert run.data.tags["mlflow.runName"] == "train-sac_smoke_best-s0"
