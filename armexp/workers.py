"""A sweep's worker processes on this machine (joblib's loky workers, submitit's local jobs) end
with the armexp command that started them.

When that command is killed outright (SIGKILL, the OOM killer) its workers are left behind:
loky's idle ones exit after loky's idle timeout (300 s), but one that was reading its next job
while the command died waits for the rest of that half-written job for good (measured: still
there 9 minutes on). A worker therefore watches the command from its first job (`job`) and,
once the command is gone, exits as soon as the job in hand has ended (that job's run ends as it
would have, so nothing logged is lost; the sweep run is closed by the next command,
`armexp.tracking.stage_runs.close_orphans`).
"""

from __future__ import annotations

import os
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

#: The armexp command's process id, inherited by the processes its launcher starts.
COMMAND_ENV = "ARMEXP_COMMAND_PID"
#: How often a worker looks for its command (s).
POLL_S = 1.0
_busy = threading.Lock()
_watching: list[int] = []


def mark_command() -> None:
    """This process is the armexp command whose sweep's workers watch it."""
    os.environ[COMMAND_ENV] = str(os.getpid())


@contextmanager
def job() -> Iterator[None]:
    """Around one job: in a worker the command started on this machine (the command is its
    parent), watch the command from now on; the watch waits for the job to end."""
    command = os.environ.get(COMMAND_ENV, "")
    if command.isdigit() and not _watching and os.getppid() == int(command) != os.getpid():
        _watching.append(int(command))
        threading.Thread(target=_exit_with, args=(int(command),), name="armexp-command-watch",
                         daemon=True).start()  # fmt: skip
    with _busy:
        yield


def _exit_with(command: int) -> None:
    """Exit this process once ``command`` is no longer its parent and no job runs."""
    while os.getppid() == command:
        time.sleep(POLL_S)
    with _busy:
        sys.stdout.flush()
        sys.stderr.flush()
        # No interpreter shutdown: its main thread may be blocked for good on the dead
        # command's pipe.
        os._exit(0)
