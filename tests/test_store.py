"""A store is a folder: copied (``cp -a``), moved (``mv``), archived (``tar``), replaced by a new
folder at its old path, read-only or busy, it keeps every run readable and writes new artifacts
inside itself (README, Looking at runs)."""

from __future__ import annotations

import os
import shutil
import sqlite3
import subprocess
import sys
import tarfile
import threading
from pathlib import Path

import pytest
from mlflow.tracking import MlflowClient

from armexp.cli import main
from armexp.tracking import anchor, store
from armexp.tracking.tags import ANCHOR_TAG
from tests.helpers import SMALL_TRAIN, stage_runs

SIM = ["simulate", "scenario=hold", "scenario.duration=0.05"]


def fresh() -> None:
    """Forget what this test process knows about stores, as a new ``armexp`` command would:
    the stores it opened, MLflow's database engines and its cache of artifact locations."""
    from mlflow.store.tracking.sqlalchemy_store import SqlAlchemyStore
    from mlflow.tracking._tracking_service import utils

    store._opened.clear()
    utils._tracking_store_registry._get_store_with_resolved_uri.cache_clear()
    for engine in SqlAlchemyStore._engine_map.values():
        engine.dispose()
    SqlAlchemyStore._engine_map.clear()
    utils._artifact_repos_cache.clear()


def run_in(runs: Path, *args: str) -> int:
    fresh()
    return main([*args, f"tracking.runs_dir={runs}"])


def simulate(runs: Path, seed: int = 0) -> str:
    assert run_in(runs, *SIM, f"seed={seed}") == 0
    return str(stage_runs(runs, "simulate")[0].info.run_id)


def client_of(runs: Path) -> MlflowClient:
    return MlflowClient(f"sqlite:///{runs / 'mlflow.db'}")


def readable(runs: Path, run_id: str, tmp: Path, path: str = "config.yaml") -> Path:
    """The artifact ``path`` of ``run_id``, read through the store at ``runs`` as armexp does."""
    fresh()
    client = client_of(runs)
    uri = client.get_run(run_id).info.artifact_uri
    assert uri.startswith((runs / "artifacts").as_uri()), uri
    dst = tmp / f"dl-{run_id}-{len(list(tmp.glob('dl-*')))}"
    dst.mkdir()
    return Path(client.download_artifacts(run_id, path, str(dst)))


def folders(runs: Path) -> set[str]:
    root = runs / "artifacts"
    return {p.name for p in root.iterdir()} if root.is_dir() else set()


@pytest.mark.slow
def test_a_copied_project_trains_into_itself_and_outlives_the_original(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """``cp -a proj proj2; cd proj2; armexp train …; rm -rf proj; armexp eval …``."""
    proj, copy = tmp_path / "proj", tmp_path / "proj2"
    train = ["train", "controller.gains=paper", *SMALL_TRAIN]
    assert run_in(proj / "runs", *train) == 0
    (first,) = [r.info.run_id for r in stage_runs(proj / "runs", "train")]
    shutil.copytree(proj, copy, symlinks=True)  # cp -a
    assert run_in(copy / "runs", *train, "seed=1") == 0
    second = stage_runs(copy / "runs", "train")[0].info.run_id
    assert folders(copy / "runs") == {first, second}
    assert folders(proj / "runs") == {first}  # the original got nothing of the copy's
    assert [r.info.run_id for r in stage_runs(proj / "runs", "train")] == [first]
    shutil.rmtree(proj)
    for run_id in (first, second):
        assert readable(copy / "runs", run_id, tmp_path, "model/model.zip").stat().st_size > 0
    baseline = ["eval.baselines=[pid_gaing]", "eval.baseline_gains=config", "tasks.n_random=0"]
    assert run_in(copy / "runs", "eval", f"eval.train_run={second}", *baseline) == 0
    (ev,) = stage_runs(copy / "runs", "eval")
    assert ev.info.status == "FINISHED" and ev.info.run_id in folders(copy / "runs")
    capsys.readouterr()
    play = ["play", f"play.train_run={first}", "play.tasks=[c]", "play.targets=[[1.2,0.5]]"]
    assert run_in(copy / "runs", *play) == 0
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert f" in {copy / 'runs' / 'artifacts'}" in line, line


@pytest.mark.slow
def test_a_new_folder_at_a_moved_projects_old_path_leaves_both_whole(tmp_path: Path) -> None:
    """``mv c47 c47_v1; mkdir c47; (cd c47; armexp simulate …)``: each store keeps its own."""
    old, kept = tmp_path / "c47", tmp_path / "c47_v1"
    a = simulate(old / "runs")
    old.rename(kept)
    old.mkdir()
    b = simulate(old / "runs", seed=1)
    c = simulate(kept / "runs", seed=2)
    assert folders(old / "runs") == {b}
    assert folders(kept / "runs") == {a, c}
    for runs, run_id in ((kept / "runs", a), (kept / "runs", c), (old / "runs", b)):
        assert readable(runs, run_id, tmp_path).read_text().startswith("seed:")


@pytest.mark.long
def test_an_archived_store_unpacked_elsewhere_reads_and_writes_in_place(tmp_path: Path) -> None:
    proj = tmp_path / "proj"
    a = simulate(proj / "runs")
    archive = tmp_path / "proj.tar.gz"
    with tarfile.open(archive, "w:gz") as tar:
        tar.add(proj, arcname="proj")
    shutil.rmtree(proj)
    with tarfile.open(archive) as tar:
        # Extraction filters came with 3.11.4; an earlier 3.11 extracts as "tar" would.
        safe = {"filter": "tar"} if hasattr(tarfile, "tar_filter") else {}
        tar.extractall(tmp_path / "restored", **safe)  # type: ignore[arg-type]
    runs = tmp_path / "restored" / "proj" / "runs"
    b = simulate(runs, seed=1)
    assert folders(runs) == {a, b}
    assert readable(runs, a, tmp_path).is_file() and readable(runs, b, tmp_path).is_file()
    assert not proj.exists()


def _make_old(runs: Path) -> None:
    """The store as armexp wrote it before locations followed the store: no anchor tag."""
    with sqlite3.connect(runs / "mlflow.db") as con:
        con.execute("DELETE FROM experiment_tags WHERE key = ?", (ANCHOR_TAG,))


@pytest.mark.long
def test_an_old_absolute_store_is_migrated_when_opened_after_a_copy(tmp_path: Path) -> None:
    proj, copy = tmp_path / "proj", tmp_path / "proj2"
    a = simulate(proj / "runs")
    _make_old(proj / "runs")
    shutil.copytree(proj, copy, symlinks=True)
    b = simulate(copy / "runs", seed=1)
    assert folders(copy / "runs") == {a, b} and folders(proj / "runs") == {a}
    fresh()
    exp = client_of(copy / "runs").get_experiment_by_name("armexp")
    assert exp is not None and exp.tags[ANCHOR_TAG] == anchor.STORE
    assert exp.artifact_location == (copy / "runs" / "artifacts").as_uri()
    shutil.rmtree(proj)
    assert readable(copy / "runs", a, tmp_path).is_file()


@pytest.mark.long
def test_an_old_store_keeps_artifacts_an_earlier_armexp_wrote_into_its_original(
    tmp_path: Path,
) -> None:
    """What the copy wrote into the original before this release is copied back into it."""
    proj, copy = tmp_path / "proj", tmp_path / "proj2"
    simulate(proj / "runs")
    _make_old(proj / "runs")
    shutil.copytree(proj, copy, symlinks=True)
    b = simulate(proj / "runs", seed=1)  # stands for a run the copy logged into the original
    with sqlite3.connect(copy / "runs" / "mlflow.db") as con:
        src = sqlite3.connect(proj / "runs" / "mlflow.db")
        row = src.execute("SELECT * FROM runs WHERE run_uuid = ?", (b,)).fetchone()
        con.execute(f"INSERT INTO runs VALUES ({','.join('?' * len(row))})", row)
        src.close()
    simulate(copy / "runs", seed=2)
    shutil.rmtree(proj)
    assert readable(copy / "runs", b, tmp_path).is_file()


@pytest.mark.long
@pytest.mark.parametrize("spelt", ["path", "uri"])
def test_an_artifact_root_of_the_users_choosing_stays_where_it_is(
    tmp_path: Path, spelt: str
) -> None:
    """A folder named ``artifacts`` without a store beside it is still the user's choice."""
    root = tmp_path / "big_disk" / "artifacts"
    given = root.as_uri() if spelt == "uri" else str(root)
    proj, moved = tmp_path / "proj", tmp_path / "proj2"
    assert run_in(proj / "runs", *SIM, f"tracking.artifact_root={given}") == 0
    a = stage_runs(proj / "runs", "simulate")[0].info.run_id
    proj.rename(moved)
    b = simulate(moved / "runs", seed=1)
    assert {p.name for p in root.iterdir()} == {a, b} and folders(moved / "runs") == set()
    exp = client_of(moved / "runs").get_experiment_by_name("armexp")
    assert exp is not None and anchor.local_path(exp.artifact_location) == root


@pytest.mark.long
def test_an_old_store_with_a_chosen_root_is_not_re_anchored(tmp_path: Path) -> None:
    root = tmp_path / "big_disk" / "artifacts"
    proj, moved = tmp_path / "proj", tmp_path / "proj2"
    assert run_in(proj / "runs", *SIM, f"tracking.artifact_root={root.as_uri()}") == 0
    _make_old(proj / "runs")
    proj.rename(moved)
    simulate(moved / "runs", seed=1)
    fresh()
    exp = client_of(moved / "runs").get_experiment_by_name("armexp")
    assert exp is not None and exp.artifact_location == root.as_uri()
    assert exp.tags[ANCHOR_TAG] == anchor.GIVEN
    assert {p.name for p in root.iterdir()} == {
        r.info.run_id for r in stage_runs(moved / "runs", "simulate")
    }


@pytest.mark.long
def test_a_changed_artifact_root_on_an_existing_store_is_one_sentence(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    simulate(runs)
    capsys.readouterr()
    other = tmp_path / "elsewhere"
    assert run_in(runs, *SIM, f"tracking.artifact_root={other}") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"tracking.artifact_root={other} is not allowed" in err[0]
    assert str(runs / "artifacts") in err[0] and "tracking.experiment" in err[0]
    assert len(stage_runs(runs, "simulate")) == 1 and not other.exists()


@pytest.mark.long
@pytest.mark.parametrize("value", ["~/x", "'~/x'"])  # as the shell passes it, Hydra-quoted
def test_a_tilde_runs_dir_is_the_home_folder(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, value: str
) -> None:
    home, work = tmp_path / "home", tmp_path / "work"
    home.mkdir()
    work.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(work)
    fresh()
    assert main([*SIM, f"tracking.runs_dir={value}"]) == 0
    assert (home / "x" / "mlflow.db").is_file() and (home / "x" / "hydra").is_dir()
    assert list(work.iterdir()) == []


def test_an_unknown_users_tilde_is_one_sentence(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    assert main([*SIM, "tracking.runs_dir=~no_such_user_armexp/x"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tracking.runs_dir=~no_such_user_armexp/x is not allowed" in err[0]
    assert list(tmp_path.iterdir()) == []


def test_an_empty_runs_dir_is_one_sentence(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """Not a store in the working folder and Hydra's folders in /hydra."""
    monkeypatch.chdir(tmp_path)
    assert main([*SIM, "tracking.runs_dir=''"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "tracking.runs_dir='' is not allowed: it names no folder" in err[0]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("key", ["report.out_dir", "tracking.runs_dir"])
def test_a_path_with_a_name_too_long_is_one_sentence(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], key: str
) -> None:
    monkeypatch.chdir(tmp_path)
    value = str(tmp_path / ("r" * 300))
    assert main(["report", f"{key}={value}"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"{key}={value} is not allowed" in err[0] and "255" in err[0]


def test_diff_in_a_folder_without_a_store_creates_none(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.chdir(tmp_path)
    fresh()
    assert main(["diff", "0123abcd", "4567ef01"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"tracking.runs_dir={tmp_path / 'runs'}" in err[0]
    assert "no MLflow store" in err[0]
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("flags", [["--cfg", "job"], ["-m"], ["--help"]])
def test_diff_refuses_flags_it_does_not_have(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    flags: list[str],
) -> None:
    monkeypatch.chdir(tmp_path)
    code = main(["diff", *flags])
    out, err = capsys.readouterr()
    if flags == ["--help"]:
        assert code == 0 and "usage: armexp diff" in out
    else:
        assert code == 2 and len(err.strip().splitlines()) == 1
        assert f"{flags[0]} is not an option of armexp diff" in err
    assert list(tmp_path.iterdir()) == []


def _as_reader(command: list[str]) -> list[str]:
    """``command`` run so that permission bits bind (root drops CAP_DAC_OVERRIDE)."""
    if os.geteuid() != 0:
        return command
    if shutil.which("setpriv") is None:
        pytest.skip("running as root without setpriv (util-linux) to drop CAP_DAC_OVERRIDE")
    return ["setpriv", "--bounding-set=-dac_override,-dac_read_search", *command]


@pytest.mark.slow
def test_a_read_only_store_still_answers_diff_and_cfg_job(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    a, b = simulate(runs), simulate(runs, seed=1)
    before = sorted((str(p.relative_to(runs)), p.stat().st_mtime_ns) for p in runs.rglob("*"))
    for path in [runs, *runs.rglob("*")]:
        path.chmod(path.stat().st_mode & ~0o222)
    where = f"tracking.runs_dir={runs}"
    try:
        diff = subprocess.run(_as_reader([sys.executable, "-m", "armexp", "diff", a, b, where]),
                              capture_output=True, text=True, timeout=300)  # fmt: skip
        show = subprocess.run(
            _as_reader([sys.executable, "-m", "armexp", "simulate", "--cfg", "job", where]),
            capture_output=True, text=True, timeout=300,
        )  # fmt: skip
    finally:
        for path in [runs, *runs.rglob("*")]:
            path.chmod(path.stat().st_mode | 0o200)
    assert diff.returncode == 0, diff.stderr[-2000:]
    assert "config:" in diff.stdout and "seed" in diff.stdout
    assert show.returncode == 0, show.stderr[-2000:]
    assert "seed: 0" in show.stdout
    after = sorted((str(p.relative_to(runs)), p.stat().st_mtime_ns) for p in runs.rglob("*"))
    assert after == before


def _hold(db: Path, release: threading.Event) -> threading.Thread:
    """Another writer: an exclusive transaction on ``db`` until ``release`` is set."""
    held = threading.Event()

    def writer() -> None:
        con = sqlite3.connect(db, isolation_level=None)
        con.execute("BEGIN EXCLUSIVE")
        held.set()
        release.wait(60)
        con.execute("COMMIT")
        con.close()

    thread = threading.Thread(target=writer, daemon=True)
    thread.start()
    assert held.wait(30)
    return thread


@pytest.mark.long
def test_a_store_busy_with_another_writer_says_so_and_is_not_called_damaged(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    simulate(runs)
    capsys.readouterr()
    monkeypatch.setattr(store, "BUSY_WAIT_S", 0.0)
    release = threading.Event()
    writer = _hold(runs / "mlflow.db", release)
    try:
        assert run_in(runs, *SIM, "seed=1") == 2
    finally:
        release.set()
        writer.join()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "busy" in err[0] and "another process" in err[0]
    assert "backup" not in err[0] and "move it aside" not in err[0]
    assert len(stage_runs(runs, "simulate")) == 1


@pytest.mark.slow
def test_a_store_busy_for_a_while_is_waited_for(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    runs = tmp_path / "runs"
    simulate(runs)
    release = threading.Event()
    writer = _hold(runs / "mlflow.db", release)
    # The writer ends while armexp waits, after SQLite's own 5 s wait on a lock has run out.
    timer = threading.Timer(8.0, release.set)
    timer.start()
    try:
        assert run_in(runs, *SIM, "seed=1") == 0
    finally:
        release.set()
        writer.join()
    assert len(stage_runs(runs, "simulate")) == 2


@pytest.mark.long
def test_an_artifacts_folder_that_cannot_be_written_is_one_sentence(tmp_path: Path) -> None:
    runs = tmp_path / "runs"
    simulate(runs)
    (runs / "artifacts").chmod(0o555)
    try:
        command = [sys.executable, "-m", "armexp", *SIM, f"tracking.runs_dir={runs}"]
        done = subprocess.run(_as_reader(command), capture_output=True, text=True, timeout=300)
    finally:
        (runs / "artifacts").chmod(0o755)
    err = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(err) == 1, done.stderr[-2000:]
    assert f"armexp cannot write in {runs / 'artifacts'} (Permission denied)" in err[0]
    assert len(stage_runs(runs, "simulate")) == 1


def test_an_old_experiment_without_runs_is_classified_by_its_location(tmp_path: Path) -> None:
    """No run folder says where its artifacts are: another store's folder, or one that is gone,
    was armexp's default; an existing folder of another name or kind is the user's."""
    other = tmp_path / "other" / "runs"
    (other / "artifacts").mkdir(parents=True)
    (other / "mlflow.db").touch()
    mine = tmp_path / "mine" / "artifacts"
    mine.mkdir(parents=True)
    db = tmp_path / "here" / "runs" / "mlflow.db"
    db.parent.mkdir(parents=True)
    client = MlflowClient(f"sqlite:///{db}")
    cases = {
        (other / "artifacts").as_uri(): anchor.STORE,
        (tmp_path / "gone" / "runs" / "artifacts").as_uri(): anchor.STORE,
        mine.as_uri(): anchor.GIVEN,
        (tmp_path / "mine").as_uri(): anchor.GIVEN,
        "s3://bucket/artifacts": anchor.GIVEN,
        (db.parent / "artifacts").as_uri(): anchor.STORE,
    }
    ids = {loc: int(client.create_experiment(f"e{i}", loc)) for i, loc in enumerate(cases)}
    with sqlite3.connect(db) as con:
        got = {loc: anchor.classify(con, i, loc, db) for loc, i in ids.items()}
    assert got == cases
