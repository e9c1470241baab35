"""Each core metric against a case computed by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from lwbench_metrics import GeometryMetric, RangeMetric, RuntimeMetric, SizeMetric

from lwbench import CodecKind, Evaluation, Frame, get_sensor
from lwbench.registry import get_registry
from lwbench.testing import room_scan


def _ev(frame: Frame, decoded: np.ndarray, payload: bytes = b"x" * 100, **kw) -> Evaluation:
    return Evaluation(frame, payload, np.asarray(decoded, np.float32), CodecKind.REPRESENTATION,
                      kw.get("timings", {"encode_ms": 2.0, "decode_ms": 1.0}), kw.get("peak_mb"))


def test_size_metrics(tiny_sensor):
    frame = Frame(np.ones((50, 3), np.float32), tiny_sensor)
    m = SizeMetric().compute(_ev(frame, np.ones((20, 3)), b"x" * 120))
    assert m["bytes"] == 120
    assert m["ratio"] == pytest.approx(600 / 120)
    assert m["bits_per_point"] == pytest.approx(8 * 120 / 50)
    assert m["link_kbps"] == pytest.approx(120 * 10 / 1000)  # 10 Hz sensor
    assert (m["points_in"], m["points_out"]) == (50, 20)


def test_range_rmsd_coverage_and_false_returns(tiny_sensor):
    dirs = tiny_sensor.ray_directions()
    # Original: 4 returns at 10 m in cells (0,0) (0,1) (1,0) (1,1).
    cells_p = [(0, 0), (0, 1), (1, 0), (1, 1)]
    p = np.array([dirs[c] * 10.0 for c in cells_p])
    # Decoded: 3 of them at 10.3, 9.6, 10.0 m and one return in an empty cell (3,5).
    q = np.array([dirs[0, 0] * 10.3, dirs[0, 1] * 9.6, dirs[1, 0] * 10.0, dirs[3, 5] * 4.0])
    m = RangeMetric().compute(_ev(Frame(p.astype(np.float32), tiny_sensor), q))
    assert m["range_rmsd"] == pytest.approx(math.sqrt((0.3**2 + 0.4**2 + 0) / 3), rel=1e-5)
    assert m["coverage"] == pytest.approx(3 / 4)
    assert m["false_returns"] == pytest.approx(1 / 4)


def test_range_metrics_of_an_empty_decode_are_undefined_not_nan(tiny_sensor):
    p = tiny_sensor.ray_directions()[0, :3] * 5.0
    m = RangeMetric().compute(_ev(Frame(p.astype(np.float32), tiny_sensor), np.zeros((0, 3))))
    assert m == {"range_rmsd": None, "range_median": None, "coverage": 0.0, "false_returns": None}


def _rotate_z(points: np.ndarray, angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return (np.asarray(points, np.float64) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T).astype(np.float32)


def _lossy(frame: Frame, seed: int = 1) -> np.ndarray:
    """A decoded cloud with every kind of damage: range noise, 20 % dropped, 5 % outliers."""
    rng = np.random.default_rng(seed)
    p = frame.points.astype(np.float64)
    keep = rng.random(len(p)) > 0.2
    q = p[keep] * (1 + rng.normal(0, 0.01, (keep.sum(), 1)))
    outliers = rng.uniform(-2, 2, (len(p) // 20, 3))
    return np.concatenate([q, outliers]).astype(np.float32)


def _grid_decode(frame: Frame) -> np.ndarray:
    """What a range-image codec does: one return per cell, put back on the cell's centre ray."""
    return frame.sensor.unproject(frame.sensor.project(frame.points).ranges)


@pytest.mark.heavy
@pytest.mark.parametrize("decode", [_lossy, _grid_decode], ids=["lossy", "grid"])
@pytest.mark.parametrize("fraction", [0.1, 0.25, 0.5, 0.77, 13.5])
def test_rotating_both_clouds_together_changes_nothing(decode, fraction):
    frame = room_scan(get_sensor("vlp16"), seed=3)
    q = decode(frame)
    base = RangeMetric().compute(_ev(frame, q))
    angle = fraction * frame.sensor.azimuth_step_rad
    turned = Frame(_rotate_z(frame.points, angle), frame.sensor)
    moved = RangeMetric().compute(_ev(turned, _rotate_z(q, angle)))
    for key in ("range_rmsd", "coverage", "false_returns"):
        assert moved[key] == pytest.approx(base[key], rel=0.01, abs=1e-4), key


@pytest.mark.heavy
@pytest.mark.parametrize("fraction", [0.0, 0.25, 0.5, 0.75])
def test_a_grid_codec_is_scored_the_same_wherever_the_scan_sits_on_its_grid(fraction):
    # Rotate the *input* by a fraction of a cell: a grid codec's output moves relative to the
    # returns, but it still has one return per direction window; coverage must not see cell edges.
    sensor = get_sensor("vlp16")
    frame = room_scan(sensor, seed=5)
    turned = Frame(_rotate_z(frame.points, fraction * sensor.azimuth_step_rad), sensor)
    m = RangeMetric().compute(_ev(turned, _grid_decode(turned)))
    assert m["coverage"] > 0.97 and m["false_returns"] < 0.01
    assert m["range_rmsd"] < 0.05


def test_every_selection_codec_scores_range_rmsd_exactly_zero():
    frame = room_scan(get_sensor("vlp16"), seed=7, dropout=0.05)
    reg = get_registry()
    # A codec that `needs` more than a scan (the oracle: labels for the sequence) is tested in its own tests.
    selectors = [c for c in reg.codecs.values() if c.kind.value == "selection" and not c.needs]
    assert len(selectors) >= 5
    for cls in selectors:
        codec = cls()
        q = codec.decode(codec.encode(frame))
        m = RangeMetric().compute(_ev(frame, q))
        assert m["range_rmsd"] == 0.0, cls.name
        assert m["false_returns"] == 0.0, cls.name
        assert m["coverage"] == pytest.approx(len(q) / len(frame), abs=1e-9), cls.name


def test_dropping_half_the_returns_covers_half():
    frame = room_scan(get_sensor("hdl64e"), seed=2)
    q = frame.points[::2]
    m = RangeMetric().compute(_ev(frame, q))
    assert m["coverage"] == pytest.approx(0.5, abs=0.005)
    assert m["range_rmsd"] == 0.0 and m["false_returns"] == 0.0


def test_tolerance_is_a_parameter_in_units_of_the_spacing(tiny_sensor):
    dirs = tiny_sensor.ray_directions()
    p = np.array([dirs[1, 2] * 10.0])
    # Decoded: the same beam, 0.3 of an azimuth step away.
    az = -math.pi + 2.8 * tiny_sensor.azimuth_step_rad
    el = tiny_sensor.elevations_rad[1]
    q = np.array([[math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)]]) * 10.0
    frame = Frame(p.astype(np.float32), tiny_sensor)
    assert RangeMetric().compute(_ev(frame, q))["coverage"] == 1.0
    assert RangeMetric(tolerance=0.2).compute(_ev(frame, q))["coverage"] == 0.0


def test_chamfer_hausdorff_and_d1_psnr_by_hand(tiny_sensor):
    # P: two points; Q: P shifted by 0.1 m in x, plus one outlier 1 m from P[1].
    p = np.array([[0, 0, 0], [5, 0, 0]], np.float32)
    q = np.array([[0.1, 0, 0], [5.1, 0, 0], [5, 1, 0]], np.float32)
    m = GeometryMetric(peak=10.0).compute(_ev(Frame(p, tiny_sensor), q))
    d_pq = [0.1, 0.1]
    d_qp = [0.1, 0.1, 1.0]
    assert m["chamfer"] == pytest.approx((np.mean(d_pq) + np.mean(d_qp)) / 2, rel=1e-5)
    assert m["hausdorff"] == pytest.approx(1.0, rel=1e-6)
    mse_worse = np.mean(np.square(d_qp))
    assert m["d1_psnr"] == pytest.approx(10 * math.log10(3 * 100 / mse_worse), rel=1e-4)


def test_d2_ignores_error_along_the_surface():
    # A dense plane z=0; the decoded cloud slides every point 2 cm along the plane.
    xs, ys = np.meshgrid(np.linspace(-5, 5, 101), np.linspace(-5, 5, 101))
    p = np.column_stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)]).astype(np.float32)
    from lwbench import get_sensor

    m = GeometryMetric().compute(_ev(Frame(p, get_sensor("vlp16")), p + [0.02, 0, 0]))
    assert m["d2_psnr"] > m["d1_psnr"] + 20


def test_lossless_decode_has_infinite_psnr_and_zero_distance(vlp16_frame):
    m = GeometryMetric().compute(_ev(vlp16_frame, vlp16_frame.points))
    assert m["chamfer"] == 0 and m["hausdorff"] == 0
    assert math.isinf(m["d1_psnr"]) and math.isinf(m["d2_psnr"])


def test_runtime_metric_reports_what_the_runner_measured(tiny_sensor):
    f = Frame(np.ones((3, 3), np.float32), tiny_sensor)
    m = RuntimeMetric().compute(_ev(f, f.points, timings={"encode_ms": 5.0, "decode_ms": 2.0}, peak_mb=3.5))
    assert m == {"encode_ms": 5.0, "decode_ms": 2.0, "select_ms": None, "peak_mb": 3.5}


def _two_returns_per_window(sensor, seed=0):
    """A scan where every direction window holds two returns at very different ranges -- what
    real scans have at depth edges and at short range (laser origins off the axis)."""
    base = room_scan(sensor, seed=seed, noise=0.0)
    r = np.linalg.norm(base.points, axis=1, keepdims=True)
    rng = np.random.default_rng(seed)
    # A second return 0.1 spacing away in azimuth and 2-8 m further out.
    step = sensor.azimuth_step_rad * 0.1
    c, s = math.cos(step), math.sin(step)
    turned = base.points.astype(np.float64) @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]).T
    far = turned / r * (r + rng.uniform(2, 8, r.shape))
    pts = np.concatenate([base.points, far]).astype(np.float32)
    return Frame(pts, sensor)


def test_a_faithful_codec_is_not_charged_for_returns_that_share_a_window():
    frame = _two_returns_per_window(get_sensor("vlp16"))
    # 0.2 mm of noise: well inside every window (at 1.2 m, half a 0.1-degree step is 1 mm).
    q = frame.points + np.random.default_rng(1).normal(0, 0.0002, frame.points.shape).astype(np.float32)
    m = RangeMetric().compute(_ev(frame, q))
    assert m["coverage"] == 1.0 and m["range_rmsd"] < 0.001  # the noise, not the 2-8 m between returns


@pytest.mark.heavy
def test_one_decoded_return_where_the_scan_had_two_covers_one():
    frame = _two_returns_per_window(get_sensor("vlp16"))
    near_only = frame.points[: len(frame) // 2]
    m = RangeMetric().compute(_ev(frame, near_only))
    assert m["coverage"] == pytest.approx(0.5) and m["range_rmsd"] == 0.0
    # Every selection codec too keeps its points' own ranges, whatever shares a window.
    for cls in [c for c in get_registry().codecs.values() if c.kind.value == "selection" and not c.needs]:
        kept = cls().decode(cls().encode(frame))
        assert RangeMetric().compute(_ev(frame, kept))["range_rmsd"] == 0.0, cls.name
