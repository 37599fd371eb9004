"""A disk that fills during a stage: one sentence, the run FAILED at once, and no cut-off file.

Two ways to fill a disk for real without root:

* a small tmpfs mounted in a user and mount namespace of its own (``unshare -rm``: no root
  needed where the kernel allows unprivileged user namespaces; skipped elsewhere): the writes of
  SB3, MLflow and SQLite fail with ENOSPC, as on a full disk;
* ``RLIMIT_FSIZE`` (``ulimit -f``) in the child process, with SIGXFSZ ignored (Python ignores it
  at start-up): a write past the limit fails with EFBIG, on any machine.
"""

from __future__ import annotations

import os
import resource
import shutil
import sqlite3
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from armexp.cli import main
from tests.helpers import SMALL_TRAIN, SMALL_TUNE

#: A model of a few MB (3 MB for these settings), so the store's own growth while it trains
#: (some KB) does not decide which write finds the disk full.
BIG_TRAIN = ["train", "controller.gains=paper", *SMALL_TRAIN, "agent.net_arch=[256,256]",
             "agent.max_env_steps=300", "train.checkpoint_every=100000"]  # fmt: skip
ARMEXP = f"{sys.executable} -m armexp"


def _namespaces_work(tmp: Path) -> bool:
    if shutil.which("unshare") is None:
        return False
    mount = tmp / "probe"
    mount.mkdir()
    done = subprocess.run(
        ["unshare", "-rm", "sh", "-c", f"mount -t tmpfs -o size=64k tmpfs {mount}"],
        capture_output=True,
    )
    return done.returncode == 0


def on_a_full_disk(tmp: Path, free_bytes: str, command: str, size: str = "64m") -> Path:
    """Run ``command`` (a shell line; ``$RUNS`` is the runs folder) in a store on a tmpfs of
    ``size`` that a simulate run created and a file then filled to ``free_bytes`` (a shell
    expression) of room; returns a copy of that folder with ``rc``, ``out`` and ``err``."""
    if not _namespaces_work(tmp):
        pytest.skip("no user namespaces here to mount a small tmpfs in (unshare -rm)")
    disk, copy = tmp / "disk", tmp / "after"
    disk.mkdir()
    script = f"""
set -e
mount -t tmpfs -o size={size} tmpfs {disk}
cd {disk}
mkdir tmp
export TMPDIR={disk}/tmp RUNS={disk}/runs
{ARMEXP} simulate scenario=hold scenario.duration=0.05 tracking.runs_dir=$RUNS > setup.log 2>&1
avail=$(df -B1 --output=avail . | tail -1)
head -c $((avail - ({free_bytes}))) /dev/zero > filler
set +e
{command} > out 2> err
echo $? > rc
rm -f filler
cp -a {disk}/. {copy}/
"""
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1])}
    done = subprocess.run(["unshare", "-rm", "bash", "-c", script], capture_output=True,
                          text=True, timeout=900, env=env)  # fmt: skip
    assert done.returncode == 0 and (copy / "rc").is_file(), done.stderr[-3000:]
    return copy


def runs_of(runs: Path, stage: str) -> list[tuple[str, str, str | None]]:
    """(run id, status, ``armexp.error``) of each run of ``stage`` in the store, oldest first."""
    with sqlite3.connect(runs / "mlflow.db") as con:
        return con.execute(
            "SELECT r.run_uuid, r.status, e.value FROM runs r JOIN tags s ON s.run_uuid = "
            "r.run_uuid AND s.key = 'armexp.stage' LEFT JOIN tags e ON e.run_uuid = r.run_uuid"
            " AND e.key = 'armexp.error' WHERE s.value = ? ORDER BY r.start_time",
            (stage,),
        ).fetchall()


def assert_failed_cleanly(folder: Path, stage: str, why: str = "the disk is full (") -> None:
    """Exit 1 with one sentence; the run FAILED with the error; every file in the store
    complete: no MLflow staging file, and every model a whole zip."""
    files = [p for p in (folder / "runs").rglob("*") if p.is_file()]
    assert [p for p in files if p.name.startswith(".artifact")] == []
    for model in (p for p in files if p.name == "model.zip"):
        with zipfile.ZipFile(model) as z:
            assert z.testzip() is None, model
    err = (folder / "err").read_text().strip().splitlines()
    assert (folder / "rc").read_text().strip() == "1", err[-30:]
    assert len(err) == 1, err[-30:]
    assert f"armexp {stage}: {why}" in err[0] and "is marked FAILED" in err[0]
    (run,) = runs_of(folder / "runs", stage)
    assert run[1] == "FAILED" and run[2] and run[0][:8] in err[0], run


# About two minutes on a loaded 2-core machine: the model is written until the disk fills.
@pytest.mark.slow
def test_a_full_disk_cuts_no_model_short(tmp_path: Path) -> None:
    """Room for the checkpoint (its save and its copy) and for half of the final model: the
    final model's copy into the store is the write that fails."""
    model = tmp_path / "sized"
    assert main([*BIG_TRAIN, f"tracking.runs_dir={model}"]) == 0
    (size,) = [p.stat().st_size for p in model.rglob("model/model.zip")]
    train = " ".join([ARMEXP, *BIG_TRAIN, "tracking.runs_dir=$RUNS"])
    folder = on_a_full_disk(tmp_path, f"{size} * 5 / 2", train)
    assert_failed_cleanly(folder, "train")
    (run,) = runs_of(folder / "runs", "train")
    artifacts = folder / "runs" / "artifacts" / run[0] / "artifacts"
    assert (artifacts / "checkpoint" / "model.zip").stat().st_size > size // 2
    assert not (artifacts / "model").exists() or not any((artifacts / "model").iterdir())


@pytest.mark.long
@pytest.mark.parametrize("stage", [pytest.param("train", marks=pytest.mark.slow), "tune"])
def test_a_store_whose_disk_fills_still_marks_the_run_failed(tmp_path: Path, stage: str) -> None:
    """So little room that the store's own writes (metrics) fail during the run: the room kept
    beside the store lets the error and the FAILED status be written."""
    args = BIG_TRAIN if stage == "train" else ["tune", *SMALL_TUNE, "tuner.n_iterations=30"]
    folder = on_a_full_disk(
        tmp_path, "48 * 1024", " ".join([ARMEXP, *args, "tracking.runs_dir=$RUNS"])
    )
    assert_failed_cleanly(folder, stage)


@pytest.mark.slow
def test_a_file_size_limit_fails_the_run_with_one_sentence(tmp_path: Path) -> None:
    """``ulimit -f`` of 2 MB: the store (1 MB) fits, the 3 MB model does not."""
    runs = tmp_path / "runs"
    assert main(["simulate", "scenario=hold", "scenario.duration=0.05",
                 f"tracking.runs_dir={runs}"]) == 0  # fmt: skip
    limit = 2 * 1024 * 1024
    assert (runs / "mlflow.db").stat().st_size < limit // 2

    def limited() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    temp = tmp_path / "tmp"
    temp.mkdir()
    done = subprocess.run(
        [sys.executable, "-m", "armexp", *BIG_TRAIN, f"tracking.runs_dir={runs}"],
        capture_output=True, text=True, timeout=600, preexec_fn=limited,
        env={**os.environ, "TMPDIR": str(temp)},
    )  # fmt: skip
    folder = tmp_path / "result"
    folder.mkdir()
    (folder / "rc").write_text(str(done.returncode))
    (folder / "err").write_text(done.stderr)
    (folder / "runs").symlink_to(runs)
    assert_failed_cleanly(folder, "train", "a file went over this process's file size limit")
    assert list(temp.rglob("*.zip")) == []


LAST_WRITES = """
import errno, os, sys
from armexp.tracking import stage_runs
from armexp.config import compose_config

cfg = compose_config([f"tracking.runs_dir={sys.argv[1]}"])
try:
    with stage_runs.stage_run(cfg, "simulate"):
        with open("filler2", "wb") as f:  # another writer takes every byte that is left
            try:
                while True:
                    f.write(bytes(4096))
                    f.flush()
            except OSError:
                pass
        raise OSError(errno.ENOSPC, "No space left on device", "trajectory.parquet")
except Exception as exc:
    os.remove("filler2")  # room again for this line
    print(type(exc).__name__, getattr(exc, "marked", None))
"""


@pytest.mark.slow
def test_the_room_kept_beside_the_store_takes_the_last_writes(tmp_path: Path) -> None:
    """A disk left with no byte free (another writer took them): the run still ends FAILED
    with its error, in the room the store kept (`armexp.disk.RESERVE_BYTES`), given back."""
    script = tmp_path / "last_writes.py"
    script.write_text(LAST_WRITES)
    folder = on_a_full_disk(tmp_path, "256 * 1024", f"{sys.executable} {script} $RUNS")
    assert (folder / "out").read_text().split() == ["DiskFull", "True"], (
        folder / "err"
    ).read_text()[-2000:]
    (run,) = runs_of(folder / "runs", "simulate")[1:]
    assert run[1] == "FAILED" and "No space left on device" in str(run[2])
    assert not (folder / "runs" / "mlflow.db.reserve").exists()


@pytest.mark.slow
def test_a_disk_with_no_room_to_start_is_one_sentence(tmp_path: Path) -> None:
    """Too little room for Hydra's job folder: said before anything is written."""
    command = f"{ARMEXP} simulate scenario=hold seed=1 tracking.runs_dir=$RUNS"
    folder = on_a_full_disk(tmp_path, "8 * 1024", command)
    err = (folder / "err").read_text().strip().splitlines()
    assert (folder / "rc").read_text().strip() == "2" and len(err) == 1, err
    runs = folder.parent / "disk" / "runs"
    assert f"tracking.runs_dir={runs} is not allowed now: its disk is full (" in err[0]
    assert len(runs_of(folder / "runs", "simulate")) == 1  # the one made before the disk filled


def test_a_nested_stage_stopped_by_a_full_disk_fails_its_parent_too(tmp_path: Path) -> None:
    """A pipeline's step: the step's run is the one named, and both runs end FAILED."""
    import errno

    from armexp import disk
    from armexp.config import compose_config
    from armexp.tracking import stage_runs

    cfg = compose_config([f"tracking.runs_dir={tmp_path / 'runs'}"])
    with (
        pytest.raises(disk.DiskFull) as stopped,
        stage_runs.stage_run(cfg, "pipeline") as outer,
        stage_runs.parent(outer.info.run_id),
        stage_runs.stage_run(cfg, "train") as child,
    ):
        raise OSError(errno.ENOSPC, "No space left on device", "model/model.zip")
    assert stopped.value.run_id == child.info.run_id and stopped.value.marked
    assert disk.sentence(stopped.value).startswith(
        "the disk is full (No space left on device: model/model.zip); run "
        f"{child.info.run_id} is marked FAILED"
    )
    statuses = {r[0]: r[1] for s in ("pipeline", "train") for r in runs_of(tmp_path / "runs", s)}
    assert statuses == {outer.info.run_id: "FAILED", child.info.run_id: "FAILED"}
