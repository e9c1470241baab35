"""``draco``: Google Draco point-cloud compression through DracoPy.

This is the general-purpose codec a team would try first: it knows nothing about the sensor,
quantizes x, y, z on a uniform grid over the scan's bounding cube and entropy-codes the
result with a k-d tree. It is the reference the sensor-aware codecs have to beat.

Both knobs are pinned explicitly: DracoPy 2.2's signature defaults ``quantization_bits`` to 14
while its docstring says 11, so relying on the library default would make results depend on
which of the two a given DracoPy release means.

Duplicate points: DracoPy builds its point cloud with ``PointCloudBuilder::Finalize(true)``,
which merges points whose attribute values are *bit-for-bit* equal before quantizing
(measured with DracoPy 2.2.0: exact copies merge; points one ulp apart, or a step/10 apart so
that they share a quantization cell, are all kept and decode onto one grid point; ``-0.0`` and
``0.0`` are kept apart). Quantization itself merges nothing. Real scans hold such copies
(nuScenes frames: 34,752 points, 25,532 distinct; a sensor writing its no-return rays as one
fixed point). ``preserve_order=True`` would keep them, at 5x the bytes (measured: 102 kB ->
527 kB on 100,000 points at 14 bits). So the encoder sends each distinct point once and, when
the scan has copies, a generic attribute (unique id 0, uint32) with each distinct point's number
of *extra* copies, which Draco codes with the positions in its k-d tree (+59 B per payload on
the generated HDL-32E sweep, whose 6,934 no-return copies are one point); the decoder repeats
each point by it. Every return comes back (v3; v2 returned the distinct points only), and a scan without
copies is coded exactly as before.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np

import lwbench
from lwbench import Frame, Param, PayloadError, RepresentationCodec, check_count, checked_cloud, hookimpl

__all__ = ["MAX_DISTINCT", "DracoCodec", "distinct_points", "quantization_step"]


def quantization_step(points: np.ndarray, bits: int, quantization_range: float | None = None) -> float:
    """Draco's grid step for these points: the bounding cube's side over ``2**bits - 1``.

    Draco rounds each coordinate to the nearest grid value, so the error per coordinate is at
    most half of this step (and the Euclidean error at most ``sqrt(3)/2`` of it).
    """
    if quantization_range is None:
        pts = np.asarray(points, dtype=np.float64)
        quantization_range = float((pts.max(axis=0) - pts.min(axis=0)).max()) if len(pts) else 0.0
    return float(quantization_range) / float((1 << bits) - 1)


def distinct_points(points: np.ndarray) -> np.ndarray:
    """Sorted indices of the first occurrence of every bit-for-bit distinct row of ``points``
    (float32 ``(N, 3)``), the rows Draco's builder keeps.

    Two stable radix sorts on int64 keys -- (x bits, y bits), then (run of equal x, y; z bits)
    -- instead of ``np.unique`` over 12-byte rows, which is several times slower on a
    124k-point scan. Stability keeps the lowest index of each group.
    """
    bits = np.ascontiguousarray(points, dtype=np.float32).reshape(-1, 3).view(np.uint32)
    n = len(bits)
    xy = ((bits[:, 0].astype(np.uint64) << np.uint64(32)) | bits[:, 1]).view(np.int64)
    order = np.argsort(xy, kind="stable")
    sorted_xy = xy[order]
    new_xy = np.ones(n, dtype=bool)
    new_xy[1:] = sorted_xy[1:] != sorted_xy[:-1]
    if new_xy.all():
        return np.arange(n)
    run = np.cumsum(new_xy, dtype=np.int64) - 1
    key = (run << 32) | bits[order, 2].astype(np.int64)
    order2 = np.argsort(key, kind="stable")
    sorted_key = key[order2]
    repeat = np.zeros(n, dtype=bool)
    repeat[1:] = sorted_key[1:] == sorted_key[:-1]
    keep = np.ones(n, dtype=bool)
    keep[order[order2[repeat]]] = False
    return np.flatnonzero(keep)


class DracoCodec(RepresentationCodec):
    """Draco k-d tree coding of the quantized x, y, z (point order is not preserved)."""

    name = "draco"
    in_default_run = True
    # 2: duplicate points are sent once (1 failed to decode scans holding them); 3: and their
    # number of copies, so that every return comes back (2 returned the distinct points only)
    version = "3"
    description = "Google Draco (DracoPy): quantized xyz, k-d tree entropy coding"
    params = (
        Param("quantization_bits", "int", 14, "bits per coordinate over the bounding cube", low=1, high=30),
        Param("compression_level", "int", 7, "Draco speed/size trade-off (0 fastest, 10 smallest)",
              low=0, high=10),
        Param("quantization_range", "float", None,
              "side of the quantization cube in metres (None: the scan's largest extent)", low=1e-3),
    )

    def encode(self, frame: Frame) -> bytes:
        import DracoPy

        pts = frame.points
        distinct = distinct_points(pts)
        bits = self.config["quantization_bits"]
        qrange = self.config["quantization_range"]
        meta: dict[str, Any] = {"n": len(pts), "bits": bits}
        extra: dict[str, Any] = {}
        if len(distinct) < len(pts):
            extra["generic_attributes"] = {_COPIES_ID: _extra_copies(pts, distinct)[:, None]}
            meta["distinct"] = len(distinct)
            pts = pts[distinct]
        if len(pts) == 0:
            return self.make_payload(frame, meta, b"")
        if len(pts) > MAX_DISTINCT:
            raise ValueError(f"draco: {len(pts):,} distinct points; a Draco payload holds at most {MAX_DISTINCT:,} "
                             "(what DracoPy allocates for a declared count before it reads the body)")
        kwargs: dict[str, Any] = {}
        if qrange is not None:
            # Draco needs the cube's origin with an explicit range; centring the cube on the
            # scan keeps every point inside it when the range covers the extent.
            lo, hi = pts.min(axis=0).astype(np.float64), pts.max(axis=0).astype(np.float64)
            if float((hi - lo).max()) > qrange:
                raise ValueError(
                    f"draco: scan extent {float((hi - lo).max()):.2f} m exceeds quantization_range {qrange} m"
                )
            origin = ((lo + hi) / 2 - qrange / 2).tolist()
            kwargs = {"quantization_range": qrange, "quantization_origin": origin}
        # Never write what the decoder refuses: every decoded point within reach, rounding included.
        lwbench.check_encodable(pts, self.name, slack=np.sqrt(3.0) * quantization_step(pts, bits, qrange))
        body = DracoPy.encode(
            pts,
            quantization_bits=bits,
            compression_level=self.config["compression_level"],
            preserve_order=False,
            **kwargs,
            **extra,
        )
        meta["step"] = quantization_step(pts, bits, qrange)
        return self.make_payload(frame, meta, bytes(body))

    def decode(self, data: bytes) -> np.ndarray:
        import DracoPy

        payload = self.read_payload(data)
        n = check_count(self.meta_field(payload, "n", int), "point count", codec=self.name)
        distinct = n
        if "distinct" in payload.meta:
            distinct = check_count(self.meta_field(payload, "distinct", int), "distinct points", codec=self.name)
            if not 0 < distinct < n:
                raise PayloadError(f"draco payload: {distinct} distinct points of {n} is not a scan with copies")
        if n == 0:
            if payload.body:
                raise PayloadError("draco payload: body present for an empty scan")
            return np.zeros((0, 3), dtype=np.float32)
        if distinct > MAX_DISTINCT:
            raise PayloadError(f"draco payload: {distinct:,} distinct points, more than the {MAX_DISTINCT:,} "
                               "this codec writes")
        _check_draco_header(payload.body, distinct)
        try:
            cloud = DracoPy.decode(payload.body)
        except MemoryError:
            # The backstop for what cannot be bounded before the C++ decoder runs: the worker's
            # memory limit turns Draco's allocation into a MemoryError, reported as the
            # payload's fault.
            raise PayloadError("draco payload: the Draco body asks for more memory than this process may use") from None
        except Exception as exc:  # DracoPy raises bare Exception subclasses for any bad buffer
            raise PayloadError(f"draco payload: body is not a valid Draco buffer ({exc})") from None
        pts = np.asarray(getattr(cloud, "points", None), dtype=np.float32)
        if pts.ndim != 2 or pts.shape != (distinct, 3):
            raise PayloadError(f"draco payload: decoded {pts.shape} points, header says ({distinct}, 3)")
        if distinct < n:
            pts = np.repeat(pts, _copies_attribute(cloud, distinct, n) + 1, axis=0)
        return checked_cloud(pts, self.name)


# Distinct points a payload may hold. DracoPy allocates for the count in Draco's own header
# before it reads the body, ~24 bytes a point: a 65 kB body declaring 2^24 points peaked at
# 384 MB before DracoPy refused it, 2^22 at 96 MB. The body cannot bound the count: Draco's k-d
# tree codes a million points in one quantization cell in 203 bytes (measured, DracoPy 2.2), so a
# legitimately tiny body can hold many points. 4 Mi distinct points is over ten times the
# densest spinning scan (a 128-beam sensor's dual returns, ~700 k); exact copies beyond it are
# counts (the copy attribute) and still reach MAX_POINTS.
MAX_DISTINCT = 1 << 22

_COPIES_ID = 0  # unique id of the generic attribute holding each distinct point's extra copies


def _extra_copies(points: np.ndarray, distinct: np.ndarray) -> np.ndarray:
    """For each of the ``distinct`` rows (first occurrences, sorted), how many more times its
    exact bit pattern occurs in ``points`` (uint32)."""
    keys = np.ascontiguousarray(points, dtype=np.float32).view(np.dtype((np.void, 12))).ravel()
    _, inverse, counts = np.unique(keys, return_inverse=True, return_counts=True)
    return (counts[inverse[distinct]] - 1).astype(np.uint32)


def _copies_attribute(cloud: Any, distinct: int, n: int) -> np.ndarray:
    """The decoded extra-copy counts (``(distinct,)`` int64), checked to add up to ``n`` points
    before anything is repeated."""
    try:
        attribute = cloud.get_attribute_by_unique_id(_COPIES_ID)
        copies = np.asarray(attribute["data"] if attribute is not None else None)
    except Exception as exc:  # noqa: BLE001 - DracoPy's attribute lookup on a crafted buffer
        raise PayloadError(f"draco payload: the copy counts cannot be read ({exc})") from None
    if copies.shape != (distinct, 1) or not np.issubdtype(copies.dtype, np.integer):
        raise PayloadError(f"draco payload: copy counts of shape {copies.shape} for {distinct} distinct points")
    copies = copies[:, 0].astype(np.int64)
    if copies.min() < 0 or int(copies.sum()) != n - distinct:
        total = int(copies.sum()) + distinct
        raise PayloadError(f"draco payload: copy counts add up to {total} points, header says {n}")
    return copies


_DRACO_HEAD = struct.Struct("<5sBBBBHi")  # magic, version major, minor, encoder type, method, flags, points


def _check_draco_header(body: bytes, n: int) -> None:
    """What can be checked before DracoPy allocates: the buffer is a point cloud as
    :meth:`DracoCodec.encode` writes it (encoder type 0, no metadata; method 1, the k-d tree, or
    method 0, sequential coding, which Draco picks at ``compression_level=0``) whose point count
    is the one the lwbench header states. Draco reads its own count and allocates for it; a
    crafted count (one flipped bit) asked it for gigabytes."""
    if len(body) < _DRACO_HEAD.size:
        raise PayloadError(f"draco payload: a body of {len(body)} bytes is shorter than Draco's header")
    magic, _major, _minor, kind, method, flags, count = _DRACO_HEAD.unpack_from(body)
    if magic != b"DRACO" or kind != 0 or method not in (0, 1) or flags != 0:
        raise PayloadError("draco payload: body is not a Draco point cloud as this codec writes")
    if count != n:
        raise PayloadError(f"draco payload: the Draco buffer holds {count} points, the header says {n}")


@hookimpl
def lwbench_codecs() -> list[type[DracoCodec]]:
    return [DracoCodec]
