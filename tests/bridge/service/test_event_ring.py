"""``events/recent`` (bridge.service.event_ring): the events a client missed, asked for afterwards (a fleet trial:
a goto's abort during a router outage and ``link_lost`` were never seen, and there was no way to ask)."""

from __future__ import annotations

import tempfile
import uuid

import pytest

from bridge.service.client import HitchClient
from bridge.service.config import ServiceConfig
from bridge.service.event_ring import EventRing
from bridge.service.schemas import RequestError, parse_request
from bridge.service.server import HitchService
from tests.helpers import wait_until
from tests.integration.service_process import free_port


def test_the_ring_answers_what_came_after_and_says_what_it_no_longer_keeps():
    ring = EventRing(kept=5)
    for n in range(1, 9):
        ring.take({"seq": n, "event": f"e{n}"})
    r = ring.after(6)
    assert [e["seq"] for e in r["events"]] == [7, 8] and not r["missed"] and (r["oldest"], r["latest"]) == (4, 8)
    r = ring.after(1)  # 2 and 3 are gone
    assert [e["seq"] for e in r["events"]] == [4, 5, 6, 7, 8] and r["missed"]
    r = ring.after(3, limit=2)
    assert [e["seq"] for e in r["events"]] == [4, 5] and r["more"] and not r["missed"]
    assert ring.after(8)["events"] == [] and not ring.after(8)["missed"]
    assert EventRing().after(0) == {"events": [], "oldest": None, "latest": None, "missed": False, "more": False}
    gap = EventRing()
    for n in (1, 2, 4, 5):  # 3 never heard (an outbox or the core's note queue dropped it)
        gap.take({"seq": n})
    assert gap.after(0)["missed"] and gap.after(1)["missed"] and not gap.after(3)["missed"]  # a review
    assert not gap.after(0, limit=2)["missed"]  # 1, 2: nothing skipped in what was answered


@pytest.mark.parametrize("body", [b'{"after": -1}', b'{"after": 1.5}', b'{"limit": 0}', b'{"limit": 501}', b'{"x": 1}'])
def test_bad_requests_are_refused_naming_the_field(body):
    with pytest.raises(RequestError) as err:
        parse_request("events/recent", body)
    assert any(k in str(err.value) for k in ("after", "limit", "x")), err.value


def test_a_client_gets_the_events_of_a_goto_it_did_not_subscribe_to():
    port = free_port()
    cfg = ServiceConfig(
        data_dir=tempfile.mkdtemp(),
        listen=(f"tcp/127.0.0.1:{port}",),
        can_channel=f"ring-{uuid.uuid4().hex}",
        control_core="thread",
        planning_processes=0,
    )
    with HitchService(cfg), HitchClient([f"tcp/127.0.0.1:{port}"], timeout_s=10) as c:
        assert wait_until(lambda: c.state()["ecu"]["online"], 10.0)
        start = c.recent_events()["latest"] or 0
        mid = c.goto({"z": c.state()["pose"]["z"] + 0.02})["motion_id"]

        def finished() -> list[dict]:
            got = c.recent_events(start)
            return [e for e in got["events"] if e.get("event") == "motion_finished" and e.get("motion_id") == mid]

        assert wait_until(lambda: bool(finished()), 15.0)
        got = c.recent_events(start)
        assert got["instance"] == c.config()["instance"] and not got["missed"]
        seqs = [e["seq"] for e in got["events"]]
        assert seqs == sorted(seqs) and seqs[0] == start + 1 and seqs == list(range(seqs[0], seqs[-1] + 1))
