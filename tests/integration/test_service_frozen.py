"""A service frozen while the hitch moves: its control core brakes on its own, and nothing resumes.

A safety trial: ``kill -STOP`` of ``hitch serve`` (default peer mode) during a work session: ``hitch stop`` could
not reach the core (clients reach it through the service's Zenoh session) and the core ran the session on for as
long as the service stayed frozen (15.6 s), and on after SIGCONT. Now the service sends its core a keep-alive
every 0.25 s (``core-keepalive``) and a core that hears nothing for ``SERVICE_SILENCE_S`` brakes the hitch to
rest (``service_lost``); ``service_restored`` when the service speaks again, and nothing resumes.

Truth while the service is frozen: the cylinder ECU's own measurements on the CAN bus, read from a tap on the
loopback CAN hub (``hitch can-hub``, a process of its own) the core's twin and link share: nothing goes through
the frozen process. Afterwards the service's black box.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from bridge.isobus.codec import PositionMeasurement, RearHitchStatus, decode_frame
from bridge.isobus.j1939 import decode_id
from bridge.link.loopback import hub_url
from bridge.link.realtime import open_bus
from bridge.service.blackbox import event_log_path, read_events
from bridge.service.client import HitchClient
from bridge.service.core.process import SERVICE_SILENCE_S, SERVICE_WATCH_S
from tests.helpers import wait_until
from tests.integration.service_process import ROOT, ServiceProcess, free_port, wait_online

pytestmark = pytest.mark.slow

#: the ECU's address (its position measurements: the truth of where the pistons are)
ECU = 169
#: a piston that moved at most this many counts in a window is at rest there (one: a value on a count's edge)
REST_COUNTS = 1
#: the window over which "at rest" is judged [s] (the goto below lifts ~4 counts a second)
REST_WINDOW_S = 1.0


class BusTap:
    """The ECU's measurements on the hub, stamped on arrival (a thread of its own): the lift's (its rear hitch
    status: one count per 0.4 % of travel) and the other pistons' counts."""

    def __init__(self, url: str) -> None:
        self.bus = open_bus("remote", url)
        self.samples: list[tuple[float, tuple[int, ...]]] = []
        self.lift: int | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while not self._stop.is_set():
            f = self.bus.recv(timeout=0.2)
            if f is None or decode_id(f.arbitration_id).source_address != ECU:
                continue
            try:
                p = decode_frame(f).payload
            except Exception:  # noqa: BLE001 — another message of the ECU
                continue
            if isinstance(p, RearHitchStatus) and p.position is not None:
                self.lift = round(p.position / 0.004)
            elif isinstance(p, PositionMeasurement) and self.lift is not None:
                counts = (self.lift, p.tilt_counts, p.top_counts, p.right_counts, p.left_counts)
                self.samples.append((time.monotonic(), tuple(int(c or 0) for c in counts)))

    def moved_since(self, t0: float) -> int:
        """The largest change of any piston over the samples after ``t0`` [counts] (0: none, or no samples)."""
        window = [c for t, c in list(self.samples) if t >= t0]
        if len(window) < 2:
            return 0
        return max(max(col) - min(col) for col in zip(*window, strict=True))

    def at_rest(self) -> bool:
        now = time.monotonic()
        recent = [t for t, _ in list(self.samples) if t >= now - REST_WINDOW_S]
        return len(recent) >= 5 and self.moved_since(now - REST_WINDOW_S) <= REST_COUNTS

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.bus.shutdown()


def _start_hub() -> tuple[subprocess.Popen, str]:
    """``hitch can-hub`` on a free loopback port, once it says where (in a process of its own: relaying the frames
    under this test's interpreter lock left the ECU's data 0.2 s stale under load, a fault)."""
    port = free_port()
    hub = subprocess.Popen(
        [sys.executable, "-m", "bridge.cli", "can-hub", "--port", str(port)],
        cwd=ROOT,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        stderr=subprocess.PIPE,
        text=True,
    )
    assert hub.stderr is not None
    line = hub.stderr.readline()
    if "CAN hub on" not in line:
        hub.kill()
        hub.wait(10)
        raise AssertionError(f"the CAN hub did not start: {line!r}")
    threading.Thread(target=hub.stderr.read, daemon=True).start()  # its pipe never fills
    return hub, hub_url(port)


def test_a_frozen_service_is_noticed_by_its_core_which_brakes_and_nothing_resumes(tmp_path):
    hub, url = _start_hub()
    cfg = tmp_path / "hitch.toml"
    cfg.write_text("[can]\nstale_timeout_s = 1.0\n")  # the hub's relay in Python: no stale-data fault under load
    try:
        ep = f"tcp/127.0.0.1:{free_port()}"
        svc = ServiceProcess(
            [
                "--listen",
                ep,
                "--data-dir",
                str(tmp_path),
                "--can-interface",
                "remote",
                "--can-channel",
                url,
                "--config",
                str(cfg),
                "--planning-processes",
                "0",
            ],
            ready_timeout_s=60.0,
        )
        tap = BusTap(url)
        frozen_pid: int | None = None
        try:
            with HitchClient([ep], timeout_s=10) as c:
                z0 = wait_online(c)["pose"]["z"]
                acc = c.goto({"z": z0 + 0.18}, speed_scale=0.15)
                assert acc["accepted"] and acc["duration"] > 10.0, acc
            assert wait_until(lambda: tap.moved_since(time.monotonic() - REST_WINDOW_S) > 2 * REST_COUNTS, 10.0), (
                tap.samples[-5:]
            )

            os.kill(svc.proc.pid, signal.SIGSTOP)
            frozen_pid = svc.proc.pid
            frozen = time.monotonic()
            time.sleep(SERVICE_SILENCE_S / 2)
            assert not tap.at_rest(), read_events(
                event_log_path(tmp_path)
            )  # it still moves half-way through the bound (no brake on a short silence)
            # braked within the bound, the watch's period and the brake itself (~0.3 s at this speed) plus margin
            bound = SERVICE_SILENCE_S + SERVICE_WATCH_S + 3.0
            assert wait_until(tap.at_rest, bound), (time.monotonic() - frozen, tap.samples[-5:])
            rested = time.monotonic() - frozen
            time.sleep(2.0)  # and stays at rest while the service is frozen
            assert tap.at_rest()

            os.kill(svc.proc.pid, signal.SIGCONT)
            frozen_pid = None
            resumed = time.monotonic()
            log = event_log_path(tmp_path)

            def events() -> list[dict]:
                return [
                    r for r in read_events(log) if "event" in r
                ]  # (a motion event's own "kind" replaces the record's)

            assert wait_until(lambda: any(e.get("event") == "service_restored" for e in events()), 15.0), events()
            time.sleep(1.5)
            assert tap.moved_since(resumed) <= REST_COUNTS  # nothing resumed
            evs = events()
            lost = next(e for e in evs if e.get("event") == "service_lost")
            assert SERVICE_SILENCE_S <= lost["silent_s"] < SERVICE_SILENCE_S + 1.0, lost
            assert "braking" in lost["message"], lost
            restored = next(e for e in evs if e.get("event") == "service_restored")
            assert restored["silent_s"] >= rested, (restored, rested)
            assert "nothing stopped resumes" in restored["message"], restored
            aborted = [e for e in evs if e.get("event") == "motion_aborted"]
            assert any("service lost" in str(e.get("reason")) for e in aborted), aborted
            started = [e.get("event_kind") for e in evs if e.get("event") == "motion_started"]
            assert started == ["goto", "stop"], started  # the goto, its stop, and nothing since
        finally:
            if frozen_pid is not None:
                os.kill(frozen_pid, signal.SIGCONT)
            svc.proc.send_signal(signal.SIGINT)
            try:
                svc.proc.wait(30)
            except Exception:  # noqa: BLE001
                svc.kill()
            tap.close()
    finally:
        hub.terminate()
        hub.wait(10)
