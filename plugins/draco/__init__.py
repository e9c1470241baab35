"""``draco``: Google Draco point-cloud compression through DracoPy.

This is the general-purpose codec a team would try first: it knows nothing about the sensor,
quantizes x, y, z on a uniform grid over the scan's bounding cube and entropy-codes the
result with a k-d tree. It is the reference the sensor-aware codecs have to beat.

Both knobs are pinned explicitly: DracoPy 2.2's signature defaults ``quantization_bits`` to 14
while its docstring says 11, so relying on the library default would make results depend on
which of the two a given DracoPy release means.

Duplicate points: DracoPy builds its point cloud with ``PointCloudBuilder::Finalize(true)``,
which merges points whose float32 coordinates are *bit-for-bit* equal before quantizing
(measured with DracoPy 2.2.0: exact copies merge; points one ulp apart, or a step/10 apart so
that they share a quantization cell, are all kept; ``-0.0`` and ``0.0`` are kept apart). Real
scans hold such copies (nuScenes frames: 34,752 points, 25,532 distinct). So the encoder sends
the distinct points itself and the header counts those: the decoded cloud is what Draco really
reproduces, and the count does not depend on whether a DracoPy release merges or not.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np

from lwbench import Frame, Param, PayloadError, RepresentationCodec, check_count, checked_cloud, hookimpl

__all__ = ["DracoCodec", "distinct_points", "quantization_step"]


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
    version = "2"  # 2: duplicate points are sent once (1 failed to decode scans holding them)
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
        if len(distinct) < len(pts):
            pts = pts[distinct]
        bits = self.config["quantization_bits"]
        qrange = self.config["quantization_range"]
        meta: dict[str, Any] = {"n": len(pts), "bits": bits}
        if len(pts) == 0:
            return self.make_payload(frame, meta, b"")
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
        body = DracoPy.encode(
            pts,
            quantization_bits=bits,
            compression_level=self.config["compression_level"],
            preserve_order=False,
            **kwargs,
        )
        meta["step"] = quantization_step(pts, bits, qrange)
        return self.make_payload(frame, meta, bytes(body))

    def decode(self, data: bytes) -> np.ndarray:
        import DracoPy

        payload = self.read_payload(data)
        n = check_count(self.meta_field(payload, "n", int), "point count", codec=self.name)
        if n == 0:
            if payload.body:
                raise PayloadError("draco payload: body present for an empty scan")
            return np.zeros((0, 3), dtype=np.float32)
        _check_draco_header(payload.body, n)
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
        if pts.ndim != 2 or pts.shape != (n, 3):
            raise PayloadError(f"draco payload: decoded {pts.shape} points, header says ({n}, 3)")
        return checked_cloud(pts, self.name)


_DRACO_HEAD = struct.Struct("<5sBBBBHi")  # magic, version major, minor, encoder type, method, flags, points


def _check_draco_header(body: bytes, n: int) -> None:
    """What can be checked before DracoPy allocates: the buffer is a k-d tree coded point cloud
    (what :meth:`DracoCodec.encode` writes: encoder type 0, method 1, no metadata) whose point
    count is the one the lwbench header states. Draco reads its own count and allocates for it;
    a crafted count (one flipped bit) asked it for gigabytes."""
    if len(body) < _DRACO_HEAD.size:
        raise PayloadError(f"draco payload: a body of {len(body)} bytes is shorter than Draco's header")
    magic, _major, _minor, kind, method, flags, count = _DRACO_HEAD.unpack_from(body)
    if magic != b"DRACO" or kind != 0 or method != 1 or flags != 0:
        raise PayloadError("draco payload: body is not a Draco k-d tree point cloud as this codec writes")
    if count != n:
        raise PayloadError(f"draco payload: the Draco buffer holds {count} points, the header says {n}")


@hookimpl
def lwbench_codecs() -> list[type[DracoCodec]]:
    return [DracoCodec]
