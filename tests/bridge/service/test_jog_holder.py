"""One jog at a time (a terminal trial: alice's page held z+ and bob's z−, alternating every 40 ms for 2 s; all 36
jogs were accepted into one motion and the hitch went 66.7 mm down while alice held "up"). Through the service
API on the simulated rig (real CAN path, simulated time); truth: the replies, the measured height, the motion."""

from __future__ import annotations

import time

import pytest

from bridge.service.motion.controller import STOP_GRACE_S
from tests.bridge.service.test_track_mode import Rig


@pytest.fixture
def r(model, tmp_path):
    rig = Rig(model, tmp_path)
    yield rig
    rig.store.close()
    rig.rig.close()


def test_another_users_jog_is_refused_while_one_is_held_and_taken_once_released(r):
    z0 = r.measured()[1]
    ok, first = r.call("jog", {"vz": 0.04, "ttl_ms": 300}, user="alice")
    assert ok, first
    refused = []
    for _ in range(25):  # 1 s: alice holds "up", bob presses "down" in between
        ok, reply = r.call("jog", {"vz": 0.04, "ttl_ms": 300}, user="alice")
        assert ok and reply["motion_id"] == first["motion_id"], reply
        r.run(0.02)
        ok, reply = r.call("jog", {"vz": -0.04, "ttl_ms": 300}, user="bob")
        refused.append((ok, reply))
        r.run(0.02)
    assert all(not ok and reply["error"] == "busy" for ok, reply in refused), refused[:2]
    assert "user 'alice'" in refused[0][1]["message"] and "s left" in refused[0][1]["message"]
    assert r.measured()[1] > z0 + 0.01  # up, as alice holds it
    ok, reply = r.call("stop", {}, user="bob")  # a stop is anyone's
    assert ok
    r.run(1.5)
    time.sleep(STOP_GRACE_S + 0.02)  # a request within the stop's grace (wall clock) may predate it: refused
    # released (the stop, or alice's ttl): bob's jog is his now
    ok, reply = r.call("jog", {"vz": -0.04, "ttl_ms": 300}, user="bob")
    assert ok, reply
    r.run(0.2)
    ok, reply = r.call("jog", {"vz": 0.04, "ttl_ms": 300}, user="alice")
    assert not ok and "user 'bob'" in reply["message"]


def test_a_released_jog_may_be_taken_over_before_it_has_braked(r):
    ok, _ = r.call("jog", {"vz": 0.04, "ttl_ms": 200}, user="alice")
    assert ok
    r.run(0.3)  # alice's command expired: the jog brakes (dead-man), still the live motion
    assert r.states[-1]["motion"] is not None
    ok, reply = r.call("jog", {"vz": 0.04, "ttl_ms": 200}, user="bob")
    assert ok, reply


def test_anonymous_clients_cannot_be_told_apart_and_stay_one_jog(r):
    ok, a = r.call("jog", {"vz": 0.04, "ttl_ms": 300})
    assert ok
    ok, b = r.call("jog", {"vz": -0.04, "ttl_ms": 300})
    assert ok and b["motion_id"] == a["motion_id"]
    ok, c = r.call("jog", {"vz": 0.04, "ttl_ms": 300}, user="alice")  # an identified user, a live anonymous jog
    assert not ok and "an anonymous client" in c["message"]


def test_a_jog_held_through_another_users_stop_stays_stopped_until_released(r):
    """A review (hitch serve, two terminal pages): bob stopped while alice's page held z+; her page went on
    sending every 80 ms and its jog started again once the stop had braked (0.45 s), and bob, told "or stop",
    was refused. A stop ends a held jog: its holder releases and presses again."""
    for _ in range(5):
        ok, reply = r.call("jog", {"vz": 0.04, "ttl_ms": 250}, user="alice")
        assert ok, reply
        r.run(0.08)
    ok, _ = r.call("stop", {}, user="bob")
    assert ok
    time.sleep(STOP_GRACE_S + 0.02)  # past the stop's grace (wall clock): only the latch refuses her now
    replies = []
    for _ in range(25):  # 2 s: alice's page still holds the button
        replies.append(r.call("jog", {"vz": 0.04, "ttl_ms": 250}, user="alice"))
        r.run(0.08)
    assert not any(ok for ok, _ in replies), [rep for ok, rep in replies if ok][:1]
    assert "ended by a stop" in replies[-1][1]["message"] and "release" in replies[-1][1]["message"], replies[-1]
    assert "for at least 0.25 s (its ttl)" in replies[-1][1]["message"]  # how long: a quick re-press is refused too
    assert not r.states[-1]["moving"]  # the stop holds
    ok, reply = r.call("jog", {"vz": -0.04, "ttl_ms": 250}, user="bob")  # the jog is anyone's but hers
    assert ok, reply
    r.run(0.5)  # bob released; so did alice (no command of hers within its ttl)
    ok, reply = r.call("jog", {"vz": 0.04, "ttl_ms": 250}, user="alice")  # pressed again: hers
    assert ok, reply


def test_a_jog_released_before_the_stop_is_not_held_back(r):
    ok, _ = r.call("jog", {"vz": 0.04, "ttl_ms": 200}, user="alice")
    assert ok
    r.run(0.3)  # released: braking by its ttl
    ok, _ = r.call("stop", {}, user="alice")
    assert ok
    r.run(1.0)
    time.sleep(STOP_GRACE_S + 0.02)
    ok, reply = r.call("jog", {"vz": 0.04, "ttl_ms": 200}, user="alice")
    assert ok, reply
