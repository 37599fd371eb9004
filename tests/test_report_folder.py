"""The report's folder: a user's files in it are never deleted, and a report killed while
building leaves nothing behind for long."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from armexp.cli import main
from armexp.report import folder as report_folder
from tests.helpers import stage_runs


def _report(store: Path, *extra: str) -> int:
    return main(["report", f"tracking.runs_dir={store}", *extra])


@pytest.mark.slow
def test_a_users_files_in_the_default_report_folder_are_kept_and_named(
    store: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``runs/report/`` (no ``report.out_dir``): a note and a table of one's own put in it."""
    out = store / "report"
    assert _report(store) == 0
    before = len(stage_runs(store, "report"))
    (out / "notes.txt").write_text("mine")
    (out / "tables" / "my_table.md").write_text("| mine |")
    capsys.readouterr()
    assert _report(store) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"report.out_dir={out} is not allowed: it holds notes.txt, tables/my_table.md," in err[0]
    assert (out / "notes.txt").read_text() == "mine"
    assert (out / "tables" / "my_table.md").read_text() == "| mine |"
    assert len(stage_runs(store, "report")) == before  # no run for a refused report
    (out / "notes.txt").unlink()
    (out / "tables" / "my_table.md").unlink()
    assert _report(store) == 0  # the report's own files alone: replaced as before


@pytest.mark.long
def test_a_report_older_than_its_file_list_keeps_a_users_file(
    store: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "r"
    assert _report(store, f"report.out_dir={out}") == 0
    (out / report_folder.MARKER).write_text(report_folder.MARKER_TEXT + "\n")  # as it was
    (out / "draft.tex").write_text("mine")
    capsys.readouterr()
    assert _report(store, f"report.out_dir={out}") == 2
    assert "it holds draft.tex," in capsys.readouterr().err
    assert (out / "draft.tex").read_text() == "mine"


KILLED_WHILE_BUILDING = """
import os, signal, sys
from armexp.cli import main
from armexp.report import page

real = page.build

def build_then_die(*args, **kwargs):
    real(*args, **kwargs)
    os.kill(os.getpid(), signal.SIGKILL)

page.build = build_then_die
main(["report", f"tracking.runs_dir={sys.argv[1]}", f"report.out_dir={sys.argv[2]}"])
"""


@pytest.mark.slow
def test_a_report_killed_while_building_leaves_nothing_after_the_next(
    store: Path, tmp_path: Path
) -> None:
    out = tmp_path / "r"
    root = Path(__file__).resolve().parents[1]
    killed = subprocess.run(
        [sys.executable, "-c", KILLED_WHILE_BUILDING, str(store), str(out)],
        capture_output=True, text=True, timeout=600,
        env={**os.environ, "PYTHONPATH": str(root)},
    )  # fmt: skip
    assert killed.returncode == -9, killed.stderr[-2000:]
    left = [p.name for p in tmp_path.iterdir() if p.name.startswith(".")]
    assert len(left) == 1 and not out.exists()  # what SIGKILL leaves: the folder it built in
    assert _report(store, f"report.out_dir={out}") == 0
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    assert (out / "index.html").is_file()


def test_a_report_being_built_by_a_live_process_is_left_alone(tmp_path: Path) -> None:
    from armexp.tracking import liveness

    work = tmp_path / f"{report_folder.BUILD_PREFIX}x"
    work.mkdir()
    (work / report_folder.OWNER).write_text(f"{liveness.process_identity()}\nr\n")
    assert report_folder.clear_leftovers(tmp_path) == []
    assert work.is_dir()


def test_a_report_killed_between_its_two_renames_gives_the_old_one_back(tmp_path: Path) -> None:
    gone = f"{socket.gethostname()}:999999999:1"  # no such process on this host
    work = tmp_path / f"{report_folder.BUILD_PREFIX}y"
    (work / "old").mkdir(parents=True)
    (work / "old" / "index.html").write_text("the earlier report")
    (work / report_folder.OWNER).write_text(f"{gone}\nr\n")
    assert report_folder.clear_leftovers(tmp_path) == [work]
    assert (tmp_path / "r" / "index.html").read_text() == "the earlier report"
    assert not work.exists()
