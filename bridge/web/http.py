"""A minimal HTTP/1.1 request reader and response writer on asyncio streams.

Enough for one page, its static files, a JSON API and the WebSocket upgrade: request line,
headers, ``Content-Length`` bodies (no chunked uploads), keep-alive. Sizes are bounded so a
misbehaving client cannot make the service allocate without limit, and so is time: a client
that keeps a connection open without starting a request is closed after ``idle_timeout_s``
(:data:`IDLE_TIMEOUT_S`), one that has started a request must finish its header within
``header_timeout_s`` (:data:`HEADER_TIMEOUT_S`, a "slowloris" gets 408) and its body within
``body_timeout_s``. A request has at most one ``Content-Length`` (digits only), ``Host`` and
``Transfer-Encoding`` header: two are refused with 400 (never "the last one wins", which lets
two parsers disagree about where a request ends).
"""

from __future__ import annotations

import asyncio
import json
import re
from dataclasses import dataclass, field
from http import HTTPStatus
from urllib.parse import unquote, urlsplit

from planner.errors import HitchInputError

__all__ = [
    "HttpError",
    "HttpRequest",
    "read_request",
    "discard",
    "response_bytes",
    "json_response",
    "MAX_HEADER_BYTES",
    "MAX_BODY_BYTES",
    "HEADER_TIMEOUT_S",
    "IDLE_TIMEOUT_S",
    "BODY_TIMEOUT_S",
]

MAX_HEADER_BYTES = 16 * 1024
#: a request body's limit [bytes]: the service's own payload limit (``schemas.MAX_PAYLOAD_BYTES``: a 64 KiB
#: maneuver script, JSON-escaped, fits), so what Zenoh takes the terminal's HTTP API takes too
MAX_BODY_BYTES = 96 * 1024
#: from the first byte of a request to the end of its header [s]
HEADER_TIMEOUT_S = 10.0
#: a kept-alive connection waiting for its next request is closed after this time [s]
IDLE_TIMEOUT_S = 120.0
#: from the end of the header to the end of the body [s]
BODY_TIMEOUT_S = 10.0
_METHODS = {"GET", "HEAD", "POST", "OPTIONS", "PUT", "DELETE", "PATCH"}
#: headers a request may carry only once (two could be read differently by a proxy and by us)
_SINGLE = ("content-length", "host", "transfer-encoding")
_DIGITS = re.compile(r"[0-9]{1,15}")


class HttpError(HitchInputError):
    """A request the server answers with an error status; the message is shown to the client."""

    def __init__(self, status: int, message: str, code: str = "bad_request"):
        self.status = status
        self.code = code
        super().__init__(message)


@dataclass(frozen=True)
class HttpRequest:
    """One parsed request; header names are lower-case."""

    method: str
    path: str
    query: str
    version: str
    headers: dict = field(default_factory=dict)
    body: bytes = b""
    #: bytes of a body over the limit that were not read (only for ``any_body_paths``: see
    #: :func:`read_request`); the connection closes after the response, the server discards them first
    unread: int = 0

    def header(self, name: str, default: str = "") -> str:
        return self.headers.get(name.lower(), default)

    @property
    def keep_alive(self) -> bool:
        if self.unread:
            return False
        conn = self.header("connection").lower()
        if self.version == "HTTP/1.0":
            return "keep-alive" in conn
        return "close" not in conn


async def _read_head(reader: asyncio.StreamReader, idle_timeout_s: float, header_timeout_s: float) -> bytes | None:
    """The header up to and including the blank line; None at a clean end of stream or when idle."""
    loop = asyncio.get_running_loop()
    for _ in range(64):  # stray CRLFs between kept-alive requests may be ignored (RFC 9112 2.2), a few of them
        try:
            first = await asyncio.wait_for(reader.read(1), idle_timeout_s)
        except TimeoutError:
            return None  # an idle kept-alive connection: close it quietly
        if not first:
            return None
        deadline = loop.time() + header_timeout_s
        head = bytearray(first)
        while not head.endswith(b"\r\n\r\n") and head != b"\r\n":
            remaining = deadline - loop.time()
            try:
                if remaining <= 0:
                    raise TimeoutError
                head += await asyncio.wait_for(reader.readuntil(b"\n"), remaining)
            except TimeoutError:
                raise HttpError(408, f"request header not complete within {header_timeout_s:g} s", "timeout") from None
            except asyncio.IncompleteReadError as exc:
                if not (bytes(head) + exc.partial).strip():
                    return None
                raise HttpError(400, "incomplete request header") from None
            except asyncio.LimitOverrunError:
                raise HttpError(431, f"request header larger than {MAX_HEADER_BYTES} bytes") from None
            if len(head) > MAX_HEADER_BYTES:
                raise HttpError(431, f"request header larger than {MAX_HEADER_BYTES} bytes")
        if head != b"\r\n":
            return bytes(head)
    raise HttpError(400, "too many empty lines before the request line")


async def read_request(
    reader: asyncio.StreamReader,
    *,
    max_body: int = MAX_BODY_BYTES,
    header_timeout_s: float = HEADER_TIMEOUT_S,
    idle_timeout_s: float = IDLE_TIMEOUT_S,
    body_timeout_s: float = BODY_TIMEOUT_S,
    any_body_paths: frozenset[str] = frozenset(),
) -> HttpRequest | None:
    """Read one request; None at a clean end of stream (or an idle connection). Raises
    :class:`HttpError` on bad input (408 when the header or body does not arrive in time).

    A POST to one of ``any_body_paths`` (the terminal's ``/api/stop``: whatever is sent to stop, stops)
    with a body over ``max_body`` is not refused: it comes back at once with an empty body and
    ``unread`` = its length, so the request is served without waiting for the body."""
    head = await _read_head(reader, idle_timeout_s, header_timeout_s)
    if head is None:
        return None
    try:
        lines = head.decode("latin-1").split("\r\n")
        method, target, version = lines[0].split(" ")
    except ValueError:
        raise HttpError(400, "malformed request line") from None
    if method not in _METHODS or version not in ("HTTP/1.0", "HTTP/1.1"):
        raise HttpError(400, f"unsupported method or version: {method} {version}")
    headers: dict[str, str] = {}
    for line in lines[1:]:
        if not line:
            continue
        name, sep, value = line.partition(":")
        if not sep or not name.strip() or name != name.strip():
            raise HttpError(400, f"malformed header line {line[:40]!r}")
        key = name.lower()
        if key in _SINGLE and key in headers:
            raise HttpError(400, f"the request has more than one {name} header (exactly one is allowed)")
        headers[key] = value.strip()
    if "transfer-encoding" in headers:
        raise HttpError(411, "Transfer-Encoding (chunked) request bodies are not supported; send Content-Length")
    raw_length = headers.get("content-length", "0")
    if not _DIGITS.fullmatch(raw_length):
        raise HttpError(400, f"Content-Length must be a non-negative integer of digits, got {raw_length[:20]!r}")
    length = int(raw_length)
    try:
        parts = urlsplit(target)
    except ValueError as exc:  # e.g. 'http://[::1/api/state': an unclosed IPv6 host
        raise HttpError(400, f"malformed request target {target[:60]!r}: {exc}") from None
    if length > max_body and method == "POST" and unquote(parts.path) in any_body_paths:
        return HttpRequest(method, unquote(parts.path), parts.query, version, headers, b"", unread=length)
    if length > max_body:
        raise HttpError(413, f"request body of {length} bytes exceeds the limit of {max_body} bytes")
    try:
        body = await asyncio.wait_for(reader.readexactly(length), body_timeout_s) if length else b""
    except TimeoutError:
        raise HttpError(408, f"request body not complete within {body_timeout_s:g} s", "timeout") from None
    except asyncio.IncompleteReadError:
        raise HttpError(400, "request body shorter than Content-Length") from None
    return HttpRequest(method, unquote(parts.path), parts.query, version, headers, body)


async def discard(reader: asyncio.StreamReader, n: int, timeout_s: float = BODY_TIMEOUT_S) -> None:
    """Read and drop up to ``n`` bytes within ``timeout_s`` (a body not read, before the connection
    closes: the client then reads the response instead of a reset); stops early at the end of stream."""
    loop = asyncio.get_running_loop()
    end = loop.time() + timeout_s
    while n > 0:
        left = end - loop.time()
        if left <= 0:
            return
        try:
            chunk = await asyncio.wait_for(reader.read(min(n, 65536)), left)
        except TimeoutError:
            return
        if not chunk:
            return
        n -= len(chunk)


def response_bytes(
    status: int,
    body: bytes = b"",
    content_type: str = "text/plain; charset=utf-8",
    *,
    headers: dict | None = None,
    keep_alive: bool = True,
    head_only: bool = False,
) -> bytes:
    """A complete response with ``Content-Length`` and conservative security headers."""
    reason = HTTPStatus(status).phrase
    all_headers = {
        "Content-Type": content_type,
        "Content-Length": str(len(body)),
        "Cache-Control": "no-store",
        "X-Content-Type-Options": "nosniff",
        "X-Frame-Options": "DENY",
        "Referrer-Policy": "no-referrer",
        "Connection": "keep-alive" if keep_alive else "close",
        **(headers or {}),
    }
    head = f"HTTP/1.1 {status} {reason}\r\n" + "".join(f"{k}: {v}\r\n" for k, v in all_headers.items()) + "\r\n"
    return head.encode("latin-1") + (b"" if head_only else body)


def json_response(status: int, obj, *, keep_alive: bool = True) -> bytes:
    """A JSON response (``application/json``); NaN/∞ are refused by the encoder, never sent."""
    body = json.dumps(obj, allow_nan=False, separators=(",", ":")).encode("utf-8")
    return response_bytes(status, body, "application/json", keep_alive=keep_alive)
