"""How far real returns sit from the rays a range image decodes them onto.

This is the error ``rangeimage`` adds even in ``mode=lossless`` (which reproduces the range
image bit for bit): each kept return is put back on one ray per cell -- the cell centre
(``refine=none``) or its beam's fitted ray (``refine=beam``) -- and returns that shared a cell
with a nearer one are dropped. The rate-distortion tables themselves come from
``tools/codecs_rd.sh`` (``lwbench run`` + ``lwbench leaderboard``).

    python tools/codecs_rd.py PATH/TO/shared/data/real
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from lwbench_plugins.rangeimage.beams import fit_beam_table, read_beam_table, unproject_refined

from lwbench import SensorModel, get_sensor
from lwbench.loaders import KittiDataset


def cases(real: Path) -> list[tuple[str, dict, str, str | None]]:
    """(folder, loader parameters, label, grid) for each comparison."""
    ouster, kitti = str(real / "ouster_os1-128_seq3"), str(real / "kitti00_frames0-1")
    return [
        ("ouster_os1-128_seq3", {"path": ouster}, "sensor_metadata.json beam table", None),
        ("ouster_os1-128_seq3", {"path": ouster}, "os1-128 preset (uniform)", "os1-128"),
        ("kitti00_frames0-1", {"path": kitti, "sensor": "hdl64e"}, "hdl64e preset", None),
        ("kitti00_frames0-1", {"path": kitti, "sensor": "hdl64e"}, "derived from the scan", "derived"),
    ]


def main() -> None:
    import sys

    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    print("| dataset | sensor grid | points | kept (1 per cell) | off-ray mean (m), cell centres "
          "| p95 | off-ray mean (m), refine=beam | p95 |")
    print("|---|---|---|---|---|---|---|---|")
    for ds_name, params, label, which in cases(Path(sys.argv[1])):
        frames = list(KittiDataset(**params))
        centre, refined, kept, n = [], [], 0, 0
        for frame in frames:
            sensor = frame.sensor
            if which == "derived":
                sensor = SensorModel.from_points(frame.points)
            elif which is not None:
                sensor = get_sensor(which)
            image = sensor.project(frame.points)
            original = frame.points[image.index[image.valid]]
            centre.append(np.linalg.norm(sensor.unproject(image.ranges) - original, axis=1))
            table = read_beam_table(fit_beam_table(sensor, frame.points, image), sensor)
            refined.append(np.linalg.norm(unproject_refined(sensor, image.ranges, *table) - original, axis=1))
            kept += len(original)
            n += len(frame)
        c, r = np.concatenate(centre), np.concatenate(refined)
        print(f"| {ds_name} | {label} ({sensor.n_beams}×{sensor.n_azimuth}) | {n / len(frames):,.0f} "
              f"| {kept / n:.3f} | {c.mean():.4f} | {np.percentile(c, 95):.4f} "
              f"| {r.mean():.4f} | {np.percentile(r, 95):.4f} |")


if __name__ == "__main__":
    main()
