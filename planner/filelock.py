"""An advisory lock (``flock``) on a file for as long as this process holds it: one user of a resource at a time.

:func:`take_lock` opens (or creates) the lock file, takes ``LOCK_EX`` without waiting and writes ``pid N`` into
it for the next taker's message; closing the returned descriptor (or the process ending: killed or crashed
too) gives it up, so nothing stale is left. Used for a service's data folder
(:mod:`bridge.service.data_lock`) and a sensor calibration's progress file
(:mod:`bridge.link.sensor_calibration`).
"""

from __future__ import annotations

import fcntl
import os
from pathlib import Path

from planner.errors import HitchInputError

__all__ = ["LockHeldError", "take_lock"]


class LockHeldError(HitchInputError):
    """Another process holds the lock; ``holder``: what its lock file says (``pid N``)."""

    def __init__(self, path: Path, holder: str):
        super().__init__(f"{path} is held by {holder}")
        self.path, self.holder = path, holder


def take_lock(path: str | Path) -> int:
    """The descriptor holding ``path``'s lock for this process (close it to give the lock up);
    :class:`LockHeldError` while another holds it; ``OSError`` when the file cannot be opened."""
    p = Path(path)
    fd = os.open(p, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 200, 0).decode("utf-8", "replace").strip() or "a process"
        os.close(fd)
        raise LockHeldError(p, holder) from None
    except OSError:
        os.close(fd)
        raise
    os.ftruncate(fd, 0)
    os.pwrite(fd, f"pid {os.getpid()}\n".encode(), 0)
    return fd
