"""The replay buffer of an interrupted off-policy run, kept with its checkpoint.

A checkpoint written every ``train.checkpoint_every`` steps holds the model without its replay
buffer (up to a few hundred MB, written once per interruption rather than every checkpoint).
When training is interrupted (Ctrl-C, SIGTERM, an error) the checkpoint written then holds the
buffer too, and ``train.resume`` continues on it. Without it (a process killed outright, or a
run interrupted before this was kept) the resumed model refills an empty buffer with its own
policy for ``learning_starts`` steps (`armexp.agents.factory.mark_resumed`) and learns for a
while on little but that (docs/plain_agent.md measures what it costs).

The interrupted episodes end with the last stored transition of each environment (the resumed
run starts new ones): they are marked truncated, so an n-step return does not run on into the
next episode, and a relabelling buffer closes them (`end_episodes`). A full buffer of 1 M
transitions of armexp/Reach-v0 is 124 MB (written in 0.2–0.3 s), one not yet full only its filled
rows; a resumed run that finishes deletes it.
"""

from __future__ import annotations

import contextlib
from pathlib import Path
from typing import Any

import mlflow
import numpy as np
from mlflow.store.artifact.artifact_repository_registry import get_artifact_repository
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

#: The buffer's file in the checkpoint, and the key of ``state.json`` that says the file
#: belongs to that checkpoint (a later checkpoint without the buffer leaves an older file).
BUFFER_FILE = "replay_buffer.pkl"
STATE_KEY = "replay_buffer"
#: The attribute a kept buffer carries in its file: the names of the arrays cut to their filled
#: rows (SB3 allocates them whole, and a buffer sized for 1 M transitions pickles to 124 MB
#: however few it holds).
CUT_KEY = "_armexp_cut_arrays"


def end_open_episodes(buffer: Any) -> None:
    """Mark the last stored transition of each environment truncated unless it ended its
    episode; a buffer with ``end_episodes`` (`armexp.agents.relabel`) closes its own records."""
    if buffer.size() == 0:
        return
    newest = (buffer.pos - 1) % buffer.buffer_size
    buffer.timeouts[newest] = np.maximum(buffer.timeouts[newest], 1.0 - buffer.dones[newest])
    if hasattr(buffer, "end_episodes"):
        buffer.end_episodes()


def save(model: Any, folder: Path) -> bool:
    """Write ``model``'s replay buffer to ``folder/BUFFER_FILE`` with its open episodes ended
    and, until it has filled, only its filled rows (`CUT_KEY`); False for a model without one
    (PPO) or with an empty one, and where it cannot be written (a full disk): the checkpoint
    then keeps the model, as without the buffer."""
    if not isinstance(model, OffPolicyAlgorithm) or model.replay_buffer is None:
        return False
    buffer = model.replay_buffer
    if buffer.size() == 0:
        return False
    end_open_episodes(buffer)
    whole = {} if buffer.full else _row_arrays(buffer)
    try:
        for name, array in whole.items():
            setattr(buffer, name, array[: buffer.pos])
        setattr(buffer, CUT_KEY, sorted(whole))
        model.save_replay_buffer(folder / BUFFER_FILE)
    except OSError:
        (folder / BUFFER_FILE).unlink(missing_ok=True)
        return False
    finally:
        for name, array in whole.items():
            setattr(buffer, name, array)
        vars(buffer).pop(CUT_KEY, None)
    return True


def restore(model: OffPolicyAlgorithm, path: Path) -> None:
    """Put the kept buffer back, its cut arrays at their full length again; updates go on at
    once (no refill)."""
    model.load_replay_buffer(path)
    buffer = model.replay_buffer
    assert buffer is not None
    for name in vars(buffer).pop(CUT_KEY, []):
        filled = getattr(buffer, name)
        rest = np.zeros((buffer.buffer_size - len(filled), *filled.shape[1:]), filled.dtype)
        setattr(buffer, name, np.concatenate([filled, rest]))


def _row_arrays(buffer: Any) -> dict[str, np.ndarray]:
    """The buffer's arrays with a row per position (SB3's observations, actions, rewards, …; a
    relabelling buffer's episode ends)."""
    return {
        name: value
        for name, value in vars(buffer).items()
        if isinstance(value, np.ndarray) and value.ndim >= 1
        and value.shape[0] == buffer.buffer_size
    }  # fmt: skip


def discard(run_id: str, path: str) -> None:
    """Delete the kept buffer at artifact ``path`` of a run that has finished: it only serves a
    resume. A store whose artifacts cannot be deleted keeps it (nothing depends on that)."""
    with contextlib.suppress(Exception):
        uri = mlflow.get_run(run_id).info.artifact_uri
        get_artifact_repository(uri).delete_artifacts(path)
