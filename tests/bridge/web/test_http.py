"""The HTTP reader against raw sockets on 127.0.0.1: a header that trickles in is cut off after
the header timeout (408), a body likewise, an idle kept-alive connection is closed quietly, and a
request with two Content-Length (or Host, Transfer-Encoding) headers is refused with 400. Chunked
bodies are decoded (RFC 9112 7.1) under the body limits, bare-LF line ends are taken (RFC 9112 2.2),
and an origin-form target is the path as sent."""

import asyncio
import json
import socket
import threading
import time

import pytest

from bridge.web.http import HttpError, json_response, read_request

HEADER_S, IDLE_S, BODY_S = 0.4, 1.0, 0.4


class _Server:
    """read_request in a loop on its own thread, as the terminal's connection handler uses it."""

    def __init__(self) -> None:
        self.loop = asyncio.new_event_loop()
        self.errors: list[HttpError] = []
        ready = threading.Event()

        async def serve(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
            try:
                while True:
                    try:
                        req = await read_request(
                            reader, header_timeout_s=HEADER_S, idle_timeout_s=IDLE_S, body_timeout_s=BODY_S
                        )
                    except HttpError as exc:
                        self.errors.append(exc)
                        writer.write(
                            json_response(exc.status, {"error": exc.code, "message": str(exc)}, keep_alive=False)
                        )
                        await writer.drain()
                        return
                    if req is None:
                        return
                    writer.write(json_response(200, {"path": req.path, "body": req.body.decode()}))
                    await writer.drain()
            finally:
                writer.close()

        async def start() -> None:
            self.server = await asyncio.start_server(serve, "127.0.0.1", 0)
            self.port = self.server.sockets[0].getsockname()[1]
            ready.set()

        self.thread = threading.Thread(target=self.loop.run_forever, daemon=True)
        self.thread.start()
        asyncio.run_coroutine_threadsafe(start(), self.loop).result(5)
        assert ready.wait(5)

    def connect(self) -> socket.socket:
        s = socket.create_connection(("127.0.0.1", self.port), timeout=5)
        s.settimeout(5)
        return s

    def close(self) -> None:
        async def stop() -> None:
            self.server.close()

        asyncio.run_coroutine_threadsafe(stop(), self.loop).result(5)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(5)
        self.loop.close()


@pytest.fixture
def server():
    s = _Server()
    yield s
    s.close()


def _read_all(sock: socket.socket, limit_s: float = 5.0) -> bytes:
    """Everything until the server closes (bounded in time)."""
    out = b""
    end = time.monotonic() + limit_s
    while time.monotonic() < end:
        try:
            chunk = sock.recv(65536)
        except (ConnectionResetError, BrokenPipeError):
            break
        if not chunk:
            break
        out += chunk
    return out


def _responses(data: bytes) -> list[tuple[int, dict]]:
    out = []
    while data:
        head, _, rest = data.partition(b"\r\n\r\n")
        lines = head.decode("latin-1").split("\r\n")
        length = next(int(v) for k, _, v in (ln.partition(": ") for ln in lines[1:]) if k.lower() == "content-length")
        out.append((int(lines[0].split(" ")[1]), json.loads(rest[:length])))
        data = rest[length:]
    return out


def test_a_header_sent_slowly_is_cut_off_after_the_header_timeout(server):
    sock = server.connect()
    t0 = time.monotonic()
    sock.sendall(b"GET /slow HTTP/1.1\r\nHost: 127.0.0.1\r\n")
    cut_at = None
    for i in range(60):  # one header byte every 50 ms for up to 3 s: never a complete header
        try:
            sock.sendall(b"X-Slow-%d: 1\r\n" % i if i % 4 == 0 else b"")
        except (BrokenPipeError, ConnectionResetError):
            cut_at = time.monotonic()
            break
        sock.settimeout(0.05)
        try:
            data = sock.recv(65536)
        except TimeoutError:
            continue
        cut_at = time.monotonic()
        data += _read_all(sock)
        break
    sock.close()
    assert cut_at is not None, "the server never cut the slow client off"
    assert cut_at - t0 < HEADER_S + 2.0  # generous: a loaded 2-core machine
    assert cut_at - t0 >= HEADER_S * 0.9
    (status, reply), *_ = _responses(data)
    assert status == 408 and reply["error"] == "timeout" and "header" in reply["message"]


def test_a_body_sent_slowly_is_cut_off_too(server):
    sock = server.connect()
    sock.sendall(b"POST /api/x HTTP/1.1\r\nHost: a\r\nContent-Length: 10\r\n\r\n12")
    t0 = time.monotonic()
    data = _read_all(sock)
    sock.close()
    assert time.monotonic() - t0 < BODY_S + 2.0
    assert _responses(data)[0][0] == 408


def test_an_idle_connection_is_closed_quietly(server):
    sock = server.connect()
    t0 = time.monotonic()
    assert _read_all(sock) == b""  # closed without a response
    assert IDLE_S * 0.9 <= time.monotonic() - t0 < IDLE_S + 2.0
    sock.close()
    assert server.errors == []


@pytest.mark.parametrize(
    "headers, needle",
    [
        (b"Content-Length: 2\r\nContent-Length: 5\r\n", "more than one Content-Length"),
        (b"Content-Length: 2\r\ncontent-length: 2\r\n", "more than one content-length"),  # even when equal
        (b"Content-Length: +2\r\n", "digits"),
        (b"Content-Length: 2, 2\r\n", "digits"),
        (b"Content-Length: -1\r\n", "digits"),
        (b"Host: b\r\nContent-Length: 2\r\n", "more than one Host"),
    ],
)
def test_exactly_one_content_length_of_digits(server, headers, needle):
    sock = server.connect()
    sock.sendall(b"POST /api/x HTTP/1.1\r\nHost: a\r\n" + headers + b"\r\nab" + b"GET /smuggled HTTP/1.1\r\n\r\n")
    data = _read_all(sock)
    sock.close()
    replies = _responses(data)
    assert len(replies) == 1  # refused and closed: the bytes after it are never read as a request
    status, reply = replies[0]
    assert status == 400 and needle in reply["message"], reply


def test_well_formed_requests_still_work_with_keep_alive(server):
    sock = server.connect()
    sock.sendall(
        b"\r\nPOST /a HTTP/1.1\r\nHost: x\r\nContent-Length: 3\r\n\r\nabc"
        b"GET /b HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    data = b""
    end = time.monotonic() + 5
    while data.count(b"HTTP/1.1 200") < 2 and time.monotonic() < end:
        data += sock.recv(65536)
    sock.close()
    assert [r for _, r in _responses(data)] == [{"path": "/a", "body": "abc"}, {"path": "/b", "body": ""}]


@pytest.mark.parametrize("target", ["http://[::1/api/state", "http://[x/api/state"])
def test_a_malformed_request_target_gets_a_400_naming_it(server, target):
    """urlsplit raises ValueError on an unclosed IPv6 host; before, nothing caught it: the connection
    closed without an answer and the log showed 'Unhandled exception in client_connected_cb'."""
    sock = server.connect()
    sock.sendall(f"GET {target} HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n".encode())
    ((status, body),) = _responses(_read_all(sock))
    sock.close()
    assert status == 400 and "malformed request target" in body["message"] and target[:10] in body["message"]


# ------------------------------------------------------------------ chunked bodies, bare LF, the target as sent


def _exchange(server, raw: bytes) -> tuple[list[tuple[int, dict]], float]:
    """Send ``raw``, read every response until the server closes; (responses, seconds until the first byte)."""
    sock = server.connect()
    t0 = time.monotonic()
    sock.sendall(raw)
    first = sock.recv(65536)
    took = time.monotonic() - t0
    data = first + _read_all(sock)
    sock.close()
    return _responses(data), took


def test_a_chunked_body_is_decoded_and_the_connection_kept_alive(server):
    """The old reader refused every chunked body with 411 (what fetch with a stream body and requests with a
    generator send); decoded here with an extension, upper-case hex and a trailer field, then a next request."""
    body = b'7;ext=1\r\n{"a": 1\r\nB\r\n, "b": [2]}\r\n0\r\nX-Trailer: t\r\n\r\n'
    raw = (
        b"POST /api/x HTTP/1.1\r\nHost: a\r\nTransfer-Encoding: chunked\r\n\r\n"
        + body
        + b"GET /next HTTP/1.1\r\nHost: a\r\nConnection: close\r\n\r\n"
    )
    replies, _ = _exchange(server, raw)
    assert [r for _, r in replies] == [{"path": "/api/x", "body": '{"a": 1, "b": [2]}'}, {"path": "/next", "body": ""}]
    assert json.loads(replies[0][1]["body"]) == {"a": 1, "b": [2]}  # what the client meant, independently


def test_a_chunked_body_over_the_limit_is_413_and_a_slow_one_408(server):
    from bridge.web.http import MAX_BODY_BYTES

    chunk = b"x" * 40_000
    body = b"".join(b"%x\r\n%s\r\n" % (len(chunk), chunk) for _ in range(3)) + b"0\r\n\r\n"
    assert 3 * len(chunk) > MAX_BODY_BYTES
    replies, _ = _exchange(server, b"POST /api/x HTTP/1.1\r\nHost: a\r\nTransfer-Encoding: chunked\r\n\r\n" + body)
    assert replies[0][0] == 413 and "limit" in replies[0][1]["message"], replies
    replies, took = _exchange(server, b"POST /api/x HTTP/1.1\r\nHost: a\r\nTransfer-Encoding: chunked\r\n\r\n4\r\nab")
    assert replies[0][0] == 408 and BODY_S * 0.9 <= took < BODY_S + 2.0, (replies, took)


@pytest.mark.parametrize(
    "headers, body, status, needle",
    [
        (b"Transfer-Encoding: chunked\r\n", b"zz\r\nab\r\n0\r\n\r\n", 400, "hexadecimal"),
        (b"Transfer-Encoding: chunked\r\n", b"2\r\nabc\r\n0\r\n\r\n", 400, "line end"),
        (b"Transfer-Encoding: chunked\r\n", b"-2\r\nab\r\n0\r\n\r\n", 400, "hexadecimal"),
        (b"Transfer-Encoding: chunked\r\nContent-Length: 5\r\n", b"0\r\n\r\n", 400, "both"),
        (b"Transfer-Encoding: gzip, chunked\r\n", b"0\r\n\r\n", 501, "only chunked"),
        (b"Transfer-Encoding: chunked\r\nTransfer-Encoding: chunked\r\n", b"0\r\n\r\n", 400, "more than one"),
    ],
)
def test_a_body_framing_the_reader_cannot_trust_is_refused_and_closed(server, headers, body, status, needle):
    raw = b"POST /api/x HTTP/1.1\r\nHost: a\r\n" + headers + b"\r\n" + body + b"GET /smuggled HTTP/1.1\r\n\r\n"
    replies, _ = _exchange(server, raw)
    assert len(replies) == 1, replies  # refused and closed: the bytes after it are never read as a request
    assert replies[0][0] == status and needle in replies[0][1]["message"], replies


def test_bare_lf_line_ends_are_taken_at_once(server):
    """RFC 9112 2.2: a recipient may take a bare LF as a line end. The old reader waited for CRLF CRLF and
    answered 408 after the header timeout (10 s in the service) instead of serving the request."""
    replies, took = _exchange(
        server,
        b"POST /api/x HTTP/1.1\nHost: a\nContent-Length: 2\n\nokGET /b HTTP/1.1\r\nHost: a\nConnection: close\n\n",
    )
    assert [r for _, r in replies] == [{"path": "/api/x", "body": "ok"}, {"path": "/b", "body": ""}]
    assert took < HEADER_S * 0.9  # answered, not timed out


def test_a_bare_cr_inside_a_header_line_is_refused(server):
    replies, took = _exchange(server, b"GET /a HTTP/1.1\r\nHost: a\rX-Evil: 1\r\n\r\n")
    assert replies[0][0] == 400 and "bare CR" in replies[0][1]["message"] and took < HEADER_S * 0.9


@pytest.mark.parametrize(
    "target, path", [("//etc/passwd", "//etc/passwd"), ("//a//b?q=//c", "//a//b"), ("/x%2Fy", "/x/y")]
)
def test_an_origin_form_target_is_the_path_as_sent(server, target, path):
    """urlsplit read '//etc' as a host: the terminal answered "nothing at '/passwd'"."""
    replies, _ = _exchange(server, f"GET {target} HTTP/1.1\r\nHost: a\r\nConnection: close\r\n\r\n".encode())
    assert replies == [(200, {"path": path, "body": ""})]
