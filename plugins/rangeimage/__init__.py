"""``rangeimage``: the scan as a beam x azimuth range image that keeps every return.

This is what most LiDAR streaming stacks send: a spinning sensor produces one range per
(beam, firing), so the cloud is a 2-D image and image / byte coders apply. Real scans are not
that image, though: firings do not sit at cell centres, clocks drift against any fixed step,
deskewed scans have no lattice at all, a cell can hold two returns (dual returns, coincident
beams, two firings drifting into one column), and some returns lie outside the beam table or
the range window the first frame suggested. Version 3 dropped all of those (coverage 0.81-0.97
on the shared real scans, see ``docs/codecs.md``); this version keeps every return:

1. **the grid follows the data** (:mod:`.grid`): the column count is the scan's firing lattice
   when its returns lie on one, each row's azimuth phase and elevation offset are measured
   from its returns (``refine=beam``; ``refine=none`` keeps the sensor model's fixed grid);
2. **every return is placed** (:mod:`.layers`): the nearest in each cell is layer 0, the others
   an overflow list, the few the grid cannot describe verbatim exceptions; each keeps its own
   azimuth/elevation offset from the cell's ray in units of ``offset_step`` times the spacing
   (or ``lossless_directions``: steps of 2**-24 rad, float32-exact directions);
3. **ranges**: ``mode=quantized`` ``rint(range / step)`` (error <= step/2), no range window --
   every positive range is kept, far or near; ``mode=lossless`` the float32 range's bits;
4. **predicted** (``predict=row-delta``: each value minus the previous occupied cell of its row,
   so holes cost nothing but their mask bit), **byte planes** (``shuffle``), then the
   entropy stage ``body`` (:mod:`.bodies`: zstd, LZMA2, or an image codec for layer 0).

Exact duplicates of a point are one return (they are dropped before encoding; the range
metrics count them once too). The decoded cloud has one point per distinct return.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from lwbench_plugins.rangeimage.bodies import (
    BODIES,
    IMAGE_BODIES,
    compress,
    decode_image,
    decompress,
    encode_image,
    level_for,
)
from lwbench_plugins.rangeimage.grid import Grid, derive_grid, elevation_units, fixed_grid, grid_model
from lwbench_plugins.rangeimage.layers import (
    Layers,
    build_layers,
    code_width,
    directions,
    read_sections,
    section_sizes,
    write_sections,
)
from lwbench_plugins.rangeimage.transform import PREDICTORS, pack_image, unpack_image

from lwbench import (
    SENSOR_PRESETS,
    Frame,
    Param,
    ParameterError,
    PayloadError,
    RepresentationCodec,
    SensorModel,
    check_count,
    checked_cloud,
    hookimpl,
)
from lwbench.geometry import spherical

__all__ = ["RangeImageCodec", "RETURNS_PER_CELL", "MAX_RETURNS", "pack_image", "unpack_image"]

_SENSORS = ("frame", "derived", *sorted(SENSOR_PRESETS))
#: Bodies whose layer-0 ranges decode approximately (overflow ranges are then coded on their own).
LOSSY_BODIES = ("jpegxl-lossy", "zfp")
_REFINE = ("beam", "none")
#: ``lossless_directions``: offsets in steps of this many radians along either axis (the offset
#: step becomes this over the grid's largest spacing), so a direction is within 3e-8 rad of the
#: original's -- below float32's resolution of a direction (6e-8 relative).
LOSSLESS_DIRECTION_RAD = 2.0**-24
#: A payload holds at most this many returns per grid cell on average, and at most
#: :data:`MAX_RETURNS` in all (16x an OS1-128 at 2,048 columns): what one sweep of a real sensor
#: has, with room. The encoder refuses a scan beyond either (an accumulated map is not a sweep).
RETURNS_PER_CELL = 2
MAX_RETURNS = 1 << 22


class RangeImageCodec(RepresentationCodec):
    """Range image on a grid derived from the scan, every return kept, predicted, entropy-coded."""

    name = "rangeimage"
    in_default_run = True
    version = "4"  # 4: every return (overflow, exceptions, offsets), the grid from the data, body=
    description = "beam x azimuth range image of every return: grid from the scan, offsets, row-delta + LZMA2"
    params = (
        Param("mode", "str", "quantized", "quantized (error <= step/2) or lossless (exact float32 ranges)",
              choices=("quantized", "lossless")),
        Param("step", "float", 0.01, "range quantization step in metres (mode=quantized)", low=1e-4, high=10.0),
        Param("body", "str", "lzma", "entropy stage: zstd, lzma (LZMA2), or an image codec for layer 0 "
              "(png, jpegxl, jpegxl-lossy, zfp: through imagecodecs)", choices=BODIES),
        Param("level", "int", None, "the body's level (zstd 1-22, lzma preset 0-9, png 1-9, jpegxl effort 1-9); "
              "default: zstd 3, lzma 6, png 6, jpegxl 7", low=0, high=22),
        Param("offset_step", "float", 0.25, "direction offset quantum, in grid spacings (a decoded direction is "
              "within half of it of the original along each axis)", low=2.0**-16, high=1.0),
        Param("lossless_directions", "bool", False, "offsets in steps of 2^-24 rad: directions as exact as float32 "
              "(with mode=lossless the decoded points are the originals to float32 rounding)"),
        Param("predict", "str", "row-delta", "predictive transform before entropy coding", choices=PREDICTORS),
        Param("shuffle", "str", "auto",
              "store byte planes separately (auto: on when quantized, off when lossless)",
              choices=("auto", "on", "off")),
        Param("refine", "str", "beam", "beam: the grid from the scan (firing lattice, each row's phase and "
              "elevation offset); none: the sensor model's fixed grid", choices=_REFINE),
        Param("sensor", "str", "frame",
              "rows: the frame's sensor model, one derived from the scan, or a preset", choices=_SENSORS),
        Param("distance", "float", 1.0, "JPEG XL distance for body=jpegxl-lossy (0 would be lossless)",
              low=0.01, high=25.0),
    )

    def __init__(self, **params: Any) -> None:
        super().__init__(**params)
        body = self.config["body"]
        level_for(body, self.config["level"])  # ParameterError for a level the body does not have
        if body in IMAGE_BODIES and self.config["mode"] == "lossless":
            raise ParameterError(f"rangeimage: body={body} codes quantized ranges; mode=lossless needs zstd or lzma")

    # -- encode ---------------------------------------------------------------------------
    def _sensor(self, frame: Frame) -> SensorModel:
        which = self.config["sensor"]
        if which == "frame":
            return frame.sensor
        if which == "derived":
            return SensorModel.from_points(frame.points, ring=frame.ring, rate_hz=frame.sensor.rate_hz)
        return SENSOR_PRESETS[which]

    def _offset_step(self, grid: Grid) -> float:
        if not self.config["lossless_directions"]:
            return self.config["offset_step"]
        largest = max(grid.column_rad, float(elevation_units(grid.sensor).max()))
        return LOSSLESS_DIRECTION_RAD / largest

    def _values(self, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, int, np.ndarray | None]:
        """The float32 ranges' bits, the coded range values (ordered like the ranges), their
        width in bytes, and which returns are nearer than half a step (0 steps: kept verbatim,
        such as the "no return" points some drivers write a few micrometres from the origin)."""
        bits = r.astype("<f4").view("<u4").astype(np.int64)
        if self.config["mode"] == "lossless":
            return bits, bits, 4, None
        q = np.rint(r / self.config["step"]).astype(np.int64)
        return bits, q, 2 if int(q.max(initial=0)) < 1 << 16 else 4, q == 0

    def layers(self, frame: Frame) -> tuple[SensorModel, Layers, int]:
        """What :meth:`encode` writes, before the byte transforms: the rows' sensor model, the
        :class:`Layers` (``source`` indexes ``frame.points``) and the range values' width."""
        sensor = self._sensor(frame)
        if len(frame.points) > MAX_RETURNS:  # refused before any per-point work (a 10 M-point map)
            raise ParameterError(
                f"rangeimage: {len(frame.points):,} points, more than the {MAX_RETURNS:,} returns a payload holds "
                "(16x an OS1-128 sweep at 2,048 columns): not one sweep of a sensor; split it or use another codec"
            )
        points = np.ascontiguousarray(frame.points, dtype=np.float32)
        r, az, el = spherical(points.astype(np.float64))
        returns = np.flatnonzero(r > 0)  # a point at the origin is no return (the range metrics skip it too)
        if len(returns) < len(points):
            points, r, az, el = points[returns], r[returns], az[returns], el[returns]
        grid = derive_grid(az, el, sensor) if self.config["refine"] == "beam" else fixed_grid(sensor)
        bits, values, width, verbatim = self._values(r)
        layers = build_layers(points, az, el, bits, values, grid, self._offset_step(grid), verbatim)
        layers.source = returns[layers.source]
        return sensor, layers, width

    def encode(self, frame: Frame) -> bytes:
        sensor, layers, width = self.layers(frame)
        q = self._offset_step(layers.grid)
        _check_returns(layers)
        body, predict = self.config["body"], self.config["predict"]
        shuffle = self.config["shuffle"] == "on" or (
            self.config["shuffle"] == "auto" and self.config["mode"] == "quantized"
        )
        codes = code_width(layers)
        meta: dict[str, Any] = {
            "sensor": self.sensor_meta(sensor), "mode": self.config["mode"], "body": body, "predict": predict,
            "shuffle": shuffle, "columns": layers.grid.columns, "offset_step": q, "width": width, "code_width": codes,
            "cells": int(layers.mask.sum()), "overflow": len(layers.ov_values), "exceptions": len(layers.exceptions),
            # LZMA2's literal coder conditions on the previous byte, which predicts the offset codes
            # better than a row-delta does (KITTI frame 0: 27.0 vs 29.0 kB); zstd's Huffman does not.
            "code_predict": "none" if body == "lzma" else predict,
        }
        if self.config["mode"] == "quantized":
            meta["step"] = self.config["step"]
        image = b""
        if body in IMAGE_BODIES:
            image = self._image(layers, width)
            meta["image_bytes"] = len(image)
        raw = write_sections(layers, width, codes, predict, meta["code_predict"], shuffle,
                             with_ranges=body not in IMAGE_BODIES, exact_layer0=body not in LOSSY_BODIES)
        return self.make_payload(frame, meta, image + compress(raw, body, self.config["level"]))

    def _image(self, layers: Layers, width: int) -> bytes:
        body, step = self.config["body"], self.config["step"]
        filled = _hole_filled(layers.mask, layers.values0)
        if body == "zfp":
            return encode_image((filled * step).astype(np.float32), body, None, tolerance=step / 2)
        if width > 2:
            raise ParameterError(
                f"rangeimage: body={body} holds ranges below 65,536 steps ({65536 * step:g} m at step={step:g}); "
                f"this scan reaches {int(layers.values0.max()) * step:.1f} m: use a coarser step or body=zstd/lzma"
            )
        return encode_image(filled, body, self.config["level"], distance=self.config["distance"])

    # -- decode ---------------------------------------------------------------------------
    def decode(self, data: bytes) -> np.ndarray:
        layers, q, ranges = self._decode(data)
        dirs, _ = directions(layers, q)
        points = np.concatenate([dirs * ranges[:, None], layers.exceptions.astype(np.float64)])
        return checked_cloud(points, self.name)

    def decode_image(self, data: bytes) -> tuple[SensorModel, np.ndarray]:
        """The grid (as a sensor model) and its layer-0 range image (float32, 0 = no return)."""
        layers, _, ranges = self._decode(data)
        image = np.zeros(layers.mask.shape, np.float32)
        image[layers.mask] = ranges[: int(layers.mask.sum())]
        return layers.grid.model(), image

    def _decode(self, data: bytes) -> tuple[Layers, float, np.ndarray]:
        payload = self.read_payload(data)
        field = lambda key, kind: self.meta_field(payload, key, kind)  # noqa: E731
        mode, body, predict = field("mode", str), field("body", str), field("predict", str)
        code_predict = field("code_predict", str)
        shuffle, width, codes = field("shuffle", bool), field("width", int), field("code_width", int)
        if mode not in ("quantized", "lossless") or body not in BODIES or {predict, code_predict} - set(PREDICTORS):
            raise PayloadError(f"rangeimage payload: unsupported mode/body/predict {mode}/{body}/{predict}")
        lossless_ok = mode != "lossless" or (width == 4 and body not in IMAGE_BODIES)
        if width not in (2, 4) or codes not in (1, 2, 4) or not lossless_ok:
            raise PayloadError(f"rangeimage payload: unsupported widths {width}/{codes} for mode={mode}")
        q = field("offset_step", float)
        if not 2.0**-32 <= q <= 1.0:
            raise PayloadError(f"rangeimage payload: offset step {q} outside [2^-32, 1]")
        step = field("step", float) if mode == "quantized" else 0.0
        if mode == "quantized" and not 1e-6 <= step <= 1e3:
            raise PayloadError(f"rangeimage payload: step must be in [1e-6, 1e3], got {step}")
        sensor = self.read_sensor(payload)
        columns = check_count(field("columns", int), "columns", codec=self.name, limit=1 << 16)
        if columns < 1:
            raise PayloadError("rangeimage payload: a grid has at least one column")
        try:
            grid_model(sensor, columns)  # the bounds every sensor grid keeps (at most MAX_RAYS cells)
        except ValueError as exc:
            raise PayloadError(f"rangeimage payload: bad grid ({exc})") from None
        n_cells = sensor.n_beams * columns
        cells = check_count(field("cells", int), "cells", codec=self.name, limit=n_cells)
        limit = min(MAX_RETURNS, RETURNS_PER_CELL * n_cells)
        overflow = check_count(field("overflow", int), "overflow returns", codec=self.name, limit=limit)
        exceptions = check_count(field("exceptions", int), "exceptions", codec=self.name, limit=limit)
        if cells + overflow + exceptions > limit:
            raise PayloadError(f"rangeimage payload: {cells + overflow + exceptions} returns, more than {limit}")
        body_bytes = payload.body
        image = None
        if body in IMAGE_BODIES:
            n_image = check_count(field("image_bytes", int), "image bytes", codec=self.name, limit=len(body_bytes))
            image, body_bytes = body_bytes[:n_image], body_bytes[n_image:]
        counts = (cells, overflow, exceptions)
        raw_size = sum(section_sizes(sensor, columns, cells, overflow, exceptions, width, codes, image is None))
        raw = decompress(body_bytes, body, raw_size)
        values0 = None
        if image is not None:
            shape = (sensor.n_beams, columns)
            mask = np.unpackbits(np.frombuffer(raw[Grid.table_size(sensor):], np.uint8, (n_cells + 7) // 8),
                                 count=n_cells).astype(bool).reshape(shape)
            decoded = decode_image(image, body, shape, tolerance=step / 2)
            values0 = _image_values(decoded[mask], body, step)
        layers = read_sections(raw, sensor, columns, counts, width, codes, predict, code_predict, shuffle, values0,
                               exact_layer0=body not in LOSSY_BODIES)
        return layers, q, self._ranges(layers, mode, step, body)

    @staticmethod
    def _ranges(layers: Layers, mode: str, step: float, body: str) -> np.ndarray:
        values = np.r_[layers.values0, layers.ov_values]
        if mode == "lossless":
            with np.errstate(invalid="ignore"):  # NaN patterns are refused just below
                r = values.astype("<u4").view("<f4").astype(np.float64)
            if not (np.isfinite(r) & (r > 0)).all():
                raise PayloadError("rangeimage payload: a lossless range is not a positive finite number")
            return r
        if body == "zfp":
            r0 = layers.values0.astype(np.float64)  # metres already (see _image_values)
            return np.r_[r0, layers.ov_values * step]
        if (values <= 0).any():
            raise PayloadError("rangeimage payload: a return with no range")
        return values * step


def _image_values(pixels: np.ndarray, body: str, step: float) -> np.ndarray:
    """Layer-0 values from a decoded image: integer steps, or (zfp) ranges in metres."""
    if body == "zfp":
        r = pixels.astype(np.float64)
        if not (np.isfinite(r) & (r > 0)).all():
            raise PayloadError("rangeimage payload: the ZFP image holds a non-positive or non-finite range")
        return r
    v = pixels.astype(np.int64)
    if body == "jpegxl-lossy":
        return np.maximum(v, 1)  # a lossy image may round a near return to 0 steps
    return v


def _hole_filled(mask: np.ndarray, values: np.ndarray) -> np.ndarray:
    """The layer-0 image with each empty cell holding its row's previous value (the first
    value of the row before it; 0 in an empty row): a smooth image for an image codec."""
    nb, n = mask.shape
    full = np.zeros(mask.shape, np.int64)
    full[mask] = values
    idx = np.where(mask, np.arange(n)[None, :], -1)
    np.maximum.accumulate(idx, axis=1, out=idx)
    first = np.where(mask.any(axis=1), mask.argmax(axis=1), 0)
    idx = np.where(idx < 0, first[:, None], idx)
    return np.take_along_axis(full, idx, axis=1)


def _check_returns(layers: Layers) -> None:
    """The bounds the decoder applies, checked before a payload is written."""
    n_cells = layers.grid.n_cells
    limit = min(MAX_RETURNS, RETURNS_PER_CELL * n_cells)
    if layers.n_returns > limit:
        raise ParameterError(
            f"rangeimage: {layers.n_returns:,} returns on a {layers.grid.n_beams} x {layers.grid.columns} grid, "
            f"more than {limit:,} (at most {RETURNS_PER_CELL} per cell, {MAX_RETURNS:,} in all): not one sweep of "
            "this sensor; name a sensor with more beams or columns, or use another codec"
        )


@hookimpl
def lwbench_codecs() -> list[type[RangeImageCodec]]:
    return [RangeImageCodec]
