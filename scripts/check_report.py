"""Open a report in headless Chromium, check that every image loaded and every table shows rows,
and keep a full-page screenshot.

    python scripts/check_report.py runs/report          # a folder: <folder>/screenshot.png
    python scripts/check_report.py <report run id>      # also logged to that run
    python scripts/check_report.py <report run id> --runs-dir runs --out shot.png

Given a report run's id, the script reads the run's ``report/`` artifact from the store
(``--tracking-uri``, else the SQLite store under ``--runs-dir``), checks it, and logs the
screenshot to the same run as ``report/screenshot.png``. Exit code 0: all loaded; 1: something
did not (each named on stderr); 2: no such folder or report run, or no Chromium.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

from armexp.report.browser import check_page, find_chromium

SCREENSHOT = "screenshot.png"


def _store(args: argparse.Namespace) -> str:
    if args.tracking_uri:
        return str(args.tracking_uri)
    return f"sqlite:///{Path(args.runs_dir).resolve() / 'mlflow.db'}"


def _check(folder: Path, out: Path) -> int:
    result = check_page(folder / "index.html", out)
    problems = result.problems()
    for problem in problems:
        print(f"check_report: {problem}", file=sys.stderr)
    loaded = sum(i["width"] > 0 for i in result.images)
    print(
        f"check_report: {loaded}/{len(result.images)} images loaded, "
        f"{sum(t['rows'] > 0 for t in result.tables)}/{len(result.tables)} tables with rows; "
        f"screenshot {result.size[0]}x{result.size[1]} px in {out}"
    )
    return 1 if problems else 0


def _check_run(run_id: str, args: argparse.Namespace) -> int:
    os.environ.setdefault("MLFLOW_ENABLE_ARTIFACTS_PROGRESS_BAR", "false")
    import mlflow
    from mlflow.exceptions import MlflowException
    from mlflow.tracking import MlflowClient

    uri = _store(args)
    client = MlflowClient(uri)
    try:
        run = client.get_run(run_id)
    except MlflowException:
        print(f"check_report: {run_id} is neither a folder nor a run in {uri}.", file=sys.stderr)
        return 2
    if run.data.tags.get("armexp.stage") != "report":
        print(f"check_report: run {run_id} is not a report run.", file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory(prefix="armexp-check-") as tmp:
        mlflow.set_tracking_uri(uri)
        folder = Path(
            mlflow.artifacts.download_artifacts(run_id=run_id, artifact_path="report", dst_path=tmp)
        )
        out = Path(args.out) if args.out else Path(tmp) / SCREENSHOT
        code = _check(folder, out)
        client.log_artifact(run_id, str(out), "report")
        print(f"check_report: logged report/{out.name} to report run {run_id}")
    return code


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("report", help="a report folder or a report run's id")
    parser.add_argument("--out", help=f"the screenshot (default: <folder>/{SCREENSHOT})")
    parser.add_argument("--runs-dir", default="runs", help="the store's runs folder (SQLite)")
    parser.add_argument("--tracking-uri", help="the store's URI (instead of --runs-dir)")
    args = parser.parse_args()
    if find_chromium() is None:
        print("check_report: no Chromium on PATH; apt-get install chromium.", file=sys.stderr)
        return 2
    folder = Path(args.report)
    if folder.is_dir():
        if not (folder / "index.html").is_file():
            print(f"check_report: {folder} has no index.html.", file=sys.stderr)
            return 2
        return _check(folder, Path(args.out) if args.out else folder / SCREENSHOT)
    return _check_run(args.report, args)


if __name__ == "__main__":
    sys.exit(main())
