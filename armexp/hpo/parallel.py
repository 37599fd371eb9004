"""`armexp hpo` on several processes (``hpo.n_jobs``): Optuna's own way of running a study in
parallel, processes that share its database, each asking for trials until the study holds
``n_trials``.

The command's process owns the study as with one job (it marks trials a dead process left
RUNNING, opens the HPO run and writes its files) and starts ``n_jobs - 1`` copies of its own
command line as workers. A worker knows the HPO run from its environment, hangs its trials under
it, and pruning compares every process's trials through the database. A worker stops asking for
trials once the owner has ended; the owner waits for its workers before it closes the HPO run, and
passes a signal it gets on to them (each marks its trial interrupted, so the next command queues
it again).
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from dataclasses import dataclass, field

from armexp.config import ConfigError

#: The HPO run a worker records into, and its index among the workers (1, 2, …).
WORKER_ENV = "ARMEXP_HPO_WORKER"
INDEX_ENV = "ARMEXP_HPO_WORKER_INDEX"
OWNER_ENV = "ARMEXP_HPO_OWNER_PID"
#: The trial's user attribute naming the process that ran it (0: the command, i: worker i).
PROCESS_ATTR = "armexp.process"
#: How long workers get to close their trials after a signal before they are killed (s).
GRACE_S = 60.0


@dataclass
class Role:
    """This process's part in the search: the owner (index 0) or worker ``index``."""

    hpo_run: str | None = None
    index: int = 0
    owner_pid: int | None = None

    @property
    def is_worker(self) -> bool:
        return self.hpo_run is not None

    def owner_alive(self) -> bool:
        """A worker goes on while the owner is its parent; the owner always does."""
        return not self.is_worker or os.getppid() == self.owner_pid


def role() -> Role:
    run = os.environ.get(WORKER_ENV)
    if not run:
        return Role()
    owner = os.environ.get(OWNER_ENV, "")
    return Role(run, int(os.environ.get(INDEX_ENV, "1")), int(owner) if owner.isdigit() else None)


def command_line() -> list[str]:
    """The command's own overrides (from Hydra), to start its workers with."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        raise ConfigError(
            "hpo.n_jobs > 1 is not allowed outside the armexp hpo command: its workers are "
            "copies of the command line; run `armexp hpo … hpo.n_jobs=N` or give hpo.n_jobs=1."
        )
    hc = HydraConfig.get()
    return [*hc.overrides.task, f"hydra.run.dir={hc.runtime.output_dir}"]


@dataclass
class Workers:
    """The worker processes an owner started; `join` waits for them, `stop` signals them."""

    procs: list[subprocess.Popen[bytes]] = field(default_factory=list)

    def join(self) -> list[int]:
        return [p.wait() for p in self.procs]

    def stop(self) -> None:
        """SIGINT to each (it closes its trial as interrupted), then wait; kill after
        `GRACE_S`."""
        for p in self.procs:
            if p.poll() is None:
                p.send_signal(signal.SIGINT)
        for p in self.procs:
            try:
                p.wait(timeout=GRACE_S)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def start(n_jobs: int, hpo_run: str, overrides: list[str]) -> Workers:
    """``n_jobs - 1`` workers running ``armexp hpo`` with ``overrides``, each writing its Hydra
    output under ``worker-<i>`` of the owner's directory."""
    out = Workers()
    for i in range(1, n_jobs):
        env = dict(os.environ)
        env.update({WORKER_ENV: hpo_run, INDEX_ENV: str(i), OWNER_ENV: str(os.getpid())})
        line = [
            *(o for o in overrides if not o.startswith("hydra.run.dir=")),
            *(f"{o}/worker-{i}" for o in overrides if o.startswith("hydra.run.dir=")),
        ]
        # A session of its own: a Ctrl-C at the terminal reaches the command alone, which
        # passes one SIGINT on (`Workers.stop`); a second one would cut the worker's clean-up.
        command = [sys.executable, "-m", "armexp", "hpo", *line]
        out.procs.append(subprocess.Popen(command, env=env, start_new_session=True))
    return out
