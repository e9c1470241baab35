"""What real spinning LiDARs are: the bounds every sensor model must respect, and the published
specs of the sensors lwbench knows by name.

Plain data (no :class:`~lwbench.sensors.model.SensorModel` here), so that both the sensor model and the
code that reads a sensor from a scan (:mod:`lwbench.sensors.beam_table`) can use it without importing
each other. :data:`SENSOR_SPECS` becomes :data:`lwbench.SENSOR_PRESETS`; a scan with no ring
field and no usable order is matched against these beam tables (:mod:`lwbench.sensors.beam_guess`).

Each table says where it comes from. ``range_noise_m`` is the 1-sigma range noise: the datasheets
state a range *accuracy* as "+-x cm" (Velodyne, Hesai: "typical"; HDL-64E/HDL-32E: "1 sigma"),
which is read as sigma = x; where a sheet gives a band by distance the band of the bulk of the
returns (beyond 1 m) is taken. Ranges are the datasheets' (maximum at 80 % reflectivity where
they give several).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "SensorSpec",
    "SENSOR_SPECS",
    "MAX_BEAMS",
    "MIN_AZIMUTH_STEP_DEG",
    "MAX_RAYS",
    "MAX_RANGE_M",
    "MAX_RATE_HZ",
    "DERIVED_RANGE_NOISE_M",
    "NO_RETURN_RANGE_M",
]

# What a real spinning LiDAR has, with room: 128 beams is the most sold today (OS1/OS2-128,
# VLS-128, Pandar128); the finest azimuth step is ~0.1 deg (VLP-16 at 5 Hz) -- a tenth of it
# is allowed; a grid of 4 Mi cells is 16x an OS1-128 at 2,048 columns.
MAX_BEAMS = 256
MIN_AZIMUTH_STEP_DEG = 0.01
MAX_RAYS = 1 << 22
MAX_RANGE_M = 10_000.0
MAX_RATE_HZ = 1_000.0

#: 1-sigma range noise of a sensor model derived from data, whose make is unknown: 3 cm, the
#: "+-3 cm typical" of the VLP-16 (the most common sensor in public datasets) and of the OS1.
DERIVED_RANGE_NOISE_M = 0.03

#: No LiDAR measures closer than this (the shortest minimum range in the specs below is 5 cm,
#: PandarXT); points nearer the origin are no-return markers a driver wrote for rays without a return
#: (nuScenes writes them at under 0.1 mm), not returns.
NO_RETURN_RANGE_M = 0.05


@dataclass(frozen=True)
class SensorSpec:
    """One sensor as its datasheet describes it (``columns`` azimuth steps a turn at ``rate_hz``)."""

    name: str
    elevations_deg: tuple[float, ...]
    columns: int
    min_range: float
    max_range: float
    rate_hz: float
    range_noise_m: float
    source: str

    @property
    def azimuth_step_deg(self) -> float:
        return 360.0 / self.columns


def _table(values) -> tuple[float, ...]:
    return tuple(float(v) for v in np.sort(np.asarray(values, dtype=np.float64)))


def _hdl64e_table() -> tuple[float, ...]:
    # HDL-64E S2 (KITTI): upper block of 32 lasers from +2.0 to -8.33 deg (1/3 deg apart),
    # lower block of 32 from -8.83 to -24.33 deg (1/2 deg apart), per the Velodyne manual.
    upper = np.linspace(2.0, -8.33, 32)
    lower = np.linspace(-8.83, -24.33, 32)
    return _table(np.concatenate([upper, lower]))


# Velodyne's VLP-32C laser table (VLP-32C user manual; the same angles as the velodyne ROS
# driver's VeloView-VLP-32C.yaml): dense around the horizon, sparse towards -25 and +15 deg.
_VLP32C = (-25.0, -15.639, -11.31, -8.843, -7.254, -6.148, -5.333, -4.667, -4.0, -3.667, -3.333, -3.0,
           -2.667, -2.333, -2.0, -1.667, -1.333, -1.0, -0.667, -0.333, 0.0, 0.333, 0.667, 1.0, 1.333, 1.667,
           2.333, 3.333, 4.667, 7.0, 10.333, 15.0)  # fmt: skip
# Hesai Pandar64 channel elevations (Pandar64 user manual, appendix "laser channel distribution";
# the default angle table of Hesai's HesaiLidar_General_SDK): 0.167 deg apart from -6 to +2 deg.
_PANDAR64 = (14.882, 11.032, 8.059, 5.057, 3.04, 2.028, 1.86, 1.688, 1.522, 1.351, 1.184, 1.013, 0.846, 0.675,
             0.508, 0.337, 0.169, 0.0, -0.169, -0.337, -0.508, -0.675, -0.845, -1.013, -1.184, -1.351, -1.522,
             -1.688, -1.86, -2.028, -2.198, -2.365, -2.536, -2.7, -2.873, -3.04, -3.21, -3.375, -3.548, -3.712,
             -3.884, -4.05, -4.221, -4.385, -4.558, -4.72, -4.892, -5.057, -5.229, -5.391, -5.565, -5.726,
             -5.898, -6.061, -7.063, -8.059, -9.06, -9.885, -11.032, -12.006, -12.974, -13.93, -18.889,
             -24.897)  # fmt: skip
# Hesai Pandar40P (user manual's channel table; the SDK's pandar40p default map).
_PANDAR40P = (15.0, 11.0, 8.0, 5.0, 3.0, 2.0, 1.67, 1.33, 1.0, 0.67, 0.33, 0.0, -0.33, -0.67, -1.0, -1.33, -1.66,
              -2.0, -2.33, -2.67, -3.0, -3.33, -3.67, -4.0, -4.33, -4.67, -5.0, -5.33, -5.67, -6.0, -7.0, -8.0,
              -9.0, -10.0, -11.0, -12.0, -13.0, -14.0, -19.0, -25.0)  # fmt: skip
# Hesai PandarQT (QT64): a 104.2 deg field of view (+-52.1 deg), 64 channels whose spacing grows
# from 1.45 deg at the horizon to 2.3 deg at the edges (Hesai's HesaiLidar_General_SDK default
# angle table, pandarQT.h).
_PANDARQT = (-52.121, -49.785, -47.577, -45.477, -43.465, -41.528, -39.653, -37.831, -36.055, -34.320, -32.619,
             -30.950, -29.308, -27.690, -26.094, -24.517, -22.964, -21.420, -19.889, -18.372, -16.865, -15.368,
             -13.880, -12.399, -10.925, -9.457, -7.994, -6.535, -5.079, -3.626, -2.175, -0.725, 0.725, 2.175,
             3.626, 5.079, 6.534, 7.993, 9.456, 10.923, 12.397, 13.877, 15.365, 16.861, 18.368, 19.885, 21.415,
             22.959, 24.524, 26.101, 27.697, 29.315, 30.957, 32.627, 34.328, 36.064, 37.840, 39.662, 41.537,
             43.475, 45.487, 47.587, 49.795, 52.133)  # fmt: skip


def _ouster(family: str, beams: int, half_fov: float, max_range: float, rev: str) -> SensorSpec:
    # Ouster's "uniform" beam configuration: beams evenly spread over the vertical field of view
    # (datasheets rev 6/7: OS0 90 deg, OS1 42.4 deg, OS2 22.5 deg), 1024 columns at 10 Hz, 0.3 m
    # minimum range (rev 6: 0.5 m for OS2), accuracy "+-3 cm" (Lambertian targets) -> sigma 3 cm.
    return SensorSpec(
        f"{family}-{beams}{rev}", _table(np.linspace(-half_fov, half_fov, beams)), 1024,
        0.5 if family == "os2" else 0.3, max_range, 10.0, 0.03,
        f"Ouster {family.upper()}-{beams} datasheet (rev 6/7), uniform beam spacing over +-{half_fov} deg",
    )  # fmt: skip


SENSOR_SPECS: dict[str, SensorSpec] = {
    # The VSGP paper's setting, not the VLP-16 datasheet's: +-15 deg in 2 deg steps (that is the
    # VLP-16's table), but 0.1 deg azimuth (3600 columns), 10 m max range, 4 Hz -> 57,600 rays.
    # Accuracy "+-3 cm (typical)" (VLP-16 datasheet) -> sigma 3 cm.
    "vlp16": SensorSpec(
        "vlp16",
        tuple(np.linspace(-15, 15, 16)),
        3600,
        0.1,
        10.0,
        4.0,
        0.03,
        "VLP-16 table (Velodyne VLP-16 manual) in the VSGP paper's setting",
    ),
    # KITTI's HDL-64E at 10 Hz: ~2,083 firings per turn; 2,048 columns (0.176 deg) keeps the
    # cell count near the scan's point count (~120k). Accuracy "< 2 cm (1 sigma)" -> 2 cm.
    "hdl64e": SensorSpec(
        "hdl64e", _hdl64e_table(), 2048, 0.9, 120.0, 10.0, 0.02, "Velodyne HDL-64E S2 manual (nominal table)"
    ),
    # Ouster OS1-128 in 1024x10 mode, 45 deg vertical field of view (the Gen 2 / rev C sheet;
    # os1-128-rev6 is the 42.4 deg one). Accuracy "+-3 cm" -> 3 cm.
    "os1-128": SensorSpec(
        "os1-128",
        tuple(np.linspace(-22.5, 22.5, 128)),
        1024,
        0.3,
        120.0,
        10.0,
        0.03,
        "Ouster OS1-128 datasheet (rev C), uniform beam spacing over +-22.5 deg",
    ),
    # HDL-32E: -30.67 to +10.67 deg in 4/3 deg steps (HDL-32E manual); 0.166 deg at 10 Hz (2,170
    # firings a turn); 1 m to 100 m; accuracy "< 2 cm (1 sigma at 25 m)" -> 2 cm.
    "hdl32e": SensorSpec(
        "hdl32e", _table(np.linspace(-30.67, 10.67, 32)), 2170, 1.0, 100.0, 10.0, 0.02, "Velodyne HDL-32E manual"
    ),
    # VLP-16 Hi-Res (Puck Hi-Res): +-10 deg in 1.33 deg steps, 0.2 deg at 10 Hz, 100 m, "+-3 cm".
    "vlp16-hires": SensorSpec(
        "vlp16-hires", _table(np.linspace(-10, 10, 16)), 1800, 0.5, 100.0, 10.0, 0.03, "Velodyne Puck Hi-Res datasheet"
    ),
    # VLP-32C (Ultra Puck): 0.2 deg at 10 Hz, 200 m, accuracy "+-3 cm (typical)".
    "vlp32c": SensorSpec(
        "vlp32c",
        _table(_VLP32C),
        1800,
        0.5,
        200.0,
        10.0,
        0.03,
        "Velodyne VLP-32C manual / velodyne ROS driver VeloView-VLP-32C.yaml",
    ),
    # Pandar64: 0.2 deg at 10 Hz, 0.3 m to 200 m, accuracy "+-2 cm (typical)".
    "pandar64": SensorSpec(
        "pandar64",
        _table(_PANDAR64),
        1800,
        0.3,
        200.0,
        10.0,
        0.02,
        "Hesai Pandar64 user manual / HesaiLidar_General_SDK",
    ),
    # Pandar40P: 0.2 deg at 10 Hz, 0.3 m to 200 m, accuracy "+-2 cm (0.5 to 200 m)" -> 2 cm.
    "pandar40p": SensorSpec(
        "pandar40p",
        _table(_PANDAR40P),
        1800,
        0.3,
        200.0,
        10.0,
        0.02,
        "Hesai Pandar40P user manual / HesaiLidar_General_SDK",
    ),
    # PandarQT: short range, 0.6 deg at 10 Hz (600 columns), 0.1 m to 20 m, accuracy "+-3 cm".
    "pandarqt": SensorSpec(
        "pandarqt",
        _table(_PANDARQT),
        600,
        0.1,
        20.0,
        10.0,
        0.03,
        "Hesai PandarQT user manual / HesaiLidar_General_SDK pandarQT.h",
    ),
    # PandarXT-32: +15 to -16 deg in 1 deg steps (SDK table), 0.18 deg at 10 Hz (2,000 columns),
    # 0.05 m to 120 m, accuracy "+-1 cm (typical)".
    "pandarxt32": SensorSpec(
        "pandarxt32",
        _table(np.arange(-16.0, 15.5, 1.0)),
        2000,
        0.05,
        120.0,
        10.0,
        0.01,
        "Hesai PandarXT-32 user manual / HesaiLidar_General_SDK pandarXT.h",
    ),
}
for _family, _half, _range in (("os0", 45.0, 50.0), ("os1", 21.2, 120.0), ("os2", 11.25, 240.0)):
    for _beams in (32, 64, 128):
        _rev = "-rev6" if (_family, _beams) == ("os1", 128) else ""  # "os1-128" is the rev C table
        _spec = _ouster(_family, _beams, _half, _range, _rev)
        SENSOR_SPECS[_spec.name] = _spec
