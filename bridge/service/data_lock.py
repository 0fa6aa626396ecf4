"""One service per data folder: an advisory lock (``flock``) on ``<data_dir>/service.lock`` for as long as the
service runs.

The data folder holds the service's store (presets, maneuvers, lines) and its event log. Two services on one
folder (``make run`` in two clones: both take ``~/.local/share/hitch-planner``) ran side by side without a
word: the second wrote a false ``previous_run_unclean`` record about the first, which was still running, and
the two logs' record numbers interleaved (a newcomer's trial). The second is now refused before it touches
anything, naming the folder and the process holding it. The lock goes with its holder's process (killed
or crashed too): nothing stale is left to clean up.
"""

from __future__ import annotations

import os
from pathlib import Path

from planner.errors import HitchInputError
from planner.filelock import LockHeldError, take_lock

__all__ = ["DataDirInUseError", "DataDirLock", "LOCK_FILE"]

#: the lock file in the data folder (it holds the holder's process id, for the message)
LOCK_FILE = "service.lock"


class DataDirInUseError(HitchInputError):
    """Another running service holds the data folder."""


class DataDirLock:
    """The lock of one data folder: :meth:`acquire` (raises :class:`DataDirInUseError`), :meth:`release`."""

    def __init__(self, data_dir: str | Path) -> None:
        self.path = Path(data_dir) / LOCK_FILE
        self._fd: int | None = None

    def acquire(self) -> DataDirLock:
        """Take the folder for this process (the folder must exist); refuses while another process holds it."""
        try:
            fd = take_lock(self.path)
        except LockHeldError as exc:
            raise DataDirInUseError(
                f"data folder {self.path.parent} is in use by another hitch service ({exc.holder}): one folder holds "
                "one service's store and event log; give this one its own (--data-dir, or [service] data_dir)"
            ) from None
        self._fd = fd
        return self

    def release(self) -> None:
        """Give the folder up (idempotent). The file stays: removing it would race a service taking it."""
        fd, self._fd = self._fd, None
        if fd is not None:
            os.close(fd)

    def __enter__(self) -> DataDirLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()
