"""lwbench's own quality gates, written with its pytest plugin the way a team would write theirs.

Each holds a codec to figures it must keep on the simulated mine tunnel (VLP-16 at 10 m, the
VSGP paper's setting), 10 frames. The thresholds leave a margin over what the codecs measure
today (noted beside each) so that they catch regressions, not noise.
"""

from __future__ import annotations

import pytest

TUNNEL = {"dataset": "sim", "dataset_params": {"scene": "tunnel"}, "frames": 10}


@pytest.mark.heavy
def test_vsgp_keeps_table_i_at_500_inducing_points(lwbench_gate):
    # The paper's Table I: M = 500 -> 9 +- 10 cm range RMSD at ~6 kB (ratio ~100 on 57,600 rays).
    # Measured here: 8.9 cm, coverage 0.999, false returns 0.02, ratio 100.
    lwbench_gate("vsgp", params={"num_inducing": 500}, **TUNNEL,
                 max_range_rmsd=0.10, min_coverage=0.99, max_false_returns=0.05, min_ratio=90)


@pytest.mark.heavy
def test_raw_is_lossless(lwbench_gate):
    lwbench_gate("raw", **TUNNEL, max_range_rmsd=0.0, min_coverage=1.0, max_chamfer=0.0, max_false_returns=0.0)


@pytest.mark.heavy
def test_draco_at_14_bits_is_near_lossless(lwbench_gate):
    # Measured: 0.35 mm range RMSD, coverage 1, ratio 5.8.
    lwbench_gate("draco", params={"quantization_bits": 14}, **TUNNEL,
                 max_range_rmsd=0.001, min_coverage=0.999, min_ratio=5.0)


@pytest.mark.heavy
def test_rangeimage_keeps_its_half_step_bound(lwbench_gate):
    # 1 cm range step: every range within 5 mm (RMSD of a uniform error: 2.9 mm), on the cell rays.
    lwbench_gate("rangeimage", params={"step": 0.01}, **TUNNEL,
                 max_range_rmsd=0.0035, min_coverage=0.999, min_ratio=20)


@pytest.mark.heavy
def test_random_selection_scores_what_it_keeps(lwbench_gate):
    result = lwbench_gate("random", params={"ratio": 0.1}, **TUNNEL, max_range_rmsd=0.0, min_coverage=0.099)
    assert result.value("coverage") <= 0.101
