"""Stopping on a signal: Ctrl-C (SIGINT) and SIGTERM (a scheduler's stop, ``kill``) end a stage at
once, its run marked KILLED (`armexp.tracking.run_end`), and armexp exits as a shell expects of
each: 128 plus the signal's number (130, 143).

Both raise KeyboardInterrupt where the stage is, and from then on each request to a remote store
gets one short attempt (`armexp.tracking.remote.hurry`), so the writes that close the run end within
seconds even when the store is gone. A SIGINT that the shell told this process to ignore (a
background job) stays ignored.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

from armexp.tracking import remote

#: The signals received since `install`, first first.
received: list[int] = []


def _stop(signum: int, frame: FrameType | None) -> None:
    received.append(signum)
    remote.hurry()
    raise KeyboardInterrupt


def install() -> Callable[[], None]:
    """Take SIGTERM, and SIGINT unless it is ignored, in this (the main) thread; returns what
    puts the previous handlers back."""
    received.clear()
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    before: dict[int, Any] = {}
    for sig in (signal.SIGTERM, signal.SIGINT):
        current = signal.getsignal(sig)
        if sig == signal.SIGINT and current is not signal.default_int_handler:
            continue
        before[sig] = current
        signal.signal(sig, _stop)

    def restore() -> None:
        for sig, handler in before.items():
            signal.signal(sig, handler)

    return restore


def exit_code() -> int:
    """128 plus the first signal's number; a KeyboardInterrupt raised without one counts as
    Ctrl-C."""
    return 128 + int(received[0] if received else signal.SIGINT)


def what() -> str:
    """How the stop is named in the message: ``terminated`` (SIGTERM) or ``interrupted``."""
    return "terminated" if received and received[0] == signal.SIGTERM else "interrupted"
