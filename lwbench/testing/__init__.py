"""The plugin author's kit: synthetic scans and the conformance checks, as scikit-learn ships
``check_estimator`` and ``parametrize_with_checks``.

- **Scans** (:mod:`lwbench.synthetic`, re-exported here): :func:`room_scan` (off the range-image
  grid, as a real sensor's), :func:`tunnel_scan`, :func:`cylinder_scan`, :func:`hdl32_ring_scan`
  and :func:`check_frames`, the scans every codec must handle -- milliseconds each, exactly
  reproducible from a seed.
- **Checks**, one top-level function per clause of the contract, each
  ``check_<kind>_<what>(plugin_cls, params=None)`` raising :class:`ConformanceError`: the codec
  checks (:mod:`.codecs`: declarations, payloads, own payloads decode, determinism, corrupt
  payloads, empty scans, selection, budget, scoring, a bounded fuzz campaign), the dataset checks
  (:mod:`.datasets`) and the metric checks (:mod:`.metrics`). Which apply follows from what the
  plugin declares (its kind, its parameters, what it ``needs``).
- **Running them** (:mod:`.kit`): ``check_codec(MyCodec)`` / ``check_dataset`` / ``check_metric``
  run all that apply; :func:`parametrize_with_checks` makes one pytest case per check in a
  plugin's own tests; ``codec_checks`` / ``dataset_checks`` / ``metric_checks`` give ``(name,
  check)`` pairs.

This repository's own conformance tests call the same functions over every registered plugin.
"""

from __future__ import annotations

from lwbench.synthetic import (
    HDL32_NOMINAL,
    NO_RETURN,
    ROOM_HALF_EXTENT,
    check_frames,
    cylinder_scan,
    hdl32_ring_scan,
    room_scan,
    tunnel_ranges,
    tunnel_scan,
    with_exact_duplicates,
)

from .base import ConformanceError
from .codecs import (
    FUZZ_CASES,
    FUZZ_SECONDS,
    check_codec_budget,
    check_codec_corrupt,
    check_codec_declared,
    check_codec_decodes_own_payloads,
    check_codec_deterministic,
    check_codec_empty_scan,
    check_codec_fuzz,
    check_codec_payloads,
    check_codec_scored,
    check_codec_selection,
)
from .datasets import check_dataset_declared, check_dataset_deterministic, check_dataset_frames
from .kit import (
    check_codec,
    check_dataset,
    check_metric,
    codec_checks,
    dataset_checks,
    metric_checks,
    parametrize_with_checks,
)
from .metrics import (
    check_metric_declared,
    check_metric_deterministic,
    check_metric_streams,
    check_metric_values,
    kit_drive,
)

__all__ = [
    "ConformanceError",
    "FUZZ_CASES",
    "FUZZ_SECONDS",
    "HDL32_NOMINAL",
    "NO_RETURN",
    "ROOM_HALF_EXTENT",
    "check_codec",
    "check_codec_budget",
    "check_codec_corrupt",
    "check_codec_declared",
    "check_codec_decodes_own_payloads",
    "check_codec_deterministic",
    "check_codec_empty_scan",
    "check_codec_fuzz",
    "check_codec_payloads",
    "check_codec_scored",
    "check_codec_selection",
    "check_dataset",
    "check_dataset_declared",
    "check_dataset_deterministic",
    "check_dataset_frames",
    "check_frames",
    "check_metric",
    "check_metric_declared",
    "check_metric_deterministic",
    "check_metric_streams",
    "check_metric_values",
    "codec_checks",
    "cylinder_scan",
    "dataset_checks",
    "hdl32_ring_scan",
    "kit_drive",
    "metric_checks",
    "parametrize_with_checks",
    "room_scan",
    "tunnel_ranges",
    "tunnel_scan",
    "with_exact_duplicates",
]
