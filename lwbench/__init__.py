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
    MAX_GENERATED_POINTS,
    MAX_POINTS,
    MAX_WORK,
    check_count,
    check_work,
    checked_cloud,
    zstd_decompress,
)
from lwbench.metric import HIGHER, LOWER, Evaluation, FrameMetric, MetricId, SequenceEvaluation, SequenceMetric
from lwbench.parallel import thread_budget
from lwbench.params import Param
from lwbench.payload import Payload
from lwbench.points import POINT_ENCODINGS, pack_points, unpack_points
from lwbench.sensor import SENSOR_PRESETS, RangeImage, SensorModel, get_sensor, register_sensor

__version__ = "0.1.0"

__all__ = [
    "BUDGET_PARAMS",
    "Codec",
    "CodecKind",
    "DEVICE_PARAM",
    "DataFormatError",
    "DataWarning",
    "Dataset",
    "DecodeError",
    "Evaluation",
    "Frame",
    "FrameMetric",
    "HIGHER",
    "LOWER",
    "MetricId",
    "MAX_GENERATED_POINTS",
    "MAX_POINTS",
    "MAX_WORK",
    "InvalidFrameError",
    "LwbenchError",
    "MissingDependencyError",
    "POINT_ENCODINGS",
    "Param",
    "ParameterError",
    "Payload",
    "PayloadError",
    "PluginError",
    "RangeImage",
    "RepresentationCodec",
    "SENSOR_FILE",
    "SENSOR_PRESETS",
    "SelectionCodec",
    "SelectionError",
    "SensorModel",
    "SequenceEvaluation",
    "SequenceMetric",
    "StoreError",
    "WorkerError",
    "check_count",
    "check_work",
    "checked_cloud",
    "get_sensor",
    "hookimpl",
    "import_open3d",
    "pack_points",
    "read_kitti_bin",
    "read_point_file",
    "register_sensor",
    "resolve_device",
    "thread_budget",
    "top_k",
    "unpack_points",
    "write_kitti_sequence",
    "zstd_decompress",
    "__version__",
]
