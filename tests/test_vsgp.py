"""VSGP codec: round trips on analytic scenes, tiles and seams, the firing-anchored grid, the
variance filter, the wire format and its bounds, the GP math, warm starts and byte budgets."""

from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest
import torch
from _scans import rotated
from lwbench_plugins.vsgp import VSGPCodec
from lwbench_plugins.vsgp.decoder import WORK_BUDGET, DecodeConfig, plan_decode, reconstruct
from lwbench_plugins.vsgp.encoder import FitConfig, fit_scan
from lwbench_plugins.vsgp.gp import Hyper, collapsed_bound, rq_cross
from lwbench_plugins.vsgp.grid import Tiling, project_anchored
from lwbench_plugins.vsgp.wire import body_size, pack_body, unpack_body

from lwbench import Frame, Payload, PayloadError, SensorModel, get_sensor
from lwbench.testing import check_frames, cylinder_scan, room_scan, tunnel_scan

CPU = torch.device("cpu")


def range_scores(frame: Frame, points: np.ndarray) -> tuple[float, float, float]:
    """(RMSD m over cells both have, coverage, false returns) on the scan's own grid."""
    a = project_anchored(frame.points, frame.sensor)[0].ranges
    b = project_anchored(points, frame.sensor)[0].ranges
    both = (a > 0) & (b > 0)
    rmsd = float(np.sqrt(np.mean((a[both] - b[both]) ** 2)))
    return rmsd, both.sum() / (a > 0).sum(), ((b > 0) & ~(a > 0)).sum() / max(1, (b > 0).sum())


def coverage(frame: Frame, points: np.ndarray) -> float:
    """lwbench's own coverage metric (returns paired by direction)."""
    from lwbench_metrics.ranges import RangeMetric

    from lwbench import CodecKind, Evaluation

    ev = Evaluation(frame, b"", np.asarray(points, np.float32), CodecKind.REPRESENTATION, {})
    return float(RangeMetric().compute(ev)["coverage"] or 0.0)




def round_trip(frame: Frame, **params) -> tuple[bytes, np.ndarray]:
    data = VSGPCodec(device="cpu", **params).encode(frame)
    decoder = VSGPCodec(device="cpu", **{k: v for k, v in params.items() if k in _DECODER_PARAMS})
    return data, decoder.use_sensors([frame.sensor]).decode(data)


_DECODER_PARAMS = {"k_m", "k_std", "v_floor", "upsample", "stride", "threads"}


@pytest.fixture(scope="module")
def tunnel() -> Frame:
    return tunnel_scan(seed=3)


@pytest.fixture(scope="module")
def tunnel_default(tunnel) -> tuple[bytes, np.ndarray]:
    return round_trip(tunnel)


# -- round trips ---------------------------------------------------------------------------------
@pytest.mark.parametrize("tile_points", [128, 0])
def test_cylinder_wall_round_trip_within_2mm(tile_points):
    frame = cylinder_scan(radius=4.0)
    _, pts = round_trip(frame, tile_points=tile_points)
    rmsd, cov, false = range_scores(frame, pts)
    assert rmsd < 0.002
    assert cov > 0.99
    assert false == 0.0


def test_tunnel_round_trip_accuracy_and_ratio(tunnel, tunnel_default):
    data, pts = tunnel_default
    rmsd, cov, false = range_scores(tunnel, pts)
    assert rmsd < 0.06
    assert cov > 0.99
    assert false < 0.05
    assert tunnel.raw_bytes / len(data) > 100  # the compression target


@pytest.mark.heavy
def test_the_paper_mode_is_one_gp_over_every_cell_with_learned_hyper_parameters(tunnel):
    codec = VSGPCodec(device="cpu", mode="paper", num_inducing=200)
    res = fit_scan(tunnel.points, tunnel.sensor, codec.fit_config(), CPU)
    assert res.body.tiling.n_tiles == 1 and res.steps_run >= 1
    assert all(t.offset == 0.0 for t in res.body.tiles) and res.body.transform == "linear"
    _, pts = round_trip(tunnel, mode="paper", num_inducing=200)
    rmsd, cov, _ = range_scores(tunnel, pts)
    assert rmsd < 0.35 and cov > 0.95  # learning steps do not improve it (docs/vsgp.md)


def test_more_inducing_points_give_a_smaller_error(tunnel):
    """The paper's Table I shape: RMSD falls with M."""
    errors = [range_scores(tunnel, round_trip(tunnel, num_inducing=m)[1])[0] for m in (150, 300, 600)]
    assert errors[0] > errors[1] > errors[2]


@pytest.mark.heavy
def test_inverse_occupancy_fits_far_planes_better():
    """A plane's inverse range is a smooth function of direction, its range is not: on the far
    walls of a big room the inverse transform errs less than the linear one."""
    frame = room_scan(get_sensor("hdl64e"), seed=2, half_extent=(40.0, 25.0, 4.0), noise=0.0)
    linear = range_scores(frame, round_trip(frame, num_inducing=3000)[1])
    inverse = range_scores(frame, round_trip(frame, transform="inverse", num_inducing=3000)[1])
    assert inverse[0] < 0.7 * linear[0] and inverse[0] < 0.1
    assert inverse[1] > 0.9


# -- tiles and seams ---------------------------------------------------------------------------
def test_tiling_follows_the_sensor_and_m():
    assert Tiling.plan(get_sensor("vlp16"), 500, 128) == Tiling(16, 3600, 1, 4)
    assert Tiling.plan(get_sensor("hdl64e"), 12000, 128).n_bands == 4
    assert Tiling.plan(get_sensor("os1-128"), 4000, 128).n_bands == 8
    assert Tiling.plan(get_sensor("vlp16"), 500, 0).n_tiles == 1


def test_seams_are_invisible_on_a_smooth_wall():
    """A cylinder decoded by 4 local GPs: no seam shows (every column within 3 mm, all kept)."""
    frame = cylinder_scan(radius=4.0)
    data, pts = round_trip(frame, num_inducing=512, tile_points=128)
    body = unpack_body("float32", Payload.from_bytes(data).body, 16, 3600)
    assert body.tiling.n_sectors == 4
    a = project_anchored(frame.points, frame.sensor)[0].ranges
    b = project_anchored(pts, frame.sensor)[0].ranges
    assert (b > 0).sum() >= 0.995 * (a > 0).sum()
    both = (a > 0) & (b > 0)
    assert np.abs(a - b)[both].max() < 0.003


def test_local_and_global_gps_agree_on_the_tunnel(tunnel, tunnel_default):
    _, glob = round_trip(tunnel, tile_points=0)
    local = range_scores(tunnel, tunnel_default[1])
    assert abs(local[0] - range_scores(tunnel, glob)[0]) < 0.015


# -- the firing-anchored grid (issue 25) ------------------------------------------------------
def _anchor_frames() -> dict[str, Frame]:
    sim = _sim_frame()
    kit = check_frames()
    return {"room": kit["room"], "hdl32-ring": kit["hdl32-ring"], "tunnel": tunnel_scan(seed=5), "sim": sim}


def _sim_frame() -> Frame:
    from lwbench.registry import get_registry

    return get_registry().dataset("sim")(scene="tunnel", frames=1)[0]


@pytest.mark.heavy
@pytest.mark.parametrize("name", ["room", "hdl32-ring", "tunnel", "sim"])
def test_rotating_a_scan_by_a_fraction_of_a_step_moves_coverage_by_at_most_001(name):
    frame = _anchor_frames()[name]
    step = frame.sensor.azimuth_step_rad
    covs = [
        coverage(f, round_trip(f, num_inducing=400)[1])
        for f in (rotated(frame, k * step) for k in (0.0, 0.13, 0.25, 0.5, 0.77))
    ]
    assert max(covs) - min(covs) <= 0.01, covs
    assert min(covs) > 0.8, covs


def test_beam_phases_follow_the_firings():
    sensor = get_sensor("vlp16")
    frame = room_scan(sensor, seed=4)
    _, codes = project_anchored(frame.points, sensor)
    _, shifted = project_anchored(rotated(frame, 0.3 * sensor.azimuth_step_rad).points, sensor)
    moved = ((shifted.astype(int) - codes.astype(int)) % 256) / 256
    assert np.allclose(moved, 0.3, atol=2 / 256)


# -- every payload decodes; the decoder's bounds ------------------------------------------------
VARIANTS = [
    {},
    {"body": "q16z"},
    {"body": "float16"},
    {"body": "q16"},
    {"transform": "inverse"},
    {"center": False},
    {"tile_points": 0},
    {"num_inducing": 2000},
    {"mode": "paper", "num_inducing": 100},
    {"residual": 0.2},
    {"residual": 0.05, "body": "q16z", "transform": "inverse"},
    {"residual": 0.5, "predictor": "none"},
]


@pytest.mark.heavy
@pytest.mark.parametrize("variant", VARIANTS, ids=[json.dumps(v) for v in VARIANTS])
def test_every_payload_vsgp_writes_on_the_kits_scans_decodes(variant):
    scans = {
        **check_frames(),
        "tunnel": tunnel_scan(seed=1),
        "one": Frame(np.array([[3.0, 1.0, 0.2]], np.float32), get_sensor("vlp16")),
    }
    for label, frame in scans.items():
        data = VSGPCodec(device="cpu", **variant).encode(frame)
        pts = VSGPCodec(device="cpu").use_sensors([frame.sensor]).decode(data)
        assert pts.dtype == np.float32 and np.isfinite(pts).all(), label
        # float32 points: a return decoded at exactly the max range may round a hair past it
        assert len(pts) == 0 or np.linalg.norm(pts, axis=1).max() <= frame.sensor.max_range * (1 + 1e-6), label


def test_a_rotating_2d_laser_gets_a_decodable_payload():
    """1 beam, 0.03 deg steps (12,000 columns): the decode grid adapts to the work bound
    instead of refusing every payload (issue 25)."""
    sensor = SensorModel("laser2d", (0.0,), 0.03, 0.1, 30.0, 40.0)
    frame = room_scan(sensor, seed=3, half_extent=(6.0, 4.0, 1.2))
    data = VSGPCodec(device="cpu", num_inducing=2000).encode(frame)
    pts = VSGPCodec(device="cpu").use_sensors([sensor]).decode(data)
    assert coverage(frame, pts) > 0.9


def test_the_encoder_refuses_what_its_decoder_would_refuse(tunnel):
    codec = VSGPCodec(device="cpu", tile_points=0, num_inducing=2049)
    with pytest.raises(ValueError, match="tile_points"):
        codec.encode(tunnel)


def test_decode_work_is_counted_and_bounded(tunnel, tunnel_default):
    body = unpack_body("float32", Payload.from_bytes(tunnel_default[0]).body, 16, 3600)
    plan = plan_decode(body, tunnel.sensor, DecodeConfig())
    assert 0 < plan.work <= WORK_BUDGET
    with pytest.raises(PayloadError, match="evaluations"):  # every column exactly: over the bound
        plan_decode(body, tunnel.sensor, DecodeConfig(stride=1, upsample=8))


def test_decoded_points_never_leave_the_sensors_reach(tunnel, tunnel_default):
    """A crafted offset (an occupancy far below zero) would put points 1e5 m away: they are
    not decoded (the range window is the sensor's)."""
    body = unpack_body("float32", Payload.from_bytes(tunnel_default[0]).body, 16, 3600)
    for t in body.tiles:
        t.offset = -1e5
    pts = reconstruct(body, tunnel.sensor, DecodeConfig(), CPU)
    assert len(pts) == 0 or np.linalg.norm(pts, axis=1).max() <= tunnel.sensor.max_range


@pytest.mark.parametrize("body", ["float32", "float16", "q16"])
def test_payload_size_equals_formula(tunnel, body):
    data = VSGPCodec(device="cpu", body=body, num_inducing=300).encode(tunnel)
    payload = Payload.from_bytes(data)
    parsed = unpack_body(body, payload.body, 16, 3600)
    assert parsed.num_inducing == 300
    per_point = {"float32": 7, "float16": 5, "q16": 5}[body]
    per_tile = 26 + (8 if body == "q16" else 0)
    assert len(payload.body) == body_size(body, 16, parsed.tiling.n_tiles, 300)
    assert len(payload.body) == 8 + 16 + per_tile * parsed.tiling.n_tiles + per_point * 300


def test_q16z_is_smaller_than_q16(tunnel):
    q16 = VSGPCodec(device="cpu", body="q16").encode(tunnel)
    q16z = VSGPCodec(device="cpu", body="q16z").encode(tunnel)
    assert len(q16z) < 0.9 * len(q16)  # the entropy coder pays for itself


@pytest.mark.parametrize(("body", "extra_mm"), [("float16", 3.0), ("q16", 1.0), ("q16z", 1.0)])
def test_compact_bodies_decode_within_stated_extra_error(tunnel, tunnel_default, body, extra_mm):
    base = range_scores(tunnel, tunnel_default[1])[0]
    rmsd, cov, _ = range_scores(tunnel, round_trip(tunnel, body=body)[1])
    assert rmsd - base < extra_mm / 1000
    assert cov > 0.99


def test_body_round_trips_exactly(tunnel):
    res = fit_scan(tunnel.points, tunnel.sensor, FitConfig(), CPU)
    again = unpack_body("float32", pack_body("float32", res.body), 16, 3600)
    assert again.tiling == res.body.tiling and np.array_equal(again.phase_codes, res.body.phase_codes)
    for a, b in zip(again.tiles, res.body.tiles, strict=True):
        assert np.array_equal(a.az_code, b.az_code) and np.array_equal(a.beam, b.beam)
        assert np.allclose(a.value, b.value, rtol=1e-6) and a.hyper == b.hyper


def test_encoding_is_deterministic(tunnel, tunnel_default):
    assert VSGPCodec(device="cpu").encode(tunnel) == tunnel_default[0]


def _replace_body(data: bytes, body: bytes, meta: dict | None = None) -> bytes:
    p = Payload.from_bytes(data)
    return Payload(p.codec_id, meta if meta is not None else p.meta, body, p.pose).to_bytes()


def test_corrupt_payloads_raise_payload_error(tunnel_default):
    data = tunnel_default[0]
    codec = VSGPCodec(device="cpu")
    body = Payload.from_bytes(data).body
    flipped = bytearray(data)
    flipped[len(data) // 2] ^= 0x10
    tile0 = 8 + 16
    bad_hyper = bytearray(body)
    struct.pack_into("<f", bad_hyper, tile0 + 2, -1.0)  # negative lengthscale
    many = bytearray(body)
    struct.pack_into("<H", many, tile0, 2049)  # a tile's M beyond the bound
    sectors = bytearray(body)
    struct.pack_into("<H", sectors, 2, 60000)  # more sectors than the sensor has columns for
    m = unpack_body("float32", body, 16, 3600).num_inducing
    beam = bytearray(body)
    beam[len(body) - 5 * m] = 200  # the first inducing point on beam 200 of 16 (planes: az u16, beam u8, f32)
    cases = [
        data[:-7],
        bytes(flipped),
        _replace_body(data, body[:-4]),
        _replace_body(data, body + b"\0" * 7),
        _replace_body(data, bytes(bad_hyper)),
        _replace_body(data, bytes(many)),
        _replace_body(data, bytes(sectors)),
        _replace_body(data, bytes(beam)),
        _replace_body(data, b"\x07" + body[1:]),
        _replace_body(data, body, {"body": "float64", "sensor": {"preset": "vlp16"}}),
        _replace_body(data, body, {"body": "float32"}),
        _replace_body(data, body, {"body": "float32", "sensor": {"preset": "nope"}}),
        Payload("raw", {}, b"", None).to_bytes(),
    ]
    for bad in cases:
        with pytest.raises(PayloadError):
            codec.decode(bad)


def test_corrupt_compressed_body_raises(tunnel):
    data = VSGPCodec(device="cpu", body="q16z").encode(tunnel)
    body = bytearray(Payload.from_bytes(data).body)
    body[20] ^= 0xFF
    with pytest.raises(PayloadError):
        VSGPCodec(device="cpu").decode(_replace_body(data, bytes(body)))
    declared = struct.pack("<I", 1 << 30) + bytes(body[4:])
    with pytest.raises(PayloadError, match="declares"):
        VSGPCodec(device="cpu").decode(_replace_body(data, declared))


def test_empty_and_tiny_scans():
    sensor = get_sensor("vlp16")
    empty = Frame(np.zeros((0, 3), np.float32), sensor)
    assert VSGPCodec(device="cpu").use_sensors([sensor]).decode(VSGPCodec(device="cpu").encode(empty)).shape == (0, 3)
    few = cylinder_scan(radius=4.0).subset(np.arange(0, 57600, 400))  # 144 points < M
    pts = VSGPCodec(device="cpu").use_sensors([sensor]).decode(VSGPCodec(device="cpu").encode(few))
    assert pts.ndim == 2 and pts.shape[1] == 3


# -- byte budgets, warm starts, threads -----------------------------------------------------------
@pytest.mark.parametrize("body", ["float32", "q16z"])
def test_a_byte_budget_is_met_and_used(tunnel, body):
    data = VSGPCodec(device="cpu", body=body, bytes=2500).encode(tunnel)
    assert 0.85 * 2500 <= len(data) <= 2500


def test_a_byte_budget_below_the_fixed_size_is_refused(tunnel):
    with pytest.raises(ValueError, match="bytes"):
        VSGPCodec(device="cpu", bytes=64).encode(tunnel)


@pytest.mark.heavy
def test_warm_start_stops_sooner_and_every_payload_decodes_alone():
    frames = [tunnel_scan(seed=20, noise=0.01 + 0.001 * i) for i in range(3)]
    params = {"mode": "paper", "num_inducing": 150, "steps": 20, "tol": 1e-3}
    cold = VSGPCodec(device="cpu", **params)
    warm = VSGPCodec(device="cpu", warm_start=True, **params)
    cold_steps, warm_steps = [], []
    for f in frames:
        cold.encode(f)
        cold_steps.append(cold.last_timings["steps_run"])
        data = warm.encode(f)
        warm_steps.append(warm.last_timings["steps_run"])
        assert len(VSGPCodec(device="cpu").use_sensors([f.sensor]).decode(data)) > 0.9 * len(f)
    assert warm_steps[0] == cold_steps[0]  # the first frame has no state yet
    assert sum(warm_steps[1:]) < sum(cold_steps[1:])
    # The default keeps each payload a function of its frame only.
    assert VSGPCodec(device="cpu").encode(frames[2]) == VSGPCodec(device="cpu").encode(frames[2])


def test_threads_are_restored():
    old = torch.get_num_threads()
    VSGPCodec(device="cpu", threads=1).encode(cylinder_scan(radius=4.0))
    assert torch.get_num_threads() == old


# -- the variance filter and the decoder's interpolation -------------------------------------------
@pytest.mark.parametrize("tile_points", [128, 0])
def test_variance_filter_removes_the_free_half(tile_points):
    frame = cylinder_scan(radius=4.0, half=True)  # returns only for azimuth in [0, pi)
    data, pts = round_trip(frame, tile_points=tile_points)
    az = np.arctan2(pts[:, 1], pts[:, 0])
    assert np.mean(az < -0.2) < 0.01  # cells within a lengthscale of the edge may survive
    rmsd, cov, _ = range_scores(frame, pts)
    assert cov > 0.95 and rmsd < 0.02
    if tile_points == 0:  # one GP: its prior mean (the mean occupancy) fills the free half ...
        unfiltered = VSGPCodec(device="cpu", k_m=100.0).use_sensors([frame.sensor]).decode(data)  # ... unfiltered
        assert np.mean(np.arctan2(unfiltered[:, 1], unfiltered[:, 0]) < -0.2) > 0.2


def test_strided_prediction_matches_exact_prediction(tunnel, tunnel_default):
    body = unpack_body("float32", Payload.from_bytes(tunnel_default[0]).body, 16, 3600)
    plan = plan_decode(body, tunnel.sensor, DecodeConfig())
    assert min(plan.strides) >= 4  # otherwise this test does not exercise the interpolation
    a = project_anchored(reconstruct(body, tunnel.sensor, DecodeConfig(), CPU), tunnel.sensor)[0].ranges
    b = project_anchored(reconstruct(body, tunnel.sensor, DecodeConfig(stride=1), CPU), tunnel.sensor)[0].ranges
    both = (a > 0) & (b > 0)
    err = np.abs(a - b)[both]
    assert err.max() < 3e-3 and np.sqrt(np.mean(err**2)) < 5e-4
    assert abs(int((a > 0).sum()) - int((b > 0).sum())) < 0.002 * (b > 0).sum()


def test_upsampled_decode_is_a_denser_superset(tunnel_default):
    from scipy.spatial import cKDTree

    plain = tunnel_default[1]
    pts = VSGPCodec(device="cpu", upsample=2).decode(tunnel_default[0])
    assert len(pts) > 1.8 * len(plain)  # azimuth doubles; between-beam rows are mostly judged uncertain
    dist, _ = cKDTree(pts).query(plain)
    assert np.percentile(dist, 99) < 0.002


# -- the GP maths ------------------------------------------------------------------------------
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

    with torch.no_grad():
        ref = kernel(embed(x1), embed(x2)).to_dense()
    for alpha in (0.7, 1.0):  # 1.0 takes the reciprocal path
        kernel.base_kernel.alpha = torch.tensor(alpha)
        with torch.no_grad():
            ref = kernel(embed(x1), embed(x2)).to_dense()
        torch.testing.assert_close(rq_cross(x1, x2, Hyper(0.3, 0.05, alpha, 4.0, 0.01)), ref, rtol=1e-6, atol=1e-9)
    seam = rq_cross(
        torch.tensor([[math.pi - 0.01, 0.0]]), torch.tensor([[-math.pi + 0.01, 0.0]]), Hyper(0.3, 0.05, 0.7, 4.0, 0.01)
    )
    assert float(seam) > 3.9  # neighbours across the seam are neighbours


def test_separable_tables_equal_the_direct_kernel():
    from lwbench_plugins.vsgp.gp import KernelTables

    gen = torch.Generator().manual_seed(2)
    az = torch.linspace(-3.0, 3.0, 50, dtype=torch.float64)
    el = torch.linspace(-0.2, 0.2, 7, dtype=torch.float64)
    z = torch.stack(
        [torch.rand(20, generator=gen, dtype=torch.float64) * 6 - 3, el[torch.randint(0, 7, (20,), generator=gen)]], 1
    )
    h = Hyper(0.4, 0.07, 1.0, 2.0, 0.01)
    grid = KernelTables(az, el, z, h).grid()
    x = torch.stack(torch.meshgrid(az, el, indexing="xy"), -1).reshape(-1, 2)  # (el-major rows)
    direct = rq_cross(x, z, h).reshape(len(el), len(az), -1)
    torch.testing.assert_close(grid, direct, rtol=1e-12, atol=1e-12)


def test_collapsed_bound_is_a_lower_bound_and_tight_when_z_equals_x():
    gen = torch.Generator().manual_seed(1)
    x = torch.rand(60, 2, generator=gen, dtype=torch.float64)
    y = torch.sin(6 * x[:, 0]) + 0.1 * torch.randn(60, generator=gen, dtype=torch.float64)
    h = Hyper(0.3, 0.3, 1.5, 1.0, 0.05)
    knn = rq_cross(x, x, h)
    cov = knn + h.noise * torch.eye(60, dtype=torch.float64)
    exact = torch.distributions.MultivariateNormal(torch.zeros(60, dtype=torch.float64), cov).log_prob(y) / 60

    def bound(z: torch.Tensor) -> float:
        return float(
            collapsed_bound(rq_cross(z, z, h), rq_cross(z, x, h), y, torch.tensor(h.outputscale), torch.tensor(h.noise))
        )

    assert bound(x[::6]) < float(exact)
    assert bound(x[::6]) < bound(x[::2]) < float(exact) + 1e-6
    assert bound(x) == pytest.approx(float(exact), abs=1e-4)


@pytest.mark.heavy
def test_refinement_steps_never_return_a_worse_bound(tunnel):
    res = fit_scan(tunnel.points, tunnel.sensor, FitConfig(steps=3, subsample=512, tile_points=0), CPU)
    assert 1 <= len(res.bounds) <= 4
    assert max(res.bounds) >= res.bounds[0]
    assert Hyper(*res.body.tiles[0].hyper).valid()


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
    res = runner.invoke(
        app,
        ["run", "--dataset", str(seq), "--codec", "vsgp", "--param", "vsgp.body=float16", "--store", str(store)],
        catch_exceptions=False,
    )
    assert res.exit_code == 0, res.output
    rows = json.loads(runner.invoke(app, ["leaderboard", "--store", str(store), "--format", "json"]).stdout)
    (row,) = [r for r in rows if r["codec"] == "vsgp"]
    assert row["frames"] == 2 and row["failures"] == 0
    assert row["params"]["body"] == "float16"
    assert row["coverage"] > 0.95 and row["range_rmsd"] < 0.08


@pytest.mark.slow
def test_every_payload_vsgp_writes_on_the_real_samples_decodes(real_data):
    """Issue 25: the first frame of every shared real folder, at the defaults and at a byte
    budget, decodes with a fresh decoder (the encoder checks its decoder's bound first)."""
    from lwbench.registry import get_registry
    from lwbench.run import resolve_dataset

    reg = get_registry()
    folders = sorted(p for p in real_data.iterdir() if p.is_dir())
    assert folders
    for folder in folders:
        frame = resolve_dataset(reg, str(folder), {}, 0).build(reg)[0]
        for params in ({}, {"body": "q16z", "bytes": 50_000}, {"body": "q16z", "residual": 0.5}):
            data = VSGPCodec(device="cpu", **params).encode(frame)
            pts = VSGPCodec(device="cpu").use_sensors([frame.sensor]).decode(data)
            assert len(pts) > 0.3 * len(frame), (folder.name, params)
