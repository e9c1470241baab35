"""Draco before/after keeping exact copies (issue 22): what v2 returned and what v3 returns.

    python tools/draco_copies.py [REAL_DIR]

For generated nuScenes-like HDL-32E sweeps (:func:`lwbench.testing.hdl32_ring_scan`, no-return
rays written as one fixed point), the conformance kit's exact-duplicates scan and every frame of
every folder of REAL_DIR (default ``../shared/data/real``): points, distinct points (what draco
v2 decoded: it sent each bit-distinct point once), points v3 decodes, v3 bytes and the bytes of
the distinct points alone (v2's body), and the range metric's coverage of both clouds. Prints a
Markdown table.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from lwbench import CodecKind, Evaluation, Frame, codec_class, frame_metric, open_dataset
from lwbench.testing import check_frames, hdl32_ring_scan

DracoCodec = codec_class("draco")


def distinct_points(points: np.ndarray) -> np.ndarray:
    """Sorted indices of the first occurrence of every bit-for-bit distinct row: the rows Draco's
    builder keeps (the plugin's own ``distinct_points`` does the same with radix sorts)."""
    rows = np.ascontiguousarray(points, dtype=np.float32).view(np.dtype((np.void, 12))).ravel()
    return np.sort(np.unique(rows, return_index=True)[1])


def frames(real: Path) -> list[tuple[str, Frame]]:
    out = [(f"hdl32_ring_scan(seed={s})", hdl32_ring_scan(seed=s)) for s in range(3)]
    out.append(("check_frames: exact-duplicates", check_frames()["exact-duplicates"]))
    for folder in sorted(p for p in real.iterdir() if p.is_dir()) if real.is_dir() else []:
        ds = open_dataset(folder)
        out += [(f"{folder.name}[{i}]", ds[i]) for i in range(len(ds))]
    return out


def coverage(frame: Frame, data: bytes, decoded) -> float:
    return frame_metric("ranges").compute(Evaluation(frame, data, decoded, CodecKind.REPRESENTATION, {}))["coverage"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    shared = Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
    ap.add_argument("real", type=Path, nargs="?", default=shared, help="real samples (default: ../shared/data/real)")
    real = ap.parse_args().real
    print("| scan | points | distinct (v2 decoded) | v3 decoded | v2 bytes | v3 bytes | coverage v2 | coverage v3 |")
    print("|---|---|---|---|---|---|---|---|")
    for label, frame in frames(real):
        distinct = frame.subset(distinct_points(frame.points))
        v2 = DracoCodec().encode(distinct)  # v2's body: the distinct points, nothing else
        v3 = DracoCodec().encode(frame)
        d2, d3 = (DracoCodec().use_sensors([frame.sensor]).decode(v) for v in (v2, v3))
        print(
            f"| {label} | {len(frame):,} | {len(distinct):,} | {len(d3):,} | {len(v2):,} | {len(v3):,} | "
            f"{coverage(frame, v2, d2):.4f} | {coverage(frame, v3, d3):.4f} |"
        )


if __name__ == "__main__":
    main()
