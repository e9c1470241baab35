"""The link's framing: how the scout's messages are cut out of the TCP byte stream at the base.

One message = a 25-byte header and a body::

    magic "LWBL" | kind u8 | seq u32 | due f64 | body_len u32 | crc32 u32 (of the 21 bytes before it)

``kind`` is HELLO (body: the stream header as JSON -- codec, parameters, sensor table -- sent
first on every connection, so a restarted base learns the table again), FRAME (body: one
lwbench payload, exactly the bytes a run measures) or END (body: JSON, the scout is done).
``due`` is when the frame's scan was due (``time.monotonic``, one clock for every process of
the machine), so the base can time each frame from capture to decode.

The header has its own checksum because a bad length would desynchronise the stream; the body
is not checked here -- a FRAME's payload carries its own CRC32 and the base's decoder rejects a
corrupted one (that is the fault ``--corrupt`` injects). Nothing is pickled.
"""

from __future__ import annotations

import json
import socket
import struct
import zlib
from dataclasses import dataclass
from typing import Any

from lwbench.errors import LwbenchError

__all__ = ["END", "FRAME", "HELLO", "HEADER", "Message", "WireError", "pack", "read_message"]

MAGIC = b"LWBL"
HELLO, FRAME, END = 1, 2, 3
_HEAD = struct.Struct("<4sBIdI")
_CRC = struct.Struct("<I")
HEADER = _HEAD.size + _CRC.size
MAX_BODY = 256 << 20  # no scan payload comes near it; a larger length is a broken stream


class WireError(LwbenchError):
    """The byte stream is not lwbench link framing (the connection cannot be trusted further)."""


@dataclass(frozen=True)
class Message:
    kind: int
    seq: int
    due: float
    body: bytes

    def json(self) -> Any:
        try:
            return json.loads(self.body.decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise WireError(f"message {self.kind}/{self.seq}: body is not JSON ({exc})") from None


def pack(kind: int, seq: int, due: float, body: bytes) -> bytes:
    head = _HEAD.pack(MAGIC, kind, seq, due, len(body))
    return head + _CRC.pack(zlib.crc32(head)) + body


def pack_json(kind: int, seq: int, due: float, obj: Any) -> bytes:
    return pack(kind, seq, due, json.dumps(obj, separators=(",", ":")).encode())


def _read_exact(sock: socket.socket, n: int) -> bytes | None:
    buf = bytearray()
    while len(buf) < n:
        chunk = sock.recv(min(n - len(buf), 1 << 20))
        if not chunk:
            if buf:
                raise WireError(f"connection closed inside a message ({len(buf)} of {n} bytes)")
            return None
        buf += chunk
    return bytes(buf)


def read_message(sock: socket.socket) -> Message | None:
    """The next message, or None at a clean end of stream (the peer closed between messages)."""
    head = _read_exact(sock, HEADER)
    if head is None:
        return None
    magic, kind, seq, due, n = _HEAD.unpack_from(head)
    (crc,) = _CRC.unpack_from(head, _HEAD.size)
    if magic != MAGIC or zlib.crc32(head[: _HEAD.size]) != crc:
        raise WireError("bad message header (not lwbench link framing, or corrupted)")
    if kind not in (HELLO, FRAME, END) or n > MAX_BODY:
        raise WireError(f"bad message header (kind {kind}, {n} body bytes)")
    body = _read_exact(sock, n) if n else b""
    if body is None:
        raise WireError("connection closed before a message body")
    return Message(kind, seq, due, body)
