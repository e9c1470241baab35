"""The noise floor's inputs, stored with every frame row: what ``lwbench rd`` and ``lwbench report``
need to place each configuration against the floor (:mod:`lwbench.noise_floor`).

The floor at a configuration's range RMSD depends on the scan only through two numbers: the
sensor model's range noise (``floor_sigma``, its ``range_noise_m``) and the bits of the scan's
return/no-return mask per point (``floor_mask_bpp``, measured from the scan's own range image
with an order-2 context model). Both belong to the *original* scan, so every configuration of a
frame stores the same values; the floor itself is computed where the distortion is known (the
board's mean ``range_rmsd``), so this metric needs no pairing of its own and costs one
projection of the original (42 ms on the 124,668-point KITTI frame 0, most of it the projection).
"""

from __future__ import annotations

from lwbench import Evaluation, FrameMetric, MetricId, Param, hookimpl, scan_floor

__all__ = ["NoiseFloorMetric"]


class NoiseFloorMetric(FrameMetric):
    name = "floor"
    order = 25
    ids = (MetricId("floor_sigma", "m", quantity="range_noise_sigma"),
           MetricId("floor_mask_bpp", "bit", quantity="mask_bits_per_point"))
    description = (
        "the noise floor's inputs: the sensor model's 1-sigma range noise (m) and the entropy of the "
        "scan's return mask (order-2 context model on its range image) in bits per original point"
    )

    # A dataset whose noise is known better than its sensor model says -- the simulator adds its
    # ``noise`` parameter (1 cm) to a VLP-16 model that declares the datasheet's 3 cm -- is given
    # it here: --metric-param floor.sigma=0.01 (part of every row's key, like any parameter).
    params = (Param("sigma", "float", None, "range noise (m); default: the sensor model's range_noise_m", low=1e-6),)

    def compute(self, ev: Evaluation) -> dict[str, float | None]:
        floor = ev.cached("noise_floor", lambda: scan_floor(ev.frame))
        sigma = self.config["sigma"] if self.config["sigma"] is not None else floor.sigma
        return {"floor_sigma": sigma, "floor_mask_bpp": floor.mask_bpp if floor.points else None}


@hookimpl
def lwbench_metrics() -> list[type[FrameMetric]]:
    return [NoiseFloorMetric]
