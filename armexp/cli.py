"""The ``armexp`` command: dispatches ``armexp <stage> [overrides] [hydra flags]`` to Hydra apps.

Every stage is a Hydra application over the same config tree (``conf/``), so Hydra's grammar
works unchanged: ``armexp simulate controller=pid``, ``armexp tune -m tuner.seed=0,1,2``,
``armexp simulate --cfg job``. Before Hydra runs, the overrides (every combination of a sweep)
are composed and validated, so a bad value stops with one sentence and exit code 2 instead of a
traceback.
"""

from __future__ import annotations

import contextlib
import errno
import importlib
import os
import sys
import tempfile
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130

# stage -> (module with `run(cfg)`, one-line help); module None = not built yet.
STAGES: dict[str, tuple[str | None, str]] = {
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
    "report": ("armexp.stages.report", "Tables I-III and Figures 3-6 from stored runs"),
    "pipeline": ("armexp.stages.pipeline", "tune -> train -> eval -> report under one parent run"),
    "ui": ("armexp.stages.ui", "open the MLflow UI on the configured store"),
}

_VALUE_FLAGS = {
    "--cfg",
    "-c",
    "--package",
    "-p",
    "--config-path",
    "-cp",
    "--config-name",
    "-cn",
    "--config-dir",
    "-cd",
    "--experimental-rerun",
    "--info",
    "-i",
}
_NO_VALIDATE = {
    "--help",
    "-h",
    "--hydra-help",
    "--info",
    "-i",
    "--shell-completion",
    "-sc",
    "--version",
}


def usage() -> str:
    lines = [
        "usage: armexp <stage> [key=value ...] [-m] [--cfg job] [--help]",
        "",
        "Stages (each a Hydra app; `armexp <stage> --help` shows its config groups):",
    ]
    for name, (module, text) in STAGES.items():
        suffix = "" if module else "   [not built yet]"
        lines.append(f"  {name:<9} {text}{suffix}")
    lines += [
        "",
        "Examples:",
        "  armexp simulate controller=pid scenario=hold",
        "  armexp tune tuner=cso_fast",
        "  armexp tune -m controller=subsystem_adaptive,pid",
        "  armexp train agent=sac_quick            # gains from the latest tune run",
        "  armexp train controller.gains=paper     # the paper's gains, no tune run needed",
        "  armexp eval tasks.n_random=100",
        "Outputs: MLflow store runs/mlflow.db (view with `armexp ui`).",
    ]
    return "\n".join(lines)


def split_args(args: Sequence[str]) -> tuple[list[str], list[str], bool, bool]:
    """(flags with their values, overrides, multirun, validate) from Hydra's command line."""
    flags: list[str] = []
    overrides: list[str] = []
    multirun = False
    validate = True
    takes_value = False
    for a in args:
        if takes_value:
            flags.append(a)
            takes_value = False
            continue
        if a.startswith("-"):
            flags.append(a)
            multirun |= a in ("-m", "--multirun")
            validate &= a not in _NO_VALIDATE
            takes_value = a in _VALUE_FLAGS and "=" not in a
        else:
            overrides.append(a)
    return flags, overrides, multirun, validate


def _search_path(flags: Sequence[str]) -> list[str]:
    """``--config-dir DIR`` / ``-cd DIR`` as the override the pre-run check composes with, so
    the check sees the same config groups as the run."""
    dirs = []
    for i, flag in enumerate(flags):
        name, eq, value = flag.partition("=")
        if name in ("--config-dir", "-cd"):
            value = value if eq else (flags[i + 1] if i + 1 < len(flags) else "")
            if value:
                dirs.append(f"file://{os.path.abspath(value)}")
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


def sweep_combinations(overrides: Sequence[str]) -> list[list[str]]:
    """Every job's overrides of a basic sweep: each is composed and checked before any runs
    (tens of milliseconds a job, small beside the job itself)."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parsed = OverridesParser.create().parse_overrides(list(overrides))
    batches = BasicSweeper.split_arguments(parsed, max_batch_size=None)
    return [list(job) for batch in batches for job in batch]


def precheck(overrides: Sequence[str], multirun: bool) -> None:
    from armexp.config import compose_config

    if not multirun:
        _writable(compose_config(overrides))
        return
    sweepable = [o for o in overrides if not o.startswith("hydra")]
    try:
        jobs = sweep_combinations(sweepable)
    except Exception:
        # Non-basic sweeps (ranges for other sweepers, …): validate the fixed part only.
        jobs = [[o for o in sweepable if "," not in o and "(" not in o]]
    for job in jobs:
        cfg = compose_config(job)
    _writable(cfg)


def _writable(cfg: Any) -> None:
    """The runs folder (Hydra's job folders and the default store go there) can be made."""
    from armexp.config import ConfigError

    folder = Path(str(cfg.tracking.runs_dir)).resolve()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        raise ConfigError(
            f"tracking.runs_dir={cfg.tracking.runs_dir} is not allowed: armexp cannot write there "
            f"({exc.strerror}); give a folder you can write to."
        ) from None


def run_stage(stage: str, args: Sequence[str]) -> int:
    module_name, _ = STAGES[stage]
    if module_name is None:
        print(
            f"armexp: the '{stage}' stage is not built yet; available now: "
            + ", ".join(s for s, (m, _) in STAGES.items() if m),
            file=sys.stderr,
        )
        return EXIT_USAGE
    from armexp.config import ConfigError, config_dir, normalize_overrides, register_schemas

    flags, overrides, multirun, validate = split_args(args)
    overrides = imply_gains_source(stage, overrides)
    overrides = _without_credentials(overrides)
    if validate:
        try:
            precheck([*_search_path(flags), *overrides], multirun)
        except ConfigError as exc:
            print(f"armexp {stage}: {exc}", file=sys.stderr)
            return EXIT_USAGE
    module = importlib.import_module(module_name)
    task: Callable[[Any], Any] = module.run

    import hydra

    def job(cfg: Any) -> Any:
        from armexp.config import validate as check

        try:
            check(cfg)
        except ConfigError as exc:
            print(f"armexp {stage}: {exc}", file=sys.stderr)
            raise SystemExit(EXIT_USAGE) from None
        try:
            return task(cfg)
        except ConfigError as exc:  # e.g. a missing upstream run found only at run time
            print(f"armexp {stage}: {exc}", file=sys.stderr)
            raise SystemExit(EXIT_USAGE) from None
        except OSError as exc:
            if exc.errno not in (errno.ENOSPC, errno.EDQUOT):
                raise
            print(
                f"armexp {stage}: the disk is full ({exc.strerror}: {exc.filename or 'a write'}); "
                "the run is marked FAILED with what it logged before; free space and run again.",
                file=sys.stderr,
            )
            raise SystemExit(1) from None

    register_schemas()
    # Hydra's parser wants the overrides as one contiguous block after the flags.
    sys.argv = [
        f"armexp {stage}",
        *flags,
        *normalize_overrides(overrides),
        f"hydra.job.name={stage}",
    ]
    app = hydra.main(config_path=str(config_dir()), config_name="config", version_base="1.3")(job)
    _terminate_as_interrupt()
    runs_jobs = multirun and validate and not {"--cfg", "-c"} & set(flags)
    sweep = _open_sweep(stage, overrides) if runs_jobs else None
    if sweep is not None:
        # Through the config, so jobs on other processes or machines (joblib, SLURM, Ray) see it.
        sys.argv.insert(-1, f"tracking.sweep_run={sweep[1]}")
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
    except KeyboardInterrupt:
        status = "KILLED"
        from armexp import tracking

        started = tracking.last_run_id is not None or sweep is not None
        print(
            f"armexp {stage}: interrupted; "
            + ("the MLflow run is marked KILLED." if started else "no run was started."),
            file=sys.stderr,
        )
        return EXIT_INTERRUPTED
    finally:
        if sweep is not None:
            _close_sweep(sweep, status)
    return 0


def _open_sweep(stage: str, overrides: Sequence[str]) -> tuple[Any, str, Any]:
    """A parent run that groups the jobs of ``armexp <stage> -m …`` in the MLflow UI; its id
    reaches every job as ``tracking.sweep_run``."""
    from mlflow.tracking import MlflowClient

    from armexp import tracking
    from armexp.config import compose_config

    fixed = [o for o in overrides if "," not in o and "(" not in o and not o.startswith("hydra")]
    cfg = compose_config(fixed)
    experiment_id = tracking.setup(cfg)
    client = MlflowClient(tracking.store_uri(cfg))
    run = tracking.retry(
        lambda: client.create_run(
            experiment_id,
            run_name=f"sweep-{stage}",
            tags={
                tracking.STAGE_TAG: "sweep",
                "armexp.sweep_stage": stage,
                tracking.HEARTBEAT_TAG: f"{time.time():.0f}",
                tracking.PROCESS_TAG: tracking.process_identity(),
            },
        )
    )
    sweep_id = run.info.run_id
    client.log_param(sweep_id, "overrides", " ".join(overrides)[:6000])
    print(f"armexp {stage}: sweep run {sweep_id} groups the jobs of this multirun")
    return client, sweep_id, tracking.Heartbeat(sweep_id, tracking.store_uri(cfg))


def _close_sweep(sweep: tuple[Any, str, Any], status: str) -> None:
    from armexp import tracking

    client, sweep_id, _ = sweep
    if status != "FINISHED":
        # Jobs stopped with the sweep (a worker killed before it could end its run) would stay
        # RUNNING: they end as the sweep did.
        experiment_id = client.get_run(sweep_id).info.experiment_id
        running = client.search_runs(
            [experiment_id],
            f"tags.`{tracking.SWEEP_TAG}` = '{sweep_id}' and attributes.status = 'RUNNING'",
            max_results=1000,
        )
        for run in running:
            run_id = str(run.info.run_id)

            def stop(rid: str = run_id) -> None:
                client.set_tag(rid, tracking.ERROR_TAG, "sweep stopped")
                client.set_terminated(rid, "KILLED")

            tracking.retry(stop)
    tracking.retry(lambda: client.set_terminated(sweep_id, status))


def _terminate_as_interrupt() -> None:
    """SIGTERM (a scheduler's stop, `kill`) ends a stage like Ctrl-C: run KILLED, state kept."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return

    def handler(signum: int, frame: Any) -> None:
        raise KeyboardInterrupt

    signal.signal(signal.SIGTERM, handler)


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    os.environ.setdefault("HYDRA_FULL_ERROR", "0")
    if not args or args[0] in ("-h", "--help", "help"):
        print(usage())
        return 0
    stage, rest = args[0], args[1:]
    if stage not in STAGES:
        print(
            f"armexp: stage={stage} is not a known stage; choose one of: {', '.join(STAGES)}.",
            file=sys.stderr,
        )
        return EXIT_USAGE
    return run_stage(stage, rest)


if __name__ == "__main__":
    sys.exit(main())
