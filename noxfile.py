"""Developer sessions: ``nox -s tests lint typecheck bench browser scale``."""

from __future__ import annotations

import nox

nox.options.sessions = ["tests", "lint", "typecheck"]
INSTALL = ("-c", "constraints.txt", "-e", ".[dev]")


@nox.session
def tests(session: nox.Session) -> None:
    """The default (quick) test suite; pass ``-- -m long`` or ``-- -m slow`` for the longer ones."""
    session.install(*INSTALL)
    session.run("pytest", *session.posargs)


@nox.session
def lint(session: nox.Session) -> None:
    session.install("ruff")
    session.run("ruff", "check", ".")
    session.run("ruff", "format", "--check", ".")


@nox.session
def typecheck(session: nox.Session) -> None:
    """mypy over what pyproject.toml's [tool.mypy] lists: armexp, tests, scripts, benchmarks
    and hydra_plugins."""
    session.install(*INSTALL)
    session.run("mypy")


@nox.session
def bench(session: nox.Session) -> None:
    """Print the performance figures named in the issues."""
    session.install("-c", "constraints.txt", "-e", ".[dev,bench]")
    session.run("python", "benchmarks/sim_speed.py")
    session.run("python", "benchmarks/tune_speed.py")
    session.run("python", "benchmarks/controller_check.py")
    session.run("python", "benchmarks/cso_quality.py")
    session.run("python", "benchmarks/env_speed.py")
    session.run("python", "benchmarks/update_speed.py")
    session.run("python", "benchmarks/report_speed.py")


@nox.session
def scale(session: nox.Session) -> None:
    """Sweeps on a real Ray cluster, through submitit, against `mlflow server` on PostgreSQL, and
    a worker SIGKILLed mid-sweep (root: each in a private network namespace; minutes), then the
    Ray-vs-joblib benchmark. Prints per sweep: points launched, how they ended, reuse, wall time."""
    session.install("-c", "constraints.txt", "-e", ".[dev,cluster]")
    # One process (-n 0): the cluster tests print what each sweep did, which workers would hide.
    session.run("pytest", "-m", "slow", "-n", "0", "-s", "-q", "-p", "no:warnings",
                "tests/test_cluster.py",
                *session.posargs)  # fmt: skip
    session.run("python", "benchmarks/ray_vs_joblib.py")


@nox.session
def competence(session: nox.Session) -> None:
    """Steps to competence of experiment=demo at seeds 0-2 and its step budget (about 15 minutes
    on 2 cores; --experiment quick --eval-every 40000 for sac_quick)."""
    session.install(*INSTALL)
    session.run("python", "benchmarks/time_to_competence.py", *session.posargs)


@nox.session
def browser(session: nox.Session) -> None:
    """A report folder (default runs/report) in headless Chromium: every image loads, every
    table has rows, screenshot in <folder>/screenshot.png (needs Debian's chromium)."""
    session.install(*INSTALL)
    session.run("python", "scripts/check_report.py", *(session.posargs or ["runs/report"]))
