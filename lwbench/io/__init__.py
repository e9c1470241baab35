"""Reading and writing scans, poses and sensor files on disk -- public: a loader plugin (the
built-in ``files`` and ``kitti`` ones, ``plugins/files``) reads its files with these.

Readers return plain arrays (:class:`ScanArrays`); a :class:`lwbench.Dataset` turns them into
frames. Errors are lwbench's own (:class:`lwbench.DataFormatError` for a bad file). This package
is the public API (docs/plugins.md); the modules behind it, one per kind of file, are not:

- :mod:`~lwbench.io.raw_bin` -- headerless float32 ``.bin`` (KITTI, nuScenes), the record size
  decided by the geometry each reading yields;
- :mod:`~lwbench.io.point_files` -- PCD, PLY, ``.xyz`` and :func:`read_point_file` (any scan by
  its name); :mod:`~lwbench.io.vtk_files` -- legacy VTK polydata (libpointmatcher);
- :mod:`~lwbench.io.poses` -- KITTI / TUM pose files, ``calib.txt``, ``times.txt``;
- :mod:`~lwbench.io.sensor_files` -- ``sensor.json``, Ouster ``sensor_metadata.json``;
- :mod:`~lwbench.io.kitti_writer` -- frames out in the KITTI layout (``lwbench simulate``).
"""

from __future__ import annotations

from lwbench.io.kitti_writer import write_kitti_sequence
from lwbench.io.point_files import read_point_file, read_xyz
from lwbench.io.poses import read_kitti_calib, read_kitti_poses, read_pose_file, read_times
from lwbench.io.raw_bin import BIN_LAYOUTS, FIELDS_HINT, read_kitti_bin
from lwbench.io.scan_arrays import NUSCENES_SUFFIX, SCAN_SUFFIXES, VTK_SUFFIX, ScanArrays, scan_suffix
from lwbench.io.sensor_files import SENSOR_FILE, read_ouster_metadata, read_sensor_file
from lwbench.io.vtk_files import read_vtk

__all__ = [
    "ScanArrays",
    "read_kitti_bin",
    "read_point_file",
    "read_kitti_poses",
    "read_kitti_calib",
    "read_pose_file",
    "read_times",
    "read_ouster_metadata",
    "read_sensor_file",
    "read_vtk",
    "read_xyz",
    "scan_suffix",
    "SCAN_SUFFIXES",
    "NUSCENES_SUFFIX",
    "VTK_SUFFIX",
    "BIN_LAYOUTS",
    "FIELDS_HINT",
    "write_kitti_sequence",
    "SENSOR_FILE",
]
