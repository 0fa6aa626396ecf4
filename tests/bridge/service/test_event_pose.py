"""Every event of the motion controller says where the hitch was (``measured_pose``, ``measured_age_s``).

An incident trial: the black box said that a fault came and a motion was aborted, not where the implement
was at that moment; the CAN log had to be replayed to find it. Truth: the service's own published state at
rest (the pose the event must carry), and the link's measurement age limit (a stale-measurement fault comes
only once the newest measurement is older than it, so the pose such a fault carries is at least that old).
"""

from __future__ import annotations

import json

from bridge.service.blackbox import EventLog, event_log_path, read_events
from bridge.service.config import ServiceConfig
from bridge.service.server import HitchService
from tests.helpers import wait_until
from tests.integration.service_process import free_port


def test_events_carry_the_measured_pose_and_its_age_into_the_black_box(tmp_path):
    port = free_port()
    cfg = ServiceConfig(
        listen=[f"tcp/127.0.0.1:{port}"],
        prefix=f"eventpose{port}/hitch",
        data_dir=tmp_path,
        planning_processes=0,
        control_core="thread",
        can_channel=f"event-pose-{port}",
    )
    svc = HitchService(cfg).start()
    log = EventLog(event_log_path(tmp_path))
    try:
        assert svc.api is not None
        log.attach(svc)  # as `hitch serve` does
        events: list[dict] = []
        svc.add_listener("event", events.append)
        assert wait_until(lambda: (svc.latest_state or {}).get("ecu", {}).get("online"), 10.0)
        z0 = svc.latest_state["pose"]["z"]
        ok, reply = svc.api.handle("goto", json.dumps({"goal": {"z": z0 + 0.05}}), None)
        assert ok, reply
        mid = reply["motion_id"]

        def finished() -> dict | None:
            return next((e for e in events if e.get("event") == "motion_finished" and e.get("motion_id") == mid), None)

        assert wait_until(lambda: finished() is not None, 20.0), events
        done = finished()
        assert done is not None
        assert wait_until(lambda: not svc.latest_state["moving"], 5.0)
        rest = svc.latest_state["pose"]
        assert set(done["measured_pose"]) >= {"x", "z", "roll", "pitch"}
        for k in ("x", "z", "roll", "pitch"):  # at rest at the end: the pose the state shows, to the sensor step
            assert abs(done["measured_pose"][k] - rest[k]) < 3e-3, (k, done["measured_pose"], rest)
        assert abs(done["measured_pose"]["z"] - (z0 + 0.05)) < 5e-3
        assert 0.0 <= done["measured_age_s"] < 0.2

        ok, reply = svc.api.handle("sim/fault", json.dumps({"cut": "ecu_to_planner"}), None)  # the ECU goes quiet
        assert ok, reply

        def quiet() -> dict | None:
            return next((e for e in events if e.get("event") == "fault" and "measured_age_s" in e), None)

        assert wait_until(lambda: quiet() is not None, 5.0), [e.get("event") for e in events]
        fault = quiet()
        assert fault is not None
        limit = cfg.stale_timeout_s  # the link's measurement age limit
        assert fault["measured_age_s"] >= limit - 0.02, (fault, limit)  # the pose from before the link went quiet
        assert abs(fault["measured_pose"]["z"] - rest["z"]) < 3e-3
        svc.api.handle("sim/fault", json.dumps({}), None)
    finally:
        svc.close()
        log.close()
    recorded = [r for r in read_events(event_log_path(tmp_path)) if r.get("kind") == "event"]
    ours = next(r for r in recorded if r.get("event") == "motion_finished" and r.get("motion_id") == mid)
    assert ours["measured_pose"] == done["measured_pose"] and ours["measured_age_s"] == done["measured_age_s"]


def test_hitch_log_says_where_in_operator_units():
    from bridge.cli.records import format_record

    rec = {
        "t": 1.0e9,
        "seq": 7,
        "kind": "event",
        "event": "fault",
        "fault": "stale_measurement",
        "measured_pose": {"x": 0.0123, "y": 0.0, "z": 0.25, "roll": -0.002, "pitch": 0.0305, "yaw": 0.0},
        "measured_age_s": 0.2134,
    }
    line = format_record(rec)
    assert line.endswith(
        "event fault: fault=stale_measurement | at x +12.3 mm, z +250.0 mm, roll -2.0 mrad, pitch +30.5 mrad "
        "(measured 0.213 s before)"
    ), line
    assert "measured_pose" not in line
    assert format_record({**rec, "measured_pose": "junk"}).endswith("fault=stale_measurement")  # a damaged record
