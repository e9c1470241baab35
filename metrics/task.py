"""Task metrics over a whole sequence: localization, odometry drift and occupancy fidelity.

Registered through the ``task_metrics`` entry point; the runner calls each once per codec
configuration when the dataset has ground-truth poses. Every number is computed with the fixed
settings in each class's ``settings`` (part of the result's key).

Ids (docs/design.md): ``ate_rmse``, ``ate_mean`` (m), ``rot_err_deg``, ``rpe_trans`` (m),
``rpe_rot_deg``, ``map_points``, ``map_share``, ``icp_failures``, ``occ_iou``, ``occ_precision``,
``occ_recall`` (occupancy at 0.2 m). Added: ``mape`` (PocoNet's combined error, mean
``|E - I|_F``), the ``odom_*`` odometry variants, and ``occ_*_005`` at 0.05 m.
"""

from __future__ import annotations

import json

import numpy as np
from lwbench_metrics.localization import (
    ICP_PARAMS,
    build_map,
    pose_metrics,
    track_against_map,
    track_odometry,
)

from lwbench import (
    ALL_CURVES,
    HIGHER,
    LOWER,
    OCCUPANCY_PARAMS,
    Guard,
    MetricId,
    SequenceEvaluation,
    SequenceMetric,
    hookimpl,
    occupancy_scores,
    occupancy_tiles,
)

__all__ = [
    "LocalizationMetric",
    "OdometryMetric",
    "OccupancyMetric",
    "ground_truth",
    "lwbench_metrics",
    "pose_ids",
    "split_drives",
]

# What depends only on the originals is the same for every codec configuration of a run; it is
# shared through SequenceEvaluation.cached (the run's sequence stage computes it once and hands it
# to every configuration's task), keyed by what it depends on besides the originals.


def ground_truth(seq: SequenceEvaluation) -> np.ndarray:
    """Ground-truth poses ``(n, 4, 4)`` of the evaluated frames (read without any scan)."""
    return seq.poses()


def split_drives(seq: SequenceEvaluation) -> tuple[list[int], list[int]] | None:
    """Positions (in ``seq``) of the mapping drive and the tracking drive when the evaluated
    frames span two of the dataset's traversals (at least two frames each), else ``None``."""
    where = {f: k for k, f in enumerate(seq.frame_indices)}
    drives = [[where[f] for f in t if f in where] for t in seq.dataset.traversals()]
    drives = [d for d in drives if len(d) >= 2]
    return (drives[0], drives[1]) if len(drives) >= 2 else None


_POSE_IDS = ("ate_rmse", "ate_mean", "rot_err_deg", "mape", "rpe_trans", "rpe_rot_deg", "icp_failures")


def pose_ids(prefix: str, default: bool) -> tuple[MetricId, ...]:
    """The trajectory-error ids, shared by map tracking and odometry (``odom_`` prefix); the map
    tracking's (``default``) are what the board shows, plots and flags a failed registration by."""
    units = {"ate_rmse": "m", "ate_mean": "m", "rot_err_deg": "deg", "mape": "", "rpe_trans": "m",
             "rpe_rot_deg": "deg", "icp_failures": "frames"}
    icp = Guard("icp_failures", "ICP failures", above=0) if default else None
    return tuple(
        MetricId(f"{prefix}{i}", units[i], LOWER, default=default and i == "ate_rmse",
                 role="distortion" if default and i == "ate_rmse" else "", guard=icp if i == "icp_failures" else None)
        for i in _POSE_IDS
    )


class LocalizationMetric(SequenceMetric):
    """PocoNet §IV-B: decoded scans tracked by point-to-plane ICP against a map of decoded scans."""

    name = "localization"
    order = 50
    ids = (
        *pose_ids("", default=True),
        MetricId("map_points", "pts", LOWER),
        MetricId("map_share", "share", LOWER),
        # When the *original* scans already fail ICP here, no codec's localization figure means
        # anything: they are shown n/m and the configurations left off every RD curve.
        MetricId("icp_failures_original", "frames", LOWER, guard=Guard(
            "localization_not_meaningful", "loc. n/m", above=0, voids=_POSE_IDS, off_curves=(ALL_CURVES,))),
    )
    version = "3"  # 2: icp_failures_original; 3: a mapping drive and a tracking drive when there are two
    description = (
        "Map of decoded scans at GT poses (voxel grid filter), each decoded scan tracked against it "
        "with point-to-plane ICP from the previous estimate; ATE/rotation/mAPE over tracked frames, "
        "RPE rmse per frame, map size and its share of the mapped original points; with two drives "
        "(dataset traversals) the map is the first drive's and the second is tracked; "
        "icp_failures_original: the same on the original scans (if they fail, no codec's localization "
        "means anything)."
    )
    settings = dict(ICP_PARAMS)

    def _localize(self, passes, gt: np.ndarray, drives: tuple[list[int], list[int]] | None):
        """(map, tracking, positions tracked). ``passes(positions, what)`` is one pass over the
        scans at those positions (decoded or original): the map from the mapping drive (or every
        scan), then the tracking drive (or the same scans, each against the map without it)."""
        everything = list(range(len(gt)))
        mapping, tracking = drives if drives is not None else (everything, everything)
        world_map = build_map((s.decoded for s in passes(mapping, "map")), gt[mapping], self.settings)
        try:
            # With two drives the map holds none of the tracked scans: nothing to leave out.
            settings = self.settings if drives is None else {**self.settings, "leave_one_out": False}
            scans = (s.decoded for s in passes(tracking, "tracking"))
            track = track_against_map(scans, gt[tracking][0], world_map, settings, poses=gt[tracking])
        finally:
            world_map.close()  # the tiles it wrote to disk
        return world_map, track, tracking

    def compute(self, seq: SequenceEvaluation) -> dict[str, float | None]:
        gt = ground_truth(seq)
        drives = split_drives(seq)
        world_map, tracking, tracked = self._localize(seq.steps, gt, drives)
        out = pose_metrics(gt[tracked], tracking)
        out["map_points"] = float(len(world_map))

        def on_originals() -> dict[str, int]:
            """The same protocol on the original scans (two passes over them), and how many
            points the mapped originals have: computed once per run, shared by every codec."""
            mapped = [0]

            def originals(positions, what):
                for step in seq.originals(positions, f"originals {what}"):
                    if what == "map":
                        mapped[0] += len(step.decoded)
                    yield step

            failures = int(self._localize(originals, gt, drives)[1].failed.sum())
            return {"failures": failures, "points": mapped[0]}

        settings_key = json.dumps(self.settings, sort_keys=True, default=str)
        original = seq.cached(f"original_tracking:{settings_key}", on_originals)
        out["map_share"] = len(world_map) / original["points"] if original["points"] else None
        out["icp_failures_original"] = float(original["failures"])
        return out


class OdometryMetric(SequenceMetric):
    """Scan-to-scan ICP drift on the decoded stream alone (no map)."""

    name = "odometry"
    order = 55
    ids = pose_ids("odom_", default=False)
    version = "2"  # 2: with two drives, the tracking drive only (no jump between drives)
    description = (
        "Decoded scans registered to the previous decoded scan (point-to-plane ICP, constant-velocity "
        "initial guess) and chained from the first GT pose: the drift of a receiver of the stream."
    )
    settings = dict(ICP_PARAMS)

    def compute(self, seq: SequenceEvaluation) -> dict[str, float | None]:
        gt = ground_truth(seq)
        drives = split_drives(seq)
        tracked = drives[1] if drives is not None else list(range(len(seq)))  # one drive: no jump
        scans = (s.decoded for s in seq.steps(tracked, "odometry"))
        return pose_metrics(gt[tracked], track_odometry(scans, gt[tracked][0], self.settings), prefix="odom_")


def _suffix(voxel: float, first: bool) -> str:
    return "" if first else "_" + f"{voxel:.2f}".replace(".", "").lstrip("0").rjust(3, "0")


class OccupancyMetric(SequenceMetric):
    """Log-odds voxel occupancy (hits and ray-cast free space) of decoded vs original scans."""

    name = "occupancy"
    order = 60
    settings = dict(OCCUPANCY_PARAMS)
    ids = tuple(
        MetricId(f"occ_{m}{_suffix(v, i == 0)}", "share", HIGHER, default=(i == 0 and m == "iou"),
                 role="distortion" if i == 0 and m == "iou" else "")
        for i, v in enumerate(OCCUPANCY_PARAMS["resolutions"])
        for m in ("iou", "precision", "recall")
    )
    description = (
        "Voxel occupancy of the decoded vs the original sequence at GT poses (log-odds map, free space "
        "from the rays): IoU, precision, recall of occupied voxels; unsuffixed at 0.2 m, _005 at 0.05 m."
    )

    def compute(self, seq: SequenceEvaluation) -> dict[str, float | None]:
        ground_truth(seq)  # every frame has a pose, or this metric has nothing to say
        sensor = seq.original(0).sensor
        p = self.settings
        resolutions = tuple(p["resolutions"])

        def tiles(passes, emit) -> None:
            def scans(what):
                return ((s.decoded, s.pose) for s in passes(what=what))

            occupancy_tiles(scans, sensor, emit, resolutions, p["l_hit"], p["l_miss"], p["max_range"])

        def original_map() -> dict[float, dict[int, tuple[str, int]]]:
            # The original map, tile by tile, kept as files every configuration's task reads.
            out: dict[float, dict[int, tuple[str, int]]] = {v: {} for v in resolutions}
            def keep(v: float, tile: int, keys: np.ndarray) -> None:
                out[v][tile] = (seq.keep(keys), len(keys))

            tiles(lambda what: seq.originals(what=f"originals {what}"), keep)
            return out

        key = f"original_occupancy_tiles:{resolutions}:{p['l_hit']}:{p['l_miss']}:{p['max_range']}"
        ref = seq.cached(key, original_map)
        common = {v: 0 for v in resolutions}
        decoded = {v: 0 for v in resolutions}

        def compare(v: float, tile: int, keys: np.ndarray) -> None:
            decoded[v] += len(keys)
            if tile in ref[v] and len(keys):
                common[v] += len(np.intersect1d(seq.fetch(ref[v][tile][0]), keys, assume_unique=True))

        tiles(seq.steps, compare)
        out: dict[str, float | None] = {}
        for i, v in enumerate(resolutions):
            original = sum(n for _, n in ref[v].values())
            for name, value in occupancy_scores(original, decoded[v], common[v]).items():
                out[f"occ_{name}{_suffix(v, i == 0)}"] = value
        return out


@hookimpl
def lwbench_metrics():
    return [LocalizationMetric, OdometryMetric, OccupancyMetric]
