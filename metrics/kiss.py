"""KISS-ICP odometry after compression: the LiDAR odometry many teams actually run.

``kiss-icp`` (Vizzo et al., RA-L 2023, MIT, github.com/PRBonn/kiss-icp) registers each scan to
a local voxel-hash map of the previous scans with point-to-point ICP, a constant-velocity
prediction, an adaptive correspondence threshold and a robust kernel. This metric runs it on
the *decoded* scans of a sequence, from a fresh pipeline per codec configuration, and scores
its trajectory against the ground truth exactly as the ``odometry`` metric scores lwbench's own
scan-to-scan ICP (:func:`lwbench_metrics.localization.pose_metrics`: APE over frames 1..n-1,
RPE over consecutive pairs, no alignment -- the estimate starts at the first GT pose).

Settings (:data:`KISS_SETTINGS`, stored with every row) are KISS-ICP's defaults, with the two
changes a stream of decoded scans forces: no deskewing (a decoded scan carries no per-point
times) and one thread (KISS-ICP's parallel reductions make the last digits depend on the
thread count; one thread makes the same command give the same table). ``max_range`` is the
sensor model's (KISS-ICP's default is 100 m) unless the ``max_range`` parameter sets it
(``--metric-param kiss.max_range=20``), and the voxel size follows KISS-ICP's own rule,
``max_range / 100``: 1 m for a VLP-16, too coarse for a 5 m wide tunnel (docs/task_metrics.md).

KISS-ICP has no failure flag of its own: a run that raises or returns a non-finite pose gives
``kiss_failed = 1`` and ``None`` for every error (the row is still recorded); ``kiss_failed = 0``
otherwise, however far it drifted. kiss-icp is imported only when the metric runs, so ``lwbench
list`` does not pay for it; it is a runtime dependency (a 1.5 MB wheel), so the metric works
offline wherever lwbench is installed. It is not in the default run (``in_default_run =
False``): ``lwbench run --metric kiss`` (or a run file's ``metrics = ["kiss"]``) computes it.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

import numpy as np
from lwbench_metrics.localization import TrackingResult, pose_metrics
from lwbench_metrics.task import ground_truth, pose_ids, split_drives

from lwbench import LOWER, MetricId, MissingDependencyError, Param, SequenceEvaluation, SequenceMetric, hookimpl

__all__ = ["KISS_SETTINGS", "KissOdometryMetric", "kiss_trajectory"]

KISS_SETTINGS: dict[str, Any] = {
    "min_range": 0.0,  # KISS-ICP's default
    "voxel_per_range": 0.01,  # voxel = max_range / 100, KISS-ICP's rule when no voxel is given
    "max_points_per_voxel": 20,
    "max_num_iterations": 500,
    "convergence_criterion": 1e-4,
    "initial_threshold": 2.0,
    "min_motion_th": 0.1,
    "deskew": False,  # decoded scans carry no per-point times
    "max_num_threads": 1,  # reproducible digits
}

_POSE_KEYS = ("ate_rmse", "ate_mean", "rot_err_deg", "mape", "rpe_trans", "rpe_rot_deg")


def _pipeline(max_range: float, p: dict[str, Any]):
    try:
        from kiss_icp.config import KISSConfig
        from kiss_icp.config.config import AdaptiveThresholdConfig, DataConfig, MappingConfig, RegistrationConfig
        from kiss_icp.kiss_icp import KissICP
    except ImportError:
        raise MissingDependencyError("the kiss metric needs kiss-icp: pip install kiss-icp") from None
    # Every section is given explicitly: KISSConfig is a pydantic BaseSettings, and explicit
    # values take precedence over KISS_ICP_* environment variables.
    config = KISSConfig(
        data=DataConfig(max_range=max_range, min_range=p["min_range"], deskew=p["deskew"]),
        mapping=MappingConfig(
            voxel_size=max_range * p["voxel_per_range"], max_points_per_voxel=p["max_points_per_voxel"]
        ),
        registration=RegistrationConfig(
            max_num_iterations=p["max_num_iterations"],
            convergence_criterion=p["convergence_criterion"],
            max_num_threads=p["max_num_threads"],
        ),
        adaptive_threshold=AdaptiveThresholdConfig(
            initial_threshold=p["initial_threshold"], min_motion_th=p["min_motion_th"]
        ),
    )
    return KissICP(config)


def kiss_trajectory(
    scans: Iterable[np.ndarray], first_pose: np.ndarray, max_range: float, settings: dict[str, Any] = KISS_SETTINGS
) -> np.ndarray | None:
    """KISS-ICP's poses ``(n, 4, 4)`` for ``scans`` (sensor frame; one pass, a generator is
    fine: KISS-ICP's own local map is all that is kept), chained from ``first_pose``; ``None``
    when KISS-ICP raises or returns a non-finite pose."""
    odometry = _pipeline(max_range, settings)
    estimates: list[np.ndarray] = []
    no_times = np.zeros(0)
    try:
        for scan in scans:
            odometry.register_frame(np.asarray(scan, dtype=np.float64).reshape(-1, 3), no_times)
            estimates.append(np.array(odometry.last_pose, dtype=np.float64))
    except (RuntimeError, ValueError, TypeError, IndexError):  # what the pybind11 bindings raise
        return None
    poses = np.stack(estimates) if estimates else np.zeros((0, 4, 4))
    if not np.isfinite(poses).all():
        return None
    return np.asarray(first_pose, dtype=np.float64) @ poses


class KissOdometryMetric(SequenceMetric):
    """KISS-ICP run on the decoded stream: its drift against the ground truth."""

    name = "kiss"
    order = 57
    # Opt-in (lwbench run --metric kiss): it made the README's main job 1.30x longer, and most
    # runs compare codecs on lwbench's own odometry; the teams that run KISS-ICP ask for it.
    in_default_run = False
    # The odometry metric's trajectory ids with a kiss_ prefix; KISS-ICP flags no registration
    # as failed, so kiss_failed (the whole run) replaces their icp_failures.
    ids = (
        *(i for i in pose_ids("kiss_", default=False) if i != "kiss_icp_failures"),
        MetricId("kiss_failed", "runs", LOWER),
    )
    description = (
        "KISS-ICP (kiss-icp, its default settings, no deskew, one thread) on the decoded scans, chained "
        "from the first GT pose: ATE/rotation/mAPE over frames 1..n-1, RPE rmse per frame; kiss_failed = 1 "
        "(errors None) when KISS-ICP raises or returns a non-finite pose."
    )
    settings = dict(KISS_SETTINGS)
    params = (
        Param(
            "max_range", "float", None, "KISS-ICP's max range, m (voxel = max_range/100); None: the sensor's", low=0.1
        ),
    )

    def compute(self, seq: SequenceEvaluation) -> dict[str, float | None]:
        gt = ground_truth(seq)
        drives = split_drives(seq)
        tracked = drives[1] if drives is not None else list(range(len(seq)))  # as the odometry metric
        scans = (s.decoded for s in seq.steps(tracked, "kiss"))
        max_range = self.config["max_range"] or float(seq.original(tracked[0]).sensor.max_range)
        poses = kiss_trajectory(scans, gt[tracked][0], max_range, self.settings)
        if poses is None:
            return {**{f"kiss_{k}": None for k in _POSE_KEYS}, "kiss_failed": 1.0}
        values = pose_metrics(gt[tracked], TrackingResult(poses, np.zeros(max(len(poses) - 1, 0), bool)), "kiss_")
        out: dict[str, float | None] = {f"kiss_{k}": values[f"kiss_{k}"] for k in _POSE_KEYS}
        out["kiss_failed"] = 0.0
        return out


@hookimpl
def lwbench_metrics() -> list[type[KissOdometryMetric]]:
    return [KissOdometryMetric]
