"""lwbench: a benchmark for LiDAR point-cloud reduction codecs.

This module is the public API. Plugins (including the built-in ones under ``plugins/``)
import only from here.
"""

from lwbench.codec import BUDGET_PARAMS, Codec, CodecKind, RepresentationCodec, SelectionCodec, top_k
from lwbench.dataset import Dataset
from lwbench.deps import import_open3d
from lwbench.device import DEVICE_PARAM, resolve_device
from lwbench.errors import (
    DataFormatError,
    DataWarning,
    DecodeError,
    InvalidFrameError,
    LwbenchError,
    MissingDependencyError,
    ParameterError,
    PayloadError,
    PluginError,
    SelectionError,
    StoreError,
    WorkerError,
)
from lwbench.frame import Frame
from lwbench.hookspecs import hookimpl
from lwbench.io import SENSOR_FILE, read_kitti_bin, read_point_file, write_kitti_sequence
from lwbench.limits import (
    MAX_COORDINATE,
    MAX_GENERATED_POINTS,
    MAX_POINTS,
    MAX_WORK,
    RANGE_MARGIN,
    check_count,
    check_encodable,
    check_work,
    checked_cloud,
    coordinate_bound,
    zstd_decompress,
)
from lwbench.metric import (
    ALL_CURVES,
    HIGHER,
    LOWER,
    METRIC_ROLES,
    Evaluation,
    FrameMetric,
    Guard,
    MetricId,
    SequenceEvaluation,
    SequenceMetric,
    SequenceStep,
)
from lwbench.noise_floor import (
    GAUSSIAN_ENTROPY_BITS,
    MaskBits,
    ScanFloor,
    floor_bits_per_point,
    gaussian_step_bits,
    mask_bits,
    quantized_gaussian_bits,
    scan_floor,
    step_for_rmsd,
)
from lwbench.occupancy import (
    OCCUPANCY_PARAMS,
    OccupancyMap,
    compare_occupancy,
    occupancy_maps,
    occupancy_scores,
    occupancy_tiles,
    occupied_voxels,
)
from lwbench.parallel import thread_budget
from lwbench.params import Param
from lwbench.payload import Payload
from lwbench.points import POINT_ENCODINGS, pack_points, unpack_points
from lwbench.resolve import codec_class, frame_metric, make_codec, open_dataset, sequence_metric
from lwbench.sensors.catalog import SensorCatalog
from lwbench.sensors.derive import Derivation, derive_sensor, outside_range_window, sensor_mismatch
from lwbench.sensors.model import SENSOR_PRESETS, RangeImage, SensorModel, get_sensor
from lwbench.tiles import TILE_M, SpillingTiles, split_by_tile, tiles_at, tiles_near
from lwbench.version import __version__


def open_results(*sources):
    """Stored results for a notebook or script: rows and boards as dicts or pandas DataFrames
    (:class:`lwbench.notebook.Results`; imported on first use, so ``import lwbench`` stays light)."""
    from lwbench.notebook import open_results as _open_results

    return _open_results(*sources)


__all__ = [
    "ALL_CURVES",
    "BUDGET_PARAMS",
    "check_count",
    "check_encodable",
    "check_work",
    "checked_cloud",
    "Codec",
    "codec_class",
    "make_codec",
    "frame_metric",
    "sequence_metric",
    "CodecKind",
    "compare_occupancy",
    "coordinate_bound",
    "DataFormatError",
    "Dataset",
    "DataWarning",
    "DecodeError",
    "Derivation",
    "derive_sensor",
    "DEVICE_PARAM",
    "Evaluation",
    "Frame",
    "FrameMetric",
    "floor_bits_per_point",
    "GAUSSIAN_ENTROPY_BITS",
    "gaussian_step_bits",
    "MaskBits",
    "mask_bits",
    "quantized_gaussian_bits",
    "scan_floor",
    "ScanFloor",
    "step_for_rmsd",
    "get_sensor",
    "Guard",
    "HIGHER",
    "hookimpl",
    "import_open3d",
    "InvalidFrameError",
    "LOWER",
    "LwbenchError",
    "MAX_COORDINATE",
    "MAX_GENERATED_POINTS",
    "MAX_POINTS",
    "MAX_WORK",
    "METRIC_ROLES",
    "MetricId",
    "MissingDependencyError",
    "OCCUPANCY_PARAMS",
    "OccupancyMap",
    "occupancy_maps",
    "SpillingTiles",
    "TILE_M",
    "split_by_tile",
    "tiles_at",
    "tiles_near",
    "occupancy_scores",
    "occupancy_tiles",
    "occupied_voxels",
    "open_dataset",
    "open_results",
    "outside_range_window",
    "pack_points",
    "Param",
    "ParameterError",
    "Payload",
    "PayloadError",
    "PluginError",
    "POINT_ENCODINGS",
    "RANGE_MARGIN",
    "RangeImage",
    "read_kitti_bin",
    "read_point_file",
    "RepresentationCodec",
    "resolve_device",
    "SelectionCodec",
    "SelectionError",
    "SENSOR_FILE",
    "sensor_mismatch",
    "SENSOR_PRESETS",
    "SensorCatalog",
    "SensorModel",
    "SequenceEvaluation",
    "SequenceStep",
    "SequenceMetric",
    "StoreError",
    "thread_budget",
    "top_k",
    "unpack_points",
    "WorkerError",
    "write_kitti_sequence",
    "zstd_decompress",
    "__version__",
]
