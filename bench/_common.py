"""Helpers shared by the benchmarks: machine note, percentiles, JSON output, loopback ports,
process CPU time from /proc and process-group clean-up."""

from __future__ import annotations

import json
import os
import platform
import random
import signal
import socket
import subprocess
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np

__all__ = [
    "free_port",
    "kill_group",
    "machine_note",
    "percentiles_ms",
    "percentiles_us",
    "proc_cpu_seconds",
    "write_json",
]


def machine_note() -> dict:
    cpu = platform.processor() or ""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        rev = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    except OSError:
        rev = ""
    return {"cpu": cpu, "cores": os.cpu_count(), "python": platform.python_version(), "commit": rev}


def percentiles_us(samples_s) -> dict:
    a = np.asarray(samples_s) * 1e6
    return {
        "p50_us": float(np.percentile(a, 50)),
        "p99_us": float(np.percentile(a, 99)),
        "max_us": float(a.max()),
        "n": int(a.size),
    }


def write_json(path: str | None, data: dict) -> None:
    if path:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(data, indent=2))


def percentiles_ms(samples_s: Iterable[float], qs: tuple[int, ...] = (50, 99)) -> dict:
    """``p<q>_ms`` for each q, ``max_ms`` and ``n`` of samples given in seconds; None values for no sample."""
    a = np.asarray(list(samples_s), float) * 1e3
    a = a[np.isfinite(a)]
    if a.size == 0:
        return {**{f"p{q}_ms": None for q in qs}, "max_ms": None, "n": 0}
    return {**{f"p{q}_ms": float(np.percentile(a, q)) for q in qs}, "max_ms": float(a.max()), "n": int(a.size)}


def _ephemeral_low() -> int:
    """The lowest port of the kernel's ephemeral range (``/proc/sys/net/ipv4/ip_local_port_range``)."""
    try:
        return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 32768  # the Linux default


class _PortPicker:
    """Hands out loopback ports below the kernel's ephemeral range, each at most once per process.

    Why not ``bind(("127.0.0.1", 0))``: that port lies in the ephemeral range, and between the probe
    and the service's own bind the kernel may give the same port to any outgoing connection on the
    machine (a Zenoh client, a browser) as its local port. A CI run failed exactly so ("Address
    already in use" for a port the test had just found free). Ports below the range are taken only
    by explicit binds, and handing each out once keeps two ports asked for in a row apart before
    either is bound."""

    def __init__(self, low: int = 20000, high: int | None = None) -> None:
        self._low, self._high = low, high if high is not None else max(low + 1000, _ephemeral_low())  # [low, high)
        self._rng = random.Random(os.getpid() ^ time.monotonic_ns())
        self._given: set[int] = set()

    def pick(self) -> int:
        for _ in range(1000):
            port = self._rng.randrange(self._low, self._high)
            if port in self._given:
                continue
            with socket.socket() as s:  # no SO_REUSEADDR: a port with lingering connections counts as taken
                try:
                    s.bind(("127.0.0.1", port))
                except OSError:
                    continue
            self._given.add(port)
            return port
        raise RuntimeError(f"no free loopback port in [{self._low}, {self._high}) after 1000 tries")


_PICKER = _PortPicker()


def free_port() -> int:
    """A TCP port on 127.0.0.1 that is free now, lies below the kernel's ephemeral range, and was not
    handed out before by this process (see ``_PortPicker`` for why)."""
    return _PICKER.pick()


def proc_cpu_seconds(pid: int) -> float:
    """utime + stime of process ``pid`` from ``/proc/<pid>/stat`` [s] (all its threads, not its children)."""
    text = Path(f"/proc/{pid}/stat").read_text()
    fields = text[text.rindex(")") + 2 :].split()  # after "pid (comm) ": field 3 (state) is index 0
    ticks = int(fields[11]) + int(fields[12])  # fields 14 utime and 15 stime, in clock ticks
    return ticks / os.sysconf("SC_CLK_TCK")


def kill_group(proc: subprocess.Popen, timeout_s: float = 5.0) -> None:
    """SIGKILL the process group of ``proc`` (started with ``start_new_session=True``) and reap it."""
    if proc.poll() is None:
        try:
            os.killpg(proc.pid, signal.SIGKILL)
        except (ProcessLookupError, PermissionError):
            pass
    try:
        proc.wait(timeout_s)
    except subprocess.TimeoutExpired:
        pass
