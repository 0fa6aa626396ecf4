"""Helpers for tests that run ``hitch serve`` and the ``hitch`` CLI as processes (loopback Zenoh only).

Bounded timeouts everywhere; callers kill the service in their teardown.
"""

from __future__ import annotations

import os
import queue
import subprocess
import sys
import threading
import time
from pathlib import Path

from bench._common import free_port
from bridge.service.client import HitchClient

__all__ = ["ROOT", "ServiceProcess", "free_port", "hitch", "start_hitch_router", "wait_online"]

ROOT = str(Path(__file__).resolve().parents[2])
"""The repository root: the working directory of every process these tests start."""


class ServiceProcess:
    """``hitch serve`` as a subprocess; lines of its stdout are collected by a reader thread."""

    def __init__(self, args: list[str], *, ready_timeout_s: float = 30.0):
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "bridge.cli", "serve", *args],
            cwd=ROOT,
            env=env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: queue.Queue = queue.Queue()
        self.output: list[str] = []
        threading.Thread(target=self._read, daemon=True).start()
        self.wait_for("ready on", ready_timeout_s)

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.output.append(line)
            self.lines.put(line)

    def wait_for(self, text: str, timeout_s: float) -> str:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                if self.proc.poll() is not None:
                    raise AssertionError("service exited: " + "".join(self.output)) from None
                continue
            if text in line:
                return line
        raise AssertionError(f"no {text!r} from the service within {timeout_s} s: " + "".join(self.output))

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)


def wait_online(client: HitchClient, timeout_s: float = 10.0) -> dict:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        s = client.state(timeout_s=2.0)
        if s["ecu"]["online"]:
            return s
    raise AssertionError("the ECU never came online")


def hitch(endpoint: str, *args: str, timeout_s: float = 60.0) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "bridge.cli", *args, "--connect", endpoint],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout_s,
    )


#: a bare Zenoh router in its own process: ``python -c ROUTER <endpoint>``; prints "router ready", ends on SIGTERM
ROUTER = """
import json, signal, sys, threading, zenoh
c = zenoh.Config()
c.insert_json5("mode", '"router"')
c.insert_json5("listen/endpoints", json.dumps([sys.argv[1]]))
c.insert_json5("scouting/multicast/enabled", "false")
s = zenoh.open(c)
stop = threading.Event()
signal.signal(signal.SIGTERM, lambda *_: stop.set())
print("router ready", flush=True)
stop.wait()
s.close()
"""


def start_router(endpoint: str) -> subprocess.Popen:
    """:data:`ROUTER` listening on ``endpoint`` (a loopback one), once it says it is ready."""
    router = subprocess.Popen([sys.executable, "-c", ROUTER, endpoint], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    assert router.stdout is not None and "router ready" in router.stdout.readline()
    return router


def start_hitch_router(endpoint: str, *args: str) -> subprocess.Popen:
    """``hitch router --listen endpoint`` (and ``args``), returned once it says it is ready (a service started
    before the router listens cannot connect)."""
    router = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", "router", "--listen", endpoint, *args],
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert router.stdout is not None
    line = router.stdout.readline()
    if "hitch router: ready on " + endpoint not in line:
        router.kill()
        router.wait(5)
        raise AssertionError(f"the router did not start: {line!r}")
    return router
