"""A page that floods the terminal, and the words of a malformed WebSocket command (a fuzz trial).

One page sending thousands of tiny junk messages a second kept the server's loop busy: an HTTP ``stop``
was answered 3.6–7.5 s late and the hitch went on 182 mm. Now a page above its command rate
(:class:`bridge.web.hub.CommandRate`) is told and closed (1008), and a stop among its commands still
stops. Malformed commands are answered in the service's own words, with the command's id.

Truths: token-bucket arithmetic by hand on a stepped clock; the close code RFC 6455 gives a policy
violation (1008); the texts the service's parser gives the same payload over HTTP.
"""

from __future__ import annotations

import json
import os
import threading
import time

import pytest

from bridge.web.hub import (
    CLOSE_TOO_MANY_COMMANDS,
    COMMAND_BURST,
    COMMAND_FIELDS,
    MAX_PAYLOAD_DEPTH,
    CommandError,
    CommandRate,
    parse_command,
)
from bridge.web.settings import WebSettings
from bridge.web.websocket import OP_CLOSE, OP_TEXT, WebSocket, encode_frame
from tests.bridge.web.test_web_api import _post, _WSClient


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_the_command_rate_is_a_token_bucket_of_commands_and_of_bytes():
    clock = _Clock()
    rate = CommandRate(rate_hz=10.0, burst=5, bytes_per_s=1000.0, burst_bytes=2000, clock=clock)
    assert all(rate.take(10) for _ in range(5))  # the burst
    assert not rate.take(10)  # the sixth at once: over
    clock.t = 0.25  # 2.5 commands refilled: two taken, the third not (and a refused one spends nothing)
    assert rate.take(10) and rate.take(10) and not rate.take(10) and not rate.take(10)
    clock.t = 10.0  # 97.5 refilled, capped at the burst of 5
    assert all(rate.take(10) for _ in range(5)) and not rate.take(10)
    clock.t = 100.0
    assert rate.take(2000) and not rate.take(1)  # bytes: the whole burst in one command, then nothing left
    clock.t = 100.5  # 500 B refilled
    assert rate.take(500) and not rate.take(1)
    with pytest.raises(ValueError, match="positive"):
        CommandRate(rate_hz=0.0)


def test_the_hub_says_the_services_payload_depth():
    from bridge.service.schemas import MAX_PAYLOAD_DEPTH as SERVICE_DEPTH

    assert MAX_PAYLOAD_DEPTH == SERVICE_DEPTH


@pytest.mark.parametrize(
    "msg, words",
    [
        (b'{"id": 1, "key": "jog", "payloads": {"vz": -0.02}}', "jog: unknown field 'payloads' in the command"),
        (
            b'{"id": 1, "key": "goto", "payload": {"goal": {"z": 0.1, "z": 0.2}}}',
            "goto: duplicate key 'z' in the payload",
        ),
        (b'{"id": 1, "key": "goto", "payload": {"goal": {"z": ' + b"1" * 5000 + b"}}}", "more than 4300 digits"),
        (b'{"id": 1, "key": "goto", "payload": ' + b"[" * 5000 + b"]" * 5000 + b"}", "nests too deeply"),
        (b'{"id": 1, "key": "presets/save", "payload": {"name": "\\ud800"}}', "lone UTF-16 surrogate"),
        (b"garbage", "not valid JSON"),
    ],
)
def test_a_malformed_command_is_refused_in_the_services_words(msg, words):
    """The old hub passed Python's texts on ('Exceeds the limit (4300 digits) … sys.set_int_max_str_digits()',
    'maximum recursion depth exceeded …', "'utf-8' codec can't encode …") and ran a misspelt ``payloads`` as
    a jog without its payload."""
    with pytest.raises(CommandError) as err:
        parse_command(msg)
    text = str(err.value)
    assert words in text, text
    assert "sys.set_int_max_str_digits" not in text and "codec" not in text and "recursion" not in text
    if "unknown field" in words:
        assert f"(allowed: {', '.join(COMMAND_FIELDS)})" in text


def test_a_well_formed_command_is_passed_on_as_sent():
    rid, key, body, csrf = parse_command('{"id": "a", "key": "goto", "payload": {"goal": {"z": NaN, "n": "ä"}}}')
    assert (rid, key, csrf) == ("a", "goto", None)
    assert body == '{"goal": {"z": NaN, "n": "ä"}}'.encode()  # NaN stays a token: the service names the field


def _flooder(web, stop: threading.Event, result: dict) -> None:
    """One page sending batches of 200 tiny junk messages as fast as the socket takes them."""
    ws = _WSClient(web)
    ws.sock.settimeout(0.2)
    batch = encode_frame(OP_TEXT, b"garbage", mask=os.urandom(4)) * 200
    try:
        while not stop.is_set():
            ws.sock.sendall(batch)
            result["sent"] = result.get("sent", 0) + 200
            try:
                while True:  # read what came back; the close frame ends the flood
                    f = ws.frame()
                    if f.opcode == OP_CLOSE:
                        result["close"] = int.from_bytes(f.payload[:2], "big")
                        return
            except TimeoutError:
                pass
    except OSError as exc:
        result.setdefault("error", repr(exc))
    finally:
        ws.close()


def test_a_flooding_page_is_closed_and_an_http_stop_is_answered_meanwhile():
    """Fails on the old hub: the page was never closed (and the stop waited seconds behind its messages)."""
    from bridge.web.server import WebServer

    stops: list[float] = []

    def handler(name, body, user, *, received):
        if name == "stop":
            stops.append(time.monotonic())
            return True, {"stopped": True}
        return True, {}

    web = WebServer(handler, WebSettings(port=0, workers=2)).start()
    done, result = threading.Event(), {}
    flood = threading.Thread(target=_flooder, args=(web, done, result), daemon=True)
    try:
        flood.start()
        flood.join(10.0)  # closed after its burst: at most COMMAND_BURST messages taken
        assert result.get("close") == CLOSE_TOO_MANY_COMMANDS, result
        assert result["sent"] >= COMMAND_BURST
        assert _post(web, "stop", {}) == (200, {"stopped": True}) and len(stops) == 1
    finally:
        done.set()
        web.close()


class _FakeWS:
    """The hub's view of a socket: the page's messages in, the hub's texts out (recorded)."""

    buffered = False

    def __init__(self, msgs: list[str], sent: list[dict], at_end=None) -> None:
        self._msgs, self.sent, self._at_end = list(msgs), sent, at_end
        self.closed: int | None = None

    async def recv(self):
        import asyncio

        if self._msgs and self.closed is None:
            return self._msgs.pop(0)
        await asyncio.sleep(0.05)
        if self._at_end is not None:
            self._at_end()
        return None

    async def send_text(self, text):
        self.sent.append(json.loads(text))

    async def close(self, code=1000, reason=""):
        if self.closed is None:
            self.closed = code


def test_a_stop_over_the_rate_still_stops_and_the_page_is_told_why_and_closed():
    import asyncio

    from bridge.web.hub import ClientHub

    calls: list[str] = []

    async def call(name, body, user, received):
        calls.append(name)
        return True, {"stopped": True} if name == "stop" else {}

    clock = _Clock()  # never advances: the burst is all there is
    msgs = [json.dumps({"id": i, "key": "ik", "payload": {}}) for i in range(5)]
    msgs += [json.dumps({"id": "s", "key": "stop"}), json.dumps({"id": 99, "key": "ik", "payload": {}})]
    sent: list[dict] = []
    ws = _FakeWS(msgs, sent)
    hub = ClientHub(call, {}, command_rate=lambda: CommandRate(rate_hz=10.0, burst=5, clock=clock))
    asyncio.run(hub.serve(ws))  # type: ignore[arg-type]
    assert ws.closed == CLOSE_TOO_MANY_COMMANDS
    assert calls.count("stop") == 1 and calls.count("ik") == 5  # the stop over the burst stopped; 99 never ran
    replies = [m for m in sent if m.get("type") == "reply"]
    told = [m for m in replies if m["id"] == "s" and not m["ok"]]
    assert told and "faster than the terminal takes" in told[0]["data"]["message"], replies
    assert "at most 10 commands a second (bursts of 5)" in told[0]["data"]["message"]
    assert any(m["id"] == "s" and m["ok"] for m in replies)
    assert not any(m["id"] == 99 for m in replies)


def test_a_busy_reply_carries_the_commands_id():
    """The pending-limit reply said id null: the page, which matches replies by id, showed 'no answer'."""
    import asyncio

    from bridge.web.hub import MAX_PENDING, ClientHub

    async def run() -> list[dict]:
        release = asyncio.Event()

        async def call(name, body, user, received):
            await release.wait()
            return True, {}

        sent: list[dict] = []
        msgs = [json.dumps({"id": i, "key": "plan", "payload": {}}) for i in range(MAX_PENDING + 3)]
        await ClientHub(call, {}).serve(_FakeWS(msgs, sent, at_end=release.set))  # type: ignore[arg-type]
        return sent

    sent = asyncio.run(run())
    busy = [m for m in sent if m.get("type") == "reply" and not m["ok"]]
    assert [m["id"] for m in busy] == [MAX_PENDING, MAX_PENDING + 1, MAX_PENDING + 2], busy


def test_the_socket_is_not_written_once_the_peer_is_gone():
    """asyncio logged 'socket.send() raised exception.' for every reply to a page that had gone (60k lines)."""
    import asyncio

    async def run() -> bool:
        got: list[WebSocket] = []

        async def on_conn(reader, writer):
            got.append(WebSocket(reader, writer))

        server = await asyncio.start_server(on_conn, "127.0.0.1", 0)
        port = server.sockets[0].getsockname()[1]
        r, w = await asyncio.open_connection("127.0.0.1", port)
        while not got:
            await asyncio.sleep(0.01)
        w.transport.abort()  # the page is gone
        ws = got[0]
        for _ in range(50):
            try:
                await ws.send_text("x" * 1000)
            except ConnectionError:
                break
            await asyncio.sleep(0.01)
        closed = ws.closed
        server.close()
        return closed

    assert asyncio.run(run())


def test_a_network_stalls_backlog_arriving_at_once_does_not_close_the_page():
    """A review: 4.4 s of a held jog and levelling (130 commands) queued in a stalled connection arrived at once
    and closed the page with a burst of 100 — levelling stopped in the field. The burst covers 25 s of it."""
    import asyncio

    from bridge.web.hub import ClientHub

    async def call(name, body, user, received):
        return True, {}

    clock = _Clock()  # the whole backlog at one instant
    msgs = [json.dumps({"id": i, "key": "jog" if i % 2 else "track/setpoint", "payload": {}}) for i in range(40 * 25)]
    sent: list[dict] = []
    ws = _FakeWS(msgs, sent)
    asyncio.run(ClientHub(call, {}, command_rate=lambda: CommandRate(clock=clock)).serve(ws))  # type: ignore[arg-type]
    assert ws.closed != CLOSE_TOO_MANY_COMMANDS
    assert len([m for m in sent if m.get("type") == "reply"]) == 40 * 25
