"""A minimal HTTP/1.1 request reader and response writer on asyncio streams.

Enough for one page, its static files, a JSON API and the WebSocket upgrade: request line,
headers, ``Content-Length`` and ``Transfer-Encoding: chunked`` bodies, keep-alive. Sizes are bounded
so a misbehaving client cannot make the service allocate without limit, and so is time: a client
that keeps a connection open without starting a request is closed after ``idle_timeout_s``
(:data:`IDLE_TIMEOUT_S`), one that has started a request must finish its header within
``header_timeout_s`` (:data:`HEADER_TIMEOUT_S`, a "slowloris" gets 408) and its body within
``body_timeout_s``. A request has at most one ``Content-Length`` (digits only), ``Host`` and
``Transfer-Encoding`` header: two are refused with 400 (never "the last one wins", which lets
two parsers disagree about where a request ends).

Lines may end in CRLF or in a bare LF (RFC 9112 2.2 lets a recipient take a bare LF as a line end, and
``printf 'POST /api/stop HTTP/1.1\nHost: …\n\n'`` must stop at once, not time out); a bare CR inside a
line is refused with 400. A chunked body (what a streaming client sends: ``fetch`` with a stream body,
``requests`` with a generator) is decoded (RFC 9112 7.1: chunk extensions and trailer fields are read and
dropped) under the same size (413) and time (408) limits as a ``Content-Length`` body; a request with both
``Transfer-Encoding`` and ``Content-Length`` (request smuggling), with a transfer coding other than
``chunked`` (501), or with ``Transfer-Encoding`` in HTTP/1.0 is refused.

``any_body_paths`` (the terminal's ``POST /api/stop``: whatever is sent to stop, stops) are served however
their body is framed: a ``Content-Length`` body over the limit is not read (``unread``), a chunked body is
not waited for (``chunked``: the server serves the request at once and reads the chunks afterwards), and
a framing refused elsewhere (both headers, an unknown coding) is served with an empty body and the
connection closed after the response (``framing_unknown``).
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
    "read_chunked",
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
#: a chunk's size: hexadecimal digits (at most 15: far beyond any body limit, never an overflow)
_HEX = re.compile(r"[0-9A-Fa-f]{1,15}")
#: the longest chunk-size line (size and extensions) taken [bytes]
MAX_CHUNK_LINE_BYTES = 1024
#: what is read and dropped at most after a request whose body is not read (over the limit, unknown
#: framing) before the connection closes [bytes]: the client then reads the response instead of a reset
MAX_DISCARD_BYTES = 1024 * 1024


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
    #: a chunked body not read yet (only for ``any_body_paths``): the server reads it after the response
    #: (:func:`read_chunked`); the connection stays open only if it is read whole and in time
    chunked: bool = False
    #: a body whose framing is not known (both Content-Length and Transfer-Encoding, another coding than
    #: chunked; only for ``any_body_paths``): served with an empty body, the connection closes after the response
    framing_unknown: bool = False
    #: a Content-Length body within the limit not read yet (only for ``any_body_paths``): served on its header,
    #: the server reads it after the response; the connection stays open only if it arrives whole and in time
    deferred: int = 0

    def header(self, name: str, default: str = "") -> str:
        return self.headers.get(name.lower(), default)

    @property
    def keep_alive(self) -> bool:
        if self.unread or self.framing_unknown:
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
        while not _head_ends(head):
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
        if not _empty_line(head):
            return bytes(head)
    raise HttpError(400, "too many empty lines before the request line")


def _head_ends(head: bytearray) -> bool:
    """Does ``head`` (whole lines but maybe the first) end with an empty line, or is it a stray empty line?
    Lines end in CRLF or a bare LF (RFC 9112 2.2)."""
    return _empty_line(head) or head.endswith((b"\n\r\n", b"\n\n"))


def _empty_line(line: bytes | bytearray) -> bool:
    """A line with nothing before its CRLF or bare LF."""
    return line == b"\r\n" or line == b"\n"


def _lines(head: bytes) -> list[str]:
    """The header's lines without their CRLF or bare LF; a CR anywhere else is refused (RFC 9112 2.2)."""
    lines = [ln[:-1] if ln.endswith("\r") else ln for ln in head.decode("latin-1").split("\n")]
    for ln in lines:
        if "\r" in ln:
            raise HttpError(400, f"bare CR in the request header line {ln[:40]!r}")
    return lines


def _split_target(target: str) -> tuple[str, str]:
    """(path, query) of a request target. An origin-form target (``/a/b?q``) is taken as sent: ``//etc/passwd``
    is the path ``//etc/passwd`` (urlsplit would read ``etc`` as a host and report ``/passwd``); an
    absolute-form one (``http://host/a``) is split as a URL."""
    if target.startswith("/"):
        path, _, query = target.partition("?")
        return path, query
    try:
        parts = urlsplit(target)
    except ValueError as exc:  # e.g. 'http://[::1/api/state': an unclosed IPv6 host
        raise HttpError(400, f"malformed request target {target[:60]!r}: {exc}") from None
    return parts.path, parts.query


async def _line(reader: asyncio.StreamReader, deadline: float, what: str, limit: int) -> bytes:
    """One line of a chunked body (up to and including its LF), read before ``deadline`` (TimeoutError after
    it); 400 over ``limit``."""
    remaining = deadline - asyncio.get_running_loop().time()
    try:
        if remaining <= 0:
            raise TimeoutError
        line = await asyncio.wait_for(reader.readuntil(b"\n"), remaining)
    except asyncio.IncompleteReadError:
        raise HttpError(400, f"chunked request body ends inside its {what}") from None
    except asyncio.LimitOverrunError:
        raise HttpError(400, f"chunked request body: {what} longer than {limit} bytes") from None
    if len(line) > limit:
        raise HttpError(400, f"chunked request body: {what} longer than {limit} bytes")
    return line


async def _line_end(reader: asyncio.StreamReader, deadline: float) -> bool:
    """Is what follows a chunk's data a line end (CRLF or a bare LF)? Reads one or two bytes (TimeoutError
    after ``deadline``)."""
    remaining = deadline - asyncio.get_running_loop().time()
    try:
        if remaining <= 0:
            raise TimeoutError
        first = await asyncio.wait_for(reader.readexactly(1), remaining)
        if first == b"\r":
            first = await asyncio.wait_for(reader.readexactly(1), max(deadline - asyncio.get_running_loop().time(), 0))
    except asyncio.IncompleteReadError:
        raise HttpError(400, "chunked request body ends after a chunk's data") from None
    return first == b"\n"


async def read_chunked(
    reader: asyncio.StreamReader, max_body: int = MAX_BODY_BYTES, timeout_s: float = BODY_TIMEOUT_S
) -> bytes:
    """A ``Transfer-Encoding: chunked`` body (RFC 9112 7.1), decoded: chunk extensions and trailer fields are
    read and dropped, lines may end in a bare LF. :class:`HttpError` 413 when the data exceed ``max_body``
    bytes, 408 when the body (up to its last chunk and trailer) does not arrive within ``timeout_s``, 400 when
    it is malformed (a size that is not hexadecimal, data not followed by a line end, an early end of stream)."""
    try:
        return await _chunks(reader, max_body, asyncio.get_running_loop().time() + timeout_s)
    except TimeoutError:
        raise HttpError(408, f"request body not complete within {timeout_s:g} s", "timeout") from None


async def _chunks(reader: asyncio.StreamReader, max_body: int, deadline: float) -> bytes:
    body = bytearray()
    while True:
        line = await _line(reader, deadline, "chunk-size line", MAX_CHUNK_LINE_BYTES)
        size_text = line.decode("latin-1").rstrip("\r\n").split(";", 1)[0].strip(" \t")
        if not _HEX.fullmatch(size_text):
            raise HttpError(400, f"chunked request body: chunk size {size_text[:20]!r} is not hexadecimal digits")
        size = int(size_text, 16)
        if size == 0:
            break
        if len(body) + size > max_body:
            raise HttpError(413, f"chunked request body exceeds the limit of {max_body} bytes")
        remaining = deadline - asyncio.get_running_loop().time()
        try:
            if remaining <= 0:
                raise TimeoutError
            body += await asyncio.wait_for(reader.readexactly(size), remaining)
        except asyncio.IncompleteReadError:
            raise HttpError(400, "chunked request body ends inside a chunk") from None
        if not await _line_end(reader, deadline):
            raise HttpError(400, "chunked request body: a chunk's data is not followed by a line end (CRLF)")
    trailer = 0
    while True:  # trailer fields, dropped, up to the empty line
        line = await _line(reader, deadline, "trailer", MAX_HEADER_BYTES)
        if _empty_line(line):
            return bytes(body)
        trailer += len(line)
        if trailer > MAX_HEADER_BYTES:
            raise HttpError(431, f"chunked request body: trailer larger than {MAX_HEADER_BYTES} bytes")


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
    is served whatever its body: over ``max_body`` it comes back at once with an empty body and
    ``unread`` = its length; chunked, at once with ``chunked`` (the caller reads the body after serving it:
    :func:`read_chunked`); with a framing refused elsewhere, at once with ``framing_unknown`` (the caller
    closes the connection after the response)."""
    head = await _read_head(reader, idle_timeout_s, header_timeout_s)
    if head is None:
        return None
    lines = _lines(head)
    try:
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
    raw_path, query = _split_target(target)
    path = unquote(raw_path)
    any_body = method == "POST" and path in any_body_paths
    if "transfer-encoding" in headers:
        codings = [c.strip().lower() for c in headers["transfer-encoding"].split(",")]
        refusal: HttpError | None = None
        if "content-length" in headers:
            refusal = HttpError(400, "the request has both Transfer-Encoding and Content-Length (send one of them)")
        elif version == "HTTP/1.0":
            refusal = HttpError(400, "Transfer-Encoding is not allowed in an HTTP/1.0 request; send Content-Length")
        elif codings != ["chunked"]:
            refusal = HttpError(
                501,
                f"Transfer-Encoding {headers['transfer-encoding'][:40]!r} is not supported (only chunked)",
                "not_implemented",
            )
        if refusal is not None:
            if any_body:  # a stop stops; what follows its header cannot be told apart from a next request
                return HttpRequest(method, path, query, version, headers, b"", framing_unknown=True)
            raise refusal
        if any_body:  # served at once; its chunks are read after the response
            return HttpRequest(method, path, query, version, headers, b"", chunked=True)
        body = await read_chunked(reader, max_body, body_timeout_s)
        return HttpRequest(method, path, query, version, headers, body)
    raw_length = headers.get("content-length", "0")
    if not _DIGITS.fullmatch(raw_length):
        raise HttpError(400, f"Content-Length must be a non-negative integer of digits, got {raw_length[:20]!r}")
    length = int(raw_length)
    if length > max_body and any_body:
        return HttpRequest(method, path, query, version, headers, b"", unread=length)
    if length and any_body:  # a stop is served on its header: a slow or short body (Expect: 100-continue) never
        return HttpRequest(method, path, query, version, headers, b"", deferred=length)  # holds it back
    if length > max_body:
        raise HttpError(413, f"request body of {length} bytes exceeds the limit of {max_body} bytes")
    try:
        body = await asyncio.wait_for(reader.readexactly(length), body_timeout_s) if length else b""
    except TimeoutError:
        raise HttpError(408, f"request body not complete within {body_timeout_s:g} s", "timeout") from None
    except asyncio.IncompleteReadError:
        raise HttpError(400, "request body shorter than Content-Length") from None
    return HttpRequest(method, path, query, version, headers, body)


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
