"""Sensor description files: lwbench's ``sensor.json`` and Ouster's ``sensor_metadata.json``."""

from __future__ import annotations

import json
from pathlib import Path

from lwbench.errors import DataFormatError
from lwbench.sensors.model import MIN_AZIMUTH_STEP_DEG, SensorModel

__all__ = ["read_ouster_metadata", "read_sensor_file", "SENSOR_FILE"]

SENSOR_FILE = "sensor.json"  # lwbench's addition to the KITTI layout: the sensor model
# Ouster datasheets (rev 6/7) state a range accuracy of "+-3 cm" (Lambertian targets): sigma 3 cm.
OUSTER_RANGE_NOISE_M = 0.03


def read_ouster_metadata(path: str | Path, *, max_range: float = 120.0) -> SensorModel:
    """A sensor model from an Ouster ``sensor_metadata.json`` (its own beam table). Both the
    legacy flat layout and the nested one of newer firmware (``beam_intrinsics``,
    ``lidar_data_format``, ``config_params``) are read."""
    meta = json.loads(Path(path).read_text())
    beams = meta.get("beam_intrinsics", meta)
    fmt = meta.get("lidar_data_format", meta.get("data_format", {}))
    cols = fmt.get("columns_per_frame", 1024)
    if isinstance(cols, bool) or not isinstance(cols, int) or not 1 <= cols <= 360 / MIN_AZIMUTH_STEP_DEG:
        raise ValueError(f"columns_per_frame must be a whole number of columns in [1, 36000], got {cols!r}")
    mode = str(meta.get("config_params", meta).get("lidar_mode", f"{cols}x10"))
    rate = float(mode.split("x")[1]) if "x" in mode else 10.0
    product = meta.get("sensor_info", meta).get("prod_line", "ouster")
    return SensorModel(
        name=str(product).lower(),
        elevations_deg=tuple(float(a) for a in beams["beam_altitude_angles"]),
        azimuth_step_deg=360.0 / cols,
        min_range=0.3,
        max_range=max_range,
        rate_hz=rate,
        range_noise_m=OUSTER_RANGE_NOISE_M,
    )


def read_sensor_file(path: str | Path) -> SensorModel:
    """A sensor model from a JSON file: lwbench's ``sensor.json`` (what
    :meth:`SensorModel.to_dict` writes) or an Ouster ``sensor_metadata.json``."""
    path = Path(path)
    try:
        meta = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise DataFormatError(f"{path}: not a readable JSON sensor file ({exc})") from None
    if not isinstance(meta, dict):
        raise DataFormatError(f"{path}: a sensor file holds a JSON object")
    try:
        inner = meta.get("beam_intrinsics", meta)
        if isinstance(inner, dict) and "beam_altitude_angles" in inner:
            return read_ouster_metadata(path)
        return SensorModel.from_dict(meta)
    except (KeyError, TypeError, ValueError, AttributeError, OverflowError) as exc:
        raise DataFormatError(
            f"{path}: neither an lwbench sensor.json (name, elevations_deg, azimuth_step_deg, min_range, "
            f"max_range, rate_hz -- or preset) nor an Ouster sensor_metadata.json (beam_altitude_angles): {exc}"
        ) from None
