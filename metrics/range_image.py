"""Range-image metrics (VSGP paper eq. 8) with the coverage and false-return guards.

Both clouds are projected onto the frame's sensor grid (one cell per beam x azimuth step,
nearest return per cell, points outside the sensor's range window dropped). RMSD is over the
cells where both have a return; coverage and false returns keep a codec from winning by
returning few points, or by hallucinating returns where the scan had none.
"""

from __future__ import annotations

import numpy as np

from lwbench import Evaluation, FrameMetric


class RangeImageMetric(FrameMetric):
    name = "range_image"
    ids = ("range_rmsd", "coverage", "false_returns")
    description = (
        "RMSD (m) of ranges over cells where both clouds return; coverage = share of the "
        "original's cells the decoded cloud fills; false_returns = share of the decoded cloud's "
        "cells where the original has none"
    )

    def compute(self, ev: Evaluation) -> dict[str, float | None]:
        sensor = ev.frame.sensor
        orig = ev.cached("original_range_image", lambda: sensor.project(ev.frame.points).ranges)
        dec = sensor.project(ev.decoded).ranges
        p_valid, q_valid = orig > 0, dec > 0
        both = p_valid & q_valid
        n_p, n_q, n_both = int(p_valid.sum()), int(q_valid.sum()), int(both.sum())
        diff = orig[both].astype(np.float64) - dec[both]
        return {
            "range_rmsd": float(np.sqrt(np.mean(diff**2))) if n_both else None,
            "coverage": n_both / n_p if n_p else None,
            "false_returns": (n_q - n_both) / n_q if n_q else None,
        }
