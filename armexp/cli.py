"""The ``armexp`` command: dispatches ``armexp <stage> [overrides] [hydra flags]`` to Hydra apps.

Every stage is a Hydra application over the same config tree (``conf/``), so Hydra's grammar
works unchanged: ``armexp simulate controller=pid``, ``armexp tune -m tuner.seed=0,1,2``,
``armexp simulate --cfg job``. Before Hydra runs, the overrides (every combination of a sweep)
are composed and validated, so a bad value stops with one sentence and exit code 2 instead of a
traceback.
"""

from __future__ import annotations

import contextlib
import importlib
import logging
import os
import sys
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from armexp.console import quiet_warnings
from armexp.precheck import precheck

EXIT_USAGE = 2

# stage -> (module with `run(cfg)`, one-line help).
STAGES: dict[str, tuple[str, str]] = {
    "simulate": ("armexp.stages.simulate", "one closed-loop run of a controller, no agent"),
    "tune": ("armexp.stages.tune", "cuckoo search (Algorithm 2) of the controller gains"),
    "train": (
        "armexp.stages.train",
        "SAC training of the motion planner with the controller in the loop",
    ),
    "eval": (
        "armexp.stages.evaluate",
        "tasks (a)-(d) and held-out targets, proposed controller and PID",
    ),
    "play": ("armexp.stages.play", "a trained policy on chosen tasks and targets, animated"),
    "report": ("armexp.stages.report", "Tables I-III and Figures 3-6 from stored runs"),
    "pipeline": ("armexp.stages.study", "tune -> train -> eval -> report under one parent run"),
    "ui": ("armexp.stages.ui", "open the MLflow UI on the configured store"),
    "hpo": ("armexp.stages.hpo", "hyperparameter search of the agent (Optuna, pruned trials)"),
}

# The Hydra flags whose meaning armexp acts on (long and short spellings, as `--hydra-help`
# lists them); every other flag is passed to Hydra untouched.
MULTIRUN_FLAGS = {"--multirun", "-m"}
SHOW_CONFIG_FLAGS = {"--cfg", "-c"}
CONFIG_DIR_FLAGS = {"--config-dir", "-cd"}
# These print and exit without running a job, so the overrides are not checked first.
INFO_FLAGS = {"--help", "-h", "--hydra-help", "--info", "-i", "--shell-completion", "-sc",
              "--version"}  # fmt: skip


def _swept_override(overrides: Sequence[str]) -> str:
    """``tracking.swept=[…]``: the keys the sweep varies, handed to every job through the
    config (jobs on other processes or machines see it) for their run names."""
    from armexp import sweeps

    keys = sorted(sweeps.swept_keys(overrides))
    return "tracking.swept=[" + ",".join(f"'{k}'" for k in keys) + "]"


def usage() -> str:
    lines = [
        "usage: armexp <stage> [key=value ...] [-m] [--cfg job] [--help]",
        "",
        "Stages (each a Hydra app; `armexp <stage> --help` shows its config groups):",
    ]
    lines += [f"  {name:<9} {text}" for name, (_, text) in STAGES.items()]
    lines += [
        "",
        "Examples:",
        "  armexp simulate controller=pid scenario=hold",
        "  armexp tune tuner=cso_fast",
        "  armexp tune -m controller=subsystem_adaptive,pid",
        "  armexp train agent=sac_quick            # gains from the latest tune run",
        "  armexp train controller.gains=paper     # the paper's gains, no tune run needed",
        "  armexp eval tasks.n_random=100",
        "  armexp play play.targets=[[1.2,0.5]]  # GIF and MP4 of each episode",
        "  armexp hpo hpo=plain_sac               # Optuna search, resumed by the same command",
        "  armexp diff <run id> <run id>         # config, metrics, code and versions",
        "Outputs: MLflow store runs/mlflow.db (view with `armexp ui`).",
    ]
    return "\n".join(lines)


@dataclass
class CommandLine:
    """A stage's arguments: Hydra's flags (with their values) and the config overrides."""

    flags: list[str] = field(default_factory=list)
    overrides: list[str] = field(default_factory=list)

    def _named(self, names: set[str]) -> bool:
        return any(f.partition("=")[0] in names for f in self.flags)

    @property
    def multirun(self) -> bool:
        return self._named(MULTIRUN_FLAGS)

    @property
    def shows_config(self) -> bool:
        return self._named(SHOW_CONFIG_FLAGS)

    @property
    def runs_no_job(self) -> bool:
        return self._named(INFO_FLAGS)

    def config_dirs(self) -> list[str]:
        """The folders of ``--config-dir DIR`` / ``-cd=DIR``."""
        dirs = []
        for i, flag in enumerate(self.flags):
            name, eq, value = flag.partition("=")
            if name in CONFIG_DIR_FLAGS:
                value = value if eq else (self.flags[i + 1] if i + 1 < len(self.flags) else "")
                dirs.append(value)
        return [d for d in dirs if d]


def split_args(args: Sequence[str]) -> CommandLine:
    """Flags and overrides as Hydra tells them apart: an argument starting with ``-`` is a flag;
    one that Hydra's override grammar parses is an override; any other follows a flag as its
    value (``--cfg job``, ``--config-dir DIR``). An argument that is none of these, or that has
    an ``=`` and does not parse, is a malformed override, reported as one sentence
    (`ConfigError`)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import OverrideParseException

    from armexp.config.errors import translate_error

    parser = OverridesParser.create()
    line = CommandLine()
    after_flag = False
    for arg in args:
        if arg.startswith("-"):
            line.flags.append(arg)
            after_flag = "=" not in arg
            continue
        try:
            parser.parse_overrides([arg])
        except OverrideParseException as exc:
            if not after_flag or "=" in arg:
                raise translate_error(exc) from None
            line.flags.append(arg)
        else:
            line.overrides.append(arg)
        after_flag = False
    return line


def _search_path(line: CommandLine) -> list[str]:
    """``--config-dir`` as the override the pre-run check composes with, so the check sees the
    same config groups as the run."""
    dirs = [f"file://{os.path.abspath(d)}" for d in line.config_dirs()]
    return [f"hydra.searchpath=[{','.join(dirs)}]"] if dirs else []


def _without_credentials(overrides: list[str]) -> list[str]:
    """A password in ``tracking.uri`` is taken out before Hydra, MLflow params, configs and
    printed lines see it (`armexp.store.keep_credentials_out`)."""
    from armexp.store import keep_credentials_out

    out = []
    for override in overrides:
        key, eq, value = override.partition("=")
        if eq and key.lstrip("+~") == "tracking.uri":
            override = f"{key}={keep_credentials_out(value)}"
        out.append(override)
    return out


def imply_gains_source(stage: str, overrides: list[str]) -> list[str]:
    """``controller.gains=<preset>`` (or ``controller.gains.a0=…``) on a train command means
    "train with these gains", not "with a tune run's": add ``train.gains=config`` unless the
    user chose ``train.gains`` themselves."""
    if stage not in ("train", "pipeline") or any(o.startswith("train.gains=") for o in overrides):
        return overrides
    keys = [o.lstrip("+~").partition("=")[0] for o in overrides]
    if any(k in ("controller.gains", "controller/gains") or k.startswith("controller.gains.")
           for k in keys):  # fmt: skip
        return [*overrides, "train.gains=config"]
    return overrides


def run_stage(stage: str, args: Sequence[str]) -> int:
    from armexp.config import (
        ConfigError,
        config_dir,
        expand_home,
        normalize_overrides,
        register_schemas,
    )

    try:
        line = split_args([expand_home(a) for a in args])
        overrides = _without_credentials(imply_gains_source(stage, line.overrides))
        if stage == "hpo" and not line.multirun:
            from armexp.hpo.space import as_params

            overrides = as_params(overrides)
        if not line.runs_no_job:
            overrides = precheck(
                stage, overrides, line.multirun, _search_path(line), not line.shows_config
            )
            if line.multirun and not line.shows_config:
                from armexp.launchers import check_launcher

                check_launcher(overrides)
        plan = None
        if line.multirun and not line.runs_no_job and not line.shows_config:
            from armexp.hpo import sweep as optuna_sweep

            if optuna_sweep.chosen(overrides):
                plan = optuna_sweep.prepare(stage, overrides, _search_path(line))
    except ConfigError as exc:
        print(f"armexp {stage}: {exc}", file=sys.stderr)
        return EXIT_USAGE
    task: Callable[[Any], Any] = importlib.import_module(STAGES[stage][0]).run

    import hydra

    from armexp import disk, remote, signals, sweeps, workers
    from armexp.launchers import register_plugins

    def job(cfg: Any) -> Any:
        quiet_warnings()  # again here: a sweep's jobs may run in worker processes
        with workers.job():
            return checked_job(cfg)

    def checked_job(cfg: Any) -> Any:
        from armexp.config import validate as check

        try:
            check(cfg, stage)
        except ConfigError as exc:
            print(f"armexp {stage}: {exc}", file=sys.stderr)
            raise SystemExit(EXIT_USAGE) from None
        try:
            return task(cfg)
        except ConfigError as exc:  # e.g. a missing upstream run found only at run time
            print(f"armexp {stage}: {exc}", file=sys.stderr)
            raise SystemExit(EXIT_USAGE) from None
        except Exception as exc:
            if disk.is_full(exc):
                print(f"armexp {stage}: {disk.sentence(exc)}", file=sys.stderr)
            elif remote.is_lost(exc):
                print(f"armexp {stage}: {remote.lost_sentence(exc, cfg.tracking.uri)}",
                      file=sys.stderr)  # fmt: skip
            else:
                raise
            raise SystemExit(1) from None

    register_schemas()
    register_plugins()
    # Launcher configs named like their plugin's schema (conf/hydra/launcher/ray.yaml) are
    # validated against it, which is what they are written for; Hydra warns about the match.
    warnings.filterwarnings("ignore", message=r"(?s).*validated against ConfigStore schema")
    runs_jobs = line.multirun and not line.runs_no_job and not line.shows_config
    sweep = (
        sweeps.open_sweep(stage, overrides, _search_path(line), *_hpo_run(plan))
        if runs_jobs
        else None
    )
    # `hydra.main` reads its command line from sys.argv only (it has no parameter for one), and
    # its parser wants the overrides as one block after the flags. The sweep run's id goes
    # through the config, so jobs on other processes or machines (joblib, SLURM, Ray) see it.
    sweep_overrides = (
        [f"tracking.sweep_run={sweep[1]}", _swept_override(overrides)] if sweep else []
    )
    if plan is not None:  # the Optuna sweeper's study, as the checks before the sweep found it
        sweep_overrides += plan.overrides()
    sys.argv = [
        f"armexp {stage}",
        *line.flags,
        # The sweep's run id through the same quoting as any run id (`config.run_keys`).
        *normalize_overrides([*overrides, *sweep_overrides]),
        f"hydra.job.name={stage}",
    ]
    app = hydra.main(config_path=str(config_dir()), config_name="config", version_base="1.3")(job)
    restore = signals.install()
    workers.mark_command()
    status = "FAILED"
    beat = contextlib.nullcontext() if sweep is None else sweep[2]
    try:
        with beat:  # the sweep run's heartbeat, while its jobs run
            app()
        status = "FINISHED"
    except SystemExit as exc:  # a user error found at run time (exit 2), or Hydra's own exit
        code = exc.code
        code = code if isinstance(code, int) else (0 if code is None else 1)
        status = "FINISHED" if code == 0 else "FAILED"
        return code
    except KeyboardInterrupt as exc:
        status = "KILLED"
        print(f"armexp {stage}: {signals.what()}; {_stopped(exc, sweep is not None)}",
              file=sys.stderr)  # fmt: skip
        return signals.exit_code()
    finally:
        try:
            if sweep is not None:
                _close_sweep(stage, sweep, status)
        finally:
            restore()
            remote.reset()
    return 0


def _hpo_run(plan: Any) -> tuple[str | None, dict[str, str] | None, str | None]:
    """The HPO run an Optuna sweep reopens (None: a new one), its tags and its name."""
    return (None, None, None) if plan is None else (plan.hpo_run, plan.tags, plan.name)


def _close_sweep(stage: str, sweep: Any, status: str) -> None:
    """End the sweep run with ``status``; when its store does not answer, or a second signal
    stops this, say what is left."""
    from armexp import remote, sweeps

    try:
        sweeps.close_sweep(sweep, status)
    except BaseException as exc:
        if not (isinstance(exc, KeyboardInterrupt) or remote.is_lost(exc)):
            raise
        why = "interrupted again" if isinstance(exc, KeyboardInterrupt) else remote.reason(exc)
        print(
            f"armexp {stage}: sweep run {sweep[1]} could not be marked {status} ({why}): it "
            "stays RUNNING in the store until the next armexp command against that store marks "
            "it FAILED.",
            file=sys.stderr,
        )


def _stopped(exc: KeyboardInterrupt, sweep: bool) -> str:
    """What became of the run a signal stopped."""
    from armexp.tracking import RunInterrupted

    if isinstance(exc, RunInterrupted) and exc.unmarked:
        return (
            f"run {exc.run_id} could not be marked KILLED ({exc.unmarked}): it stays RUNNING in "
            "the store until the next armexp command against that store marks it FAILED."
        )
    if isinstance(exc, RunInterrupted) or sweep:
        return "the MLflow run is marked KILLED."
    return "no run was started."


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    os.environ.setdefault("HYDRA_FULL_ERROR", "0")
    # A log file that cannot be written (a full disk) must not print a traceback per record.
    logging.raiseExceptions = False
    quiet_warnings()
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    stage, rest = args[0], args[1:]
    if stage == "diff":  # not a Hydra app: it reads two runs, it runs nothing
        from armexp import diff

        return diff.main(rest)
    if stage not in STAGES:
        print(
            f"armexp: stage={stage} is not a known stage; choose one of: "
            f"{', '.join([*STAGES, 'diff'])}.",
            file=sys.stderr,
        )
        return EXIT_USAGE
    return run_stage(stage, rest)


if __name__ == "__main__":
    sys.exit(main())
