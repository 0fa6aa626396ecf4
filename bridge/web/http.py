"""A minimal HTTP/1.1 request reader and response writer on asyncio streams.

Enough for one page, its static files, a JSON API and the WebSocket upgrade: request line,
headers, ``Content-Length`` bodies (no chunked uploads), keep-alive. Sizes are bounded so a
misbehaving client cannot make the service allocate without limit.
"""

from __future__ import annotations

import asyncio
import json
from dataclasses import dataclass, field
from http import HTTPStatus
from urllib.parse import unquote, urlsplit

from planner.errors import HitchInputError

__all__ = [
    "HttpError",
    "HttpRequest",
    "read_request",
    "response_bytes",
    "json_response",
    "MAX_HEADER_BYTES",
    "MAX_BODY_BYTES",
]

MAX_HEADER_BYTES = 16 * 1024
MAX_BODY_BYTES = 64 * 1024
_METHODS = {"GET", "HEAD", "POST", "OPTIONS", "PUT", "DELETE", "PATCH"}


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

    def header(self, name: str, default: str = "") -> str:
        return self.headers.get(name.lower(), default)

    @property
    def keep_alive(self) -> bool:
        conn = self.header("connection").lower()
        if self.version == "HTTP/1.0":
            return "keep-alive" in conn
        return "close" not in conn


async def read_request(reader: asyncio.StreamReader, *, max_body: int = MAX_BODY_BYTES) -> HttpRequest | None:
    """Read one request; None at a clean end of stream. Raises :class:`HttpError` on bad input."""
    try:
        head = await reader.readuntil(b"\r\n\r\n")
    except asyncio.IncompleteReadError as exc:
        if not exc.partial.strip():
            return None
        raise HttpError(400, "incomplete request header") from None
    except asyncio.LimitOverrunError:
        raise HttpError(431, f"request header larger than {MAX_HEADER_BYTES} bytes") from None
    if len(head) > MAX_HEADER_BYTES:
        raise HttpError(431, f"request header larger than {MAX_HEADER_BYTES} bytes")
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
        headers[name.lower()] = value.strip()
    if "chunked" in headers.get("transfer-encoding", "").lower():
        raise HttpError(411, "chunked request bodies are not supported; send Content-Length")
    try:
        length = int(headers.get("content-length", "0"))
    except ValueError:
        raise HttpError(400, "Content-Length must be an integer") from None
    if length < 0:
        raise HttpError(400, "Content-Length must be >= 0")
    if length > max_body:
        raise HttpError(413, f"request body of {length} bytes exceeds the limit of {max_body} bytes")
    try:
        body = await reader.readexactly(length) if length else b""
    except asyncio.IncompleteReadError:
        raise HttpError(400, "request body shorter than Content-Length") from None
    parts = urlsplit(target)
    return HttpRequest(method, unquote(parts.path), parts.query, version, headers, body)


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
