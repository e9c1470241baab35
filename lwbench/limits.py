"""Bounds on what a payload may make a decoder do -- checked *before* anything is allocated.

A payload's bytes come over a link and may have been crafted: the CRC only catches accidents.
Every count a decoder reads from a header (points, components, inducing points, a grid's
cells) is therefore a request to allocate memory and spend time, and is checked here first:

- against a sane maximum (far above any real sensor, far below what hurts a machine), and
- when the items live in the body, against the bytes the body really holds.

One helper, :func:`check_count`, so that every decoder -- the built-in ones and a plugin
author's -- bounds counts the same way and says what was wrong in a :class:`PayloadError`.
:func:`check_work` bounds the product of counts (a kernel between every grid cell and every
inducing point), :func:`zstd_decompress` bounds what a zstd section inflates to, and
:func:`checked_cloud` is the last step of every decoder: a finite float32 ``(M, 3)`` cloud whose
points lie where a LiDAR can see -- within the payload's sensor's max range (with a stated
margin) and the decoder's own header bounds, never beyond :data:`MAX_COORDINATE` -- or an error.

The budgets are sized so that a decode of a payload of at most 1 MB stays under about a second
and 512 MB on a laptop core (the fuzz harness, :mod:`lwbench.fuzz`, checks exactly that).
"""

from __future__ import annotations

import numpy as np

from lwbench.errors import PayloadError

__all__ = [
    "MAX_POINTS",
    "MAX_GENERATED_POINTS",
    "MAX_WORK",
    "MAX_INFLATED_BYTES",
    "MAX_COORDINATE",
    "RANGE_MARGIN",
    "check_count",
    "coordinate_bound",
    "check_work",
    "checked_cloud",
    "zstd_decompress",
]

#: Points a payload may carry in its body: 16.8 M, six times the largest single real scan
#: (a 128-beam sensor at 2,048 columns and 10 Hz has 262 k; accumulated sweeps a few M).
MAX_POINTS = 1 << 24
#: Points a *model* codec may be asked to draw from a few bytes (a mixture, a surface): 2.1 M,
#: eight times a 128 x 2,048 scan -- the bytes do not bound them, so this does.
MAX_GENERATED_POINTS = 1 << 21
#: Elementary evaluations (kernel entries, point-component densities) one decode may be asked
#: for: 6.7e7, about a second of one core.
MAX_WORK = 1 << 26
#: What a compressed section may inflate to: 256 MiB.
MAX_INFLATED_BYTES = 1 << 28
#: No LiDAR return is 10 km away: the farthest a decoded point may lie from the sensor (m) when
#: nothing tighter is known -- the ceiling of every sensor model's max range (sensor.MAX_RANGE_M).
MAX_COORDINATE = 10_000.0
#: How far past its sensor's max range a decoded point may lie: 50 % (a model codec's samples
#: spill past the farthest return, quantization rounds up; a crafted payload's 1e30 does not).
RANGE_MARGIN = 0.5


def check_count(
    value: object,
    what: str,
    *,
    codec: str = "payload",
    limit: int = MAX_POINTS,
    body: int | None = None,
    bytes_each: float = 0,
    exact: bool = False,
) -> int:
    """A count read from a payload, checked before a decoder allocates for it.

    ``value`` must be an integer (not a bool, not a float) in ``[0, limit]``. When the counted
    items live in the body (``bytes_each`` bytes each, ``body`` bytes present), the body must
    hold them: ``value * bytes_each <= body`` (``==`` with ``exact``). Returns the count as an
    ``int``; raises :class:`PayloadError` naming the codec and the field otherwise.
    """
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise PayloadError(f"{codec} payload: {what} must be an integer, got {type(value).__name__}")
    n = int(value)
    if n < 0 or n > limit:
        raise PayloadError(f"{codec} payload: {what} = {n} is outside [0, {limit}]")
    if body is not None and bytes_each:
        need = n * bytes_each
        if need > body or (exact and need != body):
            raise PayloadError(
                f"{codec} payload: {what} = {n} needs {need:g} bytes of body, the body holds {body}"
            )
    return n


def check_work(units: int, what: str, *, codec: str = "payload", limit: int = MAX_WORK) -> None:
    """A decode's cost (a product of checked counts) against the budget one decode may take."""
    if units > limit:
        raise PayloadError(f"{codec} payload: {what} would take {units:,} evaluations, more than {limit:,}")


def zstd_decompress(data: bytes, limit: int, what: str, *, exact: bool = False) -> bytes:
    """Inflate a zstd section to at most ``limit`` bytes (exactly ``limit`` with ``exact``).

    ``zstandard``'s ``max_output_size`` is ignored when a frame states its content size: a
    64 KB frame declaring 2 GiB is allocated in full before any length check. So the declared
    size is read first, and the data is streamed with a cap either way.
    """
    import zstandard

    limit = min(limit, MAX_INFLATED_BYTES)
    try:
        declared = zstandard.frame_content_size(data)
    except zstandard.ZstdError as exc:
        raise PayloadError(f"{what}: not a zstd frame ({exc})") from None
    if declared > limit or (exact and declared >= 0 and declared != limit):
        wanted = f"{limit}" if exact else f"at most {limit}"
        raise PayloadError(f"{what}: zstd frame declares {declared} bytes, expected {wanted}")
    chunks, size = [], 0
    try:
        with zstandard.ZstdDecompressor().stream_reader(data, read_across_frames=True) as reader:
            while size <= limit:
                chunk = reader.read(min(1 << 20, limit + 1 - size))
                if not chunk:
                    break
                chunks.append(chunk)
                size += len(chunk)
    except zstandard.ZstdError as exc:
        raise PayloadError(f"{what}: zstd section is corrupt ({exc})") from None
    if size > limit:
        raise PayloadError(f"{what}: zstd section inflates to more than {limit} bytes")
    if exact and size != limit:
        raise PayloadError(f"{what}: zstd section inflates to {size} bytes, expected {limit}")
    return b"".join(chunks)


def coordinate_bound(max_range: float | None = None) -> float:
    """The farthest a decoded point may lie from the sensor (m): the sensor's ``max_range`` plus
    :data:`RANGE_MARGIN`, at most :data:`MAX_COORDINATE` (which is the bound without a sensor)."""
    if max_range is None or not np.isfinite(max_range) or max_range <= 0:
        return MAX_COORDINATE
    return min(MAX_COORDINATE, float(max_range) * (1 + RANGE_MARGIN))


def checked_cloud(
    points: object,
    codec: str,
    *,
    max_range: float | None = None,
    bounds: tuple[object, object] | None = None,
) -> np.ndarray:
    """The last step of a decoder: a finite float32 ``(M, 3)`` array, or :class:`PayloadError`.

    Non-finite coordinates from a decoder mean the payload described something no sensor saw;
    so do coordinates no LiDAR returns: a point farther from the sensor than ``max_range`` (the
    payload's sensor's, plus :data:`RANGE_MARGIN`; :data:`MAX_COORDINATE` when there is no
    sensor), or outside ``bounds`` (``(low, high)``, each a scalar or an ``(3,)`` corner: a box
    the decoder's own header promises). They are refused here, where the payload is at fault,
    not later by the runner."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.issubdtype(pts.dtype, np.floating):
        raise PayloadError(f"{codec} payload: decodes to shape {pts.shape} ({pts.dtype}), not (M, 3) floats")
    with np.errstate(over="ignore", invalid="ignore"):  # overflow to inf is refused just below
        pts = np.ascontiguousarray(pts, dtype=np.float32)
    if not np.isfinite(pts).all():
        bad = int((~np.isfinite(pts).all(axis=1)).sum())
        raise PayloadError(f"{codec} payload: decodes to {bad} of {len(pts)} points with NaN/inf coordinates")
    if len(pts):
        _check_reach(pts, codec, max_range)
        if bounds is not None:
            _check_box(pts, codec, bounds)
    return pts


def _check_reach(pts: np.ndarray, codec: str, max_range: float | None) -> None:
    limit = coordinate_bound(max_range)
    largest = np.abs(pts).max(axis=1)  # a norm is at most sqrt(3) times the largest coordinate
    suspect = np.flatnonzero(largest > limit / np.sqrt(3.0))
    if not len(suspect):
        return
    far = suspect[np.linalg.norm(pts[suspect].astype(np.float64), axis=1) > limit]
    if len(far):
        what = "no LiDAR return is that far" if max_range is None else f"its sensor sees to {max_range:g} m"
        raise PayloadError(
            f"{codec} payload: decodes to {len(far)} of {len(pts)} points farther than {limit:g} m from the sensor "
            f"({what})"
        )


def _check_box(pts: np.ndarray, codec: str, bounds: tuple[object, object]) -> None:
    low = np.broadcast_to(np.asarray(bounds[0], dtype=np.float64), (3,))
    high = np.broadcast_to(np.asarray(bounds[1], dtype=np.float64), (3,))
    slack = 1e-5 * np.maximum(np.abs(low), np.abs(high)) + 1e-6  # float32 rounding of the corners
    outside = ((pts < low - slack) | (pts > high + slack)).any(axis=1)
    if outside.any():
        raise PayloadError(
            f"{codec} payload: decodes to {int(outside.sum())} of {len(pts)} points outside the box its header "
            f"states ({low.tolist()} to {high.tolist()})"
        )
