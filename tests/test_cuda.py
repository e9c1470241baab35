"""The CUDA paths of the learned codecs, where a GPU is present (skipped elsewhere; CI has none).

What must hold on a GPU is what a user relies on when the board mixes machines: a payload a GPU
encoded decodes on a CPU-only machine to the same cloud as on the GPU, and scores what the CPU
encoder's payload scores within float noise (the fits differ in rounding, never in method).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch
from lwbench_metrics.ranges import RangeMetric

from lwbench import CodecKind, Evaluation, Frame
from lwbench.registry import get_registry
from lwbench.testing import tunnel_scan

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
REGISTRY = get_registry()


@pytest.fixture(scope="module")
def tunnel() -> Frame:
    return tunnel_scan(seed=3)


def _scores(frame: Frame, points: np.ndarray) -> dict[str, float | None]:
    return RangeMetric().compute(Evaluation(frame, b"", points, CodecKind.REPRESENTATION, {}))


def _round_trip(name: str, frame: Frame, device: str, **params) -> tuple[bytes, np.ndarray, np.ndarray]:
    """(payload encoded on ``device``, decoded on ``device``, decoded on the CPU)."""
    cls = REGISTRY.codec(name)
    data = cls(device=device, **params).encode(frame)
    on_device = cls(device=device, **params).use_sensors([frame.sensor]).decode(data)
    on_cpu = cls(device="cpu", **params).use_sensors([frame.sensor]).decode(data)
    return data, on_device, on_cpu


@pytest.mark.parametrize(("name", "params"), [
    ("vsgp", {"num_inducing": 300}),
    ("vsgp", {"num_inducing": 300, "residual": 0.1}),
    ("gmm", {"n_components": 50, "fit_points": 4000, "max_iter": 20}),
])
def test_a_payload_encoded_on_the_gpu_decodes_on_a_cpu_and_scores_as_the_cpus(tunnel, name, params):
    _, gpu_gpu, gpu_cpu = _round_trip(name, tunnel, "cuda", **params)
    _, cpu_cpu, _ = _round_trip(name, tunnel, "cpu", **params)
    assert gpu_gpu.shape == gpu_cpu.shape
    # The same payload, two devices: the decoders' arithmetic differs only in float rounding.
    np.testing.assert_allclose(gpu_cpu, gpu_gpu, atol=1e-3 * tunnel.sensor.max_range)
    gpu, cpu = _scores(tunnel, gpu_cpu), _scores(tunnel, cpu_cpu)
    assert gpu["coverage"] == pytest.approx(cpu["coverage"], abs=0.02)
    assert gpu["range_rmsd"] == pytest.approx(cpu["range_rmsd"], rel=0.10)


def test_poconet_on_the_gpu_keeps_the_points_the_cpu_keeps(tunnel):
    cls = REGISTRY.codec("poconet")
    gpu = cls(device="cuda").use_sensors([tunnel.sensor]).decode(cls(device="cuda").encode(tunnel))
    cpu = cls(device="cpu").use_sensors([tunnel.sensor]).decode(cls(device="cpu").encode(tunnel))
    kept_gpu = {tuple(p) for p in gpu.tolist()}
    kept_cpu = {tuple(p) for p in cpu.tolist()}
    # Scores differ in float rounding; only points at the selection threshold may swap.
    assert len(kept_gpu & kept_cpu) >= 0.98 * len(kept_cpu)
