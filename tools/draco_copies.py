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

import sys
from pathlib import Path

from lwbench_metrics.ranges import RangeMetric
from lwbench_plugins.draco import DracoCodec, distinct_points

from lwbench import CodecKind, Evaluation, Frame
from lwbench.registry import get_registry
from lwbench.run.plan import resolve_dataset
from lwbench.testing import check_frames, hdl32_ring_scan


def frames(real: Path) -> list[tuple[str, Frame]]:
    out = [(f"hdl32_ring_scan(seed={s})", hdl32_ring_scan(seed=s)) for s in range(3)]
    out.append(("check_frames: exact-duplicates", check_frames()["exact-duplicates"]))
    reg = get_registry()
    for folder in sorted(p for p in real.iterdir() if p.is_dir()) if real.is_dir() else []:
        spec = resolve_dataset(reg, str(folder), {}, 0)
        ds = reg.dataset(spec.name)(**spec.params)
        out += [(f"{folder.name}[{i}]", ds[i]) for i in range(len(ds))]
    return out


def coverage(frame: Frame, data: bytes, decoded) -> float:
    return RangeMetric().compute(Evaluation(frame, data, decoded, CodecKind.REPRESENTATION, {}))["coverage"]


def main() -> None:
    real = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parents[2] / "shared" / "data" / "real"
    print("| scan | points | distinct (v2 decoded) | v3 decoded | v2 bytes | v3 bytes | coverage v2 | coverage v3 |")
    print("|---|---|---|---|---|---|---|---|")
    for label, frame in frames(real):
        distinct = frame.subset(distinct_points(frame.points))
        v2 = DracoCodec().encode(distinct)  # v2's body: the distinct points, nothing else
        v3 = DracoCodec().encode(frame)
        d2, d3 = DracoCodec().decode(v2), DracoCodec().decode(v3)
        print(
            f"| {label} | {len(frame):,} | {len(distinct):,} | {len(d3):,} | {len(v2):,} | {len(v3):,} | "
            f"{coverage(frame, v2, d2):.4f} | {coverage(frame, v3, d3):.4f} |"
        )


if __name__ == "__main__":
    main()
