"""WebSocket framing and handshake (RFC 6455) on asyncio streams, server side only.

Just what the operator page needs: text and binary messages (fragmented or not), ping/pong,
the closing handshake, a per-message size limit. No extensions (no permessage-deflate), no
subprotocols. Client frames must be masked (RFC 6455 §5.1); server frames are not.

Pure pieces (:func:`accept_key`, :func:`encode_frame`, :func:`decode_frame`) are separate from
the connection object (:class:`WebSocket`) so they can be checked against the RFC's own
examples.
"""

from __future__ import annotations

import asyncio
import base64
import hashlib
import struct
from dataclasses import dataclass

from planner.errors import HitchInputError

__all__ = [
    "WebSocketError",
    "Frame",
    "WebSocket",
    "accept_key",
    "encode_frame",
    "decode_frame",
    "OP_CONT",
    "OP_TEXT",
    "OP_BINARY",
    "OP_CLOSE",
    "OP_PING",
    "OP_PONG",
    "MAX_MESSAGE_BYTES",
]

_GUID = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"  # RFC 6455 §1.3
OP_CONT, OP_TEXT, OP_BINARY, OP_CLOSE, OP_PING, OP_PONG = 0x0, 0x1, 0x2, 0x8, 0x9, 0xA
_CONTROL = {OP_CLOSE, OP_PING, OP_PONG}
_KNOWN = {OP_CONT, OP_TEXT, OP_BINARY} | _CONTROL
#: close codes that must never appear on the wire (RFC 6455 §7.4.1)
_RESERVED_CODES = {1004, 1005, 1006, 1015}
#: largest message accepted from a client: a command's payload may be as large as the service takes
#: (``schemas.MAX_PAYLOAD_BYTES``, 96 KiB: a maneuver script), plus its envelope (id, key, CSRF token)
MAX_MESSAGE_BYTES = 100 * 1024


class WebSocketError(HitchInputError):
    """A protocol violation by the peer; ``close_code`` is the RFC 6455 status to close with."""

    def __init__(self, message: str, close_code: int = 1002):
        self.close_code = close_code
        super().__init__(message)


@dataclass(frozen=True)
class Frame:
    """One decoded frame: ``fin`` flag, opcode and unmasked payload."""

    fin: bool
    opcode: int
    payload: bytes
    masked: bool = True


def accept_key(client_key: str) -> str:
    """``Sec-WebSocket-Accept`` for a client's ``Sec-WebSocket-Key`` (RFC 6455 §4.2.2)."""
    try:
        raw = base64.b64decode(client_key.strip(), validate=True)
    except (ValueError, TypeError):
        raw = b""
    if len(raw) != 16:
        raise WebSocketError("Sec-WebSocket-Key must be 16 random bytes, base64-encoded", 1002)
    digest = hashlib.sha1((client_key.strip() + _GUID).encode("ascii")).digest()
    return base64.b64encode(digest).decode("ascii")


def _mask(payload: bytes, key: bytes) -> bytes:
    if not payload:
        return payload
    n = len(payload)
    repeated = (key * (n // 4 + 1))[:n]
    return (int.from_bytes(payload, "big") ^ int.from_bytes(repeated, "big")).to_bytes(n, "big")


def encode_frame(opcode: int, payload: bytes = b"", *, fin: bool = True, mask: bytes | None = None) -> bytes:
    """Bytes of one frame; ``mask`` (4 bytes) only for client frames (tests)."""
    if opcode not in _KNOWN:
        raise WebSocketError(f"opcode {opcode:#x} is not one of 0x0-0x2, 0x8-0xA")
    if opcode in _CONTROL and (len(payload) > 125 or not fin):
        raise WebSocketError("control frames carry at most 125 bytes and cannot be fragmented")
    head = bytes([(0x80 if fin else 0) | opcode])
    mbit = 0x80 if mask is not None else 0
    n = len(payload)
    if n < 126:
        head += bytes([mbit | n])
    elif n < 1 << 16:
        head += bytes([mbit | 126]) + struct.pack("!H", n)
    else:
        head += bytes([mbit | 127]) + struct.pack("!Q", n)
    if mask is not None:
        if len(mask) != 4:
            raise WebSocketError("mask must be 4 bytes")
        return head + mask + _mask(payload, mask)
    return head + payload


def decode_frame(
    data: bytes | bytearray, *, require_mask: bool = True, max_bytes: int = MAX_MESSAGE_BYTES
) -> tuple[Frame, int] | None:
    """Decode one frame from the start of ``data``: ``(frame, bytes used)``, or None if incomplete."""
    if len(data) < 2:
        return None
    b0, b1 = data[0], data[1]
    fin, rsv, opcode = bool(b0 & 0x80), b0 & 0x70, b0 & 0x0F
    masked, n = bool(b1 & 0x80), b1 & 0x7F
    if rsv:
        raise WebSocketError("reserved bits set but no extension was negotiated")
    if opcode not in _KNOWN:
        raise WebSocketError(f"unknown opcode {opcode:#x}")
    if require_mask and not masked:
        raise WebSocketError("client frames must be masked (RFC 6455 §5.1)")
    i = 2
    if n == 126:
        if len(data) < 4:
            return None
        n, i = struct.unpack("!H", data[2:4])[0], 4
    elif n == 127:
        if len(data) < 10:
            return None
        n, i = struct.unpack("!Q", data[2:10])[0], 10
    if opcode in _CONTROL and (n > 125 or not fin):
        raise WebSocketError("control frames carry at most 125 bytes and cannot be fragmented")
    if n > max_bytes:
        raise WebSocketError(f"frame of {n} bytes exceeds the limit of {max_bytes} bytes", 1009)
    key = b""
    if masked:
        if len(data) < i + 4:
            return None
        key, i = bytes(data[i : i + 4]), i + 4
    if len(data) < i + n:
        return None
    payload = bytes(data[i : i + n])
    return Frame(fin, opcode, _mask(payload, key) if masked else payload, masked), i + n


class WebSocket:
    """A server-side WebSocket connection on an asyncio stream pair (after the handshake).

    :meth:`recv` returns the next text (``str``) or binary (``bytes``) message, answers pings
    and returns None once the connection is closed. :meth:`send_text` may be called from
    several tasks: sends are serialised by a lock.
    """

    def __init__(
        self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter, *, max_message_bytes: int = MAX_MESSAGE_BYTES
    ):
        self._reader, self._writer = reader, writer
        self.max_message_bytes = max_message_bytes
        self._send_lock = asyncio.Lock()
        self._buf = bytearray()
        self.closed = False

    @property
    def buffered(self) -> bool:
        """Bytes of the peer's next frames already read (a :meth:`recv` may return without waiting)."""
        return bool(self._buf)

    async def _read_frame(self) -> Frame:
        while True:
            got = decode_frame(self._buf, max_bytes=self.max_message_bytes)
            if got is not None:
                frame, used = got
                # drop the frame from the front in place (a bytearray's front is cut without a copy): a
                # 64 KiB read of thousands of tiny frames was copied once per frame, quadratic in a flood
                del self._buf[:used]
                return frame
            chunk = await self._reader.read(65536)
            if not chunk:
                raise ConnectionResetError("peer closed the TCP connection")
            self._buf += chunk

    async def recv(self) -> str | bytes | None:
        """Next message, or None when the connection is (now) closed."""
        parts: list[bytes] = []
        first_op = None
        while not self.closed:
            try:
                frame = await self._read_frame()
            except WebSocketError as exc:
                await self.close(exc.close_code, str(exc)[:100])
                return None
            except (ConnectionError, asyncio.IncompleteReadError, OSError):
                self.closed = True
                return None
            if frame.opcode == OP_PING:
                await self._send(OP_PONG, frame.payload)
                continue
            if frame.opcode == OP_PONG:
                continue
            if frame.opcode == OP_CLOSE:
                code = struct.unpack("!H", frame.payload[:2])[0] if len(frame.payload) >= 2 else 1000
                await self.close(code if 1000 <= code < 5000 and code not in _RESERVED_CODES else 1002)
                return None
            if frame.opcode == OP_CONT and first_op is None:
                await self.close(1002, "continuation frame without a message")
                return None
            if frame.opcode != OP_CONT and first_op is not None:
                await self.close(1002, "new message inside a fragmented one")
                return None
            first_op = frame.opcode if first_op is None else first_op
            parts.append(frame.payload)
            if sum(map(len, parts)) > self.max_message_bytes:
                await self.close(1009, "message too big")
                return None
            if frame.fin:
                data = b"".join(parts)
                if first_op == OP_BINARY:
                    return data
                try:
                    return data.decode("utf-8")
                except UnicodeDecodeError:
                    await self.close(1007, "text message is not valid UTF-8")
                    return None
        return None

    async def _send(self, opcode: int, payload: bytes) -> None:
        async with self._send_lock:
            if self.closed and opcode != OP_CLOSE:
                raise ConnectionResetError("WebSocket is closed")
            if self._writer.is_closing():  # the peer is gone: asyncio would log every further write
                self.closed = True
                raise ConnectionResetError("the peer closed the TCP connection")
            self._writer.write(encode_frame(opcode, payload))
            await self._writer.drain()

    async def send_text(self, text: str) -> None:
        """Send one text message (raises ConnectionError once closed)."""
        await self._send(OP_TEXT, text.encode("utf-8"))

    async def close(self, code: int = 1000, reason: str = "") -> None:
        """Send a close frame (once) and close the TCP stream."""
        if self.closed:
            return
        self.closed = True
        try:
            await self._send(OP_CLOSE, struct.pack("!H", code) + reason.encode("utf-8")[:120])
        except (ConnectionError, OSError, RuntimeError):
            pass
        try:
            self._writer.close()
        except (ConnectionError, OSError, RuntimeError):
            pass
