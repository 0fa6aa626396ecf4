"""Every event's ``t`` is Unix time: maneuver and work events brought the controller's clock in ``t`` (62 s
after start beside a motion event's 1.8e9; a fleet integrator's report). Their own time is kept as ``clock``."""

from __future__ import annotations

import time

from bridge.service.motion.outbox import Outbox


def test_every_event_is_stamped_with_unix_time_and_a_clock_of_its_own_is_kept():
    outbox = Outbox(on_event=lambda e: None, on_state=lambda m: None)
    before = time.time()
    motion = outbox.put_event({"event": "motion_started", "motion_id": 7})
    step = outbox.put_event({"event": "maneuver_step", "maneuver": "m", "t": 62.08})
    after = time.time()
    for e in (motion, step):
        assert before <= e["t"] <= after  # one base: sortable together
    assert step["clock"] == 62.08 and "clock" not in motion
    assert (motion["seq"], step["seq"]) == (1, 2)
    explicit = outbox.put_event({"event": "x", "t": 1.0, "clock": 2.0})
    assert explicit["clock"] == 2.0 and before <= explicit["t"]
