"""The simulated ECU as its own process (``hitch ecu-sim``), on cross-process CAN over loopback:
a :class:`~bridge.link.loopback.LoopbackHub` on 127.0.0.1 and python-can's ``remote``
interface. No multicast group is used. The planner's link in this process claims, streams a
reference, and the ECU's system state proves that the references arrive."""

import json
import signal
import subprocess
import sys
import time

import pytest

from bridge.isobus.codec import RearHitchStatus, decode_frame
from bridge.isobus.j1939 import PGN_HEARTBEAT, PGN_POSITION_MEASUREMENT, PGN_REAR_HITCH_STATUS, decode_id
from bridge.link.can_link import CanLink
from bridge.link.loopback import LoopbackHub
from bridge.link.realtime import INTERFACES, RealtimeRunner, open_bus

pytestmark = pytest.mark.slow


def test_remote_is_an_interface_of_the_bridge():
    assert "remote" in INTERFACES


def test_ecu_sim_runs_as_its_own_process_on_the_loopback_hub(model):
    with LoopbackHub() as hub:
        assert hub.url.startswith("ws://127.0.0.1:")
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "bridge.cli.main",
                "ecu-sim",
                "--interface",
                "remote",
                "--channel",
                hub.url,
                "--duration",
                "40",
                "--json",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        tap = open_bus("remote", hub.url)
        link_bus = open_bus("remote", hub.url)
        link = CanLink(model, link_bus)
        runner = RealtimeRunner(link, max_wait_s=0.02)
        got, wanted = {}, {PGN_HEARTBEAT, PGN_POSITION_MEASUREMENT, PGN_REAR_HITCH_STATUS}
        try:
            deadline = time.monotonic() + 20
            while time.monotonic() < deadline and not wanted <= set(got):
                f = tap.recv(timeout=0.5)
                if f is not None and decode_id(f.arbitration_id).source_address == 169:
                    got.setdefault(decode_id(f.arbitration_id).pgn, decode_frame(f).payload)
            assert wanted <= set(got), proc.stderr.read() if proc.poll() is not None else got
            assert isinstance(got[PGN_REAR_HITCH_STATUS], RearHitchStatus)
            runner.start()
            deadline = time.monotonic() + 10
            while time.monotonic() < deadline and (not link.claimed or link.latest_state() is None):
                time.sleep(0.05)
            assert link.claimed and link.latest_state() is not None and runner.error is None
            link.send_reference(model.neutral, runner.now())
            deadline = time.monotonic() + 5
            while time.monotonic() < deadline and link.latest_state().system.watchdog_tripped:
                time.sleep(0.02)
            st = link.latest_state()
            assert not st.system.watchdog_tripped, link.faults  # references reach the other process
            assert link.streaming and not link.faults.any, link.faults
            link.stop_motion()
        finally:
            runner.stop()
            link_bus.shutdown()
            tap.shutdown()
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=15)
    assert proc.returncode == 0, err
    summary = json.loads(out.strip().splitlines()[-1])
    assert summary["interface"] == "remote" and summary["claim"] == "claimed"
    assert summary["counters"]["references"] > 0 and summary["counters"]["malformed"] == 0
