"""``laz``: the scan as a LAS 1.4 file compressed to LAZ (laspy + lazrs), what a map store keeps.

LAS stores each coordinate as an int32 count of a fixed ``scale`` (here ``scale=0.001`` m by
default, chosen by the user) and LAZ (the LASzip format, written by the Rust ``lazrs``) codes
the records losslessly. So the codec is lossless *at its scale*: every coordinate is rounded to
the nearest multiple of ``scale`` and nothing else changes -- each coordinate is within
``scale/2``, each range within half the scale's diagonal (``sqrt(3)/2 * scale``), every return
is kept (coverage 1), in the scan's order.

Points are written as point format 6 (the LAS 1.4 base record, 30 bytes: the fields LAZ does
not need compress to almost nothing), offsets 0 (the scan is in the sensor frame). The frame's
intensity, when it has one and ``intensity=true``, goes into the standard ``intensity`` field
(uint16): integer values in ``[0, 65535]`` unchanged (Ouster reflectivity, nuScenes), other
values normalized to the 16-bit range as the LAS specification asks (KITTI's reflectance 0..1
times 65535); the factor is in the payload metadata (``intensity_scale``). :func:`read_laz`
returns it; the benchmark's decode returns x, y, z.

Bounded decoding: laspy allocates ``point count x record length`` from the header before it
reads a point. So :func:`check_las` reads the header first and accepts exactly what this codec
writes (LAS 1.4, point format 6 compressed, one LASzip VLR with one point item, no EVLR, a chunk
table with as many chunks as the count needs) with a count that is the lwbench header's, below
:data:`lwbench.MAX_POINTS` and paid for by the bytes: at least :data:`MIN_BITS_PER_POINT` bits
of LAZ per point. LAZ codes a real scan in 14-20 bits per point at 1 mm (KITTI 00 frame 0:
18.2); only degenerate clouds (100,000 copies of one point: 0.12 bits each) go below 4, and the
encoder refuses those with the reason rather than write what its decoder would refuse.
"""

from __future__ import annotations

import datetime
import io
import math
import struct
from typing import Any

import numpy as np

from lwbench import Frame, Param, PayloadError, RepresentationCodec, check_count, checked_cloud, hookimpl

__all__ = ["LazCodec", "check_las", "read_laz", "MIN_BITS_PER_POINT"]

#: The decoder's price of a point: a LAZ body must hold at least this many bits per point it
#: declares, so that a 1 MB payload decodes at most 2 M points (about half a second).
MIN_BITS_PER_POINT = 4

_POINT_FORMAT = 6
_RECORD_LENGTH = 30
_HEADER_SIZE = 375
_VLR_HEADER = 54
_LASZIP_USER = b"laszip encoded"
_LASZIP_RECORD = 22204
_LASZIP_CHUNK = 50_000  # points per LAZ chunk (lazrs' default, what laspy writes)
_POINT14_ITEM = (10, _RECORD_LENGTH, 3)  # LASzip item: type Point14, size, version
_CHUNK_HEAD = struct.Struct("<I9I")  # a layered chunk after its raw first point: count, 9 layer sizes
# Creation date pinned: a stream frame has no meaningful "file creation day", and the bytes
# must not depend on the day they were written.
_CREATION_DATE = datetime.date(2000, 1, 1)
_INT32 = 2**31 - 1


def _lasdata(points: np.ndarray, scale: float, intensity: np.ndarray | None):
    import laspy

    header = laspy.LasHeader(point_format=_POINT_FORMAT, version="1.4")
    header.creation_date = _CREATION_DATE
    header.scales = np.full(3, scale)
    header.offsets = np.zeros(3)
    las = laspy.LasData(header)
    pts = np.asarray(points, dtype=np.float64)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    if intensity is not None:
        las.intensity = intensity
    return las


def _intensity_field(values: np.ndarray) -> tuple[np.ndarray, float]:
    """(uint16 intensity, the factor applied): integers in range unchanged, else normalized."""
    v = np.nan_to_num(np.asarray(values, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    v = np.maximum(v, 0.0)
    if len(v) == 0 or (np.all(v == np.round(v)) and v.max() <= 65535):
        return v.astype(np.uint16), 1.0
    factor = 65535.0 / max(1.0, float(v.max()))
    return np.round(v * factor).astype(np.uint16), factor


def check_las(body: bytes, n: int, codec: str = "laz") -> None:
    """Refuse (``PayloadError``) a LAZ body that is not what :class:`LazCodec` writes for ``n``
    points, before laspy allocates anything for it (see the module notes)."""
    check_count(n, "point count", codec=codec, body=len(body), bytes_each=MIN_BITS_PER_POINT / 8)
    head = _HEADER_SIZE + _VLR_HEADER
    if len(body) < head + 8:
        raise PayloadError(f"{codec} payload: a body of {len(body)} bytes is shorter than a LAZ file's headers")
    if body[:4] != b"LASF" or body[24:26] != b"\x01\x04":
        raise PayloadError(f"{codec} payload: body is not a LAS 1.4 file")
    header_size, point_offset, n_vlrs, fmt, record = struct.unpack_from("<HIIBH", body, 94)
    legacy = struct.unpack_from("<I", body, 107)[0]
    waveform, evlr_start, n_evlrs, count = struct.unpack_from("<QQIQ", body, 227)
    if (header_size, n_vlrs, fmt, record, legacy) != (_HEADER_SIZE, 1, _POINT_FORMAT | 0x80, _RECORD_LENGTH, 0):
        raise PayloadError(f"{codec} payload: LAS header is not a compressed point format {_POINT_FORMAT} file")
    if waveform or evlr_start or n_evlrs:
        raise PayloadError(f"{codec} payload: LAS file declares waveform data or extended VLRs")
    if count != n:
        raise PayloadError(f"{codec} payload: the LAS header counts {count} points, the lwbench header {n}")
    user, record_id, vlr_length = struct.unpack_from("<16sHH", body, _HEADER_SIZE + 2)
    if user.rstrip(b"\x00") != _LASZIP_USER or record_id != _LASZIP_RECORD or vlr_length != 40:
        raise PayloadError(f"{codec} payload: the LAS file's VLR is not a one-item LASzip description")
    if point_offset != head + vlr_length or point_offset + 8 > len(body):
        raise PayloadError(f"{codec} payload: point data offset {point_offset} does not follow the LASzip VLR")
    vlr = head
    compressor, coder = struct.unpack_from("<HH", body, vlr)
    chunk = struct.unpack_from("<I", body, vlr + 12)[0]
    n_items = struct.unpack_from("<H", body, vlr + 32)[0]
    item = struct.unpack_from("<HHH", body, vlr + 34)
    if compressor != 3 or coder != 0 or chunk != _LASZIP_CHUNK or n_items != 1 or item != _POINT14_ITEM:
        raise PayloadError(f"{codec} payload: LASzip VLR describes another layout than this codec writes")
    (table,) = struct.unpack_from("<q", body, point_offset)
    if not point_offset + 8 <= table <= len(body) - 8:
        raise PayloadError(f"{codec} payload: LAZ chunk table offset {table} lies outside the body")
    version, chunks = struct.unpack_from("<II", body, table)
    if version != 0 or chunks != max(1, math.ceil(n / chunk)):
        raise PayloadError(f"{codec} payload: LAZ chunk table lists {chunks} chunks for {n} points")
    _check_chunks(body, point_offset + 8, table, n, codec)


def _check_chunks(body: bytes, start: int, end: int, n: int, codec: str) -> None:
    """Walk the layered Point14 chunks between the point data and the chunk table: each is the
    first point raw, its point count and the byte sizes of its 9 layers, then the layers. lazrs
    reserves each layer's stated size before reading it (a crafted size of 4 GB aborted the
    process in Rust's allocator), so every size must lie inside the body, every count be the
    chunk's share of ``n``, and the chunks end exactly at the table."""
    off, k = start, 0
    while off < end:
        points = min(_LASZIP_CHUNK, n - k * _LASZIP_CHUNK)
        if points <= 0 or off + _CHUNK_HEAD.size > end:
            raise PayloadError(f"{codec} payload: LAZ point data holds more chunks than {n} points need")
        count, *layers = _CHUNK_HEAD.unpack_from(body, off + _RECORD_LENGTH)
        off += _RECORD_LENGTH + _CHUNK_HEAD.size + sum(layers)
        if count != points or off > end:
            raise PayloadError(f"{codec} payload: LAZ chunk {k} does not hold its {points} points within the body")
        k += 1
    if off != end or k != math.ceil(n / _LASZIP_CHUNK):
        raise PayloadError(
            f"{codec} payload: LAZ point data holds {k} chunks, {n} points need {math.ceil(n / _LASZIP_CHUNK)}"
        )


def read_laz(body: bytes, n: int, codec: str = "laz") -> tuple[np.ndarray, np.ndarray]:
    """Points ``(n, 3)`` float32 and the uint16 intensity field of a checked LAZ body."""
    check_las(body, n, codec)
    import laspy

    try:
        las = laspy.read(io.BytesIO(body), laz_backend=laspy.LazBackend.Lazrs)
        with np.errstate(over="ignore", invalid="ignore"):  # a crafted scale: inf, refused below
            points = np.stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)], axis=1)
        intensity = np.asarray(las.intensity, dtype=np.uint16)
    except MemoryError:
        raise PayloadError(f"{codec} payload: the LAZ body asks for more memory than this process may use") from None
    except BaseException as exc:  # lazrs raises Rust panics (BaseException), laspy its own errors
        if isinstance(exc, KeyboardInterrupt | SystemExit | GeneratorExit):
            raise
        raise PayloadError(f"{codec} payload: body is not a valid LAZ file ({type(exc).__name__}: {exc})") from None
    if points.shape != (n, 3):
        raise PayloadError(f"{codec} payload: LAZ decoded {points.shape} points, the header says ({n}, 3)")
    return checked_cloud(points, codec), intensity


class LazCodec(RepresentationCodec):
    """LAS 1.4 point format 6, LAZ-compressed: lossless at ``scale``, intensity kept."""

    name = "laz"
    version = "1"
    # Fast enough for the main set (~50 ms per 120k-point scan each way), but left out so that
    # the main job's table stays what the README shows: `--codec laz` adds it.
    in_default_run = False
    description = "LAS 1.4 + LAZ (laspy + lazrs): coordinates on a user-chosen scale, lossless at it"
    params = (
        Param("scale", "float", 0.001, "LAS coordinate scale in metres (the quantization step)", low=1e-6, high=10.0),
        Param("intensity", "bool", True, "store the frame's intensity (uint16 LAS field) when it has one"),
    )

    def encode(self, frame: Frame) -> bytes:
        scale = float(self.config["scale"])
        pts = frame.points
        if len(pts) and float(np.abs(pts).max()) / scale >= _INT32:
            raise ValueError(
                f"laz: a coordinate of {float(np.abs(pts).max()):.1f} m does not fit LAS int32 at scale {scale}"
            )
        meta: dict[str, Any] = {"n": len(pts), "scale": scale}
        intensity = None
        if self.config["intensity"] and frame.intensity is not None:
            intensity, meta["intensity_scale"] = _intensity_field(frame.intensity)
        buf = io.BytesIO()
        import laspy

        _lasdata(pts, scale, intensity).write(buf, do_compress=True, laz_backend=laspy.LazBackend.Lazrs)
        body = buf.getvalue()
        try:
            check_las(body, len(pts), self.name)
        except PayloadError as exc:  # never write what the decoder refuses
            raise ValueError(f"laz: cannot send this scan at scale {scale}: {exc}") from None
        return self.make_payload(frame, meta, body)

    def decode(self, data: bytes) -> np.ndarray:
        payload = self.read_payload(data)
        n = check_count(self.meta_field(payload, "n", int), "point count", codec=self.name)
        return read_laz(payload.body, n, self.name)[0]


@hookimpl
def lwbench_codecs() -> list[type[LazCodec]]:
    return [LazCodec]
