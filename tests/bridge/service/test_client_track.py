"""HitchClient's track methods: setpoints are Zenoh puts on ``<prefix>/track/setpoint`` (one publisher per
session, reused), their JSON is what ``TrackSetpoint`` parses, and bad values are refused before the wire.
A plain Zenoh peer on loopback stands in for the service (the service's own handling is tested in
``test_track_mode.py``; a real service receives them in ``tests/bridge/cli/test_track_cli.py``)."""

from __future__ import annotations

import json
import queue
import re

import pytest
import zenoh

from bench._common import free_port
from bridge.service.client import ClientError, HitchClient
from bridge.service.schemas import TrackSetpoint
from tests.helpers import loopback_zenoh_config


@pytest.fixture
def peer():
    """A listening Zenoh peer on loopback collecting every setpoint put."""
    port = free_port()
    s = zenoh.open(loopback_zenoh_config("peer", f"tcp/127.0.0.1:{port}"))
    got: queue.Queue = queue.Queue()
    sub = s.declare_subscriber("hitch/track/setpoint", lambda sample: got.put(sample.payload.to_bytes()))
    try:
        yield f"tcp/127.0.0.1:{port}", got
    finally:
        sub.undeclare()
        s.close()


def _received(got: queue.Queue, n: int, timeout_s: float = 5.0) -> list[dict]:
    return [json.loads(got.get(timeout=timeout_s)) for _ in range(n)]


def test_setpoint_puts_reach_the_subscriber_and_parse_as_the_service_parses_them(peer):
    endpoint, got = peer
    with HitchClient([endpoint], timeout_s=2.0) as c:
        # a put before the subscriber's interest has propagated may be dropped: retry the first one
        for seq in range(50):
            c.track_setpoint(7, seq, {"roll": 0.0}, {"roll": 0.0})
            try:
                first = json.loads(got.get(timeout=0.1))
                break
            except queue.Empty:
                continue
        else:
            raise AssertionError("no put arrived within 5 s")
        pub = c._track_pub
        for seq in range(100, 110):
            c.track_setpoint(7, seq, {"roll": 0.001 * seq})
        assert c._track_pub is pub  # one publisher for the session, reused
        bodies = _received(got, 10)
        c.track_setpoint(8, 0, {"z": 0.1})  # a new session: a new publisher
        assert c._track_pub is not pub and c._track_pub[1] == 8
        # a new publisher's first puts may go before its routing is known (Zenoh's interest): as the first above
        for seq in range(1, 50):
            try:
                last = json.loads(got.get(timeout=0.1))
                break
            except queue.Empty:
                c.track_setpoint(8, seq, {"z": 0.1})
        else:
            raise AssertionError("no put of the new session arrived within 5 s")
    assert first["session"] == 7 and first["pose"] == {"roll": 0.0} and first["velocity"] == {"roll": 0.0}
    assert [b["seq"] for b in bodies] == list(range(100, 110))
    for b in bodies:
        sp = TrackSetpoint.model_validate(b)
        assert sp.pose.roll == pytest.approx(0.001 * b["seq"]) and sp.velocity is None
    assert last["session"] == 8 and last["pose"] == {"z": 0.1}


@pytest.mark.parametrize(
    ("args", "words"),
    [
        ((0, 1, {"z": 0.1}), "session must be an integer >= 1"),
        ((1, -1, {"z": 0.1}), "seq must be an integer >= 0"),
        ((1, True, {"z": 0.1}), "seq must be an integer"),
        ((1, 1, {"z": float("nan")}), "pose.z must be a finite number"),
        ((1, 1, {"y": 0.1}), "pose: unknown field 'y'"),
        ((1, 1, {}), "pose must be a non-empty mapping"),
        ((1, 1, {"z": 0.1}, {"z": float("inf")}), "velocity.z must be a finite number"),
        # beyond what the service takes: a put is not answered, so it was dropped silently (a new user's report)
        ((1, 1, {"z": 120.0}), "pose.z = 120.0 is out of range (allowed: >= -2 and <= 2 m); did you mean mm?"),
        ((1, 1, {"z": 0.1}, {"roll": 1.5}), "velocity.roll = 1.5 is out of range (allowed: >= -1 and <= 1 rad/s)"),
    ],
)
def test_bad_setpoints_are_refused_before_the_wire_naming_the_field(peer, args, words):
    endpoint, _ = peer
    with HitchClient([endpoint], timeout_s=2.0) as c:
        with pytest.raises(ClientError, match=re.escape(words)):
            c.track_setpoint(*args)
        with pytest.raises(ClientError, match="dof must be a list"):
            c.track_start("level", "roll", 500)


def test_track_start_and_maneuver_control_send_the_deadline_the_service_parses(peer, monkeypatch):
    """A new user's report: HitchClient had no way to give resume, skip or track start a deadline."""
    from bridge.service.schemas import parse_request

    ep, _got = peer
    sent: list[tuple[str, dict]] = []
    monkeypatch.setattr(HitchClient, "request", lambda self, key, payload=None, **kw: sent.append((key, payload)) or {})
    with HitchClient([ep], timeout_s=2.0) as c:
        c.track_start("tractor", ["z"], 300, deadline_ms=2500)
        c.track_start("tractor", ["z"])
        c.maneuver_control("resume", deadline_ms=40)
        c.maneuver_control("skip")
        c.maneuver_control("pause")
        with pytest.raises(ClientError, match="pause only brakes"):
            c.maneuver_control("pause", deadline_ms=40)
        with pytest.raises(ClientError, match="one of pause, resume, skip"):
            c.maneuver_control("abort")
    assert [(k, p.get("deadline_ms")) for k, p in sent] == [
        ("track/start", 2500),
        ("track/start", None),
        ("maneuvers/resume", 40),
        ("maneuvers/skip", None),
        ("maneuvers/pause", None),
    ]
    for key, body in sent:  # each body is one the service takes
        parse_request(key, json.dumps(body))


def test_the_client_s_setpoint_bounds_are_the_service_s():
    """What the client refuses before the wire, the service refuses, and what it sends the service takes."""
    import math

    from bridge.service.client import _setpoint_body
    from bridge.service.schemas import RequestError, parse_request

    for k, bound in (("x", 1.0), ("z", 2.0), ("roll", math.pi / 2), ("pitch", math.pi / 2)):
        for what, b in (("pose", bound), ("velocity", 1.0)):
            for v in (b, -b):
                body = {"pose": {k: 0.0}, what: {k: v}} if what == "velocity" else {"pose": {k: v}}
                parse_request("track/setpoint", _setpoint_body(1, 1, body["pose"], body.get("velocity")))
            over = math.nextafter(b, math.inf)
            with pytest.raises(RequestError):
                parse_request("track/setpoint", json.dumps({"session": 1, "seq": 1, "pose": {k: 0.0}, what: {k: over}}))
            with pytest.raises(ClientError, match=f"{what}.{k} = "):
                _setpoint_body(
                    1, 1, {k: over} if what == "pose" else {k: 0.0}, {k: over} if what == "velocity" else None
                )


@pytest.mark.parametrize("key", ["", "presets/list/", "config#", "goto?x=1", "Goto", "a//b", "hitch/*"])
def test_a_request_key_of_no_api_key_s_shape_is_refused_before_zenoh(peer, key):
    """A new user's report: "" and "presets/list/" raised Zenoh's own error with a Rust source path, and
    "goto?x=1" went out as goto with a selector."""
    from bridge.service.schemas import API_KEYS

    endpoint, _ = peer
    with HitchClient([endpoint], timeout_s=2.0) as c:
        with pytest.raises(ClientError, match="key must be an API key such as 'goto'"):
            c.request(key, {})
    from bridge.service.client import _API_KEY_SHAPE

    assert all(_API_KEY_SHAPE.fullmatch(k) for k in API_KEYS)  # every key the service serves passes


def test_a_setpoint_without_a_pose_is_refused_naming_pose(peer):
    """A new user's report: track_setpoint(s, 1, None) returned None and put a body with no pose, which the service
    counted as a rejection while the user was told nothing."""
    endpoint, got = peer
    with HitchClient([endpoint], timeout_s=2.0) as c:
        for call in (c.track_setpoint, c.track_setpoint_request):
            with pytest.raises(ClientError, match=r"^pose is required: a mapping of every DOF the session tracks"):
                call(1, 1, None)  # type: ignore[arg-type]
    assert got.empty()


def test_numpy_numbers_are_taken_by_every_track_method(peer, monkeypatch):
    """A new user's report: {"z": np.float32(0.12)} was refused "pose.z must be a finite number", seq=np.int64(2)
    "seq must be an integer >= 0", while np.float64 and an np.int64 ttl_ms were taken."""
    import numpy as np

    from bridge.service.client import _setpoint_body
    from bridge.service.schemas import parse_request

    data = _setpoint_body(np.int64(3), np.int64(2), {"z": np.float32(0.121928595)}, {"z": np.float32(0.5)})
    body = json.loads(data)
    assert body == {"session": 3, "seq": 2, "pose": {"z": pytest.approx(0.121928595)}, "velocity": {"z": 0.5}}
    assert type(body["seq"]) is int and type(body["pose"]["z"]) is float
    parse_request("track/setpoint", data)
    for v in (np.int32(1), np.uint8(1), np.float16(0.25), np.float64(0.1)):
        assert json.loads(_setpoint_body(1, 1, {"z": v}, None))["pose"]["z"] == pytest.approx(float(v))
    for bad, words in (
        ((1, np.int64(-1), {"z": 0.1}), "seq must be an integer >= 0, got np.int64(-1)"),
        ((1, np.bool_(True), {"z": 0.1}), "seq must be an integer >= 0"),
        ((1, 2.5, {"z": 0.1}), "seq must be an integer >= 0, got 2.5"),
        ((1, 1, {"z": np.float32("nan")}), "pose.z must be a finite number"),
        ((1, 1, {"z": np.bool_(True)}), "pose.z must be a finite number"),
    ):
        with pytest.raises(ClientError, match=re.escape(words)):
            _setpoint_body(*bad, None)
    sent: list[tuple[str, dict]] = []
    monkeypatch.setattr(HitchClient, "request", lambda self, key, payload=None, **kw: sent.append((key, payload)) or {})
    endpoint, _ = peer
    with HitchClient([endpoint], timeout_s=2.0) as c:
        c.track_start("tractor", ["z"], np.int64(300), deadline_ms=np.int64(2500))
        c.track_stop(np.int64(3), last_seq=np.int64(2))
        with pytest.raises(ClientError, match=re.escape("last_seq must be an integer >= 0, got -1")):
            c.track_stop(3, last_seq=-1)
    for key, payload in sent:
        assert all(type(v) is int for v in payload.values() if not isinstance(v, (str, list))), payload
        parse_request(key, json.dumps(payload))
    assert sent[1] == ("track/stop", {"session": 3, "last_seq": 2})
