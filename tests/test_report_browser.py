"""The report as a person sees it: index.html in headless Chromium (Debian's ``chromium``), every
image loaded and every table drawn with rows, and a screenshot kept."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient
from PIL import Image

from armexp.cli import main
from armexp.report.browser import check_page, find_chromium
from tests.helpers import stage_runs

ROOT = Path(__file__).resolve().parents[1]
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(
        find_chromium() is None, reason="no Chromium installed (Debian: apt-get install chromium)"
    ),
]


def test_every_figure_animation_and_table_shows_in_chromium(store: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    assert main(["report", f"tracking.runs_dir={store}", f"report.out_dir={out}"]) == 0
    shot = tmp_path / "screenshot.png"
    result = check_page(out / "index.html", shot)
    assert result.problems() == []
    images = {i["src"]: i for i in result.images}
    animations = {f"animations/{c}/{t}.gif" for c in ("adaptive", "pid") for t in "abcd"}
    assert animations <= set(images)
    assert all(images[a]["width"] == images[a]["height"] == 480 for a in animations)
    figures = [src for src in images if src.startswith("figures/")]
    assert len(figures) >= 7 and all(images[f]["width"] > 300 for f in figures)
    names = [t["name"] for t in result.tables]
    assert any(n.startswith("Table III") for n in names) and "Runs used" in names
    assert all(t["rows"] > 0 and t["height"] > 0 for t in result.tables)
    with Image.open(shot) as png:
        assert png.format == "PNG" and png.width == 1280 and png.height == result.size[1] > 3000


def test_a_missing_image_and_an_empty_table_are_named(tmp_path: Path) -> None:
    (tmp_path / "index.html").write_text(
        "<html><body><h2>Empty</h2><table><thead><tr><th>a</th></tr></thead><tbody></tbody>"
        "</table><img src='figures/missing.png'></body></html>"
    )
    result = check_page(tmp_path / "index.html", tmp_path / "shot.png")
    assert result.problems() == [
        "image figures/missing.png did not load",
        "table 'Empty' shows no rows",
    ]


def test_the_script_logs_the_screenshot_to_the_report_run(store: Path, tmp_path: Path) -> None:
    assert main(["report", f"tracking.runs_dir={store}", f"report.out_dir={tmp_path / 'r'}"]) == 0
    report = stage_runs(store, "report")[0]
    done = subprocess.run(
        [sys.executable, "scripts/check_report.py", report.info.run_id, "--runs-dir", str(store)],
        capture_output=True, text=True, cwd=ROOT, env={**os.environ},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-3000:]
    assert "images loaded" in done.stdout and report.info.run_id in done.stdout
    client = MlflowClient(f"sqlite:///{store}/mlflow.db")
    listed = {f.path: f.file_size for f in client.list_artifacts(report.info.run_id, "report")}
    assert (listed.get("report/screenshot.png") or 0) > 10_000
