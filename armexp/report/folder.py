"""The report's folder (``report.out_dir``): replaced as a whole by each report, built beside it
first, and never holding a file the report did not write.

A report is built in a folder of its own beside the target (`building`), named `BUILD_PREFIX`
and owned by the building process (`OWNER`); when complete it is swapped in, so a failed or
interrupted report leaves the previous one as it was. Build folders left by a killed process are
removed by the next report in that place. The `MARKER` file of a finished report lists the files
it wrote, so that a file put in the folder afterwards is found and the folder refused (`check`)
rather than deleted with the rest.
"""

from __future__ import annotations

import contextlib
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

from armexp.config import ConfigError
from armexp.tracking import liveness

#: The file that marks a folder as an armexp report (which a new report may replace).
MARKER = ".armexp-report"
#: The marker's first line, and the line after which it lists the report's files.
MARKER_TEXT, FILES_LINE = "made by armexp report; the folder is replaced as a whole", "files:"
#: What a report made before the marker listed its files holds at its top level.
EARLIER_LAYOUT = frozenset({"index.html", "runs.csv", "tables", "figures", "animations", MARKER})
#: Beside the target: the folder a report is built in, and the file in it naming its process
#: (`armexp.tracking.liveness.process_identity`) and its target.
BUILD_PREFIX, OWNER = ".armexp-report-build-", "owner"


def check(folder: Path) -> None:
    """A report replaces its folder as a whole, so it writes only into a new or empty folder or
    into a previous report's (one holding the `MARKER` file) that holds nothing else."""
    if folder.exists() and not folder.is_dir():
        raise ConfigError(f"report.out_dir={folder} is not allowed: it is a file, not a folder.")
    if not folder.is_dir() or not any(folder.iterdir()):
        return
    # Reports made before the marker existed are recognised by their layout.
    earlier = (folder / MARKER).exists() or (
        (folder / "index.html").is_file() and (folder / "tables").is_dir()
    )
    if not earlier:
        raise ConfigError(
            f"report.out_dir={folder} is not allowed: the folder holds files that are not an "
            f"armexp report (no {MARKER} in it) and a report replaces its whole folder; give a "
            "new or empty folder, or an earlier report's."
        )
    foreign = others(folder)
    if foreign:
        more = f" and {len(foreign) - 3} more" if len(foreign) > 3 else ""
        raise ConfigError(
            f"report.out_dir={folder} is not allowed: it holds {', '.join(foreign[:3])}{more}, "
            "which the earlier report there did not write, and a report replaces its whole "
            "folder; move them out, or give another report.out_dir."
        )


def others(folder: Path) -> list[str]:
    """Paths in the earlier report ``folder`` (relative, sorted) that it did not write: those
    its `MARKER` does not list, or for a report older than the list, those outside its
    layout."""
    marker = folder / MARKER
    lines = marker.read_text().splitlines() if marker.is_file() else []
    if FILES_LINE in lines:
        written = set(lines[lines.index(FILES_LINE) + 1 :]) | {MARKER}
        found = [p.relative_to(folder).as_posix() for p in folder.rglob("*") if not p.is_dir()]
        return sorted(set(found) - written)
    return sorted(p.name for p in folder.iterdir() if p.name not in EARLIER_LAYOUT)


@contextlib.contextmanager
def building(target: Path) -> Iterator[Path]:
    """A new folder to build the report for ``target`` in; swapped in for ``target`` (with the
    `MARKER` listing its files) when the block ends without an error, removed in any case."""
    target.parent.mkdir(parents=True, exist_ok=True)
    clear_leftovers(target.parent)
    work = Path(tempfile.mkdtemp(prefix=BUILD_PREFIX, dir=target.parent))
    try:
        (work / OWNER).write_text(f"{liveness.process_identity()}\n{target.name}\n")
        new = work / "new"
        new.mkdir()
        yield new
        files = sorted(p.relative_to(new).as_posix() for p in new.rglob("*") if not p.is_dir())
        (new / MARKER).write_text("\n".join([MARKER_TEXT, FILES_LINE, *files]) + "\n")
        if target.exists():
            target.rename(work / "old")
        new.rename(target)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def clear_leftovers(parent: Path) -> list[Path]:
    """Remove the build folders in ``parent`` whose process is gone (killed while building);
    one killed between moving the old report out and the new one in gives the old one back.
    Returns the folders removed."""
    removed = []
    for work in parent.glob(f"{BUILD_PREFIX}*"):
        try:
            identity, name = (work / OWNER).read_text().splitlines()[:2]
        except (OSError, ValueError):
            continue  # not yet owned, or not one of these
        if not liveness.process_gone(identity):
            continue
        target = parent / name
        if not target.exists() and (work / "old").is_dir():
            (work / "old").rename(target)
        shutil.rmtree(work, ignore_errors=True)
        removed.append(work)
    return removed
