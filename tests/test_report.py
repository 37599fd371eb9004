"""armexp report: tables and figures from a store written by short real runs, MLflow only."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pandas as pd
import pytest
from mlflow.tracking import MlflowClient

from armexp.cli import main

FIGURES = (
    "fig3_tip_paths",
    "fig4_target_error",
    "fig5_torques",
    "fig6_tracking",
    "learning_curves",
    "cso_convergence",
)
TABLES = ("table1_environment", "table2_agent", "table3_performance", "comparison_pid", "cso_gains")


def _report(store: Path, out: Path) -> int:
    return main(["report", f"tracking.runs_dir={store}", f"report.out_dir={out}"])


def test_report_has_every_table_and_figure(store: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    assert _report(store, out) == 0
    table3 = pd.read_csv(out / "tables" / "table3_performance.csv")
    for controller in ("adaptive", "pid"):
        assert sorted(table3[table3.controller == controller].task) == ["a", "b", "c", "d"]
    markdown = (out / "tables" / "table3_performance.md").read_text()
    for task in "abcd":
        assert f"| ({task}) | proposed |" in markdown and f"| ({task}) | PID |" in markdown
    for name in TABLES:
        for ext in ("md", "tex", "csv"):
            assert (out / "tables" / f"{name}.{ext}").stat().st_size > 0, (name, ext)
    assert r"\toprule" in (out / "tables" / "table1_environment.tex").read_text()
    for name in FIGURES:
        png = (out / "figures" / f"{name}.png").read_bytes()
        pdf = (out / "figures" / f"{name}.pdf").read_bytes()
        assert png.startswith(b"\x89PNG") and len(png) > 5000, name
        assert pdf.startswith(b"%PDF") and len(pdf) > 1000, name
    index = (out / "index.html").read_text()
    for name in FIGURES:
        assert f"figures/{name}.png" in index
    client = MlflowClient(f"sqlite:///{store}/mlflow.db")
    (ev,) = client.search_runs(
        [client.get_experiment_by_name("armexp").experiment_id],  # type: ignore[union-attr]
        "tags.`armexp.stage` = 'eval'",
    )
    assert ev.info.run_id in index and "armexp report" in index
    # The report run carries the folder as an artifact.
    (rep,) = client.search_runs(
        [ev.info.experiment_id],
        "tags.`armexp.stage` = 'report'",
        order_by=["attributes.start_time DESC"],
        max_results=1,
    )
    assert rep.info.status == "FINISHED"
    names = {f.path for f in client.list_artifacts(rep.info.run_id, "report/tables")}
    assert "report/tables/table3_performance.md" in names


def test_report_twice_gives_identical_tables(store: Path, tmp_path: Path) -> None:
    assert _report(store, tmp_path / "one") == 0
    assert _report(store, tmp_path / "two") == 0
    for name in TABLES:
        for ext in ("md", "tex", "csv"):
            first = (tmp_path / "one" / "tables" / f"{name}.{ext}").read_bytes()
            second = (tmp_path / "two" / "tables" / f"{name}.{ext}").read_bytes()
            assert first == second, (name, ext)


def test_report_runs_without_simulation_environment_or_agent_code(
    store: Path, tmp_path: Path
) -> None:
    blocked = [
        "armexp.sim",
        "armexp.envs",
        "armexp.agents",
        "armexp.tune",
        "stable_baselines3",
        "gymnasium",
        "torch",
        "numba",
    ]
    script = (
        "import sys\n"
        f"for name in {blocked!r}:\n"
        "    sys.modules[name] = None\n"
        "from armexp.cli import main\n"
        f"sys.exit(main(['report', 'tracking.runs_dir={store}', 'report.out_dir={tmp_path}/r']))\n"
    )
    res = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={**os.environ},
    )
    assert res.returncode == 0, res.stderr[-3000:]
    assert (tmp_path / "r" / "tables" / "table3_performance.md").exists()


def test_empty_store_is_one_sentence(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["report", f"tracking.runs_dir={tmp_path / 'runs'}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "armexp eval" in err


def test_selection_without_eval_runs_is_one_sentence(
    store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    rc = main(["report", f"tracking.runs_dir={store}", "report.filter=\"tags.sweep = 'none'\""])
    assert rc == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "no FINISHED eval run" in err
