"""What ran: commit, dirty flag and package versions on every run; `armexp diff` of two runs."""

from __future__ import annotations

from importlib import metadata
from pathlib import Path

import pytest

from armexp.cli import main
from armexp.tracking.lineage import PACKAGES, git_commit
from tests.helpers import stage_runs


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, list]:
    runs = tmp_path_factory.mktemp("lineage") / "runs"
    where = f"tracking.runs_dir={runs}"
    assert main(["simulate", "scenario.duration=0.1", where]) == 0
    assert main(["simulate", "scenario.duration=0.2", "controller=pid", where]) == 0
    return runs, stage_runs(runs, "simulate", newest_first=False)


def test_every_run_records_commit_dirty_flag_and_package_versions(two_runs: tuple) -> None:
    _, (run, _) = two_runs
    tags = run.data.tags
    assert tags["armexp.git_commit"] == git_commit() and len(tags["armexp.git_commit"]) == 40
    assert tags["armexp.git_dirty"] in ("true", "false")
    for name in PACKAGES:
        assert tags[f"armexp.version.{name}"] == metadata.version(name)


def test_diff_prints_the_config_and_metric_differences(
    two_runs: tuple, capsys: pytest.CaptureFixture[str]
) -> None:
    runs, (a, b) = two_runs
    assert main(["diff", a.info.run_id, b.info.run_id, f"tracking.runs_dir={runs}"]) == 0
    out = capsys.readouterr().out.splitlines()
    rows = {line.split()[0]: line.split()[1:] for line in out if line.startswith("  ")}
    assert rows["scenario.duration"] == ["0.1", "0.2"]
    assert rows["controller.name"] == ["subsystem_adaptive", "pid"]
    assert "seed" not in rows and "robot.name" not in rows  # only what differs
    m = "rms_e1"
    x, y = a.data.metrics[m], b.data.metrics[m]
    assert rows[m] == [f"{x:.6g}", f"{y:.6g}", "(B-A", f"{y - x:+.4g})"]
    assert out[0] == f"armexp diff: A {a.info.run_id} vs B {b.info.run_id}"
    assert "what ran: the same" in out


def test_diff_of_an_unknown_run_or_one_id_is_one_sentence(
    two_runs: tuple, capsys: pytest.CaptureFixture[str]
) -> None:
    runs, (a, _) = two_runs
    unknown = "0" * 32
    assert main(["diff", a.info.run_id, unknown, f"tracking.runs_dir={runs}"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith(f"armexp diff: run id {unknown} is not allowed: no run with that id")
    assert main(["diff", a.info.run_id, "nope", f"tracking.runs_dir={runs}"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("armexp diff: run id nope is not allowed: a run id is 32 hex digits")
    assert main(["diff", a.info.run_id]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "takes exactly two run ids and got 1" in line
