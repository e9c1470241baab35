"""VSGP codec: round trips on analytic scenes, the variance filter, the wire format, the GP math."""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest
import torch
from lwbench_plugins.vsgp import VSGPCodec
from lwbench_plugins.vsgp.decoder import auto_stride, predict_grid, query_grid
from lwbench_plugins.vsgp.encoder import FitConfig, fit_scan
from lwbench_plugins.vsgp.gp import Hyper, collapsed_bound, rq_cross
from lwbench_plugins.vsgp.wire import HEADER, body_size

from lwbench import Frame, Payload, PayloadError, get_sensor
from lwbench.testing import cylinder_scan, tunnel_scan


def range_scores(frame: Frame, points: np.ndarray) -> tuple[float, float, float]:
    """(RMSD m over cells both have, coverage, false returns) on the frame's range image."""
    a = frame.sensor.project(frame.points).ranges
    b = frame.sensor.project(points).ranges
    both = (a > 0) & (b > 0)
    rmsd = float(np.sqrt(np.mean((a[both] - b[both]) ** 2)))
    return rmsd, both.sum() / (a > 0).sum(), ((b > 0) & ~(a > 0)).sum() / max(1, (b > 0).sum())


@pytest.fixture(scope="module", autouse=True)
def one_thread():
    old = torch.get_num_threads()
    torch.set_num_threads(1)  # the test machine is shared; keep timings and results steady
    yield
    torch.set_num_threads(old)


@pytest.fixture(scope="module")
def tunnel() -> Frame:
    return tunnel_scan(seed=3)


@pytest.fixture(scope="module")
def tunnel_f32(tunnel) -> tuple[bytes, np.ndarray]:
    codec = VSGPCodec(device="cpu")
    data = codec.encode(tunnel)
    return data, VSGPCodec(device="cpu").decode(data)


def test_cylinder_wall_round_trip_within_2mm():
    frame = cylinder_scan(radius=4.0)
    codec = VSGPCodec(device="cpu")
    pts = VSGPCodec(device="cpu").decode(codec.encode(frame))
    rmsd, coverage, false = range_scores(frame, pts)
    assert rmsd < 0.002
    assert coverage > 0.99
    assert false == 0.0


def test_tunnel_round_trip_accuracy_and_ratio(tunnel, tunnel_f32):
    data, pts = tunnel_f32
    rmsd, coverage, false = range_scores(tunnel, pts)
    assert rmsd < 0.06
    assert coverage > 0.95
    assert false < 0.05
    assert tunnel.raw_bytes / len(data) > 100  # the compression target


def test_variance_filter_removes_the_free_half():
    frame = cylinder_scan(radius=4.0, half=True)  # returns only for azimuth in [0, pi)
    pts = VSGPCodec(device="cpu").decode(VSGPCodec(device="cpu").encode(frame))
    az = np.arctan2(pts[:, 1], pts[:, 0])
    # Cells within a lengthscale of the edge may survive; the free half must not.
    assert np.mean(az < -0.2) < 0.01
    rmsd, coverage, _ = range_scores(frame, pts)
    assert coverage > 0.95 and rmsd < 0.02
    # Without the filter (threshold above any variance) the free half comes back as a surface.
    unfiltered = VSGPCodec(device="cpu", k_m=100.0).decode(VSGPCodec(device="cpu").encode(frame))
    assert np.mean(np.arctan2(unfiltered[:, 1], unfiltered[:, 0]) < -0.2) > 0.2


def _overhead(data: bytes) -> int:
    """Shared header bytes around the body: magic..meta, pose, body length, crc."""
    p = Payload.from_bytes(data)
    meta = json.dumps(p.meta, separators=(",", ":"), sort_keys=True).encode()
    return 4 + 3 + len(p.codec_id) + 2 + len(meta) + (24 if p.pose is not None else 0) + 4 + 4


@pytest.mark.parametrize(("body", "per_point"), [("float32", 12), ("float16", 6), ("q16", 6)])
def test_payload_size_equals_formula(tunnel, body, per_point):
    m = 300
    data = VSGPCodec(device="cpu", body=body, num_inducing=m).encode(tunnel)
    payload = Payload.from_bytes(data)
    assert struct.unpack_from("<I", payload.body)[0] == m
    assert len(payload.body) == body_size(body, m) == HEADER.size + per_point * m == 28 + per_point * m
    assert len(data) == _overhead(data) + 28 + per_point * m


def test_q16z_size_is_header_plus_stated_length(tunnel):
    data = VSGPCodec(device="cpu", body="q16z").encode(tunnel)
    body = Payload.from_bytes(data).body
    (length,) = struct.unpack_from("<I", body, HEADER.size)
    assert len(body) == HEADER.size + 4 + length
    assert len(body) < body_size("q16", 500)  # entropy coding must pay for itself


@pytest.mark.parametrize(("body", "extra_mm"), [("float16", 3.0), ("q16", 1.0), ("q16z", 1.0)])
def test_compact_bodies_decode_within_stated_extra_error(tunnel, tunnel_f32, body, extra_mm):
    base, _, _ = range_scores(tunnel, tunnel_f32[1])
    pts = VSGPCodec(device="cpu").decode(VSGPCodec(device="cpu", body=body).encode(tunnel))
    rmsd, coverage, _ = range_scores(tunnel, pts)
    assert rmsd - base < extra_mm / 1000
    assert coverage > 0.95


def test_encoding_is_deterministic(tunnel, tunnel_f32):
    assert VSGPCodec(device="cpu").encode(tunnel) == tunnel_f32[0]


def _replace_body(data: bytes, body: bytes, meta: dict | None = None) -> bytes:
    p = Payload.from_bytes(data)
    return Payload(p.codec_id, meta if meta is not None else p.meta, body, p.pose).to_bytes()


def test_corrupt_payloads_raise_payload_error(tunnel_f32):
    data = tunnel_f32[0]
    codec = VSGPCodec(device="cpu")
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0x10
    body = Payload.from_bytes(data).body
    m = struct.unpack_from("<I", body)[0]
    bad_hyper = bytearray(body)
    struct.pack_into("<f", bad_hyper, 4, -1.0)  # negative lengthscale
    nan_point = bytearray(body)
    struct.pack_into("<f", nan_point, HEADER.size + 4 * m, math.nan)  # an elevation
    cases = [
        data[:-7],  # truncated
        bytes(flipped),  # bit flip (checksum)
        _replace_body(data, body[:-4]),  # body shorter than M says
        _replace_body(data, struct.pack("<I", m + 1) + body[4:]),  # M disagrees with the body
        _replace_body(data, bytes(bad_hyper)),
        _replace_body(data, bytes(nan_point)),
        _replace_body(data, body, {"body": "float64", "sensor": {"preset": "vlp16"}}),
        _replace_body(data, body, {"body": "float32"}),  # no sensor
        _replace_body(data, body, {"body": "float32", "sensor": {"preset": "nope"}}),
        Payload("raw", {}, b"", None).to_bytes(),  # another codec's payload
    ]
    for bad in cases:
        with pytest.raises(PayloadError):
            codec.decode(bad)


def test_corrupt_compressed_body_raises(tunnel):
    data = VSGPCodec(device="cpu", body="q16z").encode(tunnel)
    body = bytearray(Payload.from_bytes(data).body)
    body[HEADER.size + 10] ^= 0xFF
    with pytest.raises(PayloadError):
        VSGPCodec(device="cpu").decode(_replace_body(data, bytes(body)))


def test_empty_and_tiny_scans():
    sensor = get_sensor("vlp16")
    empty = Frame(np.zeros((0, 3), np.float32), sensor)
    assert VSGPCodec(device="cpu").decode(VSGPCodec(device="cpu").encode(empty)).shape == (0, 3)
    few = cylinder_scan(radius=4.0).subset(np.arange(0, 57600, 400))  # 144 points < M
    pts = VSGPCodec(device="cpu").decode(VSGPCodec(device="cpu").encode(few))
    assert pts.ndim == 2 and pts.shape[1] == 3


def test_rq_kernel_is_gpytorch_rq_on_the_circle_embedding():
    import gpytorch

    kernel = gpytorch.kernels.ScaleKernel(gpytorch.kernels.RQKernel(ard_num_dims=3)).double()
    kernel.base_kernel.lengthscale = torch.tensor([[0.3, 0.3, 0.05]])
    kernel.base_kernel.alpha = torch.tensor(0.7)
    kernel.outputscale = torch.tensor(4.0)
    gen = torch.Generator().manual_seed(0)
    x1 = (torch.rand(40, 2, generator=gen, dtype=torch.float64) - 0.5) * torch.tensor([2 * math.pi, 0.5])
    x2 = (torch.rand(30, 2, generator=gen, dtype=torch.float64) - 0.5) * torch.tensor([2 * math.pi, 0.5])

    def embed(x: torch.Tensor) -> torch.Tensor:
        return torch.stack([torch.cos(x[:, 0]), torch.sin(x[:, 0]), x[:, 1]], dim=1)

    ours = rq_cross(x1, x2, Hyper(0.3, 0.05, 0.7, 4.0, 0.01))
    with torch.no_grad():
        ref = kernel(embed(x1), embed(x2)).to_dense()
    torch.testing.assert_close(ours, ref, rtol=1e-6, atol=1e-9)
    # Neighbours across the seam are neighbours.
    seam = rq_cross(torch.tensor([[math.pi - 0.01, 0.0]]), torch.tensor([[-math.pi + 0.01, 0.0]]),
                    Hyper(0.3, 0.05, 0.7, 4.0, 0.01))
    assert float(seam) > 3.9


def test_collapsed_bound_is_a_lower_bound_and_tight_when_z_equals_x():
    gen = torch.Generator().manual_seed(1)
    x = torch.rand(60, 2, generator=gen, dtype=torch.float64)
    y = torch.sin(6 * x[:, 0]) + 0.1 * torch.randn(60, generator=gen, dtype=torch.float64)
    h = Hyper(0.3, 0.3, 1.5, 1.0, 0.05)
    knn = rq_cross(x, x, h)
    cov = knn + h.noise * torch.eye(60, dtype=torch.float64)
    exact = torch.distributions.MultivariateNormal(torch.zeros(60, dtype=torch.float64), cov).log_prob(y) / 60

    def bound(z: torch.Tensor) -> float:
        return float(collapsed_bound(rq_cross(z, z, h), rq_cross(z, x, h), y, torch.tensor(h.outputscale),
                                     torch.tensor(h.noise)))

    assert bound(x[::6]) < float(exact)
    assert bound(x[::6]) < bound(x[::2]) < float(exact) + 1e-6
    assert bound(x) == pytest.approx(float(exact), abs=1e-4)


def test_refinement_steps_never_return_a_worse_bound(tunnel):
    s = tunnel.sensor
    res = fit_scan(s.project(tunnel.points).ranges, s, s.max_range, FitConfig(steps=3, subsample=512),
                   torch.device("cpu"))
    assert 1 <= len(res.bounds) <= 4
    assert max(res.bounds) >= res.bounds[0]
    assert res.hyper.valid()


def test_strided_prediction_matches_exact_prediction(tunnel):
    s = tunnel.sensor
    res = fit_scan(s.project(tunnel.points).ranges, s, s.max_range, FitConfig(), torch.device("cpu"))
    az, el = query_grid(s, 1)
    cols = slice(0, 3600, 7)  # exact prediction on a subset of columns, to keep the test fast
    exact_mean, exact_var = predict_grid(res.z, res.u, res.hyper, az[cols], el, 1, torch.device("cpu"))
    stride = auto_stride(res.hyper, az[1] - az[0])
    assert stride >= 4  # otherwise this test does not exercise the interpolation
    mean, var = predict_grid(res.z, res.u, res.hyper, az, el, stride, torch.device("cpu"))
    err = np.abs(mean[:, cols] - exact_mean)
    assert err.max() < 3e-3 and np.sqrt(np.mean(err**2)) < 5e-4
    assert np.abs(var[:, cols] - exact_var).max() < 0.01 * res.hyper.outputscale


def test_upsampled_decode_is_a_denser_superset(tunnel_f32):
    from scipy.spatial import cKDTree

    plain = tunnel_f32[1]
    pts = VSGPCodec(device="cpu", upsample=2).decode(tunnel_f32[0])
    assert len(pts) > 1.8 * len(plain)  # azimuth doubles; between-beam rows are mostly judged uncertain
    dist, _ = cKDTree(pts).query(plain)
    assert np.percentile(dist, 99) < 0.002


@pytest.mark.slow
def test_lwbench_run_stores_vsgp_rows(tmp_path):
    from typer.testing import CliRunner

    from lwbench.cli import app

    seq = tmp_path / "seq"
    (seq / "velodyne").mkdir(parents=True)
    for i in range(2):
        frame = tunnel_scan(seed=10 + i)
        xyzi = np.hstack([frame.points, np.zeros((len(frame), 1), np.float32)])
        xyzi.astype(np.float32).tofile(seq / "velodyne" / f"{i:06d}.bin")
    (seq / "sensor.json").write_text(json.dumps(get_sensor("vlp16").to_dict()))
    store = tmp_path / "r.sqlite"
    runner = CliRunner()
    res = runner.invoke(app, ["run", "--dataset", str(seq), "--codec", "vsgp", "--param", "vsgp.body=float16",
                              "--store", str(store)], catch_exceptions=False)
    assert res.exit_code == 0, res.output
    rows = json.loads(runner.invoke(app, ["leaderboard", "--store", str(store), "--format", "json"]).stdout)
    (row,) = [r for r in rows if r["codec"] == "vsgp"]
    assert row["frames"] == 2 and row["failures"] == 0
    assert row["params"]["body"] == "float16"
    assert row["coverage"] > 0.95 and row["range_rmsd"] < 0.08
