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
:func:`checked_cloud` is the last step of every decoder: a finite float32 ``(M, 3)`` cloud or an
error.

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
    "check_count",
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


def checked_cloud(points: object, codec: str) -> np.ndarray:
    """The last step of a decoder: a finite float32 ``(M, 3)`` array, or :class:`PayloadError`.

    Non-finite coordinates from a decoder mean the payload described something no sensor saw;
    they are refused here, where the payload is at fault, not later by the runner."""
    pts = np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3 or not np.issubdtype(pts.dtype, np.floating):
        raise PayloadError(f"{codec} payload: decodes to shape {pts.shape} ({pts.dtype}), not (M, 3) floats")
    with np.errstate(over="ignore", invalid="ignore"):  # overflow to inf is refused just below
        pts = np.ascontiguousarray(pts, dtype=np.float32)
    if not np.isfinite(pts).all():
        bad = int((~np.isfinite(pts).all(axis=1)).sum())
        raise PayloadError(f"{codec} payload: decodes to {bad} of {len(pts)} points with NaN/inf coordinates")
    return pts
