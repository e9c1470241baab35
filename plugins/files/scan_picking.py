"""Which files of a folder are the scans, and which row of a per-frame file (poses, times) is
each scan's.

Scans are taken from the layout, never from "every file that ends in .bin": KITTI's
``NNNNNN.bin``, or the files of a folder that share one naming scheme (``000012.bin``,
``scan_0012.pcd``, nuScenes' ``n008-...-0400__LIDAR_TOP__1533151603547590.pcd.bin``); other
scan-like files are skipped with a :class:`lwbench.DataWarning` that names them.
Per-point sidecars (``times_000012.bin``, ``timestamps_NN.bin``, ``labels_NN.bin`` beside
``raw_NN.bin``) are never scans, whatever their count.
"""

from __future__ import annotations

import re
import warnings
from pathlib import Path
from typing import Any

import numpy as np

from lwbench import DataFormatError, DataWarning
from lwbench.io import scan_suffix

__all__ = ["pick_scans", "frame_numbers", "rows_for", "natural_key", "time_sidecars", "read_time_sidecar"]

# A naming scheme whose name says it holds one value per point of a scan (times, labels, ...).
_SIDECAR = re.compile(r"^(times?|timestamps?|stamps?|labels?|intensit(?:y|ies)|rings?|semantics?)[_.-]?#")
_TIME_SIDECAR = re.compile(r"^(times?|timestamps?|stamps?)[_.-]?#\.bin$")


def natural_key(path: Path) -> list[Any]:
    """Sort ``scan_2`` before ``scan_10``: poses are matched to scans by order."""
    return [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", path.name.lower())]


def _scheme(path: Path) -> str:
    """A file's naming scheme: its name with every run of digits -- and the sign before it, as
    in the time-zone offsets of nuScenes' names (``-0400``, ``+0800``) -- as ``#``."""
    return re.sub(r"[+-]?\d+", "#", path.name.lower())


def pick_scans(candidates: list[Path], where: Path, loader: str) -> tuple[list[Path], list[Path]]:
    """The scans among ``candidates`` (the files of one folder) and the scan-like files skipped.

    One format (the most common one) and one naming scheme: names that are just a number
    (``000012.bin``, KITTI's) win, else the scheme most files share (per-point sidecars never). Names without digits
    (``source.pcd``, ``target.pcd``) are all taken when no file is numbered. A tie is an error:
    guessing which half of a folder is the data is how a per-point-times file became a scan.
    """
    candidates = [p for p in candidates if scan_suffix(p) is not None]
    by_kind: dict[str, list[Path]] = {}
    for p in candidates:
        by_kind.setdefault(scan_suffix(p), []).append(p)
    if not by_kind:
        return [], []
    ranked = sorted(by_kind.items(), key=lambda kv: -len(kv[1]))
    if len(ranked) > 1 and len(ranked[0][1]) == len(ranked[1][1]):
        counts = ", ".join(f"{len(v)} {k}" for k, v in ranked)
        raise DataFormatError(f"{loader}: {where} mixes scan formats ({counts}); point at one file or split the folder")
    kind, files = ranked[0]
    schemes: dict[str, list[Path]] = {}
    for p in files:
        schemes.setdefault(_scheme(p), []).append(p)
    numbered = {s: v for s, v in schemes.items() if "#" in s}
    if any(not _SIDECAR.match(s) for s in numbered):
        numbered = {s: v for s, v in numbered.items() if not _SIDECAR.match(s)}
    if numbered:
        plain = f"#{kind}"
        if plain in numbered:
            chosen = numbered[plain]
        else:
            best = sorted(numbered.items(), key=lambda kv: -len(kv[1]))
            if len(best) > 1 and len(best[0][1]) == len(best[1][1]):
                names = ", ".join(s.replace("#", "N") for s, _ in best)
                raise DataFormatError(
                    f"{loader}: {where} holds scans named in several ways ({names}) and none is the most "
                    "common; move the other files out or point at a folder with one kind"
                )
            chosen = best[0][1]
    else:
        chosen = files
    taken = set(chosen)
    skipped = sorted((p for p in candidates if p not in taken), key=natural_key)
    # Per-point time files beside their scans (times_NN.bin by raw_NN.bin) are read, not skipped:
    # only what is really left out is said.
    times = set(time_sidecars(chosen, skipped).values())
    left_out = [p for p in skipped if p not in times]
    if left_out:
        more = f", ... ({len(left_out)} in all)" if len(left_out) > 5 else ""
        shown = ", ".join(p.name for p in left_out[:5]) + more
        warnings.warn(
            f"{loader}: {len(left_out)} file(s) in {where} are not scans of this layout and were skipped: {shown}",
            DataWarning,
            stacklevel=3,
        )
    return sorted(chosen, key=natural_key), skipped


def frame_numbers(files: list[Path]) -> list[int] | None:
    """Each scan's frame number when every name is one (KITTI: ``000012.bin`` is frame 12)."""
    stems = [p.name.split(".")[0] for p in files]
    return [int(s) for s in stems] if all(s.isdigit() for s in stems) else None


def rows_for(files: list[Path], n_rows: int, what: Path, loader: str) -> list[int]:
    """Which row of a per-frame file (poses, times) belongs to each scan: the scan's frame
    number when scans are numbered (a folder holding frames 100-199 uses rows 100-199), else
    its position."""
    numbers = frame_numbers(files)
    rows = numbers if numbers is not None else list(range(len(files)))
    if numbers is None and n_rows != len(files):
        raise DataFormatError(f"{loader}: {n_rows} rows in {what} for {len(files)} scans")
    if max(rows) >= n_rows:
        raise DataFormatError(
            f"{loader}: {what} has {n_rows} rows, but scan {files[rows.index(max(rows))].name} is frame {max(rows)}"
        )
    return rows


def _digits(path: Path) -> str:
    return "".join(re.findall(r"\d+", path.name.split(".")[0]))


def time_sidecars(scans: list[Path], skipped: list[Path]) -> dict[Path, Path]:
    """Per-point time files among ``skipped`` (``times_NN.bin`` beside ``raw_NN.bin``), matched
    to the scan with the same number."""
    by_number = {_digits(p): p for p in skipped if _TIME_SIDECAR.match(_scheme(p))}
    return {scan: by_number[_digits(scan)] for scan in scans if _digits(scan) in by_number}


def read_time_sidecar(path: Path, n_points: int) -> np.ndarray | None:
    """One time stamp per point: float32 (4 bytes a point) or float64 (8) by the file's size;
    None (with a warning) when the file is not that -- it is then not this scan's times."""
    size = path.stat().st_size
    dtype = {4 * n_points: "<f4", 8 * n_points: "<f8"}.get(size)
    times = np.fromfile(path, dtype=dtype) if dtype is not None else None
    if times is None or not np.isfinite(times).all():
        why = "holds NaN/inf" if times is not None else f"has {size} bytes, not 4 or 8 for each of {n_points} points"
        warnings.warn(f"{path.name} {why}: not per-point times of its scan, left out", DataWarning, stacklevel=3)
        return None
    return times
