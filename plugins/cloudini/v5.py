"""Cloudini V5 messages of FLOAT32 fields (LOSSY + ZSTD), written and read with numpy + zstandard.

Cloudini's format (github.com/facontidavide/cloudini, Apache-2.0) as its encoders write it for
a cloud whose fields are all FLOAT32 at one ``resolution`` -- what Cloudini's ROS converter and
this codec send. The description below is what this module implements; it was learned from the
format's description and the Apache-2.0 C++ sources, and checked byte for byte against
``pureini`` 0.10 (a Rust Cloudini, GPL-3.0, used only by the tests as an oracle).

Header (text)
    ``CLOUDINI_V05\\n`` and a YAML block -- ``version: 5``, ``width``, ``height``, ``point_step``,
    ``encoding_opt: LOSSY``, ``compression_opt: ZSTD``, then ``fields:`` with each field's
    ``name``, ``offset``, ``type: FLOAT32`` and ``resolution`` (the float32 value, written with the
    fewest digits that read back to it, never in exponent form: ``0.001``, ``0.000001``, ``10``)
    -- closed by one NUL byte.
Chunks
    Points in groups of :data:`POINTS_PER_CHUNK`, each chunk a little-endian u32 length and one
    zstd frame (level 1, content size declared, no checksum) of its stage-1 bytes. A cloud of 0
    points is the header alone.
Stage 1 (per chunk, point after point, field after field)
    ``q = rint(value * m)`` in float32 arithmetic, ``m = float32(1) / float32(resolution)``
    (999.99994 for 1 mm: 0.0085 m gives 8), ties to even, saturated to int32 (this writer
    refuses such a value instead); the difference to the previous point's ``q`` of the same
    field (0 before a chunk's first point), wrapped to int32; its zig-zag code plus one as an
    unsigned LEB128 varint (1-5 bytes). The byte 0 is reserved: a NaN (or inf) value, after
    which the field's previous ``q`` is 0 again. Decoding gives ``float32(q * resolution)``.

Every per-value step is a numpy operation over the whole cloud, no Python loop over points: the
varint coder spreads each code's 7-bit groups into the bytes of one uint64 (five masks and
shifts) and keeps the nonzero bytes; the reader finds the varints' last bytes (< 0x80) and
gathers the 8 bytes from each start as one unaligned uint64.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

import numpy as np

from lwbench import PayloadError, zstd_decompress

__all__ = [
    "MAGIC",
    "MAX_VARINT_BYTES",
    "POINTS_PER_CHUNK",
    "ZSTD_LEVEL",
    "header",
    "quantize",
    "read_body",
    "write_body",
]

MAGIC = b"CLOUDINI_V05\n"
#: Points per chunk, Cloudini's constant: every chunk restarts the differences (a reader may
#: decode chunks in parallel).
POINTS_PER_CHUNK = 32_768
#: The longest stage-1 code: the zig-zag of an int32 difference plus one is at most 2**32, 33
#: bits, five groups of seven.
MAX_VARINT_BYTES = 5
#: Cloudini's zstd level (``ZSTD_compressCCtx(..., 1)``).
ZSTD_LEVEL = 1
_MAX_CODE = 1 << 32
_CHUNK_LENGTH = struct.Struct("<I")


def _resolution_text(resolution: float) -> str:
    """The float32 resolution as Cloudini's YAML writes it: shortest round-trip digits, positional."""
    return np.format_float_positional(np.float32(resolution), unique=True, trim="-")


def header(n: int, resolution: float, fields: Sequence[str]) -> bytes:
    """The Cloudini header of a one-row cloud of ``n`` points whose ``fields`` are FLOAT32 at
    ``resolution``, packed 4 bytes apart."""
    res = _resolution_text(resolution)
    lines = [
        "version: 5",
        f"width: {n}",
        "height: 1",
        f"point_step: {4 * len(fields)}",
        "encoding_opt: LOSSY",
        "compression_opt: ZSTD",
        "fields:",
    ]
    for i, name in enumerate(fields):
        lines += [f"  - name: {name}", f"    offset: {4 * i}", "    type: FLOAT32", f"    resolution: {res}"]
    return MAGIC + ("\n".join(lines) + "\n").encode() + b"\x00"


def quantize(values: np.ndarray, resolution: float) -> np.ndarray:
    """``int32 (n, k)``: Cloudini's quantized values of a finite float32 cloud. A value whose
    quantum does not fit int32 raises ``ValueError``: Cloudini would saturate it and decode
    another value."""
    v = np.asarray(values, dtype=np.float32)
    with np.errstate(over="ignore", invalid="ignore"):
        q = np.rint(v * (np.float32(1.0) / np.float32(resolution)))
    if not np.isfinite(q).all():
        raise ValueError("cloudini: the cloud holds NaN or inf values")
    if q.size and not (np.abs(q) < 2.0**31).all():
        worst = float(np.abs(v).max())
        raise ValueError(f"cloudini: a value of {worst:.1f} does not fit int32 at resolution {resolution}")
    return q.astype(np.int32)


def _chunk_starts(n: int) -> np.ndarray:
    return np.arange(0, n, POINTS_PER_CHUNK)


# Byte j of a varint holds bits 7j..7j+6 of its code: spreading the 7-bit groups of a code
# into the bytes of one word (and back) is a mask and a shift per byte over the whole array.
# Codes below 2**28 (four bytes; at 1 mm every difference under 134 km) take uint32 words,
# half the memory traffic of uint64 (the varint coder on KITTI 00 frame 0: 4.8 vs 8.0 ms).
_NARROW = 1 << 28


def _word(wide: bool) -> tuple[type[np.unsignedinteger], int]:
    return (np.uint64, MAX_VARINT_BYTES) if wide else (np.uint32, 4)


def _varints(zigzag: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(bytes, length of each code): the LEB128 varints of the codes ``zigzag + 1`` (``zigzag``
    uint32), concatenated."""
    kind, width = _word(len(zigzag) > 0 and int(zigzag.max()) >= _NARROW - 1)
    c = zigzag.astype(kind) + kind(1)
    lengths = np.ones(c.shape, np.uint8)
    words = c & kind(0x7F)
    for j in range(1, width):
        lengths += c >= kind(1 << (7 * j))
        words |= (c & kind(0x7F << (7 * j))) << kind(j)
    # The continuation bit on every byte but the last: 0x80 in bytes 0 .. length-2.
    words |= ((kind(1) << (kind(8) * (lengths - np.uint8(1)))) - kind(1)) & kind(int("80" * width, 16))
    # A code is at least 1, so a varint's bytes are all nonzero (its last byte holds the top
    # nonzero group, the others the continuation bit) and the bytes past it are 0.
    raw = words.astype(np.dtype(kind).newbyteorder("<"), copy=False).view(np.uint8)
    return np.compress(raw != 0, raw), lengths


def write_body(values: np.ndarray, resolution: float, fields: Sequence[str]) -> bytes:
    """The whole Cloudini message (header and chunks) of the float32 ``values`` ``(n, len(fields))``."""
    import zstandard

    v = np.asarray(values, dtype=np.float32)
    n, k = v.shape[0], len(fields)
    if v.shape != (n, k):
        raise ValueError(f"cloudini: values of shape {v.shape} for {k} fields")
    out = [header(n, resolution, fields)]
    if n == 0:
        return out[0]
    q = quantize(v, resolution)
    # int32 arithmetic throughout, as Cloudini's: numpy's int32 differences wrap around.
    delta = np.diff(q, axis=0, prepend=np.int32(0))
    starts = _chunk_starts(n)
    delta[starts] = q[starts]
    stream, lengths = _varints(((delta << 1) ^ (delta >> 31)).view(np.uint32).ravel())
    bounds = np.concatenate([[0], np.cumsum(lengths, dtype=np.int64)[starts[1:] * k - 1], [len(stream)]])
    compressor = zstandard.ZstdCompressor(level=ZSTD_LEVEL, write_content_size=True, write_checksum=False)
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        frame = compressor.compress(stream[a:b].tobytes())
        out += [_CHUNK_LENGTH.pack(len(frame)), frame]
    return b"".join(out)


def _chunk_frames(body: bytes, start: int, n: int, k: int, codec: str) -> list[tuple[bytes, int]]:
    """(zstd frame, declared stage-1 size) of every chunk after the header: as many chunks as
    ``n`` points need, each declaring between one and :data:`MAX_VARINT_BYTES` bytes per value,
    covering the body exactly. Nothing is inflated before the whole walk passes."""
    import zstandard

    expected = math.ceil(n / POINTS_PER_CHUNK)
    frames: list[tuple[bytes, int]] = []
    off = start
    while off < len(body):
        k_chunk = len(frames)
        if k_chunk == expected or off + 4 > len(body):
            raise PayloadError(f"{codec} payload: Cloudini body holds more than the {expected} chunks {n} points need")
        (length,) = _CHUNK_LENGTH.unpack_from(body, off)
        frame = body[off + 4 : off + 4 + length]
        if len(frame) != length:
            raise PayloadError(f"{codec} payload: Cloudini chunk {k_chunk} runs past the end of the body")
        values = min(POINTS_PER_CHUNK, n - k_chunk * POINTS_PER_CHUNK) * k
        try:
            declared = zstandard.frame_content_size(frame)
        except zstandard.ZstdError as exc:
            raise PayloadError(f"{codec} payload: Cloudini chunk {k_chunk} is not a zstd frame ({exc})") from None
        if not values <= declared <= values * MAX_VARINT_BYTES:
            raise PayloadError(
                f"{codec} payload: Cloudini chunk {k_chunk} declares {declared} bytes for {values} values"
            )
        frames.append((frame, declared))
        off += 4 + length
    if len(frames) != expected:
        raise PayloadError(f"{codec} payload: Cloudini body holds {len(frames)} chunks, {n} points need {expected}")
    return frames


def _read_varints(stream: np.ndarray, ends: np.ndarray, codec: str) -> np.ndarray:
    """The codes of a stream of whole varints of at most :data:`MAX_VARINT_BYTES` bytes that end
    at ``ends`` (the positions of the bytes below 0x80): uint32, uint64 when one has 5 bytes."""
    starts = np.empty_like(ends)
    starts[:1] = 0
    starts[1:] = ends[:-1] + 1
    lengths = ends - starts + 1
    if len(lengths) and int(lengths.max()) > MAX_VARINT_BYTES:
        raise PayloadError(f"{codec} payload: Cloudini varint longer than {MAX_VARINT_BYTES} bytes")
    # The bytes from each varint's start as one little-endian word (an unaligned view with a
    # stride of one byte: a word starts at every byte), cut to the varint's length.
    kind, width = _word(len(lengths) > 0 and int(lengths.max()) > 4)
    padded = np.concatenate([stream, np.zeros(8, np.uint8)])
    words = np.ndarray((len(stream),), np.dtype(kind).newbyteorder("<"), buffer=padded, strides=(1,))[starts]
    words &= ~kind(0) >> (kind(8) * (np.dtype(kind).itemsize - lengths).astype(kind))  # shifts below the width
    codes = words & kind(0x7F)
    for j in range(1, width):
        codes |= (words >> kind(j)) & kind(0x7F << (7 * j))
    if width > 4 and len(codes) and int(codes.max()) > _MAX_CODE:
        raise PayloadError(f"{codec} payload: Cloudini varint codes more than an int32 difference")
    return codes


def _restarted_sums(delta: np.ndarray, restart: np.ndarray) -> np.ndarray:
    """Per column, the running sum of ``delta`` that starts again from 0 at every ``restart`` row."""
    total = np.cumsum(delta, axis=0, dtype=delta.dtype)
    before = np.empty_like(total)
    for f in range(delta.shape[1]):
        rows = np.flatnonzero(restart[:, f])  # row 0 is always one (a chunk's first point)
        base = total[np.maximum(rows - 1, 0), f]
        base[rows == 0] = 0
        before[:, f] = np.repeat(base, np.diff(np.append(rows, len(delta))))
    return total - before


def read_body(body: bytes, n: int, resolution: float, fields: Sequence[str], codec: str = "cloudini") -> np.ndarray:
    """The float32 values ``(n, len(fields))`` of a Cloudini message that :func:`write_body` would
    write for ``n`` points of ``fields`` at ``resolution`` (NaN where the message says NaN), or
    ``PayloadError``. The caller bounds ``n`` by the body's size first."""
    k = len(fields)
    head = header(n, resolution, fields)
    if not body.startswith(head):
        raise PayloadError(f"{codec} payload: the Cloudini header is not the one for {n} points of {list(fields)}")
    frames = _chunk_frames(body, len(head), n, k, codec)
    stages = [
        np.frombuffer(zstd_decompress(f, d, f"{codec} payload: Cloudini chunk {i}", exact=True), np.uint8)
        for i, (f, d) in enumerate(frames)
    ]
    if n == 0:
        return np.zeros((0, k), np.float32)
    stream = np.concatenate(stages)
    ends = np.flatnonzero(stream < 0x80)
    # Every chunk ends on a varint's last byte and holds exactly its points' values.
    bounds = np.cumsum([len(st) for st in stages])
    counts = np.diff(np.searchsorted(ends, bounds), prepend=0)
    starts = _chunk_starts(n)
    want = np.diff(np.append(starts, n)) * k
    whole = stream[bounds - 1] < 0x80
    if not whole.all() or (counts != want).any():
        bad = int(np.flatnonzero(~whole | (counts != want))[0])
        raise PayloadError(f"{codec} payload: Cloudini chunk {bad} does not hold {int(want[bad])} whole varints")
    codes = _read_varints(stream, ends, codec).reshape(n, k)
    nan = codes == 0
    has_nan = bool(nan.any())
    zigzag = (codes - codes.dtype.type(1)).astype(np.uint32, copy=False)  # a marker's wraps: set to 0 below
    delta = (zigzag >> np.uint32(1)).view(np.int32) ^ -(zigzag & np.uint32(1)).view(np.int32)
    if has_nan:
        delta[nan] = 0
    # Each field's q restarts from 0 at every chunk and after every NaN marker (delta 0 there);
    # int32 sums wrap around as Cloudini's int32 additions do.
    restart = nan.copy() if has_nan else np.zeros((n, k), bool)
    restart[starts] = True
    q = _restarted_sums(delta, restart)
    out = np.multiply(q, np.float64(np.float32(resolution)), dtype=np.float64).astype(np.float32)
    if has_nan:
        out[nan] = np.nan
    return out
