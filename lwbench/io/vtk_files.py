"""Legacy VTK polydata scans (``.vtk``), the format libpointmatcher writes (ETH's laser datasets).

Read with VTK's own legacy reader (the ``vtk`` wheel, an optional dependency: ``pip install
lwbench[vtk]``); meshio, the lighter wheel, reads legacy unstructured grids but not POLYDATA.
The header's ``POINTS n`` is checked against what VTK returns, so a cut file is an error, not
a shorter scan. Point-data arrays named like an intensity, ring or time field are kept.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from lwbench.errors import DataFormatError, MissingDependencyError
from lwbench.io.native_stderr import captured_stderr
from lwbench.io.scan_arrays import ScanArrays

__all__ = ["read_vtk"]

_INTENSITY = ("intensity", "intensities", "reflectivity", "remission")
_RING = ("ring", "rings")
_TIME = ("timestamp", "time", "t", "stamps")


def _declared_points(path: Path) -> int:
    """``n`` of the header's ``POINTS n type`` line, after checking the header is polydata."""
    with open(path, "rb") as fh:
        head = fh.read(4096).split(b"\n")
    lines = [ln.decode("ascii", errors="replace").strip() for ln in head[:-1]]
    if not lines or not lines[0].lower().startswith("# vtk datafile"):
        raise DataFormatError(f"{path}: not a legacy VTK file (no '# vtk DataFile' line)")
    dataset = next((ln.split()[1:2] for ln in lines if ln.upper().startswith("DATASET")), None)
    if dataset != ["POLYDATA"]:
        raise DataFormatError(f"{path}: VTK dataset {dataset[0] if dataset else 'missing'}; lwbench reads POLYDATA")
    points = next((ln.split() for ln in lines if ln.upper().startswith("POINTS")), None)
    try:
        return int(points[1]) if points else 0
    except (IndexError, ValueError):
        raise DataFormatError(f"{path}: unreadable POINTS line in the VTK header") from None


def read_vtk(path: str | Path) -> ScanArrays:
    """A legacy VTK POLYDATA scan: its points (float32) and the intensity / ring / time arrays."""
    path = Path(path)
    if path.stat().st_size == 0:
        raise DataFormatError(f"{path}: empty file (0 bytes), no scan in it")
    declared = _declared_points(path)
    try:
        from vtkmodules.util.numpy_support import vtk_to_numpy
        from vtkmodules.vtkIOLegacy import vtkPolyDataReader
    except ImportError:
        raise MissingDependencyError(
            f"{path}: reading .vtk scans needs VTK: pip install vtk (or lwbench[vtk])"
        ) from None
    reader = vtkPolyDataReader()
    reader.SetFileName(str(path))
    with captured_stderr() as said:
        reader.Update()
    data = reader.GetOutput()
    n_read = data.GetNumberOfPoints() if data is not None else 0
    if reader.GetErrorCode() or n_read != declared:
        why = f" (VTK: {said[0]})" if said and said[0] else ""
        raise DataFormatError(f"{path}: the header declares {declared} points but VTK read {n_read}{why}")
    if n_read == 0:
        return ScanArrays(np.zeros((0, 3), np.float32))
    points = vtk_to_numpy(data.GetPoints().GetData()).astype(np.float32).reshape(-1, 3)
    arrays = data.GetPointData()
    found: dict[str, np.ndarray] = {}
    for i in range(arrays.GetNumberOfArrays()):
        name, array = (arrays.GetArrayName(i) or "").lower(), arrays.GetArray(i)
        if array is not None and array.GetNumberOfComponents() == 1 and array.GetNumberOfTuples() == n_read:
            found[name] = vtk_to_numpy(array).reshape(-1)

    def pick(names: tuple[str, ...]) -> np.ndarray | None:
        return next((found[n] for n in names if n in found), None)

    return ScanArrays(points, pick(_INTENSITY), pick(_RING), pick(_TIME)).finite()
