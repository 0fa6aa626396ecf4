"""The operator terminal of a real running service (simulated ECU on a virtual CAN bus, real Zenoh session)
against what a fuzz trial sent it: a stop whatever its body's framing (chunked, bare LF, an unknown coding)
stops the hitch — seen in the service's own state, the independent truth —, integers beyond a float's range
are refused naming the field and its range (over HTTP, the WebSocket and Zenoh alike, never ``internal``),
and the protocol answers say what is wrong (426 for /ws without an upgrade, a missing Host header, an unknown
key, the path as sent)."""

from __future__ import annotations

import http.client
import json
import logging
import os
import socket
import time

import pytest

from bench._common import free_port
from tests.bridge.web.test_web_api import _moving_goto, _past_stop_grace, _post, _request, _WSClient, _zenoh_get
from tests.helpers import wait_until


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    from bridge.service.config import load_service_config
    from bridge.service.server import HitchService

    cfg = load_service_config(
        data_dir=tmp_path_factory.mktemp("web-framing-data"),
        listen=[f"tcp/127.0.0.1:{free_port()}"],
        http=f"127.0.0.1:{free_port()}",
        can_channel=f"web-framing-{os.getpid()}",
    )
    svc = HitchService(cfg).start()
    assert wait_until(lambda: svc.latest_state is not None and svc.latest_state["ecu"]["online"], 5.0)
    yield svc
    svc.close()


@pytest.fixture
def web(service):
    return service.http


def _raw(web, data: bytes) -> tuple[socket.socket, float]:
    """Send ``data`` on a new connection; the socket and when it was sent."""
    sock = socket.create_connection(web.address, timeout=10)
    t0 = time.monotonic()
    sock.sendall(data)
    return sock, t0


def _first_response(sock: socket.socket) -> tuple[int, dict, dict]:
    """(status, headers, JSON body) of the first response on ``sock``."""
    buf = b""
    while b"\r\n\r\n" not in buf:
        chunk = sock.recv(65536)
        assert chunk, f"closed without a response: {buf!r}"
        buf += chunk
    head, _, rest = buf.partition(b"\r\n\r\n")
    lines = head.decode("latin-1").split("\r\n")
    headers = {k.lower(): v for k, _, v in (ln.partition(": ") for ln in lines[1:])}
    length = int(headers["content-length"])
    while len(rest) < length:
        rest += sock.recv(65536)
    return int(lines[0].split(" ")[1]), headers, json.loads(rest[:length])


def _host(web) -> str:
    host, port = web.address
    return f"{host}:{port}"


# ---------------------------------------------------------------------------------------------- stop


@pytest.mark.parametrize(
    "framing",
    [
        "curl -H 'Transfer-Encoding: chunked' --data-binary stop",
        "bare LF",
        "chunked, its body one second late",
        "Transfer-Encoding: gzip",
        "Transfer-Encoding and Content-Length",
        "Content-Length, its body one second late",
        "Expect: 100-continue, its body never sent",
    ],
)
def test_a_stop_stops_whatever_its_body_framing(service, web, framing):
    """The old terminal answered the chunked stop 411 and a bare-LF one 408 after 10 s: the hitch kept moving."""
    motion_id = _moving_goto(service, web)
    head = f"POST /api/stop HTTP/1.1\r\nHost: {_host(web)}\r\nContent-Type: application/x-www-form-urlencoded\r\n"
    then, pause = b"", 1.0
    if framing.startswith("curl"):
        data = (head + "Transfer-Encoding: chunked\r\n\r\n4\r\nstop\r\n0\r\n\r\n").encode()
    elif framing == "bare LF":
        data = (head.replace("\r\n", "\n") + "Content-Length: 4\n\nstop").encode()
    elif framing.startswith("chunked, its body"):
        data, then = (head + "Transfer-Encoding: chunked\r\n\r\n").encode(), b"4\r\nstop\r\n0\r\n\r\n"
    elif framing.startswith("Content-Length, its body"):  # a review: the stop waited for its body (then 408)
        data, then = (head + "Content-Length: 4\r\n\r\n").encode(), b"stop"
    elif framing.startswith("Expect"):  # older curl, a body over 1 KiB: it waits for 100 Continue first
        data = (head + "Content-Length: 2000\r\nExpect: 100-continue\r\n\r\n").encode()
    elif framing.endswith("gzip"):
        data = (head + "Transfer-Encoding: gzip\r\n\r\n\x1f\x8b garbage").encode("latin-1")
    else:
        data = (head + "Transfer-Encoding: chunked\r\nContent-Length: 4\r\n\r\n4\r\nstop\r\n0\r\n\r\n").encode()
    sock, t0 = _raw(web, data)
    try:
        if then:  # the stop acts on its header: answered before its body was sent
            sock.settimeout(pause * 0.8)
            status, _, reply = _first_response(sock)
            assert time.monotonic() - t0 < pause
            sock.settimeout(10)
            sock.sendall(then)  # read after the answer: the connection then serves a next request
            sock.sendall(f"GET /api/info HTTP/1.1\r\nHost: {_host(web)}\r\n\r\n".encode())
            assert _first_response(sock)[0] == 200
        else:
            sock.settimeout(pause * 0.8)  # answered on its header, not after a body (or a 10 s timeout)
            status, _, reply = _first_response(sock)
            assert time.monotonic() - t0 < pause
    finally:
        sock.close()
    assert status == 200, reply
    assert reply["stopped"] is True and reply["motion_id"] is not None and reply["motion_id"] > motion_id, reply
    assert wait_until(lambda: not service.latest_state["moving"], 5.0)


def test_a_chunked_stop_keeps_its_connection_and_a_streamed_request_is_decoded(service, web):
    """A streaming client (http.client with a generator body: chunked, as fetch with a stream body and requests
    with a generator send) stops the hitch, and the connection then serves its next request; a streamed ik is
    answered exactly as the same body with Content-Length."""
    motion_id = _moving_goto(service, web)
    conn = http.client.HTTPConnection(*web.address, timeout=10)
    try:
        conn.request("POST", "/api/stop", body=iter([b"st", b"op"]), encode_chunked=True)
        resp = conn.getresponse()
        reply = json.loads(resp.read())
        assert resp.status == 200 and reply["stopped"] is True and reply["motion_id"] > motion_id, reply
        assert wait_until(lambda: not service.latest_state["moving"], 5.0)
        payload = json.dumps({"x": 0.01, "z": 0.1, "roll": 0.0, "pitch": -0.05}).encode()
        conn.request(  # the same connection: the stop's chunks were read whole
            "POST",
            "/api/ik",
            body=iter([payload[:10], payload[10:]]),
            headers={"Content-Type": "application/json"},
            encode_chunked=True,
        )
        resp = conn.getresponse()
        streamed = json.loads(resp.read())
    finally:
        conn.close()
    status, _, data = _request(web, "POST", "/api/ik", payload)
    whole = json.loads(data)
    assert resp.status == status == 200
    drop = {"solve_time_s"}
    assert {k: v for k, v in streamed.items() if k not in drop} == {k: v for k, v in whole.items() if k not in drop}


# ---------------------------------------------------------------------------------------------- huge integers

_HUGE = "1" * 400


@pytest.mark.parametrize(
    "key, body, field",
    [
        ("goto", f'{{"goal": {{"z": {_HUGE}}}}}', "goal.z"),
        ("goto", f'{{"goal": {{"z": -{_HUGE}}}}}', "goal.z"),
        ("goto", f'{{"goal": {{"z": 0.1}}, "deadline_ms": {_HUGE}}}', "deadline_ms"),
        ("plan", f'{{"goal": {{"x": {_HUGE}}}}}', "goal.x"),
        ("presets/save", f'{{"name": "huge", "pose": {{"pitch": {_HUGE}}}}}', "pose.pitch"),
        ("presets/go", f'{{"name": "huge", "deadline_ms": {_HUGE}}}', "deadline_ms"),
        ("work/start", f'{{"z": {_HUGE}}}', "z"),
        ("track/stop", f'{{"last_seq": {_HUGE}}}', "last_seq"),
        ("ik", f'{{"x": 0, "z": {_HUGE}, "roll": 0, "pitch": 0}}', "z"),
    ],
)
def test_an_integer_beyond_a_float_is_refused_naming_field_and_range_on_every_transport(service, web, key, body, field):
    """A JSON integer of 400 digits has no float value (float() raises OverflowError): goto, plan, presets/save,
    work/start answered 500 'internal error OverflowError'. Every transport answers bad_request naming the field
    and its range, the same words (the schemas are shared)."""
    from bridge.service.schemas import REQUESTS

    status, reply = _post(web, key, body.encode())
    assert status == 400 and reply["error"] == "bad_request", reply
    msg = reply["message"]
    assert msg.startswith(f"{key}: {field} = a number of 40") and "(allowed: >= " in msg and "<= " in msg, msg
    assert "internal" not in msg
    ok, zreply = _zenoh_get(service, key, body.encode())
    assert not ok and zreply == reply
    ws = _WSClient(web)
    try:
        ws.message("hello")
        ws.send(f'{{"id": 5, "key": "{key}", "payload": {body}}}'.encode())
        wreply = ws.message("reply")
    finally:
        ws.close()
    assert not wreply["ok"] and wreply["data"] == reply, wreply
    assert key in REQUESTS and not service.latest_state["moving"]


def test_a_huge_integer_in_an_unbounded_field_is_refused_too(service, web):
    status, reply = _post(web, "work/settings", f'{{"blend": {_HUGE}}}'.encode())
    assert status == 400 and reply["message"].startswith("work/settings: blend = a number of 400 digits is out of"), (
        reply
    )


def test_an_internal_error_is_logged_with_its_traceback(service, caplog):
    """The reply stays "internal error" (never the traceback); the log gets the traceback for a developer."""
    api = service.api
    key = "config"
    original = api._handlers[key]

    def broken(_req):
        raise ArithmeticError("deliberately broken handler")

    api._handlers[key] = broken
    try:
        with caplog.at_level(logging.ERROR, logger="hitch.service.api"):
            ok, reply = api.handle(key, b"{}", None)
    finally:
        api._handlers[key] = original
    assert not ok and reply["error"] == "internal" and "Traceback" not in reply["message"]
    records = [r for r in caplog.records if r.name == "hitch.service.api"]
    assert records and records[0].exc_info is not None and records[0].exc_info[0] is ArithmeticError
    assert "deliberately broken handler" in caplog.text and "Traceback" in caplog.text and "broken" in caplog.text


# ---------------------------------------------------------------------------------------------- protocol answers


def test_get_of_a_key_that_does_not_exist_says_unknown_key_and_of_a_real_key_use_post(web):
    status, _, data = _request(web, "GET", "/api/nope")
    reply = json.loads(data)
    assert status == 404 and reply["error"] == "unknown_key" and "'nope'" in reply["message"], reply
    assert "use POST" not in reply["message"]
    for key in ("goto", "presets/save"):
        status, _, data = _request(web, "GET", f"/api/{key}")
        assert status == 405 and json.loads(data)["message"] == f"use POST for /api/{key}"


def test_another_method_on_a_get_path_says_use_get(web):
    """An operator's trial: DELETE /api/state answered 404 "unknown API key 'state'" (HEAD too)."""
    for method in ("DELETE", "POST", "PUT", "HEAD"):
        for path in ("/api/state", "/api/info"):
            status, _, data = _request(web, method, path)
            assert status == 405, (method, path, status, data)
            if method != "HEAD":
                assert json.loads(data)["message"] == f"use GET for {path}", (method, path, data)


def test_ws_without_an_upgrade_is_426_upgrade_required(web):
    status, headers, data = _request(web, "GET", "/ws")
    reply = json.loads(data)
    assert status == 426 and headers["Upgrade"].lower() == "websocket", (status, data)
    assert "WebSocket upgrade" in reply["message"] and "nothing at" not in reply["message"]


def test_a_request_without_host_is_told_the_host_header_is_missing(web):
    for version in ("HTTP/1.1", "HTTP/1.0"):
        sock, _ = _raw(web, f"GET /api/state {version}\r\nConnection: close\r\n\r\n".encode())
        try:
            status, _, reply = _first_response(sock)
        finally:
            sock.close()
        assert status == 400 and "no Host header" in reply["message"] and "Host ''" not in reply["message"], reply


def test_a_path_of_two_slashes_is_reported_as_sent(web):
    sock, _ = _raw(web, f"GET //etc/passwd HTTP/1.1\r\nHost: {_host(web)}\r\nConnection: close\r\n\r\n".encode())
    try:
        status, _, reply = _first_response(sock)
    finally:
        sock.close()
    assert status == 404 and reply["message"] == "nothing at '//etc/passwd'", reply


def test_after_the_stops_a_motion_is_served_again(service, web):
    """The stops above leave the terminal usable: a goto over a chunked body is decoded and moves the hitch."""
    _past_stop_grace()
    conn = http.client.HTTPConnection(*web.address, timeout=10)
    try:
        body = json.dumps({"goal": {"z": 0.2}, "speed_scale": 0.2}).encode()
        conn.request("POST", "/api/goto", body=iter([body]), headers={"Content-Type": "application/json"})
        resp = conn.getresponse()
        reply = json.loads(resp.read())
    finally:
        conn.close()
    assert resp.status == 200 and reply["accepted"], reply
    assert wait_until(lambda: service.latest_state["moving"], 5.0)
    service.api.handle("stop", b"", None)
    assert wait_until(lambda: not service.latest_state["moving"], 5.0)
