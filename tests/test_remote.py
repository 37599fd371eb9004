"""A store across the network held to ``tracking.timeout_s`` (`armexp.tracking.remote`): MLflow's
retry settings derived from it, a database that is not there (or has no driver) as one
sentence, and `armexp ui` on a port another program holds."""

from __future__ import annotations

import importlib.util
import os
import socket
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from armexp.cli import main
from tests.cluster import free_port

SIMULATE = ["simulate", "scenario=hold", "scenario.duration=0.05"]


@pytest.mark.parametrize("timeout_s", [5, 6, 10, 30, 60, 120, 600, 3600])
def test_mlflows_retries_fit_in_the_deadline_and_within_mlflows_limits(timeout_s: int) -> None:
    from armexp.tracking import remote

    retries, factor, attempt = remote.schedule(timeout_s)
    waits = sum(min(remote.WAIT_MAX_S, factor * 2**k) for k in range(1, retries))
    # Every wait between attempts, and every attempt waiting its longest, within the deadline.
    assert waits + (retries + 1) * attempt <= timeout_s
    assert waits <= timeout_s / 2  # a server restarting is waited for: half the deadline
    assert remote.RETRIES <= retries <= 10 and 0 <= factor <= 120 and attempt >= 1


def test_the_deadline_sets_mlflows_settings_for_one_command(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from armexp.tracking import remote

    remote.reset()  # what an earlier command in this process may have left
    monkeypatch.setenv("MLFLOW_HTTP_REQUEST_TIMEOUT", "99")
    remote.configure(60)
    try:
        assert os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"] == "4"
        assert os.environ["MLFLOW_HTTP_REQUEST_BACKOFF_FACTOR"] == "2"
        assert os.environ["MLFLOW_HTTP_REQUEST_TIMEOUT"] == "6"
        remote.hurry()  # a signal: one short attempt each from now on
        assert os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"] == "0"
        assert os.environ["MLFLOW_HTTP_REQUEST_TIMEOUT"] == "5"
        remote.configure(60)  # a later look-up in the same command does not undo it
        assert os.environ["MLFLOW_HTTP_REQUEST_MAX_RETRIES"] == "0"
    finally:
        remote.reset()
    assert os.environ["MLFLOW_HTTP_REQUEST_TIMEOUT"] == "99"
    assert "MLFLOW_HTTP_REQUEST_MAX_RETRIES" not in os.environ


@pytest.mark.parametrize("value", ["0", "4", "-1", "1e9", "abc"])
def test_a_timeout_outside_its_range_is_one_sentence(
    value: str, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([*SIMULATE, f"tracking.timeout_s={value}", f"tracking.runs_dir={runs_dir}"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("armexp simulate: tracking.timeout_s=") and "not allowed" in line
    if value != "abc":
        assert line.endswith("it must lie in [5, 3600].")
    assert not (runs_dir / "mlflow.db").exists()


HAS_PSYCOPG2 = importlib.util.find_spec("psycopg2") is not None


def _dead_postgres() -> str:
    return f"postgresql+psycopg2://u:secret@127.0.0.1:{free_port()}/db"


@pytest.mark.skipif(not HAS_PSYCOPG2, reason="PostgreSQL's driver (armexp[server]) missing")
def test_a_postgres_store_with_nothing_listening_is_one_sentence_at_once(
    runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Was: 111 s of MLflow's retries, then a 214-line traceback, exit 1."""
    uri = _dead_postgres()
    rc = main([*SIMULATE, f"tracking.uri={uri}", f"tracking.runs_dir={runs_dir}"])
    err = capsys.readouterr().err.strip().splitlines()
    shown = uri.replace(":secret@", ":***@")
    assert rc == 2
    assert err == [
        f"armexp simulate: tracking.uri={shown} is not allowed now: armexp cannot connect to its "
        "database (connection refused); start the database, or correct the address or the "
        "credentials."
    ]


def test_a_postgres_store_without_its_driver_is_one_sentence(
    runs_dir: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Was: a traceback ending in ModuleNotFoundError, exit 1."""
    monkeypatch.setitem(sys.modules, "psycopg2", None)  # as if not installed
    uri = _dead_postgres()
    rc = main([*SIMULATE, f"tracking.uri={uri}", f"tracking.runs_dir={runs_dir}"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert err == [
        f"armexp simulate: tracking.uri={uri.replace(':secret@', ':***@')} is not allowed here: "
        "its database driver psycopg2 is not installed; install psycopg2-binary (pip install "
        "'armexp[server]') and run again."
    ]


@pytest.fixture
def silent_listener() -> Iterator[int]:
    """A port that takes connections and never answers (a database that hangs)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen(8)
        yield int(s.getsockname()[1])


@pytest.mark.skipif(not HAS_PSYCOPG2, reason="PostgreSQL's driver (armexp[server]) missing")
def test_a_database_that_never_answers_is_given_up_after_tracking_timeout_s(
    silent_listener: int, runs_dir: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    uri = f"postgresql+psycopg2://u@127.0.0.1:{silent_listener}/db"
    rc = main([*SIMULATE, f"tracking.uri={uri}", "tracking.timeout_s=5",
               f"tracking.runs_dir={runs_dir}"])  # fmt: skip
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert "cannot connect to its database (no answer within 5 s)" in line


def test_ui_on_a_port_another_program_listens_on_is_one_sentence(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Was: exit 0 after printing a link that opened the other program."""
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen(1)
        port = int(taken.getsockname()[1])
        rc = main(["ui", f"ui.port={port}", f"tracking.runs_dir={tmp_path / 'runs'}"])
    captured = capsys.readouterr()
    (line,) = captured.err.strip().splitlines()
    assert rc == 2
    assert line.startswith(
        f"armexp ui: ui.port={port} is not allowed now: another program already listens on "
        f"127.0.0.1:{port}; stop it, or choose a free port (ui.port="
    )
    assert "open http" not in captured.out
